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
   its arithmetic.

   cn_dense_counts and cn_dense_fill: the verification's dense samples of the timed curve (shots/safety.py
   dense_samples for a Shot with its trajectory and curve times; the two calls because Python allocates the samples
   once their count is known). They sit here, not in a file of their own, because both stages evaluate the same
   curve at curve times by segment_of's rules and this keeps one C copy of those rules (locate, segment_of; a
   second file could not include them: the loader compiles one source file and its cache key hashes only that).
   Their arithmetic is numpy's in numpy's order: the norms of np.linalg.norm(axis=-1) ((x*x + y*y) + z*z, add.reduce
   along 3), the Bernstein basis of bezier.bernstein_basis (powers by repeated multiplication in cumprod's order,
   (binomial * u^i) * (1-u)^(D-i)) and einsum("tj,tjc->tc")'s sum over the control points in index order from 0.
   On the CPU box (numpy 2.4) the two backends agree bit for bit; the sample counts depend only on the first (and on
   maxima and the float -> int64 cast), so they are the same wherever numpy's norm sums in that order. */
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
static inline int64_t segment_of(const double *starts, int64_t M, double tt, int64_t hint) {
    if (hint >= 0 && hint < M && starts[hint] <= tt && (hint == M - 1 || tt < starts[hint + 1]))
        return hint;
    int64_t k = upper_bound(starts, M, tt) - 1;
    return k < 0 ? 0 : (k > M - 1 ? M - 1 : k);
}

/* BezierTrajectory.segment_of for one time t: its segment (returned; also stored in *hint, see segment_of) and local
   parameter *u (t clamped to [0, total], the later segment at a join, u = 1 at or past the end) */
static inline int64_t locate(const double *starts, const double *durations, int64_t M, double total, double t,
                             int64_t *hint, double *u) {
    double tt = clip(t, 0.0, total);
    int64_t k = segment_of(starts, M, tt, *hint);
    *hint = k;
    *u = clip((tt - starts[k]) / durations[k], 0.0, 1.0);
    if (tt >= total) *u = 1.0;  /* exact end point despite rounding of the cumulative sum */
    return k;
}

/* BezierTrajectory.speed at one time t: |p'(t)|; *hint: see segment_of (set to this time's segment) */
static double speed_at(const curve_t *c, double t, int64_t *hint) {
    double u;
    int64_t k = locate(c->starts, c->durations, c->M, c->total, t, hint, &u);
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


/* ------------------------------------------------------------------------------------------------------------------
   The verification's dense samples (shots/safety.py dense_samples, curve branch; see the header). */

typedef struct {
    const double *cp;  /* [M, n1, 3] Bezier control points per segment */
    int64_t M, n1;
    const double *starts, *durations;  /* [M] */
    double total;
} bezier_t;

/* np.maximum of two numbers: NaN when either is */
static inline double max_nan(double a, double b) {
    if (a != a) return a;
    if (b != b) return b;
    return a > b ? a : b;
}

/* one row of np.linalg.norm(axis=-1) over 3 components (add.reduce's order) */
static inline double norm3(double x, double y, double z) {
    return sqrt((x * x + y * y) + z * z);
}

/* numpy's float64 -> int64 cast on x86 (cvttsd2si): truncation, INT64_MIN for NaN and out of range */
static inline int64_t to_int64(double x) {
    return (x >= -9223372036854775808.0 && x < 9223372036854775808.0) ? (int64_t)x : INT64_MIN;
}

/* safety._piece_speed_bound of a piece whose ends lie in segments ka, kb: the largest vb over the segments from
   min(ka, kb) to max(ka, kb) (segment_of is monotone in t, so these are the segments of the smaller and the larger
   end) */
static inline double piece_bound(const double *vb, int64_t ka, int64_t kb) {
    int64_t lo = ka < kb ? ka : kb, hi = ka < kb ? kb : ka;
    double b = vb[lo];
    for (int64_t k = lo + 1; k <= hi; k++) b = max_nan(b, vb[k]);
    return b;
}

/* BezierTrajectory.evaluate at one time t into out [3] (bezier.bernstein_basis and derivative's einsum; see the
   header). up, vp, binom: [n1] scratch, binom holding C(n1 - 1, i). *hint: see segment_of. Returns the segment. */
static int64_t position_at(const bezier_t *c, double t, int64_t *hint, const double *binom, double *up, double *vp,
                           double *out) {
    double u;
    int64_t k = locate(c->starts, c->durations, c->M, c->total, t, hint, &u);
    const int64_t D = c->n1 - 1;
    const double v = 1.0 - u;
    up[0] = 1.0;
    vp[0] = 1.0;
    for (int64_t j = 1; j <= D; j++) {
        up[j] = up[j - 1] * u;
        vp[j] = vp[j - 1] * v;
    }
    const double *P = c->cp + k * c->n1 * 3;
    double x = 0.0, y = 0.0, z = 0.0;
    for (int64_t j = 0; j <= D; j++) {
        double b = (binom[j] * up[j]) * vp[D - j];
        x = x + b * P[3 * j];
        y = y + b * P[3 * j + 1];
        z = z + b * P[3 * j + 2];
    }
    out[0] = x;
    out[1] = y;
    out[2] = z;
    return k;
}

/* dense_samples' counts: vb [M] (safety._speed_bounds: the largest norm of the hodograph's control points
   D (P_{i+1} - P_i) / d_k) and sub [T-1] (pieces per frame interval: max(1, int64(ceil(approx_len / max_spacing)))
   with approx_len = max(chord, piece bound * |dtau|)). Returns the number of pieces, sum(sub); -1 when it does not
   fit int64. */
int64_t cn_dense_counts(const double *cp, int64_t M, int64_t n1, const double *starts, const double *durations,
                        double total, const double *f_pos, const double *tau, int64_t T, double max_spacing,
                        double *vb, int64_t *sub) {
    const double D = (double)(n1 - 1);
    for (int64_t k = 0; k < M; k++) {
        const double *P = cp + k * n1 * 3;
        double best = 0.0;
        for (int64_t i = 0; i + 1 < n1; i++) {
            double x = (D * (P[3 * i + 3] - P[3 * i])) / durations[k];
            double y = (D * (P[3 * i + 4] - P[3 * i + 1])) / durations[k];
            double z = (D * (P[3 * i + 5] - P[3 * i + 2])) / durations[k];
            double n = norm3(x, y, z);
            best = i == 0 ? n : max_nan(best, n);
        }
        vb[k] = best;
    }
    int64_t total_pieces = 0, hint = 0, ka = 0, kb = 0;
    double u;
    if (T > 0) ka = locate(starts, durations, M, total, tau[0], &hint, &u);
    for (int64_t i = 0; i + 1 < T; i++) {
        kb = locate(starts, durations, M, total, tau[i + 1], &hint, &u);
        const double *a = f_pos + 3 * i;
        double chord = norm3(a[3] - a[0], a[4] - a[1], a[5] - a[2]);
        double approx = max_nan(chord, piece_bound(vb, ka, kb) * fabs(tau[i + 1] - tau[i]));
        int64_t n = to_int64(ceil(approx / max_spacing));
        n = n > 1 ? n : 1;
        if (n > INT64_MAX - total_pieces) return -1;
        sub[i] = n;
        total_pieces += n;
        ka = kb;
    }
    return total_pieces;
}

/* dense_samples' samples from cn_dense_counts' vb and sub: per frame interval i its sub[i] samples at
   frac = k / sub[i] (k = 0 .. sub[i] - 1) of the way in frame time and curve time (f_times[i] + frac * (f_times[i+1]
   - f_times[i]), the same for tau), then the last frame; t [S + 1], pos [S + 1, 3] (the curve at those curve times)
   and lengths [S] (max(piece bound * |dtau|, chord)), S = sum(sub). Returns 0, -1 when out of memory. */
int64_t cn_dense_fill(const double *cp, int64_t M, int64_t n1, const double *starts, const double *durations,
                      double total, const double *vb, const double *f_times, const double *tau, int64_t T,
                      const int64_t *sub, double *t, double *pos, double *lengths) {
    const bezier_t c = {cp, M, n1, starts, durations, total};
    if (T <= 0) return 0;
    double *scratch = malloc((size_t)n1 * 3 * sizeof(double));
    if (scratch == NULL) return -1;
    double *binom = scratch, *up = scratch + n1, *vp = scratch + 2 * n1;
    binom[0] = 1.0;  /* C(D, i) by C(D, i - 1) (D - i + 1) / i: exact integers below 2^53, as float(math.comb) */
    for (int64_t i = 1; i < n1; i++) binom[i] = binom[i - 1] * (double)(n1 - i) / (double)i;
    int64_t j = 0, hint = 0, k_prev = 0;
    double ct_prev = 0.0;
    for (int64_t i = 0; i < T; i++) {
        const int64_t n = i + 1 < T ? sub[i] : 1;  /* the last frame: one sample, the frame itself */
        const double dt = i + 1 < T ? f_times[i + 1] - f_times[i] : 0.0;
        const double dtau = i + 1 < T ? tau[i + 1] - tau[i] : 0.0;
        for (int64_t r = 0; r < n; r++, j++) {
            double ct;
            if (i + 1 < T) {
                const double frac = (double)r / (double)n;
                t[j] = f_times[i] + frac * dt;
                ct = tau[i] + frac * dtau;
            } else {
                t[j] = f_times[i];
                ct = tau[i];
            }
            int64_t k = position_at(&c, ct, &hint, binom, up, vp, pos + 3 * j);
            if (j > 0) {
                const double *a = pos + 3 * (j - 1);
                lengths[j - 1] = max_nan(piece_bound(vb, k_prev, k) * fabs(ct - ct_prev),
                                         norm3(a[3] - a[0], a[4] - a[1], a[5] - a[2]));
            }
            k_prev = k;
            ct_prev = ct;
        }
    }
    free(scratch);
    return 0;
}

/* BezierTrajectory.evaluate at curve times tau [T] -> pos [T, 3] (position_at per time: segment_of's rules, the
   Bernstein basis and einsum's sum in numpy's order; timing.time_parametrize's frames). Returns 0, -1 when out of
   memory. */
int64_t cn_bezier_positions(const double *cp, int64_t M, int64_t n1, const double *starts, const double *durations,
                            double total, const double *tau, int64_t T, double *pos) {
    const bezier_t c = {cp, M, n1, starts, durations, total};
    double *scratch = malloc((size_t)n1 * 3 * sizeof(double));
    if (scratch == NULL) return -1;
    double *binom = scratch, *up = scratch + n1, *vp = scratch + 2 * n1;
    binom[0] = 1.0;  /* as cn_dense_fill */
    for (int64_t i = 1; i < n1; i++) binom[i] = binom[i - 1] * (double)(n1 - i) / (double)i;
    int64_t hint = 0;
    for (int64_t i = 0; i < T; i++) position_at(&c, tau[i], &hint, binom, up, vp, pos + 3 * i);
    free(scratch);
    return 0;
}
