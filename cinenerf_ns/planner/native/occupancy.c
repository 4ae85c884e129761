/* Conservative voxel occupancy of the inflated ellipsoids (scene/occupancy.py: build_occupancy), compiled.

   These entry points repeat the rasterisation of scene/occupancy.py's torch reference operation for operation, in the
   same precision and order, so both mark the very same voxels. The two square roots are torch's own: the caller
   passes the half-extents (EllipsoidScene.half_extents) and takes the square roots of the columns' discriminants with
   torch.sqrt between cn_occupancy_discs and cn_occupancy_mark (torch's sqrt need not be the correctly rounded one:
   with MKL it rounds otherwise in about one case in six on some CPUs).
   - footprints (cn_occupancy_footprints): ext = half-extent (float64) + rho, ilo = ceil(((mean - ext) - lo) / voxel
     - 0.5), ihi = floor(((mean + ext) - lo) / voxel - 0.5), clamped to the grid;
   - per ellipsoid, in float64: a_min, a_max (NaN if a radius is NaN, as torch's min / max); for each s sample
     h = a_min * (a_max / a_min)^t (libm pow, as torch's scalar loop for a row of 3 samples; the caller passes torch's
     powers when there are more), s = h / (h + rho), q_k = r_k^2 / s + (1 / (1 - s)) * rho^2 (torch's scalar / tensor is
     a reciprocal times the scalar), A_ik = R_ik / q_k, M_ij = ((0 + A_i0 R_j0) + A_i1 R_j1) + A_i2 R_j2 (torch's small
     batched matmul), M / (1 + margin), then the 6 distinct entries times voxel, times voxel again, rounded to
     float32; the centre in voxel-index coordinates (mean - lo) / voxel - 0.5;
   - per (x, y) column of the footprint, in float32: dx, dy rounded from the float64 offsets, B = m3 dx + m4 dy,
     C = ((m0 dx) dx + ((2 m1) dx) dy) + (m2 dy) dy - 1, disc = B B - A C; a column with a disc < 0 (or NaN) is empty;
     z = (-B -+ sqrt(disc)) / A; the largest lower and smallest upper root over s (a NaN empties the column, as torch's
     max / min propagate it and every comparison with it is false); k0 = ceil(mu_z + z0 - 1e-3), k1 = floor(mu_z + z1
     + 1e-3) in float64, clamped to the grid; a difference array along z, summed at the end (cn_occupancy_sum).
   A bound or index that would not be a finite number well inside int64 (an ellipsoid so large or far that a float32
   root overflows) makes an entry point return 1 (-2 for cn_occupancy_discs): torch's conversion of such a value is
   the platform's, so the caller runs the reference instead. Contraction into fused multiply-adds would round
   differently: it is turned off. */
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif
#include <math.h>
#include <stdint.h>

#define MAX_S 64

static double nan_min3(double a, double b, double c) {
    if (a != a || b != b || c != c) return NAN;
    double m = a < b ? a : b;
    return m < c ? m : c;
}

static double nan_max3(double a, double b, double c) {
    if (a != a || b != b || c != c) return NAN;
    double m = a > b ? a : b;
    return m > c ? m : c;
}

/* The s samples' quadratic coefficients of an ellipsoid (rotation R row-major, radii r): m6 [S][6] float64 (the 6
   distinct entries of R diag(1/q) R^T / (1 + margin), or NULL) and mc [S][6] float32 (times voxel, times voxel). */
static void ellipsoid_coefficients(const double R[9], const double r[3], double rho, const double *t, int64_t S,
                                   const double *pw, double margin_div, double voxel, double *m6, float *mc) {
    double amin = nan_min3(r[0], r[1], r[2]), amax = nan_max3(r[0], r[1], r[2]);
    double ratio = amax / amin, rr = rho * rho;
    for (int64_t s = 0; s < S; s++) {
        double h = amin * (pw ? pw[s] : pow(ratio, t[s]));
        double sv = h / (h + rho);
        double inv = 1.0 / (1.0 - sv);
        double q[3], A[9], m[9];
        for (int k = 0; k < 3; k++) q[k] = (r[k] * r[k]) / sv + inv * rr;
        for (int i = 0; i < 3; i++)
            for (int k = 0; k < 3; k++) A[3 * i + k] = R[3 * i + k] / q[k];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                double acc = 0.0;
                acc += A[3 * i] * R[3 * j];
                acc += A[3 * i + 1] * R[3 * j + 1];
                acc += A[3 * i + 2] * R[3 * j + 2];
                m[3 * i + j] = acc / margin_div;
            }
        const double six[6] = {m[0], m[1], m[4], m[2], m[5], m[8]};
        for (int c = 0; c < 6; c++) {
            if (m6) m6[6 * s + c] = six[c];
            mc[6 * s + c] = (float)((six[c] * voxel) * voxel);
        }
    }
}

/* B [S] and disc [S] of the column at offsets dx, dy from the centre; 1 when every disc >= 0 (else it is empty: the
   samples after the first failing one are not computed). */
static inline int column_discs(const float *mc, int64_t S, float dx, float dy, float *B, float *disc) {
    for (int64_t s = 0; s < S; s++) {
        const float *c = mc + 6 * s;
        float b = c[3] * dx + c[4] * dy;
        float C = ((c[0] * dx * dx + 2.0f * c[1] * dx * dy) + c[2] * dy * dy) - 1.0f;
        float d = b * b - c[5] * C;
        if (!(d >= 0.0f)) return 0;
        B[s] = b;
        disc[s] = d;
    }
    return 1;
}

/* The z-interval [z0, z1] from B [S] and the square roots sq [S] of the discs: 1 when it is one (no root NaN,
   z1 >= z0), else 0. */
static inline int column_roots(const float *mc, int64_t S, const float *B, const float *sq, float *z0, float *z1) {
    float lo0 = 0.0f, hi0 = 0.0f;
    for (int64_t s = 0; s < S; s++) {
        float A = mc[6 * s + 5];
        float lo = (-B[s] - sq[s]) / A, hi = (-B[s] + sq[s]) / A;
        if (lo != lo || hi != hi) return 0;
        if (s == 0 || lo > lo0) lo0 = lo;
        if (s == 0 || hi < hi0) hi0 = hi;
    }
    if (!(hi0 >= lo0)) return 0;
    *z0 = lo0;
    *z1 = hi0;
    return 1;
}

/* Ellipsoid e of the scene arrays (float32 when f32, else float64) as float64: mean m [3], rotation R [9], radii r. */
static void load_ellipsoid(const void *means, const void *rotations, const void *radii, int32_t f32, int64_t e,
                           double m[3], double R[9], double r[3]) {
    const float *mf = (const float *)means, *rf = (const float *)rotations, *af = (const float *)radii;
    const double *md = (const double *)means, *rd = (const double *)rotations, *ad = (const double *)radii;
    for (int k = 0; k < 9; k++) R[k] = f32 ? (double)rf[9 * e + k] : rd[9 * e + k];
    for (int k = 0; k < 3; k++) {
        r[k] = f32 ? (double)af[3 * e + k] : ad[3 * e + k];
        m[k] = f32 ? (double)mf[3 * e + k] : md[3 * e + k];
    }
}

static int in_reach(double x) { return fabs(x) < 4.6e18; }

/* Footprints of N ellipsoids grown by rho (scene/occupancy.py: _footprints): means [N, 3], half-extents ext [N, 3]
   (float32 when f32, else float64); out: first voxel ilo [N, 3], columns span [N, 2] along x and y (0 when it misses
   the grid). 0, or 1 when a bound is out of int64's reach (see the header). */
int64_t cn_occupancy_footprints(const void *means, const void *ext, int32_t f32, int64_t N, const double *lo,
                                double voxel, int64_t X, int64_t Y, int64_t Z, double rho, int64_t *ilo,
                                int64_t *span) {
    const int64_t dims[3] = {X, Y, Z};
    for (int64_t e = 0; e < N; e++) {
        int64_t il[3], ih[3];
        for (int k = 0; k < 3; k++) {
            double m = f32 ? (double)((const float *)means)[3 * e + k] : ((const double *)means)[3 * e + k];
            double x = (f32 ? (double)((const float *)ext)[3 * e + k] : ((const double *)ext)[3 * e + k]) + rho;
            double a = ceil(((m - x) - lo[k]) / voxel - 0.5), b = floor(((m + x) - lo[k]) / voxel - 0.5);
            if (!in_reach(a) || !in_reach(b)) return 1;
            il[k] = (int64_t)a < 0 ? 0 : (int64_t)a;
            ih[k] = (int64_t)b > dims[k] - 1 ? dims[k] - 1 : (int64_t)b;
        }
        for (int k = 0; k < 3; k++) ilo[3 * e + k] = il[k];
        for (int k = 0; k < 2; k++) span[2 * e + k] = ih[k] - il[k] + 1 > 0 ? ih[k] - il[k] + 1 : 0;
        if (ih[2] < il[2]) span[2 * e] = span[2 * e + 1] = 0;
    }
    return 0;
}

/* Ellipsoids e0..e1-1 (footprints ilo, span of the whole scene): their coefficients mc [E, S, 6] float32 (and m6
   [E, S, 6] float64 unless NULL), centres mu [E, 3], written for those with columns; the discs of every column that
   is not empty by them (ellipsoid by ellipsoid, then x, then y; S values each) into disc [cap]. Returns how many disc
   values, -1 for bad arguments or more than cap. */
int64_t cn_occupancy_discs(const void *means, const void *rotations, const void *radii, int32_t f32, int64_t e0,
                           int64_t e1, const int64_t *ilo, const int64_t *span, const double *lo, double voxel,
                           double rho, const double *t, int64_t S, const double *pw, double margin_div, float *mc,
                           double *m6, double *mu, float *disc, int64_t cap) {
    if (S < 1 || S > MAX_S) return -1;
    int64_t n = 0;
    float B[MAX_S];
    for (int64_t e = e0; e < e1; e++) {
        const int64_t *sp = span + 2 * e, *il = ilo + 3 * e;
        if (sp[0] == 0 || sp[1] == 0) continue;
        double R[9], r[3], m[3], *u = mu + 3 * (e - e0);
        float *c = mc + 6 * S * (e - e0);
        load_ellipsoid(means, rotations, radii, f32, e, m, R, r);
        for (int k = 0; k < 3; k++) u[k] = (m[k] - lo[k]) / voxel - 0.5;
        ellipsoid_coefficients(R, r, rho, t, S, pw ? pw + S * e : 0, margin_div, voxel,
                               m6 ? m6 + 6 * S * (e - e0) : 0, c);
        for (int64_t a = 0; a < sp[0]; a++) {
            float dx = (float)((double)(il[0] + a) - u[0]);
            for (int64_t b = 0; b < sp[1]; b++) {
                if (n + S > cap) return -1;
                n += S * column_discs(c, S, dx, (float)((double)(il[1] + b) - u[1]), B, disc + n);
            }
        }
    }
    return n;
}

/* After cn_occupancy_discs (same ellipsoids, its mc and mu) and torch.sqrt of its n disc values into sq: mark each
   column's voxels in diff [X * Y * (Z + 1)] int32, or (when z0 is not NULL: the tests) write each column's z0, z1
   [columns] float32 and ok [columns] uint8 instead. Returns 0, 1 when an index is out of int64's reach (see the
   header), -1 for bad arguments or when the discs do not add up to n. */
int64_t cn_occupancy_mark(int64_t e0, int64_t e1, const int64_t *ilo, const int64_t *span, const float *mc,
                          const double *mu, int64_t S, const float *sq, int64_t n, int64_t Y, int64_t Z, int32_t *diff,
                          float *z0_out, float *z1_out, uint8_t *ok_out) {
    if (S < 1 || S > MAX_S) return -1;
    int64_t used = 0, col = 0;
    float B[MAX_S], disc[MAX_S];
    for (int64_t e = e0; e < e1; e++) {
        const int64_t *sp = span + 2 * e, *il = ilo + 3 * e;
        if (sp[0] == 0 || sp[1] == 0) continue;
        const double *u = mu + 3 * (e - e0);
        const float *c = mc + 6 * S * (e - e0);
        for (int64_t a = 0; a < sp[0]; a++) {
            int64_t ci = il[0] + a;
            float dx = (float)((double)ci - u[0]);
            for (int64_t b = 0; b < sp[1]; b++, col++) {
                int64_t cj = il[1] + b;
                float z0 = 0.0f, z1 = 0.0f;
                int ok = column_discs(c, S, dx, (float)((double)cj - u[1]), B, disc);
                if (ok) {
                    if (used + S > n) return -1;
                    ok = column_roots(c, S, B, sq + used, &z0, &z1);
                    used += S;
                }
                if (z0_out) {
                    ok_out[col] = (uint8_t)ok;
                    z0_out[col] = z0;
                    z1_out[col] = z1;
                    continue;
                }
                if (!ok) continue;
                double k0f = ceil((u[2] + (double)z0) - 1e-3), k1f = floor((u[2] + (double)z1) + 1e-3);
                if (!in_reach(k0f) || !in_reach(k1f)) return 1;
                int64_t k0 = (int64_t)k0f, k1 = (int64_t)k1f;
                if (k0 < 0) k0 = 0;
                if (k1 > Z - 1) k1 = Z - 1;
                if (k1 < k0) continue;
                int32_t *d = diff + (ci * Y + cj) * (Z + 1);
                d[k0] += 1;
                d[k1 + 1] -= 1;
            }
        }
    }
    return used == n ? 0 : -1;
}

/* occ [X, Y, Z] uint8 = the running sums of diff [X * Y * (Z + 1)] along z are positive. */
void cn_occupancy_sum(const int32_t *diff, int64_t X, int64_t Y, int64_t Z, uint8_t *occ) {
    for (int64_t c = 0; c < X * Y; c++) {
        int64_t run = 0;
        const int32_t *d = diff + c * (Z + 1);
        uint8_t *o = occ + c * Z;
        for (int64_t k = 0; k < Z; k++) {
            run += d[k];
            o[k] = run > 0;
        }
    }
}
