/* The occupancy grid's segment proofs and polytopes (voxel_traversal.py, grid_polytope.py), compiled.

   cn_segments_free: voxel_traversal.segments_in_free_voxels for many segments (the same probes: the midpoint of
   every piece between consecutive face crossings, each claiming every voxel within EPS of it), stopping at a
   segment's first occupied probe voxel. cn_grid_polytope: grid_polytope.grid_polytope_planes (greedy, nearest
   surface cube first with exact segment-to-cube closest points; cubes entirely beyond a kept plane dropped).
   cn_shortcut_rounds: the grid part of the line-of-sight shortcut's rounds (search/shortcut.py: shortcut_pass).
   Contraction into fused multiply-adds would round differently from numpy: it is turned off.
   The proofs of safety are in those modules' docstrings; this file only repeats their arithmetic in C. */
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* min / max of two numbers that cannot be NaN, inlined (fmin / fmax are library calls at -O2, for their NaN rules) */
static inline double mn(double a, double b) { return b < a ? b : a; }
static inline double mx(double a, double b) { return b > a ? b : a; }

static int cmp_double(const void *x, const void *y) {
    double a = *(const double *)x, b = *(const double *)y;
    return (a > b) - (a < b);
}

/* 1 when every voxel within eps of the probe u0 + tm d (voxel units) is inside the grid and free */
static int probe_free(const uint8_t *occ, const int64_t *shape, const double u0[3], const double d[3], double tm,
                      double eps) {
    int64_t va[3], vb[3];
    for (int a = 0; a < 3; a++) {
        double u = u0[a] + tm * d[a];
        va[a] = (int64_t)floor(u - eps);
        vb[a] = (int64_t)floor(u + eps);
    }
    for (int c = 0; c < 8; c++) {
        int64_t v[3] = {c & 4 ? vb[0] : va[0], c & 2 ? vb[1] : va[1], c & 1 ? vb[2] : va[2]};
        if (v[0] < 0 || v[1] < 0 || v[2] < 0 || v[0] >= shape[0] || v[1] >= shape[1] || v[2] >= shape[2]) return 0;
        if (occ[(v[0] * shape[1] + v[1]) * shape[2] + v[2]]) return 0;
    }
    return 1;
}

/* 1 when every probe voxel of the segment u0 -> u1 (voxel units) is inside the grid and free. The probes are the
   midpoints of consecutive t of the sorted list [0, face crossings, 1] (voxel_traversal.segment_voxels). Each axis'
   crossings, clamped to [0, 1], form a monotone run (increasing in the plane index when d > 0, decreasing when
   d < 0), so merging the three runs walks that sorted list in order: no sort, and the walk stops at the first
   occupied probe. */
static int segment_free(const uint8_t *occ, const int64_t *shape, const double u0[3], const double u1[3],
                        double eps) {
    double d[3], first[3], head[3];
    int64_t count[3], used[3] = {0, 0, 0};
    for (int a = 0; a < 3; a++) {
        d[a] = u1[a] - u0[a];
        double lo = fmin(u0[a], u1[a]), hi = fmax(u0[a], u1[a]);
        first[a] = floor(lo) + 1.0;
        double c = ceil(hi) - first[a];
        count[a] = c > 0 ? (int64_t)c : 0;
    }
#define CROSSING(a, k) mn(mx((first[a] + (double)(d[a] > 0 ? (k) : count[a] - 1 - (k)) - u0[a]) / d[a], 0.0), 1.0)
    for (int a = 0; a < 3; a++) head[a] = count[a] > 0 ? CROSSING(a, 0) : INFINITY;
    double prev = 0.0;
    for (;;) {
        int a = head[0] <= head[1] ? 0 : 1;
        if (head[2] < head[a]) a = 2;
        int last = head[a] == INFINITY;  /* every crossing used: the last piece ends at t = 1 */
        double t = last ? 1.0 : head[a];
        if (!probe_free(occ, shape, u0, d, 0.5 * (prev + t), eps)) return 0;
        if (last) return 1;
        prev = t;
        used[a]++;
        head[a] = used[a] < count[a] ? CROSSING(a, used[a]) : INFINITY;
    }
#undef CROSSING
}

/* out[i] = 1 when segment p0[i] -> p1[i] (world, [P, 3]) lies in free voxels of occ ([X, Y, Z] uint8, voxel v spans
   lo + vs [v, v + 1]). Returns 0. */
int64_t cn_segments_free(const uint8_t *occ, const int64_t *shape, const double *lo, double vs, const double *p0,
                         const double *p1, int64_t P, double eps, uint8_t *out) {
    for (int64_t i = 0; i < P; i++) {
        double u0[3], u1[3];
        for (int a = 0; a < 3; a++) {
            u0[a] = (p0[3 * i + a] - lo[a]) / vs;
            u1[a] = (p1[3 * i + a] - lo[a]) / vs;
        }
        out[i] = (uint8_t)segment_free(occ, shape, u0, u1, eps);
    }
    return 0;
}

/* shortcut.FreeVoxels.contains for one world point: its voxel floor((p - lo) / vs) is inside the grid and free */
static int point_free(const uint8_t *occ, const int64_t *shape, const double *lo, double vs, const double p[3]) {
    int64_t v[3];
    for (int a = 0; a < 3; a++) {
        double f = floor((p[a] - lo[a]) / vs);
        if (!(f >= 0.0 && f < (double)shape[a])) return 0;
        v[a] = (int64_t)f;
    }
    return !occ[(v[0] * shape[1] + v[1]) * shape[2] + v[2]];
}

/* shortcut.grid_sight for one world segment p0 -> p1: every sample p0 + (k / (n - 1)) (p1 - p0), n = max(2,
   ceil(L / (vs / 2)) + 1), farther than one voxel from both ends, lies in a free voxel (numpy's arithmetic in its
   order: L = sqrt((x*x + y*y) + z*z)) */
static int grid_sight(const uint8_t *occ, const int64_t *shape, const double *lo, double vs, const double p0[3],
                      const double p1[3]) {
    double d[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
    double L = sqrt((d[0] * d[0] + d[1] * d[1]) + d[2] * d[2]);
    double c = ceil(L / (0.5 * vs));
    if (!(c < 4e18)) return 1;  /* NaN or infinite length: numpy's cast makes n = 2 (no sample); the pieces decide */
    int64_t n = (int64_t)c + 1;
    if (n < 2) n = 2;
    for (int64_t k = 1; k + 1 < n; k++) {  /* the ends (frac 0 and 1) are never farther than a voxel from both */
        double frac = (double)k / (double)(n - 1);
        if (!(fmin(frac, 1.0 - frac) * L > vs)) continue;
        double q[3] = {p0[0] + frac * d[0], p0[1] + frac * d[1], p0[2] + frac * d[2]};
        if (!point_free(occ, shape, lo, vs, q)) return 0;
    }
    return 1;
}

/* Greedy shortcut rounds (search/astar.py: batched_shortcut with search/shortcut.py: shortcut_test) for W polylines
   laid end to end in pts ([N, 3] world; polyline w is rows off[w] .. off[w + 1] - 1), up to the Corollary-1 pieces,
   which stay in Python. keep [N] holds polyline w's kept indices (local, increasing) from off[w], nkeep[w] of them
   (>= 1; the last one is the current point). A round from current point c asks j = K - 1 down to c + 2: the voxel
   walk (grid walk_*) accepting j ends the round at j; a refused j whose ends are not both in free voxels of grid
   free_* (or any refused j when grid_rule is 0) and that has grid sight is a candidate for the pieces. A round
   without candidates beyond its walk's answer jumps there (or to c + 1) and the next round starts; a round with
   candidates stops the polyline: cand[off[w] ..] = those j (decreasing), ncand[w] = their count, best[w] = the
   walk's answer (or c + 1); the caller jumps to the first candidate the pieces prove free, else best[w], and calls
   again. ncand[w] = 0: polyline w is finished (its last kept index is K - 1). Returns 0. */
int64_t cn_shortcut_rounds(const uint8_t *walk_occ, const int64_t *walk_shape, const double *walk_lo, double walk_vs,
                           double eps, const uint8_t *free_occ, const int64_t *free_shape, const double *free_lo,
                           double free_vs, int64_t grid_rule, const double *pts, const int64_t *off, int64_t W,
                           int64_t *keep, int64_t *nkeep, int64_t *best, int64_t *cand, int64_t *ncand) {
    for (int64_t w = 0; w < W; w++) {
        const double *P = pts + 3 * off[w];
        int64_t K = off[w + 1] - off[w];
        int64_t *kw = keep + off[w];
        ncand[w] = 0;
        while (kw[nkeep[w] - 1] < K - 1) {
            int64_t c = kw[nkeep[w] - 1], jump = c + 1, nc = 0;
            double u0[3];
            for (int a = 0; a < 3; a++) u0[a] = (P[3 * c + a] - walk_lo[a]) / walk_vs;
            int c_free = grid_rule ? point_free(free_occ, free_shape, free_lo, free_vs, P + 3 * c) : 0;
            for (int64_t j = K - 1; j >= c + 2; j--) {
                double u1[3];
                for (int a = 0; a < 3; a++) u1[a] = (P[3 * j + a] - walk_lo[a]) / walk_vs;
                if (segment_free(walk_occ, walk_shape, u0, u1, eps)) {
                    jump = j;
                    break;
                }
                if (c_free && point_free(free_occ, free_shape, free_lo, free_vs, P + 3 * j)) continue;
                if (grid_sight(free_occ, free_shape, free_lo, free_vs, P + 3 * c, P + 3 * j)) cand[off[w] + nc++] = j;
            }
            if (nc) {
                best[w] = jump;
                ncand[w] = nc;
                break;
            }
            kw[nkeep[w]++] = jump;
        }
    }
    return 0;
}

/* grid_polytope.segment_box_closest for one cube [v, v + 1]: closest points q (segment), p (cube), distance */
static double seg_cube_closest(const double u0[3], const double d[3], const double v[3], double q[3], double p[3]) {
    double T[8];
    int n = 0;
    T[n++] = 0.0;
    T[n++] = 1.0;
    for (int a = 0; a < 3; a++) {
        for (int s = 0; s < 2; s++) {
            double tb = (v[a] + (double)s - u0[a]) / d[a];
            T[n++] = isfinite(tb) ? fmin(fmax(tb, 0.0), 1.0) : 0.0;
        }
    }
    qsort(T, 8, sizeof(double), cmp_double);
    double cand[15];
    int nc = 0;
    for (int j = 0; j < 8; j++) cand[nc++] = T[j];
    for (int j = 0; j < 7; j++) {
        double mid = 0.5 * (T[j] + T[j + 1]), c[3], dd[3], den = 0.0, num = 0.0;
        for (int a = 0; a < 3; a++) {
            double qm = u0[a] + mid * d[a];
            int active = qm < v[a] || qm > v[a] + 1.0;
            double bnd = qm < v[a] ? v[a] : v[a] + 1.0;
            c[a] = active ? u0[a] - bnd : 0.0;
            dd[a] = active ? d[a] : 0.0;
            den += dd[a] * dd[a];
            num += c[a] * dd[a];
        }
        double ts = den > 0 ? -num / den : mid;
        cand[nc++] = fmin(fmax(ts, T[j]), T[j + 1]);
    }
    double best = INFINITY;
    for (int k = 0; k < nc; k++) {
        double qq[3], pp[3], f = 0.0;
        for (int a = 0; a < 3; a++) {
            qq[a] = u0[a] + cand[k] * d[a];
            pp[a] = fmin(fmax(qq[a], v[a]), v[a] + 1.0);
            f += (qq[a] - pp[a]) * (qq[a] - pp[a]);
        }
        if (f < best) {  /* first minimum, like numpy's argmin */
            best = f;
            memcpy(q, qq, sizeof qq);
            memcpy(p, pp, sizeof pp);
        }
    }
    return sqrt(best);
}

typedef struct {
    double lb, v[3];
    int64_t order;  /* position in the scan: ties keep the scan order (numpy's stable argsort) */
    int64_t bucket;  /* cn_grid_polytope: its lower bound's bucket */
} Cube;

static int cmp_cube(const void *x, const void *y) {
    const Cube *a = (const Cube *)x, *b = (const Cube *)y;
    if (a->lb != b->lb) return (a->lb > b->lb) - (a->lb < b->lb);
    return (a->order > b->order) - (a->order < b->order);
}

static inline int cube_less(const Cube *a, const Cube *b) {
    return a->lb < b->lb || (a->lb == b->lb && a->order < b->order);
}

/* The order of qsort(c, n, sizeof(Cube), cmp_cube) (a total order: no two cubes share ``order``), with the comparison
   inlined: quicksort (Hoare partition around the middle element), insertion sort below 16 elements, and qsort for
   what is left past a depth limit. qsort's calls through the comparator were ~3% of a 1M-Gaussian request. */
static void sort_cubes(Cube *c, int64_t n, int depth) {
    while (n > 16) {
        if (depth-- <= 0) {
            qsort(c, (size_t)n, sizeof(Cube), cmp_cube);
            return;
        }
        Cube pivot = c[n / 2], t;
        int64_t i = -1, j = n;
        for (;;) {
            do i++; while (cube_less(&c[i], &pivot));
            do j--; while (cube_less(&pivot, &c[j]));
            if (i >= j) break;
            t = c[i]; c[i] = c[j]; c[j] = t;
        }
        /* [0, j] and [j + 1, n): recurse into the smaller, loop on the larger */
        if (j + 1 < n - j - 1) {
            sort_cubes(c, j + 1, depth);
            c += j + 1;
            n -= j + 1;
        } else {
            sort_cubes(c + j + 1, n - j - 1, depth);
            n = j + 1;
        }
    }
    for (int64_t i = 1; i < n; i++) {
        Cube x = c[i];
        int64_t k = i - 1;
        for (; k >= 0 && cube_less(&x, &c[k]); k--) c[k + 1] = c[k];
        c[k + 1] = x;
    }
}

/* grid_polytope_planes: writes the planes after the box's 6 (n [F, 3], b [F], voxel units) and returns F (the
   count after the box's), -3 for None (segment within margin of a surface cube, or rounding broke a plane; the
   caller must build a Prop-2 polytope), -2 when more than cap planes are needed, -1 out of memory.
   blo/bhi: the box, already clipped to the grid and holding the segment (checked by the caller). */
/* sort_cubes on its own, for its test (tests/planner/test_native.py): cubes with lower bounds lb [n] and order =
   their index, sorted; out[i] = the order of the i-th. depth: sort_cubes' depth limit (small: its qsort fallback).
   Returns 0, or -1 out of memory. */
int64_t cn_sort_cubes(const double *lb, int64_t n, int64_t depth, int64_t *out) {
    Cube *c = (Cube *)malloc((n ? n : 1) * sizeof(Cube));
    if (!c) return -1;
    for (int64_t i = 0; i < n; i++) {
        c[i].lb = lb[i];
        c[i].v[0] = c[i].v[1] = c[i].v[2] = 0.0;
        c[i].order = i;
    }
    sort_cubes(c, n, (int)depth);
    for (int64_t i = 0; i < n; i++) out[i] = c[i].order;
    free(c);
    return 0;
}

int64_t cn_grid_polytope(const uint8_t *surface, const int64_t *shape, const double *u0, const double *u1,
                         const double *blo, const double *bhi, double margin, int64_t cap, double *out_n,
                         double *out_b) {
    int64_t a0[3], e0[3];
    for (int i = 0; i < 3; i++) {
        int64_t a = (int64_t)ceil(blo[i]) - 1, e = (int64_t)floor(bhi[i]) + 1;
        a0[i] = a > 0 ? a : 0;
        e0[i] = e < shape[i] ? e : shape[i];
    }
    double d[3] = {u1[0] - u0[0], u1[1] - u0[1], u1[2] - u0[2]};
    double dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    int64_t K = 0, kcap = 256;
    Cube *cubes = (Cube *)malloc(kcap * sizeof(Cube));
    if (!cubes) return -1;
    for (int64_t x = a0[0]; x < e0[0]; x++)
        for (int64_t y = a0[1]; y < e0[1]; y++)
            for (int64_t z = a0[2]; z < e0[2]; z++) {
                if (!surface[(x * shape[1] + y) * shape[2] + z]) continue;
                if (K == kcap) {
                    Cube *nc = (Cube *)realloc(cubes, 2 * kcap * sizeof(Cube));
                    if (!nc) { free(cubes); return -1; }
                    cubes = nc;
                    kcap *= 2;
                }
                Cube *c = cubes + K;
                c->v[0] = (double)x; c->v[1] = (double)y; c->v[2] = (double)z;
                double cen[3] = {c->v[0] + 0.5, c->v[1] + 0.5, c->v[2] + 0.5}, t = 0.0, dist2 = 0.0;
                if (dd > 0)
                    t = mn(mx(((cen[0] - u0[0]) * d[0] + (cen[1] - u0[1]) * d[1] + (cen[2] - u0[2]) * d[2]) / dd, 0.0),
                             1.0);
                for (int i = 0; i < 3; i++) {
                    double r = u0[i] + t * d[i] - cen[i];
                    dist2 += r * r;
                }
                c->lb = sqrt(dist2) - 0.5 * sqrt(3.0);
                c->order = K;
                K++;
            }
    /* The scan below visits the alive cubes in ascending (lower bound, scan order), as the Python construction's
       stable argsort. A full sort of the K cubes (~1000 at 1M Gaussians) was most of this function's time, yet a
       polytope needs ~6 planes and the scan stops at the first few cubes. So the cubes are grouped into buckets of
       their lower bound (counting sort, O(K)); the bucket of a lower bound is monotone in it, so the buckets in
       order, each sorted, are the full sorted order, and a bucket is sorted only when the scan first reaches it. */
    int64_t nb = K < 64 ? 1 : (K / 8 < 4096 ? K / 8 : 4096);
    double lbmin = INFINITY, lbmax = -INFINITY;
    for (int64_t i = 0; i < K; i++) { lbmin = mn(lbmin, cubes[i].lb); lbmax = mx(lbmax, cubes[i].lb); }
    double scale = lbmax > lbmin ? (double)nb / (lbmax - lbmin) : 0.0;
    double *dist = (double *)malloc((K ? K : 1) * sizeof(double));
    double *qs = (double *)malloc((K ? K : 1) * 3 * sizeof(double)), *ps = (double *)malloc((K ? K : 1) * 3 * sizeof(double));
    int64_t *live = (int64_t *)malloc((K ? K : 1) * sizeof(int64_t)); /* alive cubes, grouped by bucket */
    int64_t *bs = (int64_t *)calloc(2 * nb + 1, sizeof(int64_t)), *be = bs ? bs + nb : NULL;  /* bucket ranges */
    unsigned char *sorted = (unsigned char *)calloc(nb, 1);
    Cube *tmp = NULL;
    int64_t F = 0, status;
    if (!dist || !qs || !ps || !live || !bs || !sorted) { status = -1; goto done; }
    for (int64_t i = 0; i < K; i++) {
        dist[i] = NAN;
        double q = (cubes[i].lb - lbmin) * scale;  /* >= 0, monotone in lb (rounding keeps it so) */
        cubes[i].bucket = q < (double)nb ? (q > 0.0 ? (int64_t)q : 0) : nb - 1;
        be[cubes[i].bucket]++;
    }
    for (int64_t b = 0, at = 0; b < nb; b++) { bs[b] = at; at += be[b]; be[b] = bs[b]; }
    for (int64_t i = 0; i < K; i++) live[be[cubes[i].bucket]++] = i;  /* scan order within a bucket */
    for (;;) {
        /* the nearest alive cube, exactly: lower bounds in ascending order stop the scan */
        int64_t best = -1;
        int stop = 0;
        for (int64_t b = 0; b < nb && !stop; b++) {
            int64_t n = be[b] - bs[b];
            if (!sorted[b] && n > 1) {  /* the bucket's alive cubes by (lower bound, scan order) */
                if (!tmp && !(tmp = (Cube *)malloc(K * sizeof(Cube)))) { status = -1; goto done; }
                for (int64_t r = 0; r < n; r++) tmp[r] = cubes[live[bs[b] + r]];
                sort_cubes(tmp, n, 64);
                for (int64_t r = 0; r < n; r++) live[bs[b] + r] = tmp[r].order;
            }
            sorted[b] = 1;
            for (int64_t r = bs[b]; r < be[b]; r++) {
                int64_t i = live[r];
                if (best >= 0 && dist[best] <= cubes[i].lb) { stop = 1; break; }
                if (isnan(dist[i])) dist[i] = seg_cube_closest(u0, d, cubes[i].v, qs + 3 * i, ps + 3 * i);
                if (best < 0 || dist[i] < dist[best]) best = i;
            }
        }
        if (best < 0) break;
        if (dist[best] <= margin) { status = -3; goto done; }
        double n[3], neg = 0.0, nv = 0.0;
        for (int a = 0; a < 3; a++) {
            n[a] = (ps[3 * best + a] - qs[3 * best + a]) / dist[best];
            neg += fmin(n[a], 0.0);
            nv += n[a] * cubes[best].v[a];
        }
        double off = nv + neg - margin;  /* min over the cube of n.y, minus the margin */
        double s0 = n[0] * u0[0] + n[1] * u0[1] + n[2] * u0[2], s1 = n[0] * u1[0] + n[1] * u1[1] + n[2] * u1[2];
        if (fmax(s0, s1) > off) { status = -3; goto done; }
        if (F == cap) { status = -2; goto done; }
        memcpy(out_n + 3 * F, n, sizeof n);
        out_b[F] = off;
        F++;
        /* drop the cubes entirely beyond the plane; the rest stay in order, bucket by bucket (the scan above only
           visits them) */
        int64_t kept = 0;
        for (int64_t b = 0; b < nb; b++) {
            int64_t from = bs[b], to = be[b];
            bs[b] = kept;
            for (int64_t r = from; r < to; r++) {
                const double *v = cubes[live[r]].v;
                if (!(v[0] * n[0] + v[1] * n[1] + v[2] * n[2] + neg >= off)) live[kept++] = live[r];
            }
            be[b] = kept;
        }
    }
    status = F;
done:
    free(cubes); free(dist); free(qs); free(ps); free(live); free(bs); free(sorted); free(tmp);
    return status;
}

/* grid_polytope.VoxelObstacles.polytope in one call (world units in and out): the segment a -> c must lie in free
   voxels of occ (segment_free, -4 otherwise); its box is the segment's bounding box grown by box_margin, in voxel
   units, clipped to the grid, and must hold the segment (-3 otherwise); then cn_grid_polytope's planes (margin in
   world units). out_n [cap, 3], out_b [cap]: the box's six faces (I, -I) first, then the planes, with offsets back
   in world units (n.u <= b, u = (x - lo) / vs  <=>  n.x <= vs b + n.lo). Returns the number of rows F, or -4 / -3
   (no grid polytope: the caller builds an exact one), -2 (more than cap rows), -1 (out of memory). */
int64_t cn_grid_polytope_world(const uint8_t *occ, const uint8_t *surface, const int64_t *shape, const double *lo,
                               double vs, const double *a, const double *c, double box_margin, double margin,
                               double eps, int64_t cap, double *out_n, double *out_b) {
    double u0[3], u1[3], blo[3], bhi[3];
    for (int i = 0; i < 3; i++) {
        u0[i] = (a[i] - lo[i]) / vs;
        u1[i] = (c[i] - lo[i]) / vs;
    }
    if (!segment_free(occ, shape, u0, u1, eps)) return -4;
    for (int i = 0; i < 3; i++) {
        double s = (double)shape[i];
        blo[i] = mn(mx((mn(a[i], c[i]) - box_margin - lo[i]) / vs, 0.0), s);
        bhi[i] = mn(mx((mx(a[i], c[i]) + box_margin - lo[i]) / vs, 0.0), s);
        if (!(u0[i] >= blo[i] && u1[i] >= blo[i] && u0[i] <= bhi[i] && u1[i] <= bhi[i] && bhi[i] > blo[i])) return -3;
    }
    if (cap < 6) return -2;
    int64_t F = cn_grid_polytope(surface, shape, u0, u1, blo, bhi, margin / vs, cap - 6, out_n + 18, out_b + 6);
    if (F < 0) return F;
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++) {
            out_n[3 * i + j] = i == j ? 1.0 : 0.0;
            out_n[3 * (i + 3) + j] = i == j ? -1.0 : 0.0;
        }
        out_b[i] = bhi[i];
        out_b[i + 3] = -blo[i];
    }
    for (int64_t f = 0; f < F + 6; f++) {
        const double *n = out_n + 3 * f;
        out_b[f] = vs * out_b[f] + (n[0] * lo[0] + n[1] * lo[1] + n[2] * lo[2]);
    }
    return F + 6;
}

/* cn_grid_polytope_world for every segment pts[i] -> pts[i + 1] (i < n) of a polyline in one call (the corridor's
   grid polytopes: one call per path instead of one per segment; each segment's rows are those cn_grid_polytope_world
   gives it alone). skip [n] (or NULL): segments to leave out (they get count 0). The rows go one segment after the
   other into out_n [cap, 3] / out_b [cap]; counts [n] gets each segment's row count, or -4 / -3 (no grid polytope),
   0 (skipped). Returns the total number of rows, -2 (more than cap rows in all: call again with more room) or -1
   (out of memory). */
int64_t cn_grid_polytopes_world(const uint8_t *occ, const uint8_t *surface, const int64_t *shape, const double *lo,
                                double vs, const double *pts, int64_t n, const uint8_t *skip, double box_margin,
                                double margin, double eps, int64_t cap, double *out_n, double *out_b,
                                int64_t *counts) {
    int64_t used = 0;
    for (int64_t i = 0; i < n; i++) {
        if (skip && skip[i]) {
            counts[i] = 0;
            continue;
        }
        int64_t F = cn_grid_polytope_world(occ, surface, shape, lo, vs, pts + 3 * i, pts + 3 * (i + 1), box_margin,
                                           margin, eps, cap - used, out_n + 3 * used, out_b + used);
        if (F == -3 || F == -4) {
            counts[i] = F;
            continue;
        }
        if (F < 0) return F;
        counts[i] = F;
        used += F;
    }
    return used;
}
