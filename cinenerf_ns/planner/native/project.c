/* The projection of a point onto a polytope {x : A x <= b} in 3 variables (search/goal.py), compiled.

   cn_project_primal: goal.project_active_set (primal active set from a feasible start, Hessian I).
   cn_project_dual: goal.project_dual_active_set (Goldfarb-Idnani dual active set, no feasible start).
   Both take the same decisions as the numpy code (its tolerances, its first-index argmin / argmax, its dependency
   tests, its "t2 < 0: unfinished" rule); the working set's small solves are Gaussian elimination with partial
   pivoting instead of LAPACK's, so results may differ from numpy's in the last bits. A pivot that is exactly 0 is
   CN_SINGULAR: the Python wrapper raises np.linalg.LinAlgError there, as numpy's solve does. Contraction into fused
   multiply-adds would round differently from numpy: it is turned off. The proofs (KKT multipliers, Farkas) are in
   goal.py's docstrings; this file only repeats their arithmetic. */
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define CN_DONE 0         /* x written */
#define CN_NOT_FOUND 1    /* primal: did not finish in max_iter; dual: the polytope is empty */
#define CN_UNFINISHED 2   /* dual: did not finish, or a step rounding cannot be trusted */
#define CN_SINGULAR (-1)  /* a working set's Gram matrix had an exactly zero pivot (numpy: LinAlgError) */
#define CN_ZERO_DIV (-2)  /* primal: a one-face working set whose |a|^2 is 0 (underflow; Python: ZeroDivisionError) */
#define CN_NOMEM (-3)
#define STACK_F 64        /* faces whose work arrays live on the stack */
#define STACK_W 16        /* dual working-set size held on the stack */

static double dot3(const double *a, const double *b) { return (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]; }

/* max_i |x_i| (0 for none), NaN when one is NaN (numpy's max) */
static double absmax(const double *x, int64_t n) {
    double m = 0.0;
    for (int64_t i = 0; i < n; i++) {
        double a = fabs(x[i]);
        if (a > m || a != a) m = a;
        if (m != m) break;
    }
    return m;
}

/* 1 when value v replaces the best so far in numpy's argmin (the first minimum; the first NaN wins) */
static int better_min(double v, double best, int64_t have) {
    return !have || (best == best && (v < best || v != v));
}

/* G [k, k] y = R [k, m] by Gaussian elimination with partial pivoting (largest |pivot|, first on ties: LAPACK's
   getrf); G and R are overwritten, R by y. CN_SINGULAR when a pivot is exactly 0. */
static int gauss_solve(int64_t k, double *G, double *R, int64_t m) {
    for (int64_t c = 0; c < k; c++) {
        int64_t piv = c;
        double best = fabs(G[c * k + c]);
        for (int64_t i = c + 1; i < k; i++) {
            double a = fabs(G[i * k + c]);
            if (a > best) {
                best = a;
                piv = i;
            }
        }
        if (best == 0.0) return CN_SINGULAR;
        if (piv != c) {
            for (int64_t j = 0; j < k; j++) {
                double s = G[c * k + j];
                G[c * k + j] = G[piv * k + j];
                G[piv * k + j] = s;
            }
            for (int64_t j = 0; j < m; j++) {
                double s = R[c * m + j];
                R[c * m + j] = R[piv * m + j];
                R[piv * m + j] = s;
            }
        }
        double d = G[c * k + c];
        for (int64_t i = c + 1; i < k; i++) {
            double f = G[i * k + c] / d;
            for (int64_t j = c + 1; j < k; j++) G[i * k + j] -= f * G[c * k + j];
            for (int64_t j = 0; j < m; j++) R[i * m + j] -= f * R[c * m + j];
        }
    }
    for (int64_t c = k - 1; c >= 0; c--)
        for (int64_t j = 0; j < m; j++) {
            double s = R[c * m + j];
            for (int64_t i = c + 1; i < k; i++) s -= G[c * k + i] * R[i * m + j];
            R[c * m + j] = s / G[c * k + c];
        }
    return 0;
}

/* G = N N^T for the rows W [k] of A [F, 3] */
static void gram(const double *A, const int64_t *W, int64_t k, double *G) {
    for (int64_t i = 0; i < k; i++)
        for (int64_t j = 0; j < k; j++) G[i * k + j] = dot3(A + 3 * W[i], A + 3 * W[j]);
}

/* goal.project_active_set: x [3] (out) from the feasible x0 [3]. CN_DONE, CN_NOT_FOUND (max_iter steps),
   CN_SINGULAR, CN_ZERO_DIV or CN_NOMEM. */
int64_t cn_project_primal(const double *A, const double *b, int64_t F, const double *t, const double *x0,
                          int64_t max_iter, double *xout) {
    double stack[3 * STACK_F];
    int64_t istack[STACK_F];
    double *ws = stack;
    int64_t *ids = istack;
    void *heap = NULL;
    if (F > STACK_F) {
        heap = malloc((size_t)F * (3 * sizeof(double) + sizeof(int64_t)));
        if (heap == NULL) return CN_NOMEM;
        ws = (double *)heap;
        ids = (int64_t *)(ws + 3 * F);
    }
    double *row_norm = ws, *slack = ws + F, *Ap = ws + 2 * F;
    double x[3] = {x0[0], x0[1], x0[2]};
    double scale = 1.0 + absmax(t, 3) + absmax(x, 3);
    for (int64_t f = 0; f < F; f++) {
        const double *a = A + 3 * f;
        row_norm[f] = sqrt(dot3(a, a));
        slack[f] = b[f] - dot3(a, x);
    }
    int64_t W[3], nw = 0;  /* working set: independent faces held with equality (never more than 3) */
    int64_t ret = CN_NOT_FOUND;
    for (int64_t iter = 0; iter < max_iter; iter++) {
        double r[3] = {t[0] - x[0], t[1] - x[1], t[2] - x[2]}, p[3], lam[3];
        if (nw == 1) {
            const double *m = A + 3 * W[0];
            double mm = dot3(m, m);
            if (mm == 0.0) {
                ret = CN_ZERO_DIV;
                break;
            }
            lam[0] = dot3(m, r) / mm;
            for (int i = 0; i < 3; i++) p[i] = r[i] - lam[0] * m[i];
        } else if (nw) {
            double G[9];
            gram(A, W, nw, G);
            for (int64_t i = 0; i < nw; i++) lam[i] = dot3(A + 3 * W[i], r);
            if (gauss_solve(nw, G, lam, 1)) {
                ret = CN_SINGULAR;
                break;
            }
            for (int j = 0; j < 3; j++) {
                double s = 0.0;
                for (int64_t i = 0; i < nw; i++) s += A[3 * W[i] + j] * lam[i];
                p[j] = nw < 3 ? r[j] - s : 0.0;  /* 3 independent faces: a vertex */
            }
        } else {
            p[0] = r[0], p[1] = r[1], p[2] = r[2];
        }
        if (absmax(p, 3) <= 1e-13 * scale) {
            int64_t kmin = -1;
            double lmin = 0.0;
            for (int64_t i = 0; i < nw; i++)
                if (better_min(lam[i], lmin, kmin >= 0)) kmin = i, lmin = lam[i];
            if (nw == 0 || lmin >= -1e-12 * scale) {  /* KKT: x - t + M^T lam = 0 with lam >= 0 */
                ret = CN_DONE;
                break;
            }
            for (int64_t i = kmin; i + 1 < nw; i++) W[i] = W[i + 1];  /* a face pulling the wrong way leaves */
            nw--;
            continue;
        }
        double thr = 1e-14 * sqrt(dot3(p, p));
        int64_t nid = 0;
        for (int64_t f = 0; f < F; f++) {
            Ap[f] = dot3(A + 3 * f, p);
            if (Ap[f] > thr * row_norm[f]) {
                int in_w = 0;
                for (int64_t i = 0; i < nw; i++) in_w |= W[i] == f;
                if (!in_w) ids[nid++] = f;
            }
        }
        if (nid && nw) {
            /* a face whose normal lies in the span of the working set's (a repeated plane, or three planes through
               one line) has A p = 0 in exact arithmetic; rounding must not let it block and make the set dependent */
            double G[9], Q[9];
            gram(A, W, nw, G);
            for (int64_t i = 0; i < nw; i++) memcpy(Q + 3 * i, A + 3 * W[i], 3 * sizeof(double));
            if (gauss_solve(nw, G, Q, 3)) {
                ret = CN_SINGULAR;
                break;
            }
            int64_t keep = 0;
            for (int64_t c = 0; c < nid; c++) {
                const double *a = A + 3 * ids[c];
                double co[3], off[3];
                for (int64_t i = 0; i < nw; i++) co[i] = dot3(a, A + 3 * W[i]);
                for (int j = 0; j < 3; j++) {
                    double s = 0.0;
                    for (int64_t i = 0; i < nw; i++) s += co[i] * Q[3 * i + j];
                    off[j] = a[j] - s;
                }
                if (sqrt(dot3(off, off)) > 1e-9 * row_norm[ids[c]]) ids[keep++] = ids[c];
            }
            nid = keep;
        }
        double alpha = 1.0;
        int64_t j = -1;
        if (nid) {
            int64_t kbest = -1;
            double rbest = 0.0;
            for (int64_t c = 0; c < nid; c++) {
                double s = slack[ids[c]];
                double ratio = (s > 0.0 || s != s ? s : 0.0) / Ap[ids[c]];
                if (better_min(ratio, rbest, kbest >= 0)) kbest = c, rbest = ratio;
            }
            if (rbest < 1.0) alpha = rbest, j = ids[kbest];
        }
        for (int i = 0; i < 3; i++) x[i] = x[i] + alpha * p[i];
        for (int64_t f = 0; f < F; f++) slack[f] = slack[f] - alpha * Ap[f];
        if (j >= 0 && nw < 3) W[nw++] = j;  /* p != 0 here, so nw < 3 before this */
    }
    if (ret == CN_DONE) memcpy(xout, x, sizeof(x));
    free(heap);
    return ret;
}

/* the dual method's working set: faces, their multipliers, and room for its Gram matrix and right-hand side */
typedef struct {
    int64_t n, cap;
    int64_t *W;
    double *u, *G, *r;
    int64_t W_s[STACK_W];
    double u_s[STACK_W], G_s[STACK_W * STACK_W], r_s[STACK_W];
    void *heap;
} WorkSet;

static int workset_reserve(WorkSet *s, int64_t need) {
    if (need <= s->cap) return 0;
    int64_t cap = 2 * s->cap;
    while (cap < need) cap *= 2;
    char *h = malloc((size_t)cap * (sizeof(int64_t) + 2 * sizeof(double)) + (size_t)cap * cap * sizeof(double));
    if (h == NULL) return CN_NOMEM;
    int64_t *W = (int64_t *)h;
    double *u = (double *)(W + cap), *r = u + cap, *G = r + cap;
    memcpy(W, s->W, (size_t)s->n * sizeof(int64_t));
    memcpy(u, s->u, (size_t)s->n * sizeof(double));
    free(s->heap);
    s->heap = h, s->W = W, s->u = u, s->r = r, s->G = G, s->cap = cap;
    return 0;
}

/* goal.project_dual_active_set: x [3] (out) from the target t [3]. CN_DONE, CN_NOT_FOUND (the polytope is empty),
   CN_UNFINISHED (more than max_iter steps, or a step rounding made untrustworthy), CN_SINGULAR or CN_NOMEM. */
int64_t cn_project_dual(const double *A, const double *b, int64_t F, const double *t, int64_t max_iter,
                        double *xout) {
    double stack[STACK_F];
    double *row2 = stack;
    void *heap = NULL;
    if (F > STACK_F) {
        heap = malloc((size_t)F * sizeof(double));
        if (heap == NULL) return CN_NOMEM;
        row2 = (double *)heap;
    }
    WorkSet s;
    s.n = 0, s.cap = STACK_W, s.W = s.W_s, s.u = s.u_s, s.G = s.G_s, s.r = s.r_s, s.heap = NULL;
    double x[3] = {t[0], t[1], t[2]};
    for (int64_t f = 0; f < F; f++) row2[f] = dot3(A + 3 * f, A + 3 * f);
    double scale = 1.0 + absmax(b, F) + absmax(x, 3);
    double tol = 1e-13 * scale;
    int64_t it = 0, ret = CN_DONE;
    for (;;) {
        if (F == 0) break;
        int64_t p = -1;
        double vp = 0.0;
        for (int64_t f = 0; f < F; f++) {  /* the most violated face (numpy's argmax: the first maximum) */
            double v = dot3(A + 3 * f, x) - b[f];
            if (p < 0 || (vp == vp && (v > vp || v != v))) p = f, vp = v;
        }
        double rn = sqrt(row2[p]);
        if (vp <= tol * (rn > 1.0 ? rn : 1.0)) break;
        const double *a = A + 3 * p;
        double up = 0.0;  /* multiplier of the face being added */
        for (;;) {
            if (++it > max_iter) {
                ret = CN_UNFINISHED;
                goto out;
            }
            int64_t k = s.n;
            double z[3];
            double *r = s.r;
            if (k) {
                gram(A, s.W, k, s.G);
                for (int64_t i = 0; i < k; i++) r[i] = dot3(A + 3 * s.W[i], a);
                if (gauss_solve(k, s.G, r, 1)) {
                    ret = CN_SINGULAR;
                    goto out;
                }
                for (int j = 0; j < 3; j++) {  /* dx per unit of u_p: minus a's part off the working set's span */
                    double acc = 0.0;
                    for (int64_t i = 0; i < k; i++) acc += A[3 * s.W[i] + j] * r[i];
                    z[j] = acc - a[j];
                }
            } else {
                z[0] = -a[0], z[1] = -a[1], z[2] = -a[2];
            }
            double zz = dot3(z, z);
            int dependent = zz <= 1e-18 * row2[p];
            double rthr = 1e-12 * (1.0 + absmax(r, k));
            double t1 = INFINITY;
            int64_t kk = -1;
            for (int64_t i = 0; i < k; i++)
                if (r[i] > rthr) {
                    double ratio = s.u[i] / r[i];
                    if (better_min(ratio, t1, kk >= 0)) kk = i, t1 = ratio;
                }
            double t2 = dependent ? INFINITY : (dot3(a, x) - b[p]) / zz;
            if (!isfinite(t1) && !isfinite(t2)) {
                ret = CN_NOT_FOUND;  /* a nonnegative combination of the working set's faces and face p is infeasible */
                goto out;
            }
            if (t2 < 0) {
                ret = CN_UNFINISHED;  /* rounding: face p no longer violated after a partial step */
                goto out;
            }
            double step = t2 < t1 ? t2 : t1;  /* Python's min(t1, t2) */
            if (isfinite(t2))
                for (int j = 0; j < 3; j++) x[j] = x[j] + step * z[j];
            for (int64_t i = 0; i < k; i++) s.u[i] = s.u[i] - step * r[i];
            up += step;
            if (step == t2) {  /* full step: face p joins the working set */
                if (workset_reserve(&s, k + 1)) {
                    ret = CN_NOMEM;
                    goto out;
                }
                s.W[k] = p, s.u[k] = up, s.n = k + 1;
                break;
            }
            for (int64_t i = kk; i + 1 < k; i++) s.W[i] = s.W[i + 1], s.u[i] = s.u[i + 1];  /* face kk leaves */
            s.n = k - 1;
        }
    }
out:
    if (ret == CN_DONE) memcpy(xout, x, sizeof(x));
    free(s.heap);
    free(heap);
    return ret;
}
