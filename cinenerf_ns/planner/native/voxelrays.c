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
#include <pthread.h>
#include <stdint.h>

#define MAX_THREADS 64
#define BLOCK 64 /* voxels a thread takes at a time: their cost varies (a seen voxel stops at its first free ray) */

typedef struct {
    const uint8_t *surf;
    int64_t X, Y, Z;
    const int64_t *idx;
    int64_t V;
    const double *cams;
    int64_t C;
    double step;
    uint8_t *hidden;
    int64_t next; /* the next block's first voxel, shared (atomic) */
} job_t;

static uint8_t voxel_hidden(const job_t *J, int64_t v) {
    const int64_t X = J->X, Y = J->Y, Z = J->Z;
    const double p[3] = {(double)J->idx[3 * v], (double)J->idx[3 * v + 1], (double)J->idx[3 * v + 2]};
    int all_blocked = J->C > 0;
    for (int64_t c = 0; c < J->C && all_blocked; c++) {
        const double *cam = J->cams + 3 * c;
        double d[3] = {cam[0] - p[0], cam[1] - p[1], cam[2] - p[2]};
        double len = sqrt((d[0] * d[0] + d[1] * d[1]) + d[2] * d[2]);
        double den = len > 1e-300 ? len : 1e-300;
        d[0] /= den;
        d[1] /= den;
        d[2] /= den;
        int blocked = 0;
        for (int64_t n = 1;; n++) {
            double t = (double)n * J->step;
            if (!(t <= len)) break;
            double q0 = floor((p[0] + t * d[0]) + 0.5), q1 = floor((p[1] + t * d[1]) + 0.5),
                   q2 = floor((p[2] + t * d[2]) + 0.5);
            if (q0 < 0 || q1 < 0 || q2 < 0 || q0 >= (double)X || q1 >= (double)Y || q2 >= (double)Z) break;
            if (J->surf[((int64_t)q0 * Y + (int64_t)q1) * Z + (int64_t)q2]) {
                blocked = 1;
                break;
            }
        }
        if (!blocked) all_blocked = 0;
    }
    return (uint8_t)all_blocked;
}

static void *run(void *arg) {
    job_t *J = (job_t *)arg;
    for (;;) {
        int64_t a = __atomic_fetch_add(&J->next, BLOCK, __ATOMIC_RELAXED);
        if (a >= J->V) break;
        int64_t b = a + BLOCK < J->V ? a + BLOCK : J->V;
        for (int64_t v = a; v < b; v++) J->hidden[v] = voxel_hidden(J, v);
    }
    return NULL;
}

/* hidden[v] = 1 when, for every camera, the sampled segment from voxel idx[v] toward it meets a set voxel of surf
   [X, Y, Z] (C order) before it reaches the camera or leaves the grid; 0 otherwise (and with no camera). The voxels
   are shared among `threads` threads (each voxel's answer is its own: the same result with any number). */
int64_t cn_hidden_voxels(const uint8_t *surf, int64_t X, int64_t Y, int64_t Z, const int64_t *idx, int64_t V,
                         const double *cams, int64_t C, double step, uint8_t *hidden, int64_t threads) {
    if (step <= 0.0) return -1;
    job_t J = {surf, X, Y, Z, idx, V, cams, C, step, hidden, 0};
    if (threads < 1) threads = 1;
    if (threads > MAX_THREADS) threads = MAX_THREADS;
    if (threads > V / BLOCK + 1) threads = V / BLOCK + 1; /* a few voxels: no thread to start */
    pthread_t tid[MAX_THREADS];
    int64_t started = 0;
    for (int64_t t = 1; t < threads; t++) {
        if (pthread_create(&tid[t], NULL, run, &J) != 0) break; /* this thread does the rest */
        started = t;
    }
    run(&J);
    for (int64_t t = 1; t <= started; t++) pthread_join(tid[t], NULL);
    return 0;
}
