/* The corridor QP by its equality-free form and the dual active-set method (trajectory/dual_qp.py), compiled.

   cn_corridor_dual: dual_qp.solve_corridor_dual's steps 1-4 in one call. The numpy code is the reference; this file
   repeats its arithmetic with the structure the dense reference ignores:
   - a control point's row of T is zero outside a column range [lo, hi) (a variable, or the variables its join
     conditions reach), so B = blockdiag(F_k) T is built per segment over those columns, and its Householder QR stays
     inside each column's row envelope (a banded matrix: ~50 rows x ~45 columns, ~10 of each touched per column);
   - a face row in Y-space is w_p a_f^T, so two rows' inner product is (w_p . w_q)(a_f . a_g) and the working set's
     Gram matrix is kept as its Cholesky factor, updated when a face joins or leaves (O(k^2) a step, where the
     reference solves with the whole matrix; w_p is zero before lo[p], so its products start there); w_p = U^-T T[p]^T
     is solved for a point only when one of its faces joins the working set;
   - violations are computed from the control points X = T U^-1 Y + t, as the reference does.
   The decisions are the reference's (first maximum, its dependency and ratio tests, "t2 < 0: unfinished"); sums run
   in another order and the QR's reflectors may differ in sign from LAPACK's (Y differs by those signs; X does not), so
   iterates may differ in the last bits and, on near-ties, the order of the steps; the optimum is unique (strictly
   convex), and the tests compare it. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define CN_OK 0
#define CN_INFEASIBLE 1
#define CN_UNFINISHED 2
#define CN_SINGULAR (-1)   /* a working set's Gram matrix had an exactly zero pivot */
#define CN_NOMEM (-3)
#define CN_NOT_PD (-4)     /* the reduced cost is singular or too ill-conditioned (dual_qp.CONDITION_LIMIT) */
#define CONDITION_LIMIT 1e7  /* dual_qp.CONDITION_LIMIT */

enum { FREE = 0, START = 1, GOAL = 2, JOINED = 3 };

/* The working set's Gram matrix G [k, k] is kept as its Cholesky factor: G = R^T R, R upper triangular [k, k] stored
   with row stride ld. Joining a face appends a column (O(k^2)), leaving removes one and restores the triangle by Givens
   rotations (O(k^2)); a solve is two triangular ones (O(k^2)): no factorisation from scratch per step (O(k^3)). */

/* G r = c: z = R^-T c (kept in z: the new column of R when the face joins), then r = R^-1 z; CN_SINGULAR on a zero
   pivot */
static int chol_solve(int64_t k, const double *R, int64_t ld, const double *c, double *z, double *r) {
    for (int64_t i = 0; i < k; i++) {
        double s = c[i];
        for (int64_t j = 0; j < i; j++) s -= R[j * ld + i] * z[j];
        if (R[i * ld + i] == 0.0) return CN_SINGULAR;
        z[i] = s / R[i * ld + i];
    }
    for (int64_t i = k - 1; i >= 0; i--) {
        double s = z[i];
        for (int64_t j = i + 1; j < k; j++) s -= R[i * ld + j] * r[j];
        r[i] = s / R[i * ld + i];
    }
    return 0;
}

/* R [k, k] -> R [k-1, k-1] of G without row and column q: column q removed, then Givens rotations of rows (i, i+1),
   i = q..k-2, zero the subdiagonal the removal leaves (G = R^T R is unchanged by them) */
static void chol_remove(int64_t k, double *R, int64_t ld, int64_t q) {
    for (int64_t i = 0; i < k; i++)
        for (int64_t j = q; j + 1 < k; j++) R[i * ld + j] = R[i * ld + j + 1];
    for (int64_t i = q; i + 1 < k; i++) {
        double a = R[i * ld + i], b = R[(i + 1) * ld + i];
        double h = hypot(a, b);
        if (h == 0.0) continue;
        double c = a / h, sn = b / h;
        R[i * ld + i] = h;
        R[(i + 1) * ld + i] = 0.0;
        for (int64_t j = i + 1; j + 1 < k; j++) {
            double x = R[i * ld + j], y = R[(i + 1) * ld + j];
            R[i * ld + j] = c * x + sn * y;
            R[(i + 1) * ld + j] = -sn * x + c * y;
        }
    }
}

typedef struct {
    int64_t n, N, npts;
    const double *T;  /* [N, n] */
    const int64_t *lo, *hi;
    const double *L;  /* [n, n] lower */
    const double *U;  /* [n, n] row-major, upper triangle = L^T (the QR's R, kept in B): rows read contiguously */
    const double *t;  /* [N, 3] */
} Map;

/* X [N, 3] = T L^-T Y + t; Z [n, 3] work. L^T = U is read by rows (contiguous), the three columns at once: the
   same operations in the same order as column by column through L (a stride-n walk, ~25% of the solve) */
static void points_of(const Map *mp, const double *Y, double *Z, double *X) {
    int64_t n = mp->n;
    for (int64_t i = n - 1; i >= 0; i--) {
        const double *urow = mp->U + i * n;
        double s0 = Y[i * 3], s1 = Y[i * 3 + 1], s2 = Y[i * 3 + 2];
        for (int64_t j = i + 1; j < n; j++) {
            double u = urow[j];
            s0 -= u * Z[j * 3];
            s1 -= u * Z[j * 3 + 1];
            s2 -= u * Z[j * 3 + 2];
        }
        double dg = urow[i];
        Z[i * 3] = s0 / dg, Z[i * 3 + 1] = s1 / dg, Z[i * 3 + 2] = s2 / dg;
    }
    for (int64_t p = 0; p < mp->N; p++) {
        double x0 = mp->t[p * 3], x1 = mp->t[p * 3 + 1], x2 = mp->t[p * 3 + 2];
        const double *row = mp->T + p * n;
        for (int64_t j = mp->lo[p]; j < mp->hi[p]; j++) {
            double w = row[j];
            x0 += w * Z[j * 3];
            x1 += w * Z[j * 3 + 1];
            x2 += w * Z[j * 3 + 2];
        }
        X[p * 3] = x0, X[p * 3 + 1] = x1, X[p * 3 + 2] = x2;
    }
}

/* w = L^-1 T[p]^T [n] (zero before lo[p]) */
static void w_of(const Map *mp, int64_t p, double *w) {
    int64_t n = mp->n;
    const double *row = mp->T + p * n;
    for (int64_t i = 0; i < mp->lo[p]; i++) w[i] = 0.0;
    for (int64_t i = mp->lo[p]; i < n; i++) {
        double s = row[i];
        for (int64_t j = mp->lo[p]; j < i; j++) s -= mp->L[i * n + j] * w[j];
        w[i] = s / mp->L[i * n + i];
    }
}

static double dot(const double *a, const double *b, int64_t n) {
    double s = 0.0;
    for (int64_t i = 0; i < n; i++) s += a[i] * b[i];
    return s;
}

static double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

/* m segments of degree D, continuity c; durations [m]; factors [m, fr, D+1] (qp.segment_factors: H_k = F_k^T F_k); diffs [c+1, 2, D+1] ((Delta^r)_last and
   (Delta^r)_0 per order r); kind [N] (dual_qp.point_kinds); ends [2, 3] start, goal; faces A [F, 3], b' [F] (shrunk),
   segment k's faces face_start[k]..face_start[k+1]; tol (scene units); max_iter (< 0: 50 + 4 K).
   out [N, 3] control points (CN_OK); info [2]: steps taken, working-set size at the end. */
int64_t cn_corridor_dual(int64_t m, int64_t degree, int64_t cont, int64_t fr, const double *durations,
                         const double *factors,
                         const double *diffs, const int64_t *kind, const double *ends, const double *A,
                         const double *b, const int64_t *face_start, double tol, int64_t max_iter, double *out,
                         int64_t *info) {
    int64_t npts = degree + 1, N = m * npts, n = 0;
    for (int64_t p = 0; p < N; p++) n += kind[p] == FREE;
    int64_t K = 0;
    for (int64_t p = 0; p < N; p++)
        if (kind[p] == FREE || kind[p] == JOINED) K += face_start[p / npts + 1] - face_start[p / npts];
    if (max_iter < 0) max_iter = 50 + 4 * K;
    int64_t cap = 3 * n + 1;
    size_t rows_ = (size_t)m * fr, F_ = (size_t)face_start[m];
    size_t nd = (size_t)N * n + 2 * (size_t)N + (size_t)N * 3 + (size_t)n * n + 3 * (size_t)n * 3 + (size_t)N * 3 +
                (size_t)N * n + (size_t)cap * cap + 4 * (size_t)cap + F_ + rows_ * n + rows_ * 3;
    size_t ni = 3 * (size_t)N + 2 * (size_t)cap + 2 * (size_t)n;
    double *buf = calloc(nd + 1, sizeof(double));
    int64_t *ibuf = calloc(ni + 1, sizeof(int64_t));
    if (buf == NULL || ibuf == NULL) {
        free(buf);
        free(ibuf);
        return CN_NOMEM;
    }
    double *next = buf;
#define TAKE(count) (next += (count), next - (count))
    double *T = TAKE((size_t)N * n), *cs = TAKE(N), *cg = TAKE(N), *t = TAKE((size_t)N * 3);
    double *Lf = TAKE((size_t)n * n), *Y = TAKE((size_t)n * 3), *Z = TAKE((size_t)n * 3), *zdir = TAKE((size_t)n * 3);
    double *X = TAKE((size_t)N * 3), *wc = TAKE((size_t)N * n), *R = TAKE((size_t)cap * cap);
    double *zc = TAKE(cap), *u = TAKE(cap), *rv = TAKE(cap), *aw = TAKE(cap), *inv_norm = TAKE(F_);
    double *B = TAKE(rows_ * n), *Ft = TAKE(rows_ * 3);
#undef TAKE
    int64_t *lo = ibuf, *hi = lo + N, *have_w = hi + N, *Wp = have_w + N, *Wf = Wp + cap, *rfirst = Wf + cap;
    int64_t *rlast = rfirst + n;
    int64_t ret = CN_OK, it = 0, k = 0;

    /* step 1: T, and the start / goal coefficients, by forward substitution */
    int64_t v = 0;
    for (int64_t p = 0; p < N; p++) {
        lo[p] = n, hi[p] = 0;
        if (kind[p] == FREE) T[p * n + v] = 1.0, lo[p] = v, hi[p] = v + 1, v++;
        else if (kind[p] == START) cs[p] = 1.0;
        else if (kind[p] == GOAL) cg[p] = 1.0;
    }
    for (int64_t s = 1; s < m; s++) {
        for (int64_t r = 0; r <= cont; r++) {
            /* P_{s,r} = ratio (dl . P_{s-1}) - sum_{i<r} d0[i] P_{s,i} over the columns the terms reach */
            int64_t p = s * npts + r, q0 = (s - 1) * npts;
            const double *dl = diffs + (r * 2) * npts, *d0 = diffs + (r * 2 + 1) * npts;
            double ratio = pow(durations[s] / durations[s - 1], (double)r);
            int64_t l = n, h = 0;
            for (int64_t i = 0; i < npts; i++) if (dl[i] != 0.0 && lo[q0 + i] < hi[q0 + i]) {
                if (lo[q0 + i] < l) l = lo[q0 + i];
                if (hi[q0 + i] > h) h = hi[q0 + i];
            }
            for (int64_t i = 0; i < r; i++) if (d0[i] != 0.0 && lo[s * npts + i] < hi[s * npts + i]) {
                if (lo[s * npts + i] < l) l = lo[s * npts + i];
                if (hi[s * npts + i] > h) h = hi[s * npts + i];
            }
            double *row = T + p * n;
            for (int64_t j = l; j < h; j++) {
                double a = 0.0, c = 0.0;
                for (int64_t i = 0; i < npts; i++) a += dl[i] * T[(q0 + i) * n + j];
                for (int64_t i = 0; i < r; i++) c += d0[i] * T[(s * npts + i) * n + j];
                row[j] = ratio * a - c;
            }
            double as = 0.0, ag = 0.0, bs = 0.0, bg = 0.0;
            for (int64_t i = 0; i < npts; i++) as += dl[i] * cs[q0 + i], ag += dl[i] * cg[q0 + i];
            for (int64_t i = 0; i < r; i++) bs += d0[i] * cs[s * npts + i], bg += d0[i] * cg[s * npts + i];
            cs[p] = ratio * as - bs;
            cg[p] = ratio * ag - bg;
            if (l < h) lo[p] = l, hi[p] = h;
        }
    }
    for (int64_t p = 0; p < N; p++)
        for (int c = 0; c < 3; c++) t[p * 3 + c] = cs[p] * ends[c] + cg[p] * ends[3 + c];

    /* step 2: B = blockdiag(F_k) T [rows, n] and Ft = blockdiag(F_k) t [rows, 3], each segment over its columns */
    int64_t rows = m * fr;
    for (int64_t j = 0; j < n; j++) rfirst[j] = rows, rlast[j] = -1;
    for (int64_t s = 0; s < m; s++) {
        int64_t l = n, h = 0;
        for (int64_t i = 0; i < npts; i++) {
            int64_t p = s * npts + i;
            if (lo[p] < hi[p]) {
                if (lo[p] < l) l = lo[p];
                if (hi[p] > h) h = hi[p];
            }
        }
        const double *F = factors + s * fr * npts;
        for (int64_t rr = 0; rr < fr; rr++) {
            double *brow = B + (s * fr + rr) * n;
            for (int64_t j = l; j < h; j++) {
                double a = 0.0;
                for (int64_t i = 0; i < npts; i++) a += F[rr * npts + i] * T[(s * npts + i) * n + j];
                brow[j] = a;
            }
            for (int c = 0; c < 3; c++) {
                double a = 0.0;
                for (int64_t i = 0; i < npts; i++) a += F[rr * npts + i] * t[(s * npts + i) * 3 + c];
                Ft[(s * fr + rr) * 3 + c] = a;
            }
        }
        for (int64_t j = l; j < h; j++) {
            if (s * fr < rfirst[j]) rfirst[j] = s * fr;
            if ((s + 1) * fr - 1 > rlast[j]) rlast[j] = (s + 1) * fr - 1;
        }
    }
    /* Householder QR of B (B = Q U), kept inside each column's envelope: the reflector of column j spans rows
       j..rl (rl: the largest last row of columns 0..j) and reaches the columns whose first row is <= rl (variables are
       in segment order, so first rows do not decrease). Ft becomes Q^T Ft. */
    double dmin = INFINITY, dmax = 0.0;
    for (int64_t j = 0, rl = -1, kmax = 0; j < n; j++) {
        if (rlast[j] > rl) rl = rlast[j];
        if (rl < j) rl = j;
        if (rl > rows - 1) rl = rows - 1;
        while (kmax + 1 < n && rfirst[kmax + 1] <= rl) kmax++;
        double norm2 = 0.0;
        for (int64_t i = j; i <= rl; i++) norm2 += B[i * n + j] * B[i * n + j];
        double x0 = B[j * n + j], alpha = x0 > 0 ? -sqrt(norm2) : sqrt(norm2);
        double d = fabs(alpha);
        if (d < dmin) dmin = d;
        if (d > dmax) dmax = d;
        if (!(d > 0.0)) {
            ret = CN_NOT_PD;
            goto done;
        }
        /* v = x - alpha e_j (v_j = x0 - alpha, the rest B[i, j]); H = I - v v^T / (alpha (alpha - x0)) */
        double v0 = x0 - alpha, tau = 1.0 / (alpha * (alpha - x0));
        for (int64_t k = j + 1; k <= kmax; k++) {
            double sk = v0 * B[j * n + k];
            for (int64_t i = j + 1; i <= rl; i++) sk += B[i * n + j] * B[i * n + k];
            sk *= tau;
            B[j * n + k] -= sk * v0;
            for (int64_t i = j + 1; i <= rl; i++) B[i * n + k] -= sk * B[i * n + j];
        }
        for (int c = 0; c < 3; c++) {
            double sk = v0 * Ft[j * 3 + c];
            for (int64_t i = j + 1; i <= rl; i++) sk += B[i * n + j] * Ft[i * 3 + c];
            sk *= tau;
            Ft[j * 3 + c] -= sk * v0;
            for (int64_t i = j + 1; i <= rl; i++) Ft[i * 3 + c] -= sk * B[i * n + j];
        }
        B[j * n + j] = alpha;
    }
    if (n && dmax > CONDITION_LIMIT * dmin) {
        ret = CN_NOT_PD;
        goto done;
    }
    /* L = U^T (lower), Y0 = -(Q^T Ft)[:n] */
    for (int64_t i = 0; i < n; i++) {
        for (int64_t j = 0; j <= i; j++) Lf[i * n + j] = B[j * n + i];
        for (int c = 0; c < 3; c++) Y[i * 3 + c] = -Ft[i * 3 + c];
    }
    for (int64_t f = 0; f < face_start[m]; f++) inv_norm[f] = 1.0 / sqrt(dot3(A + 3 * f, A + 3 * f));
    Map mp = {n, N, npts, T, lo, hi, Lf, B, t};

    /* step 4: dual active set */
    for (;;) {
        points_of(&mp, Y, Z, X);
        if (n == 0 || K == 0) break;
        int64_t pp = -1, pf = -1;
        double vp = -INFINITY;
        int nan_seen = 0;
        /* the first largest violation (numpy's argmax); a NaN (never with finite input) takes the exact rule below */
        for (int64_t p = 0; p < N; p++) {
            if (kind[p] != FREE && kind[p] != JOINED) continue;
            int64_t s = p / npts;
            for (int64_t f = face_start[s]; f < face_start[s + 1]; f++) {
                double vv = (dot3(A + 3 * f, X + 3 * p) - b[f]) * inv_norm[f];
                nan_seen |= vv != vv;
                if (vv > vp) pp = p, pf = f, vp = vv;
            }
        }
        if (nan_seen || pp < 0) {  /* argmax's rule with NaN (the first NaN wins) or all -inf (the first wins) */
            pp = -1, vp = 0.0;
            for (int64_t p = 0; p < N; p++) {
                if (kind[p] != FREE && kind[p] != JOINED) continue;
                int64_t s = p / npts;
                for (int64_t f = face_start[s]; f < face_start[s + 1]; f++) {
                    double vv = (dot3(A + 3 * f, X + 3 * p) - b[f]) * inv_norm[f];
                    if (pp < 0 || (vp == vp && (vv > vp || vv != vv))) pp = p, pf = f, vp = vv;
                }
            }
        }
        if (vp <= tol) break;
        for (int64_t i = 0; i < k; i++)  /* a face held with equality left outside by rounding (dual_qp.py) */
            if (Wp[i] == pp && Wf[i] == pf) {
                ret = CN_UNFINISHED;
                goto done;
            }
        if (!have_w[pp]) w_of(&mp, pp, wc + pp * n), have_w[pp] = 1;
        const double *wp = wc + pp * n, *ap = A + 3 * pf;
        double wpwp = dot(wp, wp, n), apap = dot3(ap, ap);
        double row2 = wpwp * apap;
        double beta = b[pf] - dot3(ap, t + 3 * pp);
        /* aw[i] = (w_i . w_p)(a_i . a_p): N_W ap (w_q is zero before lo[q]) */
        for (int64_t i = 0; i < k; i++) {
            int64_t j0 = lo[Wp[i]] > lo[pp] ? lo[Wp[i]] : lo[pp];
            aw[i] = (j0 < n ? dot(wc + Wp[i] * n + j0, wp + j0, n - j0) : 0.0) * dot3(A + 3 * Wf[i], ap);
        }
        double up = 0.0;
        for (;;) {
            it++;
            if (it > max_iter) {
                ret = CN_UNFINISHED;
                goto done;
            }
            if (k && chol_solve(k, R, cap, aw, zc, rv) != 0) {
                ret = CN_SINGULAR;
                goto done;
            }
            /* zdir = sum_i r_i w_i a_i^T - w_p a_p^T [n, 3] */
            for (int64_t j = 0; j < n; j++)
                for (int c = 0; c < 3; c++) zdir[j * 3 + c] = -wp[j] * ap[c];
            for (int64_t i = 0; i < k; i++) {
                const double *wi = wc + Wp[i] * n, *ai = A + 3 * Wf[i];
                double ri = rv[i];
                for (int64_t j = lo[Wp[i]]; j < n; j++) {
                    double s = ri * wi[j];
                    zdir[j * 3] += s * ai[0];
                    zdir[j * 3 + 1] += s * ai[1];
                    zdir[j * 3 + 2] += s * ai[2];
                }
            }
            double zz = dot(zdir, zdir, 3 * n);
            int dependent = zz <= 1e-18 * row2;
            double rmax = 0.0;
            for (int64_t i = 0; i < k; i++) if (fabs(rv[i]) > rmax) rmax = fabs(rv[i]);
            double rtol = 1e-12 * (1.0 + rmax), t1 = INFINITY;
            int64_t jdrop = -1;
            for (int64_t i = 0; i < k; i++)
                if (rv[i] > rtol) {
                    double ratio = u[i] / rv[i];
                    if (jdrop < 0 || ratio < t1) t1 = ratio, jdrop = i;
                }
            double t2 = INFINITY;
            if (!dependent) {
                double ay = 0.0;  /* <w_p a_p^T, Y> */
                for (int64_t j = 0; j < n; j++) ay += wp[j] * dot3(ap, Y + 3 * j);
                t2 = (ay - beta) / zz;
            }
            if (!isfinite(t1) && !isfinite(t2)) {
                ret = CN_INFEASIBLE;
                goto done;
            }
            if (t2 < 0) {
                ret = CN_UNFINISHED;
                goto done;
            }
            double st = t1 < t2 ? t1 : t2;
            if (isfinite(t2))
                for (int64_t j = 0; j < 3 * n; j++) Y[j] += st * zdir[j];
            for (int64_t i = 0; i < k; i++) u[i] -= st * rv[i];
            up += st;
            if (st == t2) {  /* full step: face (pp, pf) joins; R gains the column (R^-T aw, sqrt(row2 - |R^-T aw|^2)) */
                if (k + 1 > cap) {
                    ret = CN_UNFINISHED;
                    goto done;
                }
                for (int64_t i = 0; i < k; i++) R[i * cap + k] = zc[i], R[k * cap + i] = 0.0;
                double d2 = row2;  /* the Schur complement of G's new row: R^T R = G as stored */
                for (int64_t i = 0; i < k; i++) d2 -= zc[i] * zc[i];
                R[k * cap + k] = sqrt(d2 > 0.0 ? d2 : zz);  /* rounding: |zdir|^2, the same in exact arithmetic */
                Wp[k] = pp, Wf[k] = pf, u[k] = up;
                k++;
                break;
            }
            /* partial step: face jdrop leaves; R of the Gram matrix without its row and column */
            int64_t kk = k - 1;
            chol_remove(k, R, cap, jdrop);
            for (int64_t i = jdrop; i < kk; i++) Wp[i] = Wp[i + 1], Wf[i] = Wf[i + 1], u[i] = u[i + 1], aw[i] = aw[i + 1];
            k = kk;
        }
    }
    memcpy(out, X, (size_t)N * 3 * sizeof(double));
done:
    info[0] = it;
    info[1] = k;
    free(buf);
    free(ibuf);
    return ret;
}
