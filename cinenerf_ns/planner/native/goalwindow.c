/* One window of the goal's voxel fallback (search/goal.py _nearest_free_voxel_centre), compiled.

   cn_goal_window: the voxels of the window [a, e) that are free, reachable and hold no Gaussian mean, as the numpy
   code finds them (sub = ~occ & reachable; sub &= ~mean; argwhere in C order), their centres lo + (ijk + 0.5) vs
   and distances to the target, and the first `limit` of them in the order of a stable argsort of the distance. Why:
   the numpy code makes ~8 passes over a window that grows to ~33^3 voxels, ~0.4 ms a goal on the CPU box; one
   pass here. The distance is sqrt((dx^2 + dy^2) + dz^2) with contraction off, numpy's sum order for 3 terms, so the
   order (ties included) is the numpy order. */
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

typedef struct {
    double d;
    int64_t i;
} Cand;

static int before(const Cand *x, const Cand *y) { return x->d < y->d || (x->d == y->d && x->i < y->i); }

/* sort c [n] by (d, i) (n: about limit; insertion sort) */
static void sort_cands(Cand *c, int64_t n) {
    for (int64_t k = 1; k < n; k++) {
        Cand v = c[k];
        int64_t j = k - 1;
        while (j >= 0 && before(&v, &c[j])) {
            c[j + 1] = c[j];
            j--;
        }
        c[j + 1] = v;
    }
}

/* the k-th smallest (0-based) of x [n] by quickselect on a scratch copy (x is reordered) */
static double kth_smallest(double *x, int64_t n, int64_t k) {
    int64_t lo = 0, hi = n - 1;
    while (lo < hi) {
        double pivot = x[lo + (hi - lo) / 2];
        int64_t i = lo, j = hi;
        while (i <= j) {
            while (x[i] < pivot) i++;
            while (x[j] > pivot) j--;
            if (i <= j) {
                double s = x[i];
                x[i] = x[j];
                x[j] = s;
                i++;
                j--;
            }
        }
        if (k <= j) hi = j;
        else if (k >= i) lo = i;
        else return x[k];
    }
    return x[k];
}

/* occ [X, Y, Z] uint8 (1: occupied); labels [X, Y, Z] int32 or NULL (reachable iff labels == comp); reach [X, Y, Z]
   uint8 or NULL (reachable iff reach != 0; used when labels is NULL); mean [X, Y, Z] uint8 (1: holds a mean);
   dims [3]; window a [3] .. e [3] (exclusive); lo [3], vs: the grid; t [3] the target; limit > 0.
   Returns -1 when no voxel of the window is free and reachable (numpy: sub.any() is false), else K, the number of
   candidates; centres [min(K, limit), 3] in stable distance order; dmin (out): their
   smallest distance (inf when K = 0). -3: out of memory. */
int64_t cn_goal_window(const uint8_t *occ, const int32_t *labels, int64_t comp, const uint8_t *reach,
                       const uint8_t *mean, const int64_t *dims, const int64_t *a, const int64_t *e, const double *lo,
                       double vs, const double *t, int64_t limit, double *centres, double *dmin) {
    int64_t Y = dims[1], Z = dims[2];
    int64_t nx = e[0] - a[0], ny = e[1] - a[1], nz = e[2] - a[2];
    int64_t cap = nx * ny * nz;
    *dmin = INFINITY;
    if (cap <= 0) return -1;
    double *d = malloc((size_t)cap * 2 * sizeof(double));
    int64_t *id = malloc((size_t)cap * sizeof(int64_t));
    if (d == NULL || id == NULL) {
        free(d);
        free(id);
        return -3;
    }
    double *scratch = d + cap;
    int any_free = 0;
    int64_t K = 0;
    for (int64_t i = a[0]; i < e[0]; i++)
        for (int64_t j = a[1]; j < e[1]; j++) {
            int64_t row = (i * Y + j) * Z;
            for (int64_t k = a[2]; k < e[2]; k++) {
                int64_t v = row + k;
                if (occ[v]) continue;
                if (labels != NULL ? labels[v] != comp : (reach != NULL && !reach[v])) continue;
                any_free = 1;
                if (mean[v]) continue;
                double cx = lo[0] + ((double)i + 0.5) * vs, cy = lo[1] + ((double)j + 0.5) * vs;
                double cz = lo[2] + ((double)k + 0.5) * vs;
                double dx = cx - t[0], dy = cy - t[1], dz = cz - t[2];
                double dist = sqrt((dx * dx + dy * dy) + dz * dz);
                d[K] = dist;
                id[K] = ((i - a[0]) * ny + (j - a[1])) * nz + (k - a[2]);  /* window C order: argwhere's */
                K++;
            }
        }
    if (!any_free) {
        free(d);
        free(id);
        return -1;
    }
    int64_t m = K < limit ? K : limit;
    if (m > 0) {
        for (int64_t q = 0; q < K; q++) scratch[q] = d[q];
        double thr = kth_smallest(scratch, K, m - 1);
        Cand *c = malloc((size_t)K * sizeof(Cand));
        if (c == NULL) {
            free(d);
            free(id);
            return -3;
        }
        int64_t n = 0;
        for (int64_t q = 0; q < K; q++)  /* every candidate at most thr: the first m of the stable order are here */
            if (d[q] <= thr) c[n].d = d[q], c[n].i = q, n++;
        sort_cands(c, n);
        *dmin = c[0].d;
        for (int64_t q = 0; q < m; q++) {
            int64_t w = id[c[q].i];
            int64_t i = a[0] + w / (ny * nz), j = a[1] + (w / nz) % ny, k = a[2] + w % nz;
            centres[q * 3] = lo[0] + ((double)i + 0.5) * vs;
            centres[q * 3 + 1] = lo[1] + ((double)j + 0.5) * vs;
            centres[q * 3 + 2] = lo[2] + ((double)k + 0.5) * vs;
        }
        free(c);
    }
    free(d);
    free(id);
    return K;
}
