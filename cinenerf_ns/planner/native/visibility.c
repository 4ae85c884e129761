/* Optical depth of segments through semi-transparent Gaussians (geometry/visibility.py), compiled.

   Each Gaussian j is (mean mu_j, whitening W_j = diag(1 / sigma_j) R_j^T as 9 row-major doubles, opacity o_j,
   class c_j in {0, 1}). Along the segment x(t) = p0 + t (p1 - p0), t in [0, 1], its alpha is the 3D ray-tracing
   approximation of the splat's alpha: a_j = min(o_j exp(-m^2 / 2), ALPHA_MAX), m^2 = min_t |W_j (x(t) - mu_j)|^2,
   counted only for m^2 < cut2 (cut2 = (cut-off sigmas)^2); the segment's optical depth in class c is
   sum_j -log(1 - a_j) over the Gaussians of that class it meets. Gaussians are found in a uniform grid of cells
   (CSR: cell_start [C + 1], cell_ids [E]) that lists every Gaussian whose cut-off box meets the cell, plus a list of
   big Gaussians tested for every segment; a stamp per Gaussian makes each count once per segment. The walk visits
   every cell the segment passes (Amanatides-Woo), so it finds every Gaussian a brute-force loop finds: the point of
   the segment closest to a Gaussian lies in its cut-off box, hence in a visited cell that lists it.

   The same float64 arithmetic as visibility.py's optical_depth_walk_reference, term by term. */
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>

#define ALPHA_MAX 0.99

/* packed [N, 13]: mean (3), whitening rows (9), opacity (1): one Gaussian's numbers together in memory. sph [N, 4]
   (NULL: none): mean (3) and a bound s >= sigma_max^2 (1 + margin) per Gaussian: a segment farther than sqrt(cut2 s)
   from the mean is farther than cut2 in sigma units too (|W y| >= |y| / sigma_max), so the Gaussian is left out
   after reading 32 bytes instead of its 104 (the same Gaussians are added, in the same order: the same sums).
   d [4]: the segment's direction and d[3] = |d|^2. */
static inline void add_gaussian(int64_t j, const double *p0, const double *d, const double *packed,
                                const double *sph, const uint8_t *cls, double cut2, double *tau) {
    if (sph) {
        const double *s = sph + 4 * j;
        double f0 = p0[0] - s[0], f1 = p0[1] - s[1], f2 = p0[2] - s[2];
        double fd = (f0 * d[0] + f1 * d[1]) + f2 * d[2];
        double ts = d[3] > 0.0 ? -fd / d[3] : 0.0;
        if (ts < 0.0) ts = 0.0;
        if (ts > 1.0) ts = 1.0;
        double g0 = f0 + ts * d[0], g1 = f1 + ts * d[1], g2 = f2 + ts * d[2];
        if ((g0 * g0 + g1 * g1) + g2 * g2 > cut2 * s[3]) return;
    }
    const double *mu = packed + 13 * j;
    const double *w = mu + 3;
    double e0 = p0[0] - mu[0], e1 = p0[1] - mu[1], e2 = p0[2] - mu[2];
    double u[3], v[3];
    for (int r = 0; r < 3; r++) {
        u[r] = (w[3 * r] * e0 + w[3 * r + 1] * e1) + w[3 * r + 2] * e2;
        v[r] = (w[3 * r] * d[0] + w[3 * r + 1] * d[1]) + w[3 * r + 2] * d[2];
    }
    double vv = (v[0] * v[0] + v[1] * v[1]) + v[2] * v[2];
    double uv = (u[0] * v[0] + u[1] * v[1]) + u[2] * v[2];
    double t = vv > 0.0 ? -uv / vv : 0.0;
    if (t < 0.0) t = 0.0;
    if (t > 1.0) t = 1.0;
    double q0 = u[0] + t * v[0], q1 = u[1] + t * v[1], q2 = u[2] + t * v[2];
    double m2 = (q0 * q0 + q1 * q1) + q2 * q2;
    if (!(m2 < cut2)) return;
    double a = mu[12] * exp(-0.5 * m2);
    if (a > ALPHA_MAX) a = ALPHA_MAX;
    tau[cls[j] ? 1 : 0] += -log1p(-a);
}

/* Walk the cells of one grid (lo, cell, dims, CSR) that segment p0 + t d, t in [0, 1], passes (Amanatides-Woo),
   adding each listed Gaussian not yet stamped with mark; the early stops of cn_optical_depth. */
static void walk_grid(const double *lo, const double *box_hi, double cell, const int64_t *dims, const int64_t *cell_start,
                      const int32_t *cell_ids, const double *p0, const double *d, int32_t *stamp, int32_t mark,
                      const double *packed, const double *sph, const uint8_t *cls, double cut2, double *tl,
                      double stop1, double stop0, double after1) {
    const int64_t X = dims[0], Y = dims[1], Z = dims[2];
    /* clip the segment to the volume's box [lo, box_hi] (the fine grid's; slab test), then walk its cells */
    double t0 = 0.0, t1 = 1.0;
    for (int a = 0; a < 3; a++) {
        double hi = box_hi[a];
        if (d[a] == 0.0) {
            if (p0[a] < lo[a] || p0[a] > hi) return;
        } else {
            double ta = (lo[a] - p0[a]) / d[a], tb = (hi - p0[a]) / d[a];
            if (ta > tb) { double s = ta; ta = tb; tb = s; }
            if (ta > t0) t0 = ta;
            if (tb < t1) t1 = tb;
            if (t0 > t1) return;
        }
    }
    int64_t idx[3], step[3];
    double tmax[3], tdelta[3];
    for (int a = 0; a < 3; a++) {
        double x = p0[a] + t0 * d[a];
        int64_t i = (int64_t)floor((x - lo[a]) / cell);
        if (i < 0) i = 0;
        if (i >= dims[a]) i = dims[a] - 1;
        idx[a] = i;
        if (d[a] > 0.0) {
            step[a] = 1;
            tmax[a] = (lo[a] + (double)(i + 1) * cell - p0[a]) / d[a];
            tdelta[a] = cell / d[a];
        } else if (d[a] < 0.0) {
            step[a] = -1;
            tmax[a] = (lo[a] + (double)i * cell - p0[a]) / d[a];
            tdelta[a] = -cell / d[a];
        } else {
            step[a] = 0;
            tmax[a] = INFINITY;
            tdelta[a] = INFINITY;
        }
    }
    for (;;) {
        int64_t c = (idx[0] * Y + idx[1]) * Z + idx[2];
        for (int64_t e = cell_start[c]; e < cell_start[c + 1]; e++) {
            int64_t j = cell_ids[e];
            if (stamp[j] == mark) continue;
            stamp[j] = mark;
            add_gaussian(j, p0, d, packed, sph, cls, cut2, tl);
        }
        if (tl[1] > stop1) return;
        int a = tmax[0] < tmax[1] ? (tmax[0] < tmax[2] ? 0 : 2) : (tmax[1] < tmax[2] ? 1 : 2);
        if (tmax[a] > t1) return;
        if (tl[0] > stop0 && tmax[a] >= after1) return; /* the next cell starts at tmax[a] */
        idx[a] += step[a];
        if (idx[a] < 0 || idx[a] >= (a == 0 ? X : (a == 1 ? Y : Z))) return;
        tmax[a] += tdelta[a];
    }
}

/* What one thread needs: the volume, the segments and the range [l0, l1) it walks. */
typedef struct {
    const double *packed, *sph;
    const uint8_t *cls;
    int64_t N;
    const double *lo;
    double cell;
    const int64_t *dims, *cell_start;
    const int32_t *cell_ids;
    double ccell;
    const int64_t *cdims, *ccell_start;
    const int32_t *ccell_ids, *big;
    int64_t n_big;
    double cut2;
    const double *p0s, *p1s;
    const int64_t *skip;
    int64_t l0, l1;
    double stop1, stop0;
    const double *after1;
    double *tau;
    int64_t rc;
} depth_job;

/* Segments [l0, l1) of a job, with the job's own stamp array (segments are independent: each thread writes only its
   own rows of tau, so the sums are the same whatever the number of threads). */
static void *depth_range(void *arg) {
    depth_job *jb = (depth_job *)arg;
    int32_t *stamp = (int32_t *)calloc((size_t)(jb->N > 0 ? jb->N : 1), sizeof(int32_t));
    if (!stamp) {
        jb->rc = -1;
        return NULL;
    }
    double box_hi[3];
    for (int a = 0; a < 3; a++) box_hi[a] = jb->lo[a] + (double)jb->dims[a] * jb->cell;
    for (int64_t l = jb->l0; l < jb->l1; l++) {
        const double *p0 = jb->p0s + 3 * l, *p1 = jb->p1s + 3 * l;
        double d[4] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2], 0.0};
        d[3] = (d[0] * d[0] + d[1] * d[1]) + d[2] * d[2];
        double *tl = jb->tau + 2 * l;
        tl[0] = 0.0;
        tl[1] = 0.0;
        const int32_t mark = (int32_t)((l - jb->l0) % 2147483647) + 1;  /* unique within a job of < 2^31 segments */
        const double a1 = jb->after1 ? jb->after1[l] : INFINITY;
        if (jb->skip[l] >= 0 && jb->skip[l] < jb->N) stamp[jb->skip[l]] = mark;
        for (int64_t b = 0; b < jb->n_big; b++) {
            int64_t j = jb->big[b];
            if (stamp[j] == mark) continue;
            stamp[j] = mark;
            add_gaussian(j, p0, d, jb->packed, jb->sph, jb->cls, jb->cut2, tl);
        }
        if (tl[1] > jb->stop1) continue;
        if (jb->ccell > 0.0) {
            walk_grid(jb->lo, box_hi, jb->ccell, jb->cdims, jb->ccell_start, jb->ccell_ids, p0, d, stamp, mark,
                      jb->packed, jb->sph, jb->cls, jb->cut2, tl, jb->stop1, jb->stop0, a1);
            if (tl[1] > jb->stop1) continue;
        }
        walk_grid(jb->lo, box_hi, jb->cell, jb->dims, jb->cell_start, jb->cell_ids, p0, d, stamp, mark, jb->packed,
                  jb->sph, jb->cls, jb->cut2, tl, jb->stop1, jb->stop0, a1);
    }
    free(stamp);
    jb->rc = 0;
    return NULL;
}

#define MAX_THREADS 64

/* tau [L, 2]: optical depth of segment l (p0[l] -> p1[l]) in class 0 and class 1; skip[l] >= 0: a Gaussian that
   segment l ignores (its own target), -1: none. Gaussians are listed in a fine grid (cell) and, those whose box spans
   too many fine cells, in a coarse one (ccell > 0, same lo); the few spanning too many coarse cells are tested for
   every segment (big). The walk of a segment stops once its class-1 depth exceeds stop1 (its light is then below
   exp(-stop1) in any case; both sums are then partial, class 1's still above stop1), and once its class-0 depth
   exceeds stop0 in a cell that starts beyond after1[l] (no class-1 Gaussian lies beyond that parameter: class 1's
   sum is then whole, class 0's partial but above stop0); after1 NULL: never. The segments are split over
   n_threads threads (1: this thread; a thread that cannot start is walked here). Each thread's results are the
   same as one thread's: tau does not depend on n_threads.
   sph [N, 4] or NULL: each Gaussian's mean and bound for a cheaper test first (add_gaussian).
   Returns 0, or -1 on bad arguments / no memory. */
int64_t cn_optical_depth(const double *packed, const double *sph, const uint8_t *cls, int64_t N,
                         const double *lo, double cell, const int64_t *dims, const int64_t *cell_start,
                         const int32_t *cell_ids, double ccell, const int64_t *cdims, const int64_t *ccell_start,
                         const int32_t *ccell_ids, const int32_t *big, int64_t n_big, double cut2,
                         const double *p0s, const double *p1s, const int64_t *skip, int64_t L, double stop1,
                         double stop0, const double *after1, double *tau, int64_t n_threads) {
    if (cell <= 0.0 || N < 0 || L < 0) return -1;
    if (n_threads < 1) n_threads = 1;
    if (n_threads > MAX_THREADS) n_threads = MAX_THREADS;
    if (n_threads > L) n_threads = L > 0 ? L : 1;
    depth_job jobs[MAX_THREADS];
    pthread_t tid[MAX_THREADS];
    int started[MAX_THREADS];
    for (int64_t t = 0; t < n_threads; t++) {
        depth_job jb = {packed, sph, cls, N, lo, cell, dims, cell_start, cell_ids, ccell, cdims, ccell_start, ccell_ids,
                        big, n_big, cut2, p0s, p1s, skip, L * t / n_threads, L * (t + 1) / n_threads, stop1, stop0,
                        after1, tau, -1};
        jobs[t] = jb;
    }
    for (int64_t t = 1; t < n_threads; t++)
        started[t] = pthread_create(&tid[t], NULL, depth_range, &jobs[t]) == 0;
    depth_range(&jobs[0]);
    int64_t rc = jobs[0].rc;
    for (int64_t t = 1; t < n_threads; t++) {
        if (started[t])
            pthread_join(tid[t], NULL);
        else
            depth_range(&jobs[t]);  /* no thread: walk its range here */
        if (jobs[t].rc != 0) rc = -1;
    }
    return rc;
}
