/* Look-at rotations of a shot's frames (trajectory/orientation.py look_at_rotations), compiled, for the usual case:
   every frame away from the target and outside the singular cone around +-up. Those frames take no input from
   their neighbours, and this file repeats the Python path's arithmetic in numpy's order: z = (p - g) / |p - g|,
   x = (up x z) / |up x z|, then x / |x| again (orientation._normalise) and y = z x x, with _cross's products and
   differences and np.linalg.norm(axis=-1)'s sum ((x*x + y*y) + z*z, as native/timing.c's norm3); so the two paths
   agree bit for bit where numpy's norm sums in that order (the CPU box). Any other case (a frame at the target, one
   inside the cone, a non-finite number) returns a status and the caller takes the Python path, which carries the
   previous frame's axis through the cone and raises the errors. */
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif
#include <math.h>
#include <stdint.h>

static inline double norm3(double x, double y, double z) {
    return sqrt((x * x + y * y) + z * z);
}

/* pos [T, 3]; tgt [3] (tgt_rows 0) or [T, 3] (tgt_rows 1); up [3], already a unit vector; out [T, 3, 3] row-major,
   columns x, y, z. Returns 0 (written), 1 (a frame needs the Python path: at the target or inside the cone), 2 (a
   non-finite input). */
int64_t cn_look_at(const double *pos, const double *tgt, int64_t tgt_rows, int64_t T, const double *up,
                   double singular_sin, double *out) {
    double scale = 1.0;  /* max(1, |pos|.max(), |tgt|.max()) */
    for (int64_t i = 0; i < 3 * T; i++) {
        double a = fabs(pos[i]);
        if (!isfinite(a)) return 2;
        if (a > scale) scale = a;
    }
    for (int64_t i = 0; i < (tgt_rows ? 3 * T : 3); i++) {
        double a = fabs(tgt[i]);
        if (!isfinite(a)) return 2;
        if (a > scale) scale = a;
    }
    for (int64_t t = 0; t < T; t++) {
        const double *p = pos + 3 * t, *g = tgt + (tgt_rows ? 3 * t : 0);
        double b0 = p[0] - g[0], b1 = p[1] - g[1], b2 = p[2] - g[2];
        double d = norm3(b0, b1, b2);
        if (!(d > 1e-9 * scale)) return 1;
        double z0 = b0 / d, z1 = b1 / d, z2 = b2 / d;
        double c0 = up[1] * z2 - up[2] * z1, c1 = up[2] * z0 - up[0] * z2, c2 = up[0] * z1 - up[1] * z0;
        double s = norm3(c0, c1, c2);
        if (!(s >= singular_sin)) return 1;
        double x0 = c0 / s, x1 = c1 / s, x2 = c2 / s;
        double n = norm3(x0, x1, x2);
        x0 = x0 / n;
        x1 = x1 / n;
        x2 = x2 / n;
        double y0 = z1 * x2 - z2 * x1, y1 = z2 * x0 - z0 * x2, y2 = z0 * x1 - z1 * x0;
        double *r = out + 9 * t;
        r[0] = x0; r[1] = y0; r[2] = z0;
        r[3] = x1; r[4] = y1; r[5] = z1;
        r[6] = x2; r[7] = y2; r[8] = z2;
    }
    return 0;
}
