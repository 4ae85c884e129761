/* Sampled sight lines through a voxel grid (method/object_centre.py: hidden_voxels), compiled.

   cn_hidden_voxels repeats hidden_voxels' numpy arithmetic in the same order, in float64 (sample n at
   t = n * step; voxel = floor((p + t * d) + 0.5); d = (c - p) / max(|c - p|, 1e-300) with |.| = sqrt((x*x + y*y) + z*z)),
   so both give the same voxels. Contraction into fused multiply-adds would round differently: it is turned off. */
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif
#include <math.h>
#include <stdint.h>

/* hidden[v] = 1 when, for every camera, the sampled segment from voxel idx[v] toward it meets a set voxel of surf
   [X, Y, Z] (C order) before it reaches the camera or leaves the grid; 0 otherwise (and with no camera). */
int64_t cn_hidden_voxels(const uint8_t *surf, int64_t X, int64_t Y, int64_t Z, const int64_t *idx, int64_t V,
                         const double *cams, int64_t C, double step, uint8_t *hidden) {
    if (step <= 0.0) return -1;
    for (int64_t v = 0; v < V; v++) {
        const double p[3] = {(double)idx[3 * v], (double)idx[3 * v + 1], (double)idx[3 * v + 2]};
        int all_blocked = C > 0;
        for (int64_t c = 0; c < C && all_blocked; c++) {
            double d[3] = {cams[3 * c] - p[0], cams[3 * c + 1] - p[1], cams[3 * c + 2] - p[2]};
            double len = sqrt((d[0] * d[0] + d[1] * d[1]) + d[2] * d[2]);
            double den = len > 1e-300 ? len : 1e-300;
            d[0] /= den;
            d[1] /= den;
            d[2] /= den;
            int blocked = 0;
            for (int64_t n = 1;; n++) {
                double t = (double)n * step;
                if (!(t <= len)) break;
                double q0 = floor((p[0] + t * d[0]) + 0.5), q1 = floor((p[1] + t * d[1]) + 0.5),
                       q2 = floor((p[2] + t * d[2]) + 0.5);
                if (q0 < 0 || q1 < 0 || q2 < 0 || q0 >= (double)X || q1 >= (double)Y || q2 >= (double)Z) break;
                if (surf[((int64_t)q0 * Y + (int64_t)q1) * Z + (int64_t)q2]) {
                    blocked = 1;
                    break;
                }
            }
            if (!blocked) all_blocked = 0;
        }
        hidden[v] = (uint8_t)all_blocked;
    }
    return 0;
}
