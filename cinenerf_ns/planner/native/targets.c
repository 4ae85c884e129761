/* What an object target's first request derives from its Gaussians (shots/target_object.py, shots/framing.py),
   compiled: one pass where numpy makes a temporary array per operation.

   cn_member_box: the box of the members' cut-off boxes (geometry/visibility.py subject_box) and the running sum of
   their cover (SubjectSamples.of_members' draw), with numpy's arithmetic (m - h, m + h; a sequential sum): the same
   bits as the numpy path.

   cn_subject_size: framing.subject_size of cameras looking at one point (framing.camera_axes, framing.project),
   with numpy's arithmetic in numpy's order (np.cross's products and differences, np.linalg.norm's (x*x + y*y) + z*z)
   except the projections, which numpy takes as one matrix product (BLAS: its own order of the three products'
   sum): here (a0 q0 + a1 q1) + a2 q2 - (a0 c0 + a1 c1) + a2 c2; so the two agree to rounding
   (tests/planner/test_native.py). A non-finite input returns 2 and the caller takes the numpy path. */
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif
#include <math.h>
#include <stdint.h>

/* members [K] (valid ids, K >= 1); means, half [N, 3]; cover [N] or NULL; out lo [3], hi [3], cum [K] (if cover). */
int64_t cn_member_box(const int64_t *members, int64_t K, const double *means, const double *half,
                      const double *cover, double *lo, double *hi, double *cum) {
    double l0 = INFINITY, l1 = INFINITY, l2 = INFINITY, h0 = -INFINITY, h1 = -INFINITY, h2 = -INFINITY;
    double acc = 0.0;
    int nan = 0;
    for (int64_t k = 0; k < K; k++) {
        const double *m = means + 3 * members[k], *h = half + 3 * members[k];
        double a0 = m[0] - h[0], a1 = m[1] - h[1], a2 = m[2] - h[2];
        double b0 = m[0] + h[0], b1 = m[1] + h[1], b2 = m[2] + h[2];
        nan |= (a0 != a0) | (a1 != a1) | (a2 != a2) | (b0 != b0) | (b1 != b1) | (b2 != b2);
        if (a0 < l0) l0 = a0;
        if (a1 < l1) l1 = a1;
        if (a2 < l2) l2 = a2;
        if (b0 > h0) h0 = b0;
        if (b1 > h1) h1 = b1;
        if (b2 > h2) h2 = b2;
        if (cover) {
            acc += cover[members[k]];
            cum[k] = acc;
        }
    }
    lo[0] = l0; lo[1] = l1; lo[2] = l2;
    hi[0] = h0; hi[1] = h1; hi[2] = h2;
    return nan ? 2 : 0;  /* numpy's min / max propagate NaN: the caller takes the numpy path */
}

static inline double norm3(double x, double y, double z) {
    return sqrt((x * x + y * y) + z * z);
}

static inline void cross3(const double *a, const double *b, double *o) {
    o[0] = a[1] * b[2] - a[2] * b[1];
    o[1] = a[2] * b[0] - a[0] * b[2];
    o[2] = a[0] * b[1] - a[1] * b[0];
}

static inline double dot3(const double *a, const double *q) {
    return (a[0] * q[0] + a[1] * q[1]) + a[2] * q[2];
}

/* cams [M, 3]; look [3]; up [3] (unit); pts [P, 3] (P >= 1); pad; th, tv: tangents of half the fov; in_frame;
   out size [M], whole [M] (0 / 1). Returns 0, or 2 for a non-finite input (nothing written then). */
int64_t cn_subject_size(const double *cams, int64_t M, const double *look, const double *up, const double *pts,
                        int64_t P, double pad, double th, double tv, double in_frame, double *size, uint8_t *whole) {
    for (int64_t i = 0; i < 3 * M; i++)
        if (!isfinite(cams[i])) return 2;
    for (int64_t i = 0; i < 3 * P; i++)
        if (!isfinite(pts[i])) return 2;
    for (int i = 0; i < 3; i++)
        if (!isfinite(look[i]) || !isfinite(up[i])) return 2;
    if (!isfinite(pad) || !isfinite(th) || !isfinite(tv) || !isfinite(in_frame)) return 2;
    const double ex[3] = {1.0, 0.0, 0.0}, ey[3] = {0.0, 1.0, 0.0};
    const double *other = fabs(up[0]) < 0.9 ? ex : ey;
    for (int64_t m = 0; m < M; m++) {
        const double *c = cams + 3 * m;
        double f[3] = {look[0] - c[0], look[1] - c[1], look[2] - c[2]}, r[3], u[3], alt[3];
        double fn = norm3(f[0], f[1], f[2]);
        fn = fn > 1e-12 ? fn : 1e-12;
        f[0] = f[0] / fn; f[1] = f[1] / fn; f[2] = f[2] / fn;
        cross3(f, up, r);
        double rn = norm3(r[0], r[1], r[2]);
        if (rn > 1e-9) {
            r[0] = r[0] / rn; r[1] = r[1] / rn; r[2] = r[2] / rn;
        } else {
            cross3(f, other, alt);
            double an = norm3(alt[0], alt[1], alt[2]);
            an = an > 1e-12 ? an : 1e-12;
            r[0] = alt[0] / an; r[1] = alt[1] / an; r[2] = alt[2] / an;
        }
        cross3(r, f, u);
        double ef = dot3(f, c), er = dot3(r, c), eu = dot3(u, c);
        double xmax = -INFINITY, xmin = INFINITY, ymax = -INFINITY, ymin = INFINITY;
        double dmin = INFINITY, axmax = -INFINITY, aymax = -INFINITY, pxmax = -INFINITY, pymax = -INFINITY;
        for (int64_t p = 0; p < P; p++) {
            const double *q = pts + 3 * p;
            double depth = dot3(f, q) - ef;
            double z = depth > 1e-9 ? depth : 1e-9;
            double x = (dot3(r, q) - er) / (z * th), y = (dot3(u, q) - eu) / (z * tv);
            double px = pad / (z * th), py = pad / (z * tv);
            double a;
            if ((a = x + px) > xmax) xmax = a;
            if ((a = x - px) < xmin) xmin = a;
            if ((a = y + py) > ymax) ymax = a;
            if ((a = y - py) < ymin) ymin = a;
            if (depth < dmin) dmin = depth;
            if ((a = fabs(x)) > axmax) axmax = a;
            if ((a = fabs(y)) > aymax) aymax = a;
            if (px > pxmax) pxmax = px;
            if (py > pymax) pymax = py;
        }
        double w = (xmax - xmin) / 2, h = (ymax - ymin) / 2;
        size[m] = w > h ? w : h;  /* np.maximum(w, h) (neither is NaN: inputs are finite) */
        whole[m] = (dmin > pad) && (axmax + pxmax <= in_frame) && (aymax + pymax <= in_frame);
    }
    return 0;
}

/* Each point's distance to its nearest other point: pts [P, 3]; order [P] the points by x ascending; out d [P]
   (inf for a single point). A sweep along x: a pair further apart in x than the best distance so far cannot be
   nearer, so the scan stops there (pairs no nearer than the best are the only ones left out: the minimum is the
   brute force's). Squared distances as (dx dx + dy dy) + dz dz, then one square root. */
/* One direction of the sweep from p: order[b], order[b + step], ... up to (not including) order[end]. */
static inline double gap_scan(const double *pts, const int64_t *order, const double *p, int64_t b, int64_t end,
                              int64_t step, double best) {
    for (; b != end; b += step) {
        const double *q = pts + 3 * order[b];
        double dx = q[0] - p[0];
        if (dx * dx > best) break;
        double dy = q[1] - p[1], dz = q[2] - p[2];
        double d2 = (dx * dx + dy * dy) + dz * dz;
        if (d2 < best) best = d2;
    }
    return best;
}

int64_t cn_nearest_gaps(const double *pts, int64_t P, const int64_t *order, double *out) {
    for (int64_t a = 0; a < P; a++) {
        const double *p = pts + 3 * order[a];
        double best = gap_scan(pts, order, p, a + 1, P, 1, INFINITY);
        best = gap_scan(pts, order, p, a - 1, -1, -1, best);
        out[order[a]] = sqrt(best);
    }
    return 0;
}

/* end_pose.frame_coverage's raster, given numpy's projections: x, y, rx, ry [M, P] (frame coordinates and disc half
   axes, half-frame units), front [M, P] (0 / 1); cell centres cx [nx], cy [ny] (ascending, evenly spaced over
   [-1, 1]); out [M]: the share of cells whose centre lies in a front point's disc, ((cx - x) / rx)^2 +
   ((cy - y) / ry)^2 <= 1 with numpy's operations (the same cells: the same bits). Each point tests only the cells
   within its disc's box grown by one cell: a cell beyond it has |cx - x| > rx (1 + 1e-9), whose quotient rounds
   above 1. scratch [nx ny] bytes. */
static inline void cell_range(double c, double r, int64_t n, int64_t *lo, int64_t *hi) {
    double a = ((c - r * (1 + 1e-9)) + 1.0) * (double)n / 2.0 - 0.5, b = ((c + r * (1 + 1e-9)) + 1.0) * (double)n / 2.0 - 0.5;
    if (!(isfinite(a) && isfinite(b))) {
        *lo = 0;
        *hi = n - 1;
        return;
    }
    *lo = a - 1 < 0 ? 0 : (a - 1 > (double)(n - 1) ? n : (int64_t)floor(a - 1));
    *hi = b + 1 < 0 ? -1 : (b + 1 > (double)(n - 1) ? n - 1 : (int64_t)ceil(b + 1));
}

int64_t cn_coverage(const double *x, const double *y, const double *rx, const double *ry, const uint8_t *front,
                    int64_t M, int64_t P, const double *cx, int64_t nx, const double *cy, int64_t ny,
                    uint8_t *covered, double *out) {
    for (int64_t m = 0; m < M; m++) {
        for (int64_t c = 0; c < nx * ny; c++) covered[c] = 0;
        for (int64_t p = m * P; p < (m + 1) * P; p++) {
            if (!front[p]) continue;
            int64_t i0, i1, j0, j1;
            cell_range(x[p], rx[p], nx, &i0, &i1);
            cell_range(y[p], ry[p], ny, &j0, &j1);
            for (int64_t j = j0; j <= j1; j++) {
                double dy = (cy[j] - y[p]) / ry[p];
                for (int64_t i = i0; i <= i1; i++) {
                    if (covered[j * nx + i]) continue;
                    double dx = (cx[i] - x[p]) / rx[p];
                    if (dx * dx + dy * dy <= 1.0) covered[j * nx + i] = 1;
                }
            }
        }
        int64_t count = 0;
        for (int64_t c = 0; c < nx * ny; c++) count += covered[c];
        out[m] = (double)count / (double)(nx * ny);
    }
    return 0;
}

/* One pass of target_object.exact_median: v [n]; out mid [<= n] the values in [lo, hi] (in order), counts [2] those
   below lo and above hi (a NaN is neither: the caller sees the counts not add up). Returns how many are in mid. */
int64_t cn_bracket(const double *v, int64_t n, double lo, double hi, double *mid, int64_t *counts) {
    int64_t below = 0, above = 0, c = 0;
    for (int64_t i = 0; i < n; i++) {
        double a = v[i];
        below += a < lo;
        above += a > hi;
        mid[c] = a;
        c += (a >= lo) & (a <= hi);
    }
    counts[0] = below;
    counts[1] = above;
    return c;
}
