/* The timing stage's arc length and its inversion (trajectory/timing.py), compiled.

   cn_arc_length_table: timing.arc_length_table (curve times tau [K] on the table grid, cumulative arc length s [K]
   by 5-point Gauss-Legendre per table interval, the speed at tau [K]). cn_invert_arc_length: timing.invert_arc_length
   with the table's speeds (the cubic Hermite start of _hermite_guess, then the safeguarded Newton steps, all points
   together: the same number of steps as numpy, which stops when the largest |step| of ALL points is <= tol).
   Every speed is BezierTrajectory.speed's: the point's segment and local parameter by segment_of's rules (clamped to
   [0, total], the later segment at a join, u = 1 at or past the end), Horner's rule on the power coefficients of p'
   in the same order, and the norm summed as numpy's einsum("tc,tc->t") sums 3 components on x86 (two SIMD lanes:
   (x*x + z*z) + y*y). The quadrature sum repeats OpenBLAS's dgemv (numpy's speed_q @ weights) on the AVX-512
   CPU box: fma(s4, w4, (s0 w0 + s2 w2) + (s1 w1 + s3 w3)), an explicit fma() (correctly rounded everywhere).
   Both orders were found by comparing with numpy 2.4 / scipy-openblas 0.3.31 there, where the two backends agree
   bit for bit; another numpy build or BLAS kernel may sum in another order, and the backends then agree to rounding
   (a few ulp per sum: all its terms are >= 0). Implicit contraction into fused multiply-adds would round differently
   from numpy: it is turned off. The derivation of the method is in timing.py's docstrings; this file only repeats
   its arithmetic. */
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

typedef struct {
    const double *coef;  /* [M, n1, 3] power coefficients of p' per segment (c_0 + c_1 u + ... ) */
    int64_t M, n1;
    const double *starts, *durations;  /* [M] */
    double total;
} curve_t;

/* np.clip(x, lo, hi) for a number x: minimum(maximum(x, lo), hi) */
static inline double clip(double x, double lo, double hi) {
    double y = x > lo ? x : lo;
    return y < hi ? y : hi;
}

/* np.searchsorted(a[:n], x, side="right"): how many of the sorted a are <= x */
static inline int64_t upper_bound(const double *a, int64_t n, double x) {
    int64_t lo = 0, hi = n;
    while (lo < hi) {
        int64_t mid = lo + (hi - lo) / 2;
        if (x < a[mid]) hi = mid;
        else lo = mid + 1;
    }
    return lo;
}

/* segment_of's segment of a clamped time tt: np.searchsorted(starts, tt, side="right") - 1 clipped to [0, M - 1].
   hint: a likely answer (the segment of a nearby time), used when starts[hint] <= tt < starts[hint + 1], which
   makes it the searchsorted answer; else the binary search. */
static inline int64_t segment_of(const curve_t *c, double tt, int64_t hint) {
    if (hint >= 0 && hint < c->M && c->starts[hint] <= tt && (hint == c->M - 1 || tt < c->starts[hint + 1]))
        return hint;
    int64_t k = upper_bound(c->starts, c->M, tt) - 1;
    return k < 0 ? 0 : (k > c->M - 1 ? c->M - 1 : k);
}

/* BezierTrajectory.speed at one time t: |p'(t)|; *hint: see segment_of (set to this time's segment) */
static double speed_at(const curve_t *c, double t, int64_t *hint) {
    double tt = clip(t, 0.0, c->total);
    int64_t k = segment_of(c, tt, *hint);
    *hint = k;
    double u = clip((tt - c->starts[k]) / c->durations[k], 0.0, 1.0);
    if (tt >= c->total) u = 1.0;  /* exact end point despite rounding of the cumulative sum */
    const double *q = c->coef + k * c->n1 * 3;
    int64_t n = c->n1 - 1;
    double x = q[3 * n], y = q[3 * n + 1], z = q[3 * n + 2];
    for (int64_t j = n - 1; j >= 0; j--) {
        x = x * u + q[3 * j];
        y = y * u + q[3 * j + 1];
        z = z * u + q[3 * j + 2];
    }
    return sqrt((x * x + z * z) + y * y);
}

/* speed_q @ weights for one row of 5 (see the header) */
static inline double gl5_sum(const double *sp, const double *w) {
    return fma(sp[4], w[4], (sp[0] * w[0] + sp[2] * w[2]) + (sp[1] * w[1] + sp[3] * w[3]));
}

/* arc length from lo to lo + 2 half past s_lo: s_lo + half * sum_m w_m |p'((lo + half) + half * node_m)| */
static inline double gl5_piece(const curve_t *c, double mid, double half, const double *nodes, const double *weights,
                               double s_lo, int64_t *hint) {
    double sp[5];
    for (int m = 0; m < 5; m++) sp[m] = speed_at(c, mid + half * nodes[m], hint);
    return s_lo + half * gl5_sum(sp, weights);
}

/* timing.arc_length_table: tau, s and (v != NULL) the speed at tau, each [M * S + 1]. Returns 0. */
int64_t cn_arc_length_table(const double *coef, int64_t M, int64_t n1, const double *starts, const double *durations,
                            double total, int64_t S, const double *nodes, const double *weights, double *tau,
                            double *s, double *v) {
    const curve_t c = {coef, M, n1, starts, durations, total};
    const double step = 1.0 / (double)S;  /* np.linspace(0, 1, S + 1)[i] = i * (1 / S) */
    const int64_t K = M * S + 1;
    for (int64_t k = 0; k < M; k++)
        for (int64_t i = 0; i < S; i++) tau[k * S + i] = starts[k] + durations[k] * ((double)i * step);
    tau[K - 1] = total;
    s[0] = 0.0;
    int64_t hint = 0;
    for (int64_t j = 0; j + 1 < K; j++) {
        double a = tau[j], b = tau[j + 1];
        s[j + 1] = gl5_piece(&c, 0.5 * (a + b), 0.5 * (b - a), nodes, weights, s[j], &hint);  /* np.cumsum's order */
    }
    if (v != NULL)
        for (int64_t j = 0; j < K; j++) v[j] = speed_at(&c, tau[j], &hint);
    return 0;
}

/* timing._hermite_guess for one s in table interval i */
static double hermite_guess(const double *tau_tab, const double *s_tab, const double *v_tab, int64_t i, double s) {
    double t0 = tau_tab[i], h = tau_tab[i + 1] - tau_tab[i];
    double s0 = s_tab[i], s1 = s_tab[i + 1];
    double m0 = v_tab[i] * h, m1 = v_tab[i + 1] * h;
    double ds = s1 - s0;
    double u = clip(ds > 0 ? (s - s0) / ds : 0.0, 0.0, 1.0);
    double c2 = (3.0 * ds - 2.0 * m0) - m1, c3 = (m0 + m1) - 2.0 * ds;
    for (int it = 0; it < 6; it++) {
        double f = (s0 + u * (m0 + u * (c2 + u * c3))) - s;
        double df = m0 + u * (2.0 * c2 + (3.0 * u) * c3);
        u = clip(u - (df > 1e-300 ? f / df : 0.0), 0.0, 1.0);
    }
    return t0 + u * h;
}

/* timing.invert_arc_length with v_tab: tau [T] with arc length s [T] on the table (tau_tab, s_tab, v_tab) [K], at
   most 8 Newton steps, stopping when every |step| <= tol. Returns the Newton steps taken, -1 when out of memory. */
int64_t cn_invert_arc_length(const double *coef, int64_t M, int64_t n1, const double *starts,
                             const double *durations, double total, const double *nodes, const double *weights,
                             const double *tau_tab, const double *s_tab, const double *v_tab, int64_t K,
                             const double *s, int64_t T, double tol, double *tau) {
    const curve_t c = {coef, M, n1, starts, durations, total};
    if (T <= 0) return 0;
    int64_t *bracket = malloc((size_t)T * 2 * sizeof(int64_t));
    if (bracket == NULL) return -1;
    int64_t *seg = bracket + T;  /* the segment of each point's last evaluation (a hint) */
    for (int64_t p = 0; p < T; p++) {
        int64_t i = upper_bound(s_tab, K, s[p]) - 1;
        i = i < 0 ? 0 : (i > K - 2 ? K - 2 : i);
        bracket[p] = i;
        seg[p] = -1;
        tau[p] = clip(hermite_guess(tau_tab, s_tab, v_tab, i, s[p]), tau_tab[i], tau_tab[i + 1]);
    }
    int64_t steps = 0;
    while (steps < 8) {
        steps++;
        double worst = 0.0;
        int nan = 0;
        for (int64_t p = 0; p < T; p++) {
            int64_t i = bracket[p];
            double lo = tau_tab[i], hi = tau_tab[i + 1];
            double half = 0.5 * (tau[p] - lo);
            double s_here = gl5_piece(&c, lo + half, half, nodes, weights, s_tab[i], seg + p);
            double sp = speed_at(&c, tau[p], seg + p);
            double step = sp > 1e-12 ? (s_here - s[p]) / sp : 0.0;
            tau[p] = clip(tau[p] - step, lo, hi);
            double a = fabs(step);
            if (a != a) nan = 1;
            else if (a > worst) worst = a;
        }
        if (!nan && worst <= tol) break;  /* numpy: np.abs(step).max() <= tol (False for a NaN) */
    }
    free(bracket);
    return steps;
}
