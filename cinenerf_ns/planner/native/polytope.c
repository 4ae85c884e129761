/* Safe polytope of a point or segment seed (paper Prop. 2; polytope.py holds the rules and the proofs), compiled.

   One call does what polytope.safe_polytope's Python path does in ~100 numpy/torch calls: gather the ellipsoids
   whose padded AABB meets the (possibly oriented) box from the grid index (spatial_index.GridIndex's CSR levels),
   keep those whose bounding sphere, inflated by the camera radius, reaches the box, then visit them nearest first
   (by a lower bound of the distance from the seed to the inflated body) and give each one that no kept plane
   already cuts off (exact support test) its own plane: the best-slack one of the normal rules at the seed's
   reference point, with the exact offset n.mu - ||diag(a) R^T n|| - r - margin. Any unit normal gives a safe
   plane with that offset (polytope.py's module docstring), so safety never depends on this file's normals or on
   its order of visit; only the free space kept does.

   Differences from the Python path (both are safe; tests compare them):
   - order: ellipsoids are bucketed by the distance lower bound (~16 per bucket; Python: chunks of the 32 nearest),
     and each bucket's planes are taken nearest plane first, as in a Python chunk; the kept planes can differ a
     little.

   Index dedupe: an ellipsoid is listed in every cell of its level that its padded AABB meets (a box of cells). Each
   entry carries home bits (native_scene.native_arrays: bit i set when the entry's cell is the first of that box
   along axis i, so the index does not also list the ellipsoid in the previous cell along i). A copy in a visited
   cell is skipped when, along some axis, the cell is not the first of the query's range, the entry's home bit is
   clear and the previous cell along that axis is not culled (second pass): that cell then holds a copy too and is
   visited. Following those steps back ends at a copy that is kept, so nothing is ever dropped, and each ellipsoid
   is kept once. The rule reads only the entry's bits, not its row: a skipped copy costs no cache miss (the rows of
   copies were most of the gather's reads at 1M Gaussians).

   Memory: the index lists each ellipsoid in several cells, so the gather is bound by cache misses. It reads one
   packed float32 row per ellipsoid ([N, 12]: padded AABB lo rounded down, hi rounded up, mean, max semi-axis
   rounded up, min semi-axis rounded down, 1 unused), one cache line instead of three arrays.
   native_scene.native_arrays stores these rows and the means, rotations and radii in spatial (Morton) order and
   gives the index ids as positions in that order, so the rows of one cell's ellipsoids lie close together; the ids
   this file returns are such positions (the caller maps them back to scene ids). Rounding only ever widens these
   tests; planes and exact tests use the scene's own values (float32 or float64 scene arrays, f32 flag), computed in
   float64. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* min / max of two finite numbers, inlined: fmin / fmax are library calls at -O2 (their NaN rules), ~5% of a
   gather at 1M Gaussians. Only for values that cannot be NaN. */
static inline double mn(double a, double b) { return b < a ? b : a; }
static inline double mx(double a, double b) { return b > a ? b : a; }

static inline double ld(const void *p, int64_t i, int f32) {
    return f32 ? (double)((const float *)p)[i] : ((const double *)p)[i];
}

typedef struct {
    int64_t id;
    double key, mu[3], amax;  /* exact mean; amax >= the largest semi-axis */
} Cand;

/* ---------------------------------------------------------------- per-ellipsoid kernels (polytope.py) */
static double k_sphere(const double w2[3], const double lam[3], double kappa, double s) {
    double v = 0.0;
    for (int i = 0; i < 3; i++) v += w2[i] * s * (1.0 - s) / (kappa + s * (lam[i] - kappa));
    return v;
}

/* _argmax_k: 64-sample grid on (0, 1), then 6 golden-section steps in the best bracket */
static double argmax_k(const double w2[3], const double lam[3], double kappa) {
    const int T = 64;
    int best = 0;
    double bv = -INFINITY;
    for (int j = 0; j < T; j++) {
        double s = (double)(j + 1) / (double)(T + 1);
        double v = k_sphere(w2, lam, kappa, s);
        if (v > bv) { bv = v; best = j; }
    }
    double step = 1.0 / (double)(T + 1);
    double gb = (double)(best + 1) / (double)(T + 1);
    double lo = fmax(gb - step, 1e-9), hi = fmin(gb + step, 1.0 - 1e-9);
    const double g = (sqrt(5.0) - 1.0) / 2.0;
    for (int it = 0; it < 6; it++) {
        double m1 = hi - g * (hi - lo), m2 = lo + g * (hi - lo);
        if (k_sphere(w2, lam, kappa, m1) > k_sphere(w2, lam, kappa, m2)) hi = m2; else lo = m1;
    }
    return 0.5 * (lo + hi);
}

/* _closest_t: t >= 0 with sum lam w^2 / (lam + t)^2 = 1 (Newton from a lower bound; 10 steps) */
static double closest_t(const double w2[3], const double lam[3]) {
    double c[3], lmin = lam[0], lmax = lam[0], ws = 0.0;
    for (int i = 0; i < 3; i++) {
        c[i] = lam[i] * w2[i];
        lmin = fmin(lmin, lam[i]);
        lmax = fmax(lmax, lam[i]);
        ws += w2[i];
    }
    double t = fmax(sqrt(lmin * ws) - lmax, 0.0);
    for (int it = 0; it < 10; it++) {
        double S = 0.0, Sd = 0.0;
        for (int i = 0; i < 3; i++) {
            double den = lam[i] + t, q = c[i] / (den * den);
            S += q;
            Sd += q / den;
        }
        double phi = 1.0 / sqrt(fmax(S, 1e-300));
        double dphi = phi * phi * phi * Sd;
        if (phi < 1.0 && isfinite(phi) && isfinite(dphi)) t += (1.0 - phi) / fmax(dphi, 1e-300);
    }
    return t;
}

/* Euclidean distance from body point w to the ellipsoid with squared semi-axes lam (outside points) */
static double ell_dist(const double w[3], const double lam[3]) {
    double w2[3] = {w[0] * w[0], w[1] * w[1], w[2] * w[2]};
    double t = closest_t(w2, lam), d = 0.0;
    for (int i = 0; i < 3; i++) {
        double e = t * w[i] / (lam[i] + t);
        d += e * e;
    }
    return sqrt(d);
}

/* _segment_closest_u: golden section (30 steps) on u in [0, 1] of ell_dist(w0 + u dw) */
static double segment_closest_u(const double w0[3], const double dw[3], const double lam[3]) {
    const double g = (sqrt(5.0) - 1.0) / 2.0;
    double lo = 0.0, hi = 1.0, w[3];
#define DIST_AT(u) (w[0] = w0[0] + (u) * dw[0], w[1] = w0[1] + (u) * dw[1], w[2] = w0[2] + (u) * dw[2], ell_dist(w, lam))
    double x1 = hi - g * (hi - lo), x2 = lo + g * (hi - lo);
    double f1 = DIST_AT(x1), f2 = DIST_AT(x2);
    for (int it = 0; it < 30; it++) {
        if (f1 <= f2) {  /* minimum in [lo, x2] */
            hi = x2;
            double nx = hi - g * (hi - lo), fn = DIST_AT(nx);
            x2 = x1; f2 = f1; x1 = nx; f1 = fn;
        } else {
            lo = x1;
            double nx = lo + g * (hi - lo), fn = DIST_AT(nx);
            x1 = x2; f1 = f2; x2 = nx; f2 = fn;
        }
    }
#undef DIST_AT
    return 0.5 * (lo + hi);
}

typedef struct {
    double mu[3], R[9], a[3], lam[3];  /* R row-major: R[3 i + j], columns = body axes */
} Ell;

/* _planes_at: best-slack plane among the normal rules at body reference point w -> n (world), offset, slack */
static double planes_at(const double w_in[3], const Ell *E, const double *seeds, int S, double r, int mode,
                        double margin, double n_out[3], double *off_out) {
    double w[3] = {w_in[0], w_in[1], w_in[2]};
    if (w[0] * w[0] + w[1] * w[1] + w[2] * w[2] < 1e-24) { w[0] = 0.0; w[1] = 0.0; w[2] = 1e-12; }
    double w2[3] = {w[0] * w[0], w[1] * w[1], w[2] * w[2]};
    double cands[3][3];
    int nc = 0;
    double kappa = r * r;
    if (mode == 0 || mode == 1) {  /* prop2 */
        double s = argmax_k(w2, E->lam, kappa);
        for (int i = 0; i < 3; i++) cands[nc][i] = -(s * (1.0 - s) / (kappa + s * (E->lam[i] - kappa))) * w[i];
        nc++;
    }
    if (mode == 0 || mode == 2) {  /* mahalanobis */
        for (int i = 0; i < 3; i++) cands[nc][i] = -w[i] / E->lam[i];
        nc++;
    }
    if (mode == 0 || mode == 3) {  /* closest */
        double t = closest_t(w2, E->lam);
        for (int i = 0; i < 3; i++) cands[nc][i] = -w[i] / (E->lam[i] + t);
        nc++;
    }
    double best = -INFINITY;
    for (int c = 0; c < nc; c++) {
        double *nb = cands[c];
        double nn = fmax(sqrt(nb[0] * nb[0] + nb[1] * nb[1] + nb[2] * nb[2]), 1e-300);
        double u[3] = {nb[0] / nn, nb[1] / nn, nb[2] / nn};
        double nw[3], an = 0.0;
        for (int i = 0; i < 3; i++) nw[i] = E->R[3 * i] * u[0] + E->R[3 * i + 1] * u[1] + E->R[3 * i + 2] * u[2];
        for (int i = 0; i < 3; i++) an += (E->a[i] * u[i]) * (E->a[i] * u[i]);
        double off = nw[0] * E->mu[0] + nw[1] * E->mu[1] + nw[2] * E->mu[2] - sqrt(an) - r - margin;
        double smax = -INFINITY;
        for (int s = 0; s < S; s++) {
            double p = nw[0] * seeds[3 * s] + nw[1] * seeds[3 * s + 1] + nw[2] * seeds[3 * s + 2];
            if (p > smax) smax = p;
        }
        double slack = off - smax;
        if (slack > best) {  /* strict: ties keep the earlier rule, like numpy's argmax */
            best = slack;
            n_out[0] = nw[0]; n_out[1] = nw[1]; n_out[2] = nw[2];
            *off_out = off;
        }
    }
    return best;
}

/* _plane_candidates for one ellipsoid: plane at the metric-closest seed point, retried from other segment points
   when it cuts the segment (see polytope.py) */
static double plane_for(const Ell *E, const double *seeds, int S, double r, int mode, double margin, double n[3],
                        double *off) {
    double wb[2][3];
    for (int s = 0; s < S; s++) {
        double d[3] = {seeds[3 * s] - E->mu[0], seeds[3 * s + 1] - E->mu[1], seeds[3 * s + 2] - E->mu[2]};
        for (int i = 0; i < 3; i++) wb[s][i] = E->R[i] * d[0] + E->R[3 + i] * d[1] + E->R[6 + i] * d[2];  /* R^T d */
    }
    double w[3];
    if (S == 2) {
        double d[3], den = 0.0, num = 0.0;
        for (int i = 0; i < 3; i++) {
            d[i] = wb[1][i] - wb[0][i];
            den += d[i] * d[i] / E->lam[i];
            num += wb[0][i] * d[i] / E->lam[i];
        }
        double u = den > 0 ? fmin(fmax(-num / fmax(den, 1e-300), 0.0), 1.0) : 0.0;
        for (int i = 0; i < 3; i++) w[i] = wb[0][i] + u * d[i];
        double slack = planes_at(w, E, seeds, S, r, mode, margin, n, off);
        if (slack >= 0) return slack;
        double dd = 0.0, de = 0.0;
        for (int i = 0; i < 3; i++) { dd += d[i] * d[i]; de += wb[0][i] * d[i]; }
        double ue = fmin(fmax(-de / fmax(dd, 1e-300), 0.0), 1.0);
        double uc = segment_closest_u(wb[0], d, E->lam);
        double us[4] = {uc, ue, 0.0, 1.0};
        for (int k = 0; k < 4; k++) {
            double w2[3], n2[3], o2;
            for (int i = 0; i < 3; i++) w2[i] = wb[0][i] + us[k] * d[i];
            double s2 = planes_at(w2, E, seeds, S, r, mode, margin, n2, &o2);
            if (s2 > slack) {
                slack = s2;
                n[0] = n2[0]; n[1] = n2[1]; n[2] = n2[2];
                *off = o2;
            }
        }
        return slack;
    }
    return planes_at(wb[0], E, seeds, S, r, mode, margin, n, off);
}

static void load_ell(Ell *E, int64_t g, const double mu[3], const void *rots, const void *radii, int f32) {
    for (int i = 0; i < 3; i++) {
        E->mu[i] = mu[i];
        E->a[i] = ld(radii, 3 * g + i, f32);
        E->lam[i] = E->a[i] * E->a[i];
    }
    for (int i = 0; i < 9; i++) E->R[i] = ld(rots, 9 * g + i, f32);
}

/* min over the inflated body of n.x (exact support function, polytope._support_gap) */
static double support_gap(const double n[3], const Ell *E, double r) {
    double an = 0.0;
    for (int i = 0; i < 3; i++) {
        double nb = E->R[i] * n[0] + E->R[3 + i] * n[1] + E->R[6 + i] * n[2];
        an += (E->a[i] * nb) * (E->a[i] * nb);
    }
    return n[0] * E->mu[0] + n[1] * E->mu[1] + n[2] * E->mu[2] - sqrt(an) - r;
}

/* bounding sphere (centre mu, radius amax >= every semi-axis, inflated by r) beyond one of planes [from, F) */
static int sphere_cut_by(const double *pn, const double *pb, int64_t from, int64_t F, const double mu[3], double amax,
                         double r) {
    for (int64_t f = from; f < F; f++) {
        const double *n = pn + 3 * f;
        if (n[0] * mu[0] + n[1] * mu[1] + n[2] * mu[2] - amax - r >= pb[f]) return 1;
    }
    return 0;
}

/* the inflated body beyond one of planes [from, F) (exact support test, polytope._cut_by's second step) */
static int exact_cut_by(const double *pn, const double *pb, int64_t from, int64_t F, const Ell *E, double r) {
    for (int64_t f = from; f < F; f++) {
        if (support_gap(pn + 3 * f, E, r) >= pb[f]) return 1;
    }
    return 0;
}

typedef struct {
    int64_t id, c;  /* c: row in sorted[] */
    double slack, off, n[3];
} Plane;

static int cmp_plane(const void *x, const void *y) {
    const Plane *a = (const Plane *)x, *b = (const Plane *)y;
    if (a->slack != b->slack) return (a->slack > b->slack) - (a->slack < b->slack);
    return (a->id > b->id) - (a->id < b->id);  /* deterministic ties */
}

/* realloc *p to n elements of elem bytes; 0 on success, -1 (p unchanged) when out of memory */
static int grow(void **p, int64_t n, size_t elem) {
    void *q = realloc(*p, (size_t)n * elem);
    if (!q) return -1;
    *p = q;
    return 0;
}

/* cells [clo, chi] (clamped to the level's grid) that the box [qlo, qhi] meets, as GridIndex's _cell_of */
static void cell_range(const double qlo[3], const double qhi[3], const double *origin, double cell, const int64_t *dm,
                       int64_t clo[3], int64_t chi[3]) {
    for (int i = 0; i < 3; i++) {
        double a = floor((qlo[i] - origin[i]) / cell), b = floor((qhi[i] - origin[i]) / cell);
        clo[i] = (int64_t)fmin(fmax(a, 0.0), (double)(dm[i] - 1));
        chi[i] = (int64_t)fmin(fmax(b, 0.0), (double)(dm[i] - 1));
    }
}

typedef struct {
    /* scene */
    const void *means, *rots, *radii;
    const float *pack;
    int f32;
    /* index */
    const double *origin, *cells;
    const int64_t *dims;
    const int64_t *const *offsets, *const *ids;
    const uint8_t *const *homes;
    int n_levels;
    /* request */
    const double *seeds, *box_lo, *box_hi;
    int S, mode, require_inside;
    double Rb[9], r, margin, e;
    /* state */
    Cand *cand;
    int64_t K, kcap;
    double *pn, *pb;  /* kept planes [F, 3], [F] */
    int64_t *pid, F, pcap;
    int64_t *bid, nbad, bcap;
    double *bsl;
    Plane *chunk;
    int64_t ccap;
    int64_t visited;
} State;

/* min over the axis-aligned cell [lo, lo + size]^3 (grown a little) of n.x > b + shift for some plane f < F: every
   point of the cell is outside that halfspace (planes shifted by shift_f = e |n_f|_1, as in query_box_in_planes) */
static int cell_culled(const double lo[3], double size, const double *pn, const double *pb, int64_t F, double e) {
    double half = 0.5 * size * (1.0 + 1e-7) + 1e-12 * (1.0 + fmax(fabs(lo[0]), fmax(fabs(lo[1]), fabs(lo[2]))));
    double c[3] = {lo[0] + 0.5 * size, lo[1] + 0.5 * size, lo[2] + 0.5 * size};
    for (int64_t f = 0; f < F; f++) {
        const double *n = pn + 3 * f;
        double l1 = fabs(n[0]) + fabs(n[1]) + fabs(n[2]);
        double low = n[0] * c[0] + n[1] * c[1] + n[2] * c[2] - half * l1;
        if (low > pb[f] + e * l1 + 1e-12 * (1.0 + fabs(pb[f]))) return 1;
    }
    return 0;
}

static inline int pack_meets(const float *pk, const double lo[3], const double hi[3]) {
    return !(pk[0] > hi[0] || pk[1] > hi[1] || pk[2] > hi[2] || pk[3] < lo[0] || pk[4] < lo[1] || pk[5] < lo[2]);
}

/* Appends to st->cand every ellipsoid whose packed AABB meets [qlo, qhi] and whose inflated bounding sphere reaches
   the box, skipping those whose AABB meets [skip_lo, skip_hi] (already gathered) and the cells that one of the
   planes (cull_n, cull_b: [n_cull]) culls (see cell_culled and spatial_index.query_box_in_planes for why that
   loses nothing that can meet the polytope). */
static int gather(State *st, const double qlo[3], const double qhi[3], const double *skip_lo, const double *skip_hi,
                  const double *cull_n, const double *cull_b, int64_t n_cull) {
    const double *sd0 = st->seeds, *sd1 = st->seeds + 3 * (st->S - 1);
    double sdir[3] = {sd1[0] - sd0[0], sd1[1] - sd0[1], sd1[2] - sd0[2]};
    double sdd = fmax(sdir[0] * sdir[0] + sdir[1] * sdir[1] + sdir[2] * sdir[2], 1e-300);
    const double *Rb = st->Rb;
    for (int L = 0; L < st->n_levels; L++) {
        double cell = st->cells[L];
        const int64_t *dm = st->dims + 3 * L;
        int64_t clo[3], chi[3];
        cell_range(qlo, qhi, st->origin, cell, dm, clo, chi);
        const int64_t *off = st->offsets[L], *lid = st->ids[L];
        const uint8_t *home = st->homes[L];
        /* culled cells of the range, decided first: the dedupe below must know whether a neighbour is visited */
        int64_t nx = chi[0] - clo[0] + 1, ny = chi[1] - clo[1] + 1, nz = chi[2] - clo[2] + 1;
        unsigned char *culled = NULL;
        if (n_cull && nx * ny * nz <= 4000000) {
            culled = (unsigned char *)malloc((size_t)(nx * ny * nz));
            if (!culled) return -1;
            for (int64_t x = 0; x < nx; x++)
                for (int64_t y = 0; y < ny; y++)
                    for (int64_t z = 0; z < nz; z++) {
                        double lo[3] = {st->origin[0] + (clo[0] + x) * cell, st->origin[1] + (clo[1] + y) * cell,
                                        st->origin[2] + (clo[2] + z) * cell};
                        culled[(x * ny + y) * nz + z] = (unsigned char)cell_culled(lo, cell, cull_n, cull_b, n_cull, st->e);
                    }
        }
#define CULLED(x, y, z) (culled && culled[(((x) - clo[0]) * ny + ((y) - clo[1])) * nz + ((z) - clo[2])])
        for (int64_t x = clo[0]; x <= chi[0]; x++)
            for (int64_t y = clo[1]; y <= chi[1]; y++)
                for (int64_t z = clo[2]; z <= chi[2]; z++) {
                    int64_t cell_at[3] = {x, y, z};
                    if (CULLED(x, y, z)) continue;
                    int64_t lin = (x * dm[1] + y) * dm[2] + z;
                    for (int64_t k = off[lin]; k < off[lin + 1]; k++) {
                        st->visited++;
                        /* a copy is skipped only for one in the previous cell along an axis that is visited too
                           (the header's rule), decided from the entry's home bits before its row is read */
                        int dup = 0;
                        for (int i = 0; i < 3 && !dup; i++)
                            dup = cell_at[i] > clo[i] && !(home[k] >> i & 1) &&
                                  !CULLED(x - (i == 0), y - (i == 1), z - (i == 2));
                        if (dup) continue;
                        int64_t g = lid[k];
                        /* one cache line: lo[3] (rounded down), hi[3] (up), mu[3], amax (up) */
                        const float *pk = st->pack + 12 * g;
                        if (!pack_meets(pk, qlo, qhi)) continue;
                        if (skip_lo && pack_meets(pk, skip_lo, skip_hi)) continue;
                        /* bounding sphere (radius amax, inflated by r) reaches the box (box coordinates) */
                        double m[3] = {pk[6], pk[7], pk[8]};
                        double am = pk[9], gap2 = 0.0, mabs = 0.0;
                        for (int i = 0; i < 3; i++) {
                            double mb = Rb[i] * m[0] + Rb[3 + i] * m[1] + Rb[6 + i] * m[2];
                            double cl = mn(mx(mb, st->box_lo[i]), st->box_hi[i]);
                            gap2 += (mb - cl) * (mb - cl);
                            mabs = mx(mabs, fabs(m[i]));
                        }
                        if (sqrt(gap2) > am + st->r + 1e-6 * (1.0 + mabs)) continue;
                        if (!st->f32) {  /* float64 scene: the packed mean is rounded; decisions below use the exact one */
                            for (int i = 0; i < 3; i++) m[i] = ((const double *)st->means)[3 * g + i];
                        }
                        /* visiting key: lower bound of the distance from the seed set to the inflated body */
                        double u = 0.0;
                        if (st->S == 2)
                            u = mn(mx(((m[0] - sd0[0]) * sdir[0] + (m[1] - sd0[1]) * sdir[1] +
                                           (m[2] - sd0[2]) * sdir[2]) / sdd, 0.0), 1.0);
                        double dx = sd0[0] + u * sdir[0] - m[0], dy = sd0[1] + u * sdir[1] - m[1],
                               dz = sd0[2] + u * sdir[2] - m[2];
                        if (st->K == st->kcap) {
                            if (grow((void **)&st->cand, 2 * st->kcap, sizeof(Cand))) { free(culled); return -1; }
                            st->kcap *= 2;
                        }
                        Cand *cd = st->cand + st->K++;
                        cd->id = g;
                        cd->key = sqrt(dx * dx + dy * dy + dz * dz) - am;
                        cd->mu[0] = m[0]; cd->mu[1] = m[1]; cd->mu[2] = m[2];
                        cd->amax = am;
                    }
                }
#undef CULLED
        free(culled);
    }
    return 0;
}

/* Decides the gathered candidates st->cand[0, K) nearest first: each is cut off by a kept plane, gets its own plane,
   or (seed not inside its plane) goes to the bad list. Empties st->cand. */
static int decide(State *st) {
    int64_t K = st->K;
    if (!K) return 0;
    /* nearest first without a full sort: bucket by key (~16 per bucket), then order each bucket's planes */
    int64_t nbins = K < 64 ? 1 : (K / 16 < 1024 ? K / 16 : 1024);
    double kmin = INFINITY, kmax = -INFINITY;
    for (int64_t i = 0; i < K; i++) { kmin = mn(kmin, st->cand[i].key); kmax = mx(kmax, st->cand[i].key); }
    double scale = kmax > kmin ? (double)nbins / (kmax - kmin) : 0.0;
    int64_t *start = (int64_t *)calloc(nbins + 2, sizeof(int64_t));
    Cand *sorted = (Cand *)malloc(K * sizeof(Cand));
    if (!start || !sorted) { free(start); free(sorted); return -1; }
    for (int64_t i = 0; i < K; i++) {
        int64_t b = (int64_t)((st->cand[i].key - kmin) * scale);
        b = b >= nbins ? nbins - 1 : (b < 0 ? 0 : b);
        start[b + 1]++;
    }
    for (int64_t b = 0; b < nbins; b++) start[b + 1] += start[b];
    /* place: reuse start[] shifted (start[b] = first slot of bucket b; after placing, start[b] = end of b) */
    for (int64_t i = 0; i < K; i++) {
        int64_t b = (int64_t)((st->cand[i].key - kmin) * scale);
        b = b >= nbins ? nbins - 1 : (b < 0 ? 0 : b);
        sorted[start[b]++] = st->cand[i];
    }
    /* now start[b] = end of bucket b = begin of bucket b + 1 */
    int rc = 0;
    int64_t begin = 0;
    for (int64_t b = 0; b < nbins; b++) {
        int64_t end = start[b], n = 0, F0 = st->F;
        for (int64_t i = begin; i < end; i++) {
            const Cand *cd = sorted + i;
            if (sphere_cut_by(st->pn, st->pb, 0, st->F, cd->mu, cd->amax, st->r)) continue;
            Ell E;
            load_ell(&E, cd->id, cd->mu, st->rots, st->radii, st->f32);
            if (exact_cut_by(st->pn, st->pb, 0, st->F, &E, st->r)) continue;
            double nrm[3], off;
            double slack = plane_for(&E, st->seeds, st->S, st->r, st->mode, st->margin, nrm, &off);
            if (st->require_inside && !(slack >= 0)) {
                if (st->nbad == st->bcap) {
                    if (grow((void **)&st->bid, 2 * st->bcap, sizeof(int64_t)) ||
                        grow((void **)&st->bsl, 2 * st->bcap, sizeof(double))) { rc = -1; goto out; }
                    st->bcap *= 2;
                }
                st->bid[st->nbad] = cd->id;
                st->bsl[st->nbad] = slack;
                st->nbad++;
                continue;
            }
            if (n == st->ccap) {
                if (grow((void **)&st->chunk, 2 * st->ccap, sizeof(Plane))) { rc = -1; goto out; }
                st->ccap *= 2;
            }
            Plane *pl = st->chunk + n++;
            pl->id = cd->id;
            pl->c = i;
            pl->slack = slack;
            pl->off = off;
            pl->n[0] = nrm[0]; pl->n[1] = nrm[1]; pl->n[2] = nrm[2];
        }
        if (n > 1) qsort(st->chunk, n, sizeof(Plane), cmp_plane);
        for (int64_t j = 0; j < n; j++) {
            const Plane *pl = st->chunk + j;
            const Cand *cd = sorted + pl->c;
            if (st->F > F0) {
                if (sphere_cut_by(st->pn, st->pb, F0, st->F, cd->mu, cd->amax, st->r)) continue;
                Ell E;
                load_ell(&E, cd->id, cd->mu, st->rots, st->radii, st->f32);
                if (exact_cut_by(st->pn, st->pb, F0, st->F, &E, st->r)) continue;
            }
            if (st->F == st->pcap) {
                if (grow((void **)&st->pn, 2 * st->pcap, 3 * sizeof(double)) ||
                    grow((void **)&st->pb, 2 * st->pcap, sizeof(double)) ||
                    grow((void **)&st->pid, 2 * st->pcap, sizeof(int64_t))) { rc = -1; goto out; }
                st->pcap *= 2;
            }
            st->pn[3 * st->F] = pl->n[0]; st->pn[3 * st->F + 1] = pl->n[1]; st->pn[3 * st->F + 2] = pl->n[2];
            st->pb[st->F] = pl->off;
            st->pid[st->F] = pl->id;
            st->F++;
        }
        begin = end;
    }
out:
    free(start);
    free(sorted);
    st->K = 0;
    return rc;
}

/* ---------------------------------------------------------------- emptiness proof (safe_polytope's stop_when_empty)
   Seidel's incremental LP in 3D (then 2D on a plane, 1D on a line): minimize c.x over {a_f.x <= b_f - shrink |a_f|}
   inside the cube |x - centre|_inf <= M (the caller's cube holds its box, so the cube changes no answer). When the
   current optimum violates constraint i, any optimum of the constraints up to i lies on its plane, so an empty
   restriction to that plane proves the constraints up to i (hence all) empty. Rounding errs towards "not empty":
   a constraint counts as violated only beyond a tolerance and a 1D interval is empty only beyond it. */
static int lp2(const double *G, const double *h, int64_t m, const double c[2], double M, double tol, double y[2]) {
    y[0] = c[0] > 0 ? -M : M;
    y[1] = c[1] > 0 ? -M : M;
    for (int64_t j = 0; j < m; j++) {
        const double *g = G + 2 * j;
        double gn = hypot(g[0], g[1]);
        if (g[0] * y[0] + g[1] * y[1] <= h[j] + tol * gn) continue;
        if (gn < 1e-12) {
            if (h[j] < -tol) return 0;  /* 0 <= h[j] fails for every y */
            continue;
        }
        double q[2] = {g[0] * h[j] / (gn * gn), g[1] * h[j] / (gn * gn)}, d[2] = {-g[1] / gn, g[0] / gn};
        double lo = -INFINITY, hi = INFINITY;
        for (int i = 0; i < 2; i++) {  /* -M <= q_i + lam d_i <= M */
            if (fabs(d[i]) > 1e-15) {
                double t0 = (-M - q[i]) / d[i], t1 = (M - q[i]) / d[i];
                lo = fmax(lo, fmin(t0, t1));
                hi = fmin(hi, fmax(t0, t1));
            } else if (fabs(q[i]) > M + tol) {
                return 0;
            }
        }
        for (int64_t k = 0; k < j; k++) {
            const double *e = G + 2 * k;
            double en = hypot(e[0], e[1]), ed = e[0] * d[0] + e[1] * d[1];
            double rhs = h[k] - (e[0] * q[0] + e[1] * q[1]);
            if (fabs(ed) <= 1e-12 * en) {
                if (rhs < -tol * (1.0 + en)) return 0;  /* parallel to the line and the line is outside */
                continue;
            }
            if (ed > 0) hi = fmin(hi, rhs / ed);
            else lo = fmax(lo, rhs / ed);
        }
        if (lo > hi + tol) return 0;
        double cd = c[0] * d[0] + c[1] * d[1];
        double lam = lo > hi ? 0.5 * (lo + hi) : (cd > 0 ? lo : hi);
        y[0] = q[0] + lam * d[0];
        y[1] = q[1] + lam * d[1];
    }
    return 1;
}

/* 1 when {x : n_f.x <= b_f - shrink |n_f|, f < F} has no point in the cube |x - centre|_inf <= M (proven as above),
   0 when it has one (as far as rounding tells), -1 out of memory. */
int64_t cn_planes_empty(const double *pn, const double *pb, int64_t F, double shrink, const double *centre,
                        double M) {
    const double c[3] = {1.0, 0.7548776662466927, 0.5698402909980532};
    double scale = 1.0 + M + fmax(fabs(centre[0]), fmax(fabs(centre[1]), fabs(centre[2])));
    double tol = 1e-12 * scale;
    int64_t n = F + 6;
    double *A = (double *)malloc(n * 3 * sizeof(double)), *B = (double *)malloc(n * sizeof(double));
    double *G = (double *)malloc(n * 2 * sizeof(double)), *H = (double *)malloc(n * sizeof(double));
    int64_t *ord = (int64_t *)malloc(F * sizeof(int64_t) + 1);
    int64_t res = -1;
    if (!A || !B || !G || !H || !ord) goto out;
    /* the cube's six planes first, then the planes (unit normals) in a fixed pseudo-random order */
    for (int a = 0; a < 3; a++) {
        for (int i = 0; i < 3; i++) { A[3 * a + i] = (i == a); A[3 * (a + 3) + i] = -(double)(i == a); }
        B[a] = centre[a] + M;
        B[a + 3] = M - centre[a];
    }
    for (int64_t f = 0; f < F; f++) ord[f] = f;
    uint64_t rs = 0x9E3779B97F4A7C15ull;
    for (int64_t f = F - 1; f > 0; f--) {
        rs = rs * 6364136223846793005ull + 1442695040888963407ull;
        int64_t j = (int64_t)((rs >> 33) % (uint64_t)(f + 1)), t = ord[f];
        ord[f] = ord[j];
        ord[j] = t;
    }
    int64_t m = 6;
    for (int64_t k = 0; k < F; k++) {
        const double *a = pn + 3 * ord[k];
        double an = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
        if (!(an > 0)) {  /* 0 <= b - 0: a zero row is empty only when its offset is negative */
            if (pb[ord[k]] < -tol) { res = 1; goto out; }
            continue;
        }
        for (int i = 0; i < 3; i++) A[3 * m + i] = a[i] / an;
        B[m++] = pb[ord[k]] / an - shrink;
    }
    double x[3];
    for (int i = 0; i < 3; i++) x[i] = centre[i] + (c[i] > 0 ? -M : M);
    double M2 = 2.0 * sqrt(3.0) * M * (1.0 + 1e-9) + tol;
    for (int64_t i = 6; i < m; i++) {
        const double *a = A + 3 * i;
        if (a[0] * x[0] + a[1] * x[1] + a[2] * x[2] <= B[i] + tol) continue;
        /* orthonormal u, v with a: u = a x (the axis least aligned with a), v = a x u */
        int ax = fabs(a[0]) <= fabs(a[1]) ? (fabs(a[0]) <= fabs(a[2]) ? 0 : 2) : (fabs(a[1]) <= fabs(a[2]) ? 1 : 2);
        double e[3] = {ax == 0, ax == 1, ax == 2};
        double u[3] = {a[1] * e[2] - a[2] * e[1], a[2] * e[0] - a[0] * e[2], a[0] * e[1] - a[1] * e[0]};
        double un = sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
        for (int t = 0; t < 3; t++) u[t] /= un;
        double v[3] = {a[1] * u[2] - a[2] * u[1], a[2] * u[0] - a[0] * u[2], a[0] * u[1] - a[1] * u[0]};
        double off = B[i] - (a[0] * centre[0] + a[1] * centre[1] + a[2] * centre[2]);
        double p0[3] = {centre[0] + off * a[0], centre[1] + off * a[1], centre[2] + off * a[2]};
        for (int64_t j = 0; j < i; j++) {
            const double *aj = A + 3 * j;
            G[2 * j] = aj[0] * u[0] + aj[1] * u[1] + aj[2] * u[2];
            G[2 * j + 1] = aj[0] * v[0] + aj[1] * v[1] + aj[2] * v[2];
            H[j] = B[j] - (aj[0] * p0[0] + aj[1] * p0[1] + aj[2] * p0[2]);
        }
        double c2[2] = {c[0] * u[0] + c[1] * u[1] + c[2] * u[2], c[0] * v[0] + c[1] * v[1] + c[2] * v[2]}, y[2];
        if (!lp2(G, H, i, c2, M2, tol, y)) { res = 1; goto out; }
        for (int t = 0; t < 3; t++) x[t] = p0[t] + y[0] * u[t] + y[1] * v[t];
    }
    res = 0;
out:
    free(A); free(B); free(G); free(H); free(ord);
    return res;
}

/* safe_polytope's pass 0 shrinks the first pass's near box by this factor (polytope.EMPTY_PROBE_FRACTION) */
#define EMPTY_PROBE_FRACTION 0.125

/* cn_planes_empty of the box's six planes and the kept ones */
static int64_t planes_empty_with_box(const State *st, const double *box_n, const double *box_b, double shrink,
                                     const double *centre, double M) {
    double *n = (double *)malloc((6 + st->F) * 3 * sizeof(double)), *b = (double *)malloc((6 + st->F) * sizeof(double));
    int64_t res = -1;
    if (n && b) {
        memcpy(n, box_n, 18 * sizeof(double));
        memcpy(b, box_b, 6 * sizeof(double));
        memcpy(n + 18, st->pn, 3 * st->F * sizeof(double));
        memcpy(b + 6, st->pb, st->F * sizeof(double));
        res = cn_planes_empty(n, b, 6 + st->F, shrink, centre, M);
    }
    free(n); free(b);
    return res;
}

/* Returns the number of planes F (>= 0), or a negative status: -1 out of memory, -2 an output buffer of ``cap``
   rows is too small (info[2] = rows needed). info (out, int64[4]): n bad ellipsoids, n candidates decided, rows
   needed, index entries visited. box_rot: NULL or a row-major [3, 3] whose columns are the box axes (the box is
   lo <= R^T x <= hi). mode: 0 auto, 1 prop2, 2 mahalanobis, 3 closest. near_fraction: the first pass gathers the
   ellipsoids near the seeds (their bounding box grown by near_fraction x the seeds' smallest distance to the box's
   faces), the second pass every other one of the box in index cells that no plane kept by then culls (<= 0: one
   pass). empty_shrink >= 0 (two passes): first a probe pass 0 in a box EMPTY_PROBE_FRACTION x the first pass's;
   when the box and its planes hold no ball of radius empty_shrink (cn_planes_empty) the call stops there, else its
   planes are dropped and the two passes run; when the box and the first pass's planes hold no such ball the second
   pass is skipped. Stopped: info[4] = 1 (the planes returned prove the polytope has no such ball; the caller makes
   it explicitly empty). */
int64_t cn_safe_polytope(
    const void *means, const void *rots, const void *radii, const float *pack, int32_t f32,
    const double *origin, int32_t n_levels, const double *cells, const int64_t *dims,
    const int64_t *const *offsets, const int64_t *const *ids, const uint8_t *const *homes, double pad,
    const double *seeds, int32_t S, const double *box_lo, const double *box_hi, const double *box_rot,
    double r, double margin, int32_t mode, int32_t require_inside, double near_fraction, double empty_shrink,
    int64_t cap, double *out_n, double *out_b, int64_t *out_id, int64_t *bad_id, double *bad_slack, int64_t *info) {
    info[0] = info[1] = info[2] = info[3] = info[4] = 0;
    State st;
    memset(&st, 0, sizeof st);
    st.means = means; st.rots = rots; st.radii = radii; st.pack = pack; st.f32 = f32;
    st.origin = origin; st.cells = cells; st.dims = dims; st.offsets = offsets; st.ids = ids; st.homes = homes;
    st.n_levels = n_levels;
    st.seeds = seeds; st.S = S; st.box_lo = box_lo; st.box_hi = box_hi; st.mode = mode;
    st.require_inside = require_inside; st.r = r; st.margin = margin;
    double I[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    memcpy(st.Rb, box_rot ? box_rot : I, sizeof st.Rb);
    const double *Rb = st.Rb;
    /* world AABB of the box, grown by e = max(r - pad, 0): the padded AABB grown by e holds the inflated body */
    double bc[3], bh[3], qlo[3], qhi[3];
    for (int i = 0; i < 3; i++) { bc[i] = 0.5 * (box_lo[i] + box_hi[i]); bh[i] = 0.5 * (box_hi[i] - box_lo[i]); }
    st.e = fmax(r - pad, 0.0) * (1.0 + 1e-9);
    for (int i = 0; i < 3; i++) {
        double c = Rb[3 * i] * bc[0] + Rb[3 * i + 1] * bc[1] + Rb[3 * i + 2] * bc[2];
        double h = fabs(Rb[3 * i]) * bh[0] + fabs(Rb[3 * i + 1]) * bh[1] + fabs(Rb[3 * i + 2]) * bh[2];
        qlo[i] = c - h - st.e;
        qhi[i] = c + h + st.e;
    }
    /* the box's own 6 planes (world normals = +-box axes) cull cells outside an oriented box */
    double box_n[6 * 3], box_b[6];
    for (int a = 0; a < 3; a++) {
        for (int i = 0; i < 3; i++) { box_n[3 * a + i] = Rb[3 * i + a]; box_n[3 * (a + 3) + i] = -Rb[3 * i + a]; }
        box_b[a] = box_hi[a];
        box_b[a + 3] = -box_lo[a];
    }
    st.kcap = 1024; st.pcap = 256; st.bcap = 64; st.ccap = 64;
    st.cand = (Cand *)malloc(st.kcap * sizeof(Cand));
    st.pn = (double *)malloc(st.pcap * 3 * sizeof(double));
    st.pb = (double *)malloc(st.pcap * sizeof(double));
    st.pid = (int64_t *)malloc(st.pcap * sizeof(int64_t));
    st.bid = (int64_t *)malloc(st.bcap * sizeof(int64_t));
    st.bsl = (double *)malloc(st.bcap * sizeof(double));
    st.chunk = (Plane *)malloc(st.ccap * sizeof(Plane));
    int64_t status = -1, decided = 0;
    double *cull_n = NULL, *cull_b = NULL;
    if (!st.cand || !st.pn || !st.pb || !st.pid || !st.bid || !st.bsl || !st.chunk) goto done;
    /* pass 1: near the seeds */
    double rho = INFINITY, nlo[3], nhi[3];
    for (int s = 0; s < S; s++)
        for (int i = 0; i < 3; i++) {
            double p = Rb[i] * seeds[3 * s] + Rb[3 + i] * seeds[3 * s + 1] + Rb[6 + i] * seeds[3 * s + 2];
            rho = fmin(rho, fmin(p - box_lo[i], box_hi[i] - p));
        }
    int two = near_fraction > 0 && isfinite(rho) && rho > 0;
    double wc[3], M = sqrt(bh[0] * bh[0] + bh[1] * bh[1] + bh[2] * bh[2]) * (1.0 + 1e-9);  /* cube around the box */
    for (int i = 0; i < 3; i++) wc[i] = Rb[3 * i] * bc[0] + Rb[3 * i + 1] * bc[1] + Rb[3 * i + 2] * bc[2];
    if (two && empty_shrink >= 0) {
        /* pass 0 (a probe): the planes of the ellipsoids in a much smaller box around the seeds usually prove a seed
           deep in clutter has an empty polytope; when they do not, they are dropped and the passes below run as
           without the probe (same planes) */
        double r0 = rho * near_fraction * EMPTY_PROBE_FRACTION;
        for (int i = 0; i < 3; i++) {
            nlo[i] = fmax(fmin(seeds[i], seeds[3 * (S - 1) + i]) - r0, qlo[i]);
            nhi[i] = fmin(fmax(seeds[i], seeds[3 * (S - 1) + i]) + r0, qhi[i]);
        }
        if (gather(&st, nlo, nhi, NULL, NULL, NULL, NULL, 0)) goto done;
        decided += st.K;
        if (decide(&st)) goto done;
        if (st.F > 0) {
            int64_t em = planes_empty_with_box(&st, box_n, box_b, empty_shrink, wc, M);
            if (em < 0) goto done;
            info[4] = em;
        }
        if (!info[4]) st.F = 0;
    }
    if (two && !info[4]) {
        rho *= near_fraction;
        for (int i = 0; i < 3; i++) {
            nlo[i] = fmin(seeds[i], seeds[3 * (S - 1) + i]) - rho;
            nhi[i] = fmax(seeds[i], seeds[3 * (S - 1) + i]) + rho;
            nlo[i] = fmax(nlo[i], qlo[i]);
            nhi[i] = fmin(nhi[i], qhi[i]);
        }
        if (gather(&st, nlo, nhi, NULL, NULL, NULL, NULL, 0)) goto done;
        decided += st.K;
        if (decide(&st)) goto done;
    }
    if (info[4]) goto finish;
    /* pass 2 (or the only pass): the rest of the box, in cells not culled by the box's planes or the kept ones */
    cull_n = (double *)malloc((6 + st.F) * 3 * sizeof(double));
    cull_b = (double *)malloc((6 + st.F) * sizeof(double));
    if (!cull_n || !cull_b) goto done;
    memcpy(cull_n, box_n, sizeof box_n);
    memcpy(cull_b, box_b, sizeof box_b);
    memcpy(cull_n + 18, st.pn, 3 * st.F * sizeof(double));
    memcpy(cull_b + 6, st.pb, st.F * sizeof(double));
    if (two && empty_shrink >= 0 && st.F > 0) {
        /* the box and pass 1's planes already hold no ball of radius empty_shrink: more planes keep it so */
        int64_t em = cn_planes_empty(cull_n, cull_b, 6 + st.F, empty_shrink, wc, M);
        if (em < 0) goto done;
        info[4] = em;
    }
    if (!info[4]) {
        if (gather(&st, qlo, qhi, two ? nlo : NULL, two ? nhi : NULL, cull_n, cull_b, 6 + st.F)) goto done;
        decided += st.K;
        if (decide(&st)) goto done;
    }
finish:
    /* a bad ellipsoid (no plane of its own keeps the seeds) is fatal only if no kept plane cuts it off */
    {
        int64_t nb2 = 0;
        for (int64_t i = 0; i < st.nbad; i++) {
            Ell E;
            int64_t g = st.bid[i];
            double bm[3] = {ld(means, 3 * g, f32), ld(means, 3 * g + 1, f32), ld(means, 3 * g + 2, f32)};
            load_ell(&E, g, bm, rots, radii, f32);
            if (!exact_cut_by(st.pn, st.pb, 0, st.F, &E, r)) { st.bid[nb2] = g; st.bsl[nb2] = st.bsl[i]; nb2++; }
        }
        st.nbad = nb2;
    }
    info[0] = st.nbad;
    info[1] = decided;
    info[2] = st.F > st.nbad ? st.F : st.nbad;
    info[3] = st.visited;
    if (st.F > cap || st.nbad > cap) { status = -2; goto done; }
    memcpy(out_n, st.pn, 3 * st.F * sizeof(double));
    memcpy(out_b, st.pb, st.F * sizeof(double));
    memcpy(out_id, st.pid, st.F * sizeof(int64_t));
    memcpy(bad_id, st.bid, st.nbad * sizeof(int64_t));
    memcpy(bad_slack, st.bsl, st.nbad * sizeof(double));
    status = st.F;
done:
    free(st.cand); free(st.pn); free(st.pb); free(st.pid); free(st.bid); free(st.bsl); free(st.chunk);
    free(cull_n); free(cull_b);
    return status;
}

/* cn_safe_polytope for K two-point seeds (segments) in their axis-aligned boxes, one after the other, each polytope's
   rows written after the last one's in corridor order: its box's 6 faces (+x, +y, +z, -x, -y, -z; b = hi, -lo), the
   call's F planes (out_id: their ids; the box rows' ids are not written), and where the call stopped (info[4]) the
   explicit contradiction row (+x, b = lo[0] - (hi[0] - lo[0])): the rows corridor.polytope.aabb_polytope builds
   around one cn_safe_polytope call. seeds [K, 2, 3], box_lo / box_hi [K, 3]. seg (out, int64 [K, 3]): rows written,
   F, number of bad ellipsoids (> 0: the seeds are not free; the caller builds that segment again its own way). bad_id
   / bad_slack: scratch of ``cap`` items. Returns the rows written in all, or -1 (out of memory), -2 (``cap`` rows are
   too few: info[2] = rows a retry needs at least). */
int64_t cn_safe_polytopes_aabb(
    const void *means, const void *rots, const void *radii, const float *pack, int32_t f32,
    const double *origin, int32_t n_levels, const double *cells, const int64_t *dims,
    const int64_t *const *offsets, const int64_t *const *ids, const uint8_t *const *homes, double pad,
    const double *seeds, int64_t K, const double *box_lo, const double *box_hi,
    double r, double margin, int32_t mode, int32_t require_inside, double near_fraction, double empty_shrink,
    int64_t cap, double *out_n, double *out_b, int64_t *out_id, int64_t *bad_id, double *bad_slack, int64_t *seg,
    int64_t *info) {
    int64_t o = 0;
    for (int64_t k = 0; k < K; k++) {
        const double *lo = box_lo + 3 * k, *hi = box_hi + 3 * k;
        int64_t room = cap - o - 7;
        if (room < 0) { info[2] = o + 7; return -2; }
        int64_t F = cn_safe_polytope(means, rots, radii, pack, f32, origin, n_levels, cells, dims, offsets, ids, homes,
                                     pad, seeds + 6 * k, 2, lo, hi, NULL, r, margin, mode, require_inside,
                                     near_fraction, empty_shrink, room, out_n + 3 * (o + 6), out_b + o + 6,
                                     out_id + o + 6, bad_id, bad_slack, info);
        if (F == -2) { info[2] = o + 7 + info[2]; return -2; }
        if (F < 0) return F;
        seg[3 * k + 1] = F;
        seg[3 * k + 2] = info[0];
        if (info[0] > 0) { seg[3 * k] = 0; continue; }  /* not free: nothing kept */
        for (int a = 0; a < 3; a++) {
            for (int i = 0; i < 3; i++) {
                out_n[3 * (o + a) + i] = i == a ? 1.0 : 0.0;
                out_n[3 * (o + 3 + a) + i] = i == a ? -1.0 : -0.0;  /* -np.eye(3): negative zeros */
            }
            out_b[o + a] = hi[a];
            out_b[o + 3 + a] = -lo[a];
        }
        int64_t rows = 6 + F;
        if (info[4]) {
            out_n[3 * (o + rows)] = 1.0; out_n[3 * (o + rows) + 1] = 0.0; out_n[3 * (o + rows) + 2] = 0.0;
            out_b[o + rows] = lo[0] - (hi[0] - lo[0]);
            out_id[o + rows] = -1;
            rows++;
        }
        seg[3 * k] = rows;
        o += rows;
    }
    return o;
}

/* ------------------------------------------------------------------ point tests (collision.points_collide) */
/* Corollary 1: K(s) = sum_i w_i^2 s (1 - s) / (s r^2 + (1 - s) a_i^2) */
static double k_cor1(const double w[3], const double a[3], double r2, double s) {
    double v = 0.0;
    for (int i = 0; i < 3; i++) v += s * (1.0 - s) * w[i] * w[i] / (s * r2 + (1.0 - s) * a[i] * a[i]);
    return v;
}

static double sigmoid(double u) { return 1.0 / (1.0 + exp(-u)); }

/* collision.maximize_concave for Corollary 1: 17 samples of u = logit(s) on [-16, 16], then 24 golden-section
   steps in the best bracket; returns the best TRUE value of K seen (a lower bound of the maximum) */
static double max_k_cor1(const double w[3], const double a[3], double r) {
    const double UMAX = 16.0, G = (sqrt(5.0) - 1.0) / 2.0;
    const int NG = 17;
    double r2 = r * r, best_k = -INFINITY, best_u = 0.0;
    for (int j = 0; j < NG; j++) {
        double u = -UMAX + 2.0 * UMAX * (double)j / (double)(NG - 1);
        double k = k_cor1(w, a, r2, sigmoid(u));
        if (isnan(k)) k = -INFINITY;
        if (k > best_k) { best_k = k; best_u = u; }
    }
    double step = 2.0 * UMAX / (double)(NG - 1), lo = best_u - step, hi = best_u + step;
    double x1 = hi - G * (hi - lo), x2 = lo + G * (hi - lo);
    double f1 = k_cor1(w, a, r2, sigmoid(x1)), f2 = k_cor1(w, a, r2, sigmoid(x2));
    for (int it = 0; it < 24; it++) {
        if (f1 >= f2) {
            hi = x2;
            double nx = hi - G * (hi - lo), fn = k_cor1(w, a, r2, sigmoid(nx));
            x2 = x1; f2 = f1; x1 = nx; f1 = fn;
        } else {
            lo = x1;
            double nx = lo + G * (hi - lo), fn = k_cor1(w, a, r2, sigmoid(nx));
            x1 = x2; f1 = f2; x2 = nx; f2 = fn;
        }
        if (f1 > best_k) best_k = f1;
        if (f2 > best_k) best_k = f2;
    }
    return best_k;
}

/* 1 unless the ball (centre p, radius r) is proven clear of the ellipsoid (collision.points_collide's pair rule:
   sure collisions first, then one K evaluation at the support-direction s, then the full maximisation) */
static int pair_collides(const double p[3], double r, const Ell *E, double margin) {
    double d[3] = {p[0] - E->mu[0], p[1] - E->mu[1], p[2] - E->mu[2]}, w[3];
    for (int i = 0; i < 3; i++) w[i] = E->R[i] * d[0] + E->R[3 + i] * d[1] + E->R[6 + i] * d[2];
    double m2 = 0.0, wn2 = 0.0;
    for (int i = 0; i < 3; i++) { m2 += (w[i] / E->a[i]) * (w[i] / E->a[i]); wn2 += w[i] * w[i]; }
    double m = sqrt(m2), wn = sqrt(wn2);
    if (m <= 1.0 || wn * (1.0 - 1.0 / fmax(m, 1e-300)) <= r) return 1;  /* inside, or the radial point within r */
    double h2 = 0.0, nn = fmax(wn, 1e-300);
    for (int i = 0; i < 3; i++) h2 += (E->a[i] * w[i] / nn) * (E->a[i] * w[i] / nn);
    double h = sqrt(h2), s0 = fmin(fmax(h / (h + r), 1e-12), 1.0 - 1e-12);
    if (k_cor1(w, E->a, r * r, s0) > 1.0 + margin) return 0;
    return !(max_k_cor1(w, E->a, r) > 1.0 + margin);
}

/* Calls visit(ctx, g) for the index entries (ids g) of the cells meeting the box [qlo, qhi] whose packed AABB meets
   the box (with dedupe: each ellipsoid once, by the header's rule, all cells of the range being visited), until
   visit returns nonzero; returns 1 then, else 0. */
typedef int (*entry_fn)(void *ctx, int64_t g);
static int for_each_in_box(const float *pack, const double *origin, int32_t n_levels, const double *cells,
                           const int64_t *dims, const int64_t *const *offsets, const int64_t *const *ids,
                           const uint8_t *const *homes, const double qlo[3], const double qhi[3], int dedupe,
                           entry_fn visit, void *ctx) {
    for (int L = 0; L < n_levels; L++) {
        double cell = cells[L];
        const int64_t *dm = dims + 3 * L;
        int64_t clo[3], chi[3];
        cell_range(qlo, qhi, origin, cell, dm, clo, chi);
        const int64_t *off = offsets[L], *lid = ids[L];
        const uint8_t *home = homes[L];
        for (int64_t x = clo[0]; x <= chi[0]; x++)
            for (int64_t y = clo[1]; y <= chi[1]; y++)
                for (int64_t z = clo[2]; z <= chi[2]; z++) {
                    int64_t cell_at[3] = {x, y, z}, lin = (x * dm[1] + y) * dm[2] + z;
                    for (int64_t k = off[lin]; k < off[lin + 1]; k++) {
                        int dup = 0;
                        for (int i = 0; i < 3 && dedupe && !dup; i++) dup = cell_at[i] > clo[i] && !(home[k] >> i & 1);
                        if (dup) continue;
                        int64_t g = lid[k];
                        const float *pk = pack + 12 * g;
                        if (!pack_meets(pk, qlo, qhi)) continue;
                        if (visit(ctx, g)) return 1;
                    }
                }
    }
    return 0;
}

typedef struct {
    const void *means, *rots, *radii;
    int f32;
    const double *p;
    double rad, margin;
} PointCtx;

static int point_hits(void *ctx, int64_t g) {
    const PointCtx *c = (const PointCtx *)ctx;
    Ell E;
    double mu[3] = {ld(c->means, 3 * g, c->f32), ld(c->means, 3 * g + 1, c->f32), ld(c->means, 3 * g + 2, c->f32)};
    load_ell(&E, g, mu, c->rots, c->radii, c->f32);
    return pair_collides(c->p, c->rad, &E, c->margin);
}

/* hit[p] = 1 unless the camera ball of radius rad[p] at point p is proven clear of every ellipsoid (candidates: the
   index entries whose padded AABB meets the cube of half-width max(rad - pad, 0) around p, as
   GridIndex.query_points). Returns 0, or -1 on bad input. */
int64_t cn_points_collide(
    const void *means, const void *rots, const void *radii, const float *pack, int32_t f32,
    const double *origin, int32_t n_levels, const double *cells, const int64_t *dims,
    const int64_t *const *offsets, const int64_t *const *ids, const uint8_t *const *homes, double pad,
    const double *points, const double *rad, int64_t P, double margin, uint8_t *hit) {
    for (int64_t q = 0; q < P; q++) {
        const double *p = points + 3 * q;
        double half = fmax(rad[q] - pad, 0.0), qlo[3], qhi[3];
        for (int i = 0; i < 3; i++) { qlo[i] = p[i] - half; qhi[i] = p[i] + half; }
        PointCtx c = {means, rots, radii, f32, p, rad[q], margin};
        int collides = for_each_in_box(pack, origin, n_levels, cells, dims, offsets, ids, homes, qlo, qhi, 1, point_hits, &c);
        hit[q] = (uint8_t)collides;
    }
    return 0;
}

/* ---------------------------------------------------------------- exact distances and sight lines (scoring) */

/* F(t) = sum c_i / (lam_i + t)^2 - 1 with c_i = lam_i w_i^2 (its root t > 0 gives the closest surface point of an
   outside body point w: x_i = lam_i w_i / (lam_i + t)); F is convex and decreasing on t > -min lam. */
static double f_closest(const double c[3], const double lam[3], double t, double *df) {
    double s = 0.0, ds = 0.0;
    for (int i = 0; i < 3; i++) {
        double den = lam[i] + t, q = c[i] / (den * den);
        s += q;
        ds -= 2.0 * q / den;
    }
    *df = ds;
    return s - 1.0;
}

/* Exact Euclidean distance from an OUTSIDE body point w (sum w^2 / lam > 1) to the ellipsoid with squared semi-axes
   lam: Newton from a lower bound of the root (monotone on a convex decreasing function), safeguarded by bisection
   against an upper bound, to relative 1e-15, as distance._distance_local does in Eberly's scaled variables. */
static double ell_dist_exact(const double w[3], const double lam[3]) {
    double c[3], lo = 0.0, sum = 0.0, df;
    for (int i = 0; i < 3; i++) {
        c[i] = lam[i] * w[i] * w[i];
        sum += c[i];
        lo = fmax(lo, sqrt(c[i]) - lam[i]);  /* term i alone is >= 1 up to here */
    }
    double hi = fmax(sqrt(sum), lo);  /* sum c_i / t^2 <= 1 there */
    for (int it = 0; it < 200; it++) {
        double g = f_closest(c, lam, lo, &df);
        double newton = lo - g / df;
        double mid = 0.5 * (lo + hi), dm;
        double lo2 = lo, hi2 = hi;
        if (f_closest(c, lam, mid, &dm) > 0) lo2 = mid; else hi2 = mid;
        if (isfinite(newton) && newton > lo2 && newton < hi2) {
            if (f_closest(c, lam, newton, &dm) >= 0) lo2 = newton; else hi2 = newton;
        }
        int done = (hi2 - lo2) <= 1e-15 * (1.0 + fabs(hi2)) || fabs(newton - lo) <= 1e-15 * (1.0 + fabs(lo));
        lo = lo2;
        hi = hi2;
        if (done) break;
    }
    double d = 0.0;
    for (int i = 0; i < 3; i++) {
        double e = lo * w[i] / (lam[i] + lo);
        d += e * e;
    }
    return sqrt(d);
}

/* out[p] = min(max_d, min over ellipsoids of the Euclidean distance from point p to the ellipsoid) for points
   outside every ellipsoid; NaN where p is inside (or on) one (the caller measures those another way).
   Candidates: an ellipsoid closer than a bound B of the answer has its padded AABB meeting the cube of half-width
   h = max(B - pad, 0) around p (as GridIndex.query_points), so it is listed in a cell meeting that cube. Cells are
   visited in Chebyshev rings around p's cell, nearest first; ring k (k >= 1) lies at least (k - 1) cells from p,
   so the search stops at the first ring beyond h. B starts at max_d and only shrinks: each ring is read twice, first
   for the cheap upper bounds |p - mu| - min semi-axis (the ball of that radius lies inside the ellipsoid), then for
   the exact distance of every entry whose bounding-sphere lower bound |p - mu| - max semi-axis is below B. The
   packed mean and radii are float32, rounded outward by the slack below; the answer is the smallest EXACT distance
   (or max_d). Copies of one ellipsoid in several cells are simply measured again. */
int64_t cn_points_distance(
    const void *means, const void *rots, const void *radii, const float *pack, int32_t f32,
    const double *origin, int32_t n_levels, const double *cells, const int64_t *dims,
    const int64_t *const *offsets, const int64_t *const *ids, const uint8_t *const *homes, double pad,
    const double *points, int64_t P, double max_d, double *out) {
    (void)homes;  /* copies are measured again (see above) */
    if (!(max_d >= 0) || !isfinite(max_d)) return -1;
    const double *prev = NULL;  /* the last point with an exact distance below max_d, and that distance */
    double prev_d = 0.0;
    for (int64_t q = 0; q < P; q++) {
        const double *p = points + 3 * q;
        double best = max_d, bound = max_d;  /* best: smallest exact distance (or max_d); bound >= the answer */
        if (prev) {  /* 1-Lipschitz: d(p) <= d(prev) + |p - prev| (widened for rounding): a smaller first cube */
            double e0 = p[0] - prev[0], e1 = p[1] - prev[1], e2 = p[2] - prev[2];
            double ub = (prev_d + sqrt(e0 * e0 + e1 * e1 + e2 * e2)) * (1.0 + 1e-9) + 1e-12;
            if (ub < bound) bound = ub;
        }
        int inside = 0;
        for (int L = 0; L < n_levels && !inside; L++) {
            double cell = cells[L];
            const int64_t *dm = dims + 3 * L;
            const int64_t *off = offsets[L], *lid = ids[L];
            int64_t c0[3];
            for (int i = 0; i < 3; i++) c0[i] = (int64_t)floor((p[i] - origin[i]) / cell);
            for (int64_t k = 0; !inside; k++) {
                double h = fmax(bound - pad, 0.0);
                if (k >= 1 && (double)(k - 1) * cell > h * (1.0 + 1e-12) + 1e-12) break;  /* ring beyond the cube */
                double qlo[3], qhi[3];
                int64_t clo[3], chi[3];
                for (int i = 0; i < 3; i++) { qlo[i] = p[i] - h; qhi[i] = p[i] + h; }
                cell_range(qlo, qhi, origin, cell, dm, clo, chi);
                for (int pass = 0; pass < 2 && !inside; pass++) {
                    for (int64_t x = c0[0] - k; x <= c0[0] + k && !inside; x++) {
                        if (x < clo[0] || x > chi[0]) continue;
                        for (int64_t y = c0[1] - k; y <= c0[1] + k && !inside; y++) {
                            if (y < clo[1] || y > chi[1]) continue;
                            for (int64_t z = c0[2] - k; z <= c0[2] + k && !inside; z++) {
                                if (z < clo[2] || z > chi[2]) continue;
                                int64_t ax = llabs(x - c0[0]), ay = llabs(y - c0[1]), az = llabs(z - c0[2]);
                                if ((ax > ay ? (ax > az ? ax : az) : (ay > az ? ay : az)) != k) continue;  /* inner */
                                int64_t lin = (x * dm[1] + y) * dm[2] + z;
                                for (int64_t kk = off[lin]; kk < off[lin + 1]; kk++) {
                                    int64_t g = lid[kk];
                                    const float *pk = pack + 12 * g;
                                    if (!pack_meets(pk, qlo, qhi)) continue;
                                    double dx = p[0] - pk[6], dy = p[1] - pk[7], dz = p[2] - pk[8];
                                    double slack = 1e-6 * (1.0 + fmax(fabs(pk[6]), fmax(fabs(pk[7]), fabs(pk[8]))));
                                    double dc = sqrt(dx * dx + dy * dy + dz * dz);
                                    if (pass == 0) {  /* upper bound: shrink the bound (and the cube) early */
                                        double ub = dc - pk[10] + slack;
                                        if (ub < bound) {
                                            bound = fmax(ub, 0.0);
                                            h = fmax(bound - pad, 0.0);
                                            for (int i = 0; i < 3; i++) { qlo[i] = p[i] - h; qhi[i] = p[i] + h; }
                                        }
                                        continue;
                                    }
                                    if (dc - pk[9] - slack >= bound) continue;  /* not closer than the bound */
                                    Ell E;
                                    double mu[3] = {ld(means, 3 * g, f32), ld(means, 3 * g + 1, f32), ld(means, 3 * g + 2, f32)};
                                    load_ell(&E, g, mu, rots, radii, f32);
                                    double w[3], m2 = 0.0;
                                    for (int i = 0; i < 3; i++) {
                                        w[i] = E.R[i] * (p[0] - mu[0]) + E.R[3 + i] * (p[1] - mu[1]) + E.R[6 + i] * (p[2] - mu[2]);
                                        m2 += w[i] * w[i] / E.lam[i];
                                    }
                                    if (!(m2 > 1.0)) { inside = 1; break; }
                                    /* the body lies in its box |x_i| <= a_i: the distance to the box (widened) is a
                                       lower bound; no closer than the bound: the exact distance cannot lower best */
                                    double gb = 0.0;
                                    for (int i = 0; i < 3; i++) { double e = fmax(fabs(w[i]) - E.a[i], 0.0); gb += e * e; }
                                    if (sqrt(gb) * (1.0 - 1e-12) - 1e-15 >= bound) continue;
                                    double d = ell_dist_exact(w, E.lam);
                                    if (d < best) best = d;
                                    if (d < bound) {
                                        bound = d;
                                        h = fmax(bound - pad, 0.0);
                                        for (int i = 0; i < 3; i++) { qlo[i] = p[i] - h; qhi[i] = p[i] + h; }
                                    }
                                }
                            }
                        }
                    }
                }
                /* every cell of the cube's range is within Chebyshev distance dmax of p's cell: no farther ring */
                cell_range(qlo, qhi, origin, cell, dm, clo, chi);
                int64_t dmax = 0;
                for (int i = 0; i < 3; i++) {
                    int64_t a = llabs(c0[i] - clo[i]), b = llabs(c0[i] - chi[i]);
                    dmax = a > dmax ? a : dmax;
                    dmax = b > dmax ? b : dmax;
                }
                if (k >= dmax) break;
            }
        }
        out[q] = inside ? NAN : best;
        if (!inside && best < max_d) { prev = p; prev_d = best; }
    }
    return 0;
}

/* out[p] = min(cap, the distance from point p to the nearest occupied voxel box of occ (uint8 [vdims] C order, voxel
   (i, j, k) = vlo + vs [i, i + 1] x [j, j + 1] x [k, k + 1]; voxels outside the grid count as occupied)), over the
   voxels within w of p's voxel in every index axis (the caller takes w with (w - 1) vs >= cap); the float64 sum of
   squared gaps, its sqrt (clearance_queries.box_clearance_bound widens it). */
int64_t cn_box_distance(const uint8_t *occ, const double *vlo, double vs, const int64_t *vdims, const double *points,
                        int64_t P, int64_t w, double cap, double *out) {
    if (!(vs > 0) || w < 0) return -1;
    for (int64_t q = 0; q < P; q++) {
        const double *p = points + 3 * q;
        int64_t c[3];
        for (int i = 0; i < 3; i++) c[i] = (int64_t)floor((p[i] - vlo[i]) / vs);
        double best2 = cap * cap;
        for (int64_t x = c[0] - w; x <= c[0] + w; x++) {
            double gx = fmax(fmax(vlo[0] + x * vs - p[0], p[0] - (vlo[0] + x * vs + vs)), 0.0);
            if (gx * gx >= best2) continue;
            for (int64_t y = c[1] - w; y <= c[1] + w; y++) {
                double gy = fmax(fmax(vlo[1] + y * vs - p[1], p[1] - (vlo[1] + y * vs + vs)), 0.0);
                double g2 = gx * gx + gy * gy;
                if (g2 >= best2) continue;
                for (int64_t z = c[2] - w; z <= c[2] + w; z++) {
                    double gz = fmax(fmax(vlo[2] + z * vs - p[2], p[2] - (vlo[2] + z * vs + vs)), 0.0);
                    double d2 = g2 + gz * gz;
                    if (d2 >= best2) continue;
                    int in = x >= 0 && y >= 0 && z >= 0 && x < vdims[0] && y < vdims[1] && z < vdims[2];
                    if (!in || occ[(x * vdims[1] + y) * vdims[2] + z]) best2 = d2;
                }
            }
        }
        out[q] = sqrt(best2);
    }
    return 0;
}

typedef struct {
    const void *means, *rots, *radii;
    int f32;
    const uint8_t *skip;
    const double *a0, *d;
    double t0, t1, dd;  /* dd = |d|^2 */
    const float *pack;
} SightCtx;

/* the piece a0 + t d, t in [t0, t1], stays farther than the bounding sphere of packed entry pk (its float32 mean,
   its max semi-axis rounded up, with the slack of cn_points_distance): it cannot meet the ellipsoid, whatever the
   exact test below would round to (it reads only the entry's 48 packed bytes, not the ellipsoid's rotation). */
static int piece_misses_sphere(const SightCtx *c, const float *pk) {
    const double *a0 = c->a0, *d = c->d;
    double m[3] = {(double)pk[6] - a0[0], (double)pk[7] - a0[1], (double)pk[8] - a0[2]};
    double t = c->dd > 0 ? (m[0] * d[0] + m[1] * d[1] + m[2] * d[2]) / c->dd : c->t0;
    t = fmin(fmax(t, c->t0), c->t1);
    double e2 = 0.0;
    for (int i = 0; i < 3; i++) { double e = m[i] - t * d[i]; e2 += e * e; }
    double slack = 1e-6 * (1.0 + fmax(fabs(pk[6]), fmax(fabs(pk[7]), fabs(pk[8]))));
    double r = (double)pk[9] + slack;
    return e2 > r * r * (1.0 + 1e-9);
}

/* the piece a0 + t d, t in [t0, t1], meets ellipsoid g: its closest point to the centre, in the ellipsoid's unit
   coordinates, is within 1 */
static int sight_hits(void *ctx, int64_t g) {
    const SightCtx *c = (const SightCtx *)ctx;
    if (c->skip && c->skip[g]) return 0;
    if (piece_misses_sphere(c, c->pack + 12 * g)) return 0;
    Ell E;
    double mu[3] = {ld(c->means, 3 * g, c->f32), ld(c->means, 3 * g + 1, c->f32), ld(c->means, 3 * g + 2, c->f32)};
    load_ell(&E, g, mu, c->rots, c->radii, c->f32);
    const double *a0 = c->a0, *d = c->d;
    double u[3], v[3], uv = 0.0, vv = 0.0;
    for (int i = 0; i < 3; i++) {
        u[i] = (E.R[i] * (a0[0] - mu[0]) + E.R[3 + i] * (a0[1] - mu[1]) + E.R[6 + i] * (a0[2] - mu[2])) / E.a[i];
        v[i] = (E.R[i] * d[0] + E.R[3 + i] * d[1] + E.R[6 + i] * d[2]) / E.a[i];
        uv += u[i] * v[i];
        vv += v[i] * v[i];
    }
    double t = vv > 0 ? -uv / fmax(vv, 1e-300) : c->t0;
    t = fmin(fmax(t, c->t0), c->t1);
    double m = 0.0;
    for (int i = 0; i < 3; i++) { double w = u[i] + t * v[i]; m += w * w; }
    return m <= 1.0;
}

/* blocked[l] = 1 when the segment from p0[l] to p1[l] meets an ellipsoid (the unit ball of diag(1/a) R^T (x - mu)),
   ellipsoids with skip[id] set excepted (skip: NULL or uint8 [N] in this file's id order). As
   occlusion.sight_lines_blocked: the segment is cut into pieces no longer than piece_len; each piece's candidates are
   the index entries whose padded AABB meets the piece's box; a piece meets an ellipsoid when the closest point of
   the piece to its centre, in the ellipsoid's unit coordinates, is within 1. A line stops at its first hit.
   occ (NULL: unused): the occupancy grid, uint8 [vdims] C order, voxel (i, j, k) = [vlo + (i, j, k) vs, + vs]; a
   piece whose box lies in free voxels only (occ 0) is skipped: every point of a free voxel keeps the camera ball
   clear (occupancy.py), so the piece is >= the camera radius from every ellipsoid and cannot meet one (the same
   answer, without the candidates' query). */
static int box_in_free_voxels(const double qlo[3], const double qhi[3], const uint8_t *occ, const double *vlo,
                              double vs, const int64_t *vdims) {
    int64_t a[3], b[3];
    for (int i = 0; i < 3; i++) {
        double u = (qlo[i] - vlo[i]) / vs, v = (qhi[i] - vlo[i]) / vs;
        if (!(u >= 1e-6) || !(v < (double)vdims[i] - 1e-6)) return 0;  /* outside the grid (or NaN): not proven */
        a[i] = (int64_t)floor(u - 1e-6);  /* widened: a box corner on a voxel face takes both voxels */
        b[i] = (int64_t)floor(v + 1e-6);
    }
    for (int64_t x = a[0]; x <= b[0]; x++)
        for (int64_t y = a[1]; y <= b[1]; y++)
            for (int64_t z = a[2]; z <= b[2]; z++)
                if (occ[(x * vdims[1] + y) * vdims[2] + z]) return 0;
    return 1;
}

int64_t cn_segments_blocked(
    const void *means, const void *rots, const void *radii, const float *pack, int32_t f32,
    const double *origin, int32_t n_levels, const double *cells, const int64_t *dims,
    const int64_t *const *offsets, const int64_t *const *ids, const uint8_t *const *homes, double pad,
    const double *p0, const double *p1, int64_t Lines, double piece_len, const uint8_t *skip, uint8_t *blocked,
    const uint8_t *occ, const double *vlo, double vs, const int64_t *vdims) {
    (void)pad;
    if (!(piece_len > 0) || !isfinite(piece_len)) return -1;
    for (int64_t l = 0; l < Lines; l++) {
        const double *a0 = p0 + 3 * l, *a1 = p1 + 3 * l;
        double d[3] = {a1[0] - a0[0], a1[1] - a0[1], a1[2] - a0[2]};
        double dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2], len = sqrt(dd);
        int64_t n = (int64_t)ceil(len / piece_len);
        if (n < 1) n = 1;
        int hit = 0;
        for (int64_t k = 0; k < n && !hit; k++) {
            double t0 = (double)k / (double)n, t1 = (double)(k + 1) / (double)n, qlo[3], qhi[3];
            for (int i = 0; i < 3; i++) {
                double u = a0[i] + t0 * d[i], v = a0[i] + t1 * d[i];
                qlo[i] = fmin(u, v);
                qhi[i] = fmax(u, v);
            }
            if (occ && box_in_free_voxels(qlo, qhi, occ, vlo, vs, vdims)) continue;
            SightCtx c = {means, rots, radii, f32, skip, a0, d, t0, t1, dd, pack};
            hit = for_each_in_box(pack, origin, n_levels, cells, dims, offsets, ids, homes, qlo, qhi, 1, sight_hits, &c);
        }
        blocked[l] = (uint8_t)hit;
    }
    return 0;
}
