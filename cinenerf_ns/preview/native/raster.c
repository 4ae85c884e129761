/* Tile-based classic 3DGS rasteriser on the CPU (gsplat 1.5.3 semantics, rasterize_mode="classic", packed=False).
 *
 * Compiled twice by preview/native/__init__.py: REAL=float (previews) and REAL=double (tests against the float64
 * torch path). One call renders one camera:
 *   1. project (threads over Gaussians): world -> camera with the 4x4 viewmat, drop depth < near, EWA projection with
 *      the clamped Jacobian, eps2d added, conic, opacity-aware box (gsplat's radius_x/radius_y), drop off-image;
 *   2. sort the visible Gaussians by depth (stable LSD radix sort on the bits of the positive depth);
 *   3. per 16x16 tile, the depth-ordered list of Gaussians whose tile box touches it;
 *   4. composite front to back (threads over tiles): alpha = min(0.999, o exp(-sigma)), skipped below 1/255, a pixel
 *      stops before the Gaussian that would take its transmittance to <= 1e-4.
 * Output: premultiplied colour [H, W, 3] and alpha = 1 - final transmittance [H, W]; the caller adds a background.
 * Returns the number of visible Gaussians, or -1 when memory ran out. stats: [visible, tile intersections].
 */
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#ifndef REAL
#define REAL float
#endif
typedef REAL real;
#define TILE 16
#define MAX_THREADS 64
#if defined(__GNUC__) || defined(__clang__)
#define PREFETCH(p) __builtin_prefetch(p)
#else
#define PREFETCH(p) ((void)0)
#endif

#if defined(REAL_IS_DOUBLE)
#define EXP exp
#define SQRT sqrt
#define LOG log
typedef uint64_t key_t_;
#else
#define EXP expf
#define SQRT sqrtf
#define LOG logf
typedef uint32_t key_t_;
#endif

typedef struct {
    real mx, my, ca, cb, cc, op, r, g, b;
    int32_t rx, ry; /* box half sizes in pixels (gsplat radii) */
} splat_t;

typedef struct {
    /* inputs */
    const real *means, *cov, *opac, *col, *V;
    int64_t n, width, height, tiles_x, tiles_y;
    real fx, fy, cx, cy, near_plane, eps2d;
    /* work */
    splat_t *sp; /* [n] by Gaussian (written by the projection) */
    const splat_t *sp_sorted; /* [visible] in depth order (read by the rasteriser; tile lists index it) */
    real *depth;
    uint8_t *valid;
    const int64_t *tile_start, *tile_list;
    real *out_rgb, *out_alpha;
    int64_t lo, hi;
    volatile int64_t *next_tile;
} job_t;

static void project_range(job_t *j) {
    const real *V = j->V;
    const real W = (real)j->width, H = (real)j->height;
    const real tan_x = (real)0.5 * W / j->fx, tan_y = (real)0.5 * H / j->fy;
    const real lxp = (W - j->cx) / j->fx + (real)0.3 * tan_x, lxn = j->cx / j->fx + (real)0.3 * tan_x;
    const real lyp = (H - j->cy) / j->fy + (real)0.3 * tan_y, lyn = j->cy / j->fy + (real)0.3 * tan_y;
    const real amin = (real)(1.0 / 255.0);
    for (int64_t i = j->lo; i < j->hi; i++) {
        j->valid[i] = 0;
        const real *m = j->means + 3 * i;
        real x = V[0] * m[0] + V[1] * m[1] + V[2] * m[2] + V[3];
        real y = V[4] * m[0] + V[5] * m[1] + V[6] * m[2] + V[7];
        real z = V[8] * m[0] + V[9] * m[1] + V[10] * m[2] + V[11];
        if (z < j->near_plane) continue;
        const real *c = j->cov + 6 * i; /* xx xy xz yy yz zz */
        real S[3][3] = {{c[0], c[1], c[2]}, {c[1], c[3], c[4]}, {c[2], c[4], c[5]}};
        real RS[3][3], C[3][3];
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) RS[a][b] = V[4 * a] * S[0][b] + V[4 * a + 1] * S[1][b] + V[4 * a + 2] * S[2][b];
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) C[a][b] = RS[a][0] * V[4 * b] + RS[a][1] * V[4 * b + 1] + RS[a][2] * V[4 * b + 2];
        real rz = (real)1 / z, rz2 = rz * rz;
        real u = x * rz, v = y * rz;
        real tx = z * (u < -lxn ? -lxn : (u > lxp ? lxp : u));
        real ty = z * (v < -lyn ? -lyn : (v > lyp ? lyp : v));
        real j00 = j->fx * rz, j02 = -j->fx * tx * rz2, j11 = j->fy * rz, j12 = -j->fy * ty * rz2;
        /* cov2d = J C J^T, J = [[j00, 0, j02], [0, j11, j12]] */
        real a0 = j00 * C[0][0] + j02 * C[2][0], a1 = j00 * C[0][1] + j02 * C[2][1], a2 = j00 * C[0][2] + j02 * C[2][2];
        real b1 = j11 * C[1][1] + j12 * C[2][1], b2 = j11 * C[1][2] + j12 * C[2][2];
        real sxx = a0 * j00 + a2 * j02 + j->eps2d;
        real sxy = a1 * j11 + a2 * j12;
        real syy = b1 * j11 + b2 * j12 + j->eps2d;
        real det = sxx * syy - sxy * sxy;
        if (det <= 0) continue;
        real o = j->opac[i];
        if (o < amin) continue;
        real ext = SQRT((real)2 * LOG(o / amin));
        if (ext > (real)3.33) ext = (real)3.33;
        real rxf = ceil(ext * SQRT(sxx)), ryf = ceil(ext * SQRT(syy));
        if (rxf <= 0 && ryf <= 0) continue; /* radius_clip = 0 */
        real mx = j->fx * x * rz + j->cx, my = j->fy * y * rz + j->cy;
        if (mx + rxf <= 0 || mx - rxf >= W || my + ryf <= 0 || my - ryf >= H) continue;
        splat_t *s = j->sp + i;
        real id = (real)1 / det;
        s->mx = mx; s->my = my;
        s->ca = syy * id; s->cb = -sxy * id; s->cc = sxx * id;
        s->op = o;
        s->r = j->col[3 * i]; s->g = j->col[3 * i + 1]; s->b = j->col[3 * i + 2];
        s->rx = (int32_t)rxf; s->ry = (int32_t)ryf;
        j->depth[i] = z;
        j->valid[i] = 1;
    }
}

/* gsplat IntersectTile: tile_min = clamp(floor(m/16 - r/16)), tile_max = clamp(ceil(m/16 + r/16)), max exclusive */
static void tile_box(const splat_t *s, int64_t tx, int64_t ty, int64_t *x0, int64_t *x1, int64_t *y0, int64_t *y1) {
    real cx = s->mx / TILE, cy = s->my / TILE, rx = (real)s->rx / TILE, ry = (real)s->ry / TILE;
    real a = floor(cx - rx), b = ceil(cx + rx), c = floor(cy - ry), d = ceil(cy + ry);
    *x0 = a < 0 ? 0 : (a > tx ? tx : (int64_t)a);
    *x1 = b < 0 ? 0 : (b > tx ? tx : (int64_t)b);
    *y0 = c < 0 ? 0 : (c > ty ? ty : (int64_t)c);
    *y1 = d < 0 ? 0 : (d > ty ? ty : (int64_t)d);
}

static void raster_tile(const job_t *j, int64_t tile) {
    const int64_t tx = tile % j->tiles_x, ty = tile / j->tiles_x;
    const int64_t X0 = tx * TILE, Y0 = ty * TILE;
    const int64_t nx = (j->width - X0) < TILE ? (j->width - X0) : TILE;
    const int64_t ny = (j->height - Y0) < TILE ? (j->height - Y0) : TILE;
    real T[TILE * TILE], acc[TILE * TILE][3];
    uint8_t done[TILE * TILE];
    for (int p = 0; p < TILE * TILE; p++) { T[p] = 1; acc[p][0] = acc[p][1] = acc[p][2] = 0; done[p] = 0; }
    int64_t left = nx * ny;
    const real amin = (real)(1.0 / 255.0);
    const int64_t k_end = j->tile_start[tile + 1];
    for (int64_t k = j->tile_start[tile]; k < k_end && left > 0; k++) {
        if (k + 8 < k_end) PREFETCH(j->sp_sorted + j->tile_list[k + 8]); /* scattered reads: ask early */
        const splat_t *s = j->sp_sorted + j->tile_list[k];
        /* only pixels in the Gaussian's box (+1 px) can reach alpha >= 1/255 (sigma >= ext^2 / 2 outside it) */
        int64_t x0 = (int64_t)floor(s->mx - s->rx - 1) - X0, x1 = (int64_t)ceil(s->mx + s->rx + 1) - X0;
        int64_t y0 = (int64_t)floor(s->my - s->ry - 1) - Y0, y1 = (int64_t)ceil(s->my + s->ry + 1) - Y0;
        if (x0 < 0) x0 = 0;
        if (y0 < 0) y0 = 0;
        if (x1 > nx) x1 = nx;
        if (y1 > ny) y1 = ny;
        /* o exp(-sigma) < 1/255 exactly when sigma > log(o * 255); beyond it by a margin far wider than the rounding
           of exp and of the product, the pixel is skipped without calling exp: the same pixels are skipped */
        const real skip = LOG(s->op / amin) + (real)1e-3;
        for (int64_t py = y0; py < y1; py++) {
            real dy = s->my - ((real)(Y0 + py) + (real)0.5);
            for (int64_t px = x0; px < x1; px++) {
                int64_t p = py * TILE + px;
                if (done[p]) continue;
                real dx = s->mx - ((real)(X0 + px) + (real)0.5);
                real sigma = (real)0.5 * (s->ca * dx * dx + s->cc * dy * dy) + s->cb * dx * dy;
                if (sigma < 0 || sigma > skip) continue;
                real alpha = s->op * EXP(-sigma);
                if (alpha > (real)0.999) alpha = (real)0.999;
                if (alpha < amin) continue;
                real nT = T[p] * ((real)1 - alpha);
                if (nT <= (real)1e-4) { done[p] = 1; left--; continue; }
                real w = alpha * T[p];
                acc[p][0] += w * s->r; acc[p][1] += w * s->g; acc[p][2] += w * s->b;
                T[p] = nT;
            }
        }
    }
    for (int64_t py = 0; py < ny; py++)
        for (int64_t px = 0; px < nx; px++) {
            int64_t p = py * TILE + px, o = (Y0 + py) * j->width + X0 + px;
            j->out_rgb[3 * o] = acc[p][0]; j->out_rgb[3 * o + 1] = acc[p][1]; j->out_rgb[3 * o + 2] = acc[p][2];
            j->out_alpha[o] = (real)1 - T[p];
        }
}

static void *worker(void *arg) {
    job_t *j = (job_t *)arg;
    if (j->next_tile == NULL) { project_range(j); return NULL; }
    const int64_t ntiles = j->tiles_x * j->tiles_y;
    for (;;) {
        int64_t t = __sync_fetch_and_add(j->next_tile, 1);
        if (t >= ntiles) break;
        raster_tile(j, t);
    }
    return NULL;
}

static void run_threads(job_t *proto, int64_t nthreads, int project) {
    pthread_t th[MAX_THREADS];
    job_t jobs[MAX_THREADS];
    int started[MAX_THREADS];
    for (int64_t t = 0; t < nthreads; t++) {
        jobs[t] = *proto;
        if (project) {
            jobs[t].lo = proto->n * t / nthreads;
            jobs[t].hi = proto->n * (t + 1) / nthreads;
            jobs[t].next_tile = NULL;
        }
        started[t] = t > 0 && pthread_create(&th[t], NULL, worker, &jobs[t]) == 0;
        if (t > 0 && !started[t]) worker(&jobs[t]); /* no thread: do its share here */
    }
    worker(&jobs[0]);
    for (int64_t t = 1; t < nthreads; t++)
        if (started[t]) pthread_join(th[t], NULL);
}

/* stable LSD radix sort of idx[0..m) by the bits of key[idx] (non-negative reals: bit order = value order) */
static int sort_by_depth(const real *depth, int64_t *idx, int64_t m) {
    key_t_ *k = malloc(sizeof(key_t_) * (size_t)(m ? m : 1)), *k2 = malloc(sizeof(key_t_) * (size_t)(m ? m : 1));
    int64_t *i2 = malloc(sizeof(int64_t) * (size_t)(m ? m : 1));
    if (!k || !k2 || !i2) { free(k); free(k2); free(i2); return -1; }
    for (int64_t a = 0; a < m; a++) memcpy(&k[a], &depth[idx[a]], sizeof(key_t_));
    for (unsigned shift = 0; shift < 8 * sizeof(key_t_); shift += 8) {
        int64_t cnt[257] = {0};
        for (int64_t a = 0; a < m; a++) cnt[((k[a] >> shift) & 255u) + 1]++;
        if (cnt[((k[0] >> shift) & 255u) + 1] == m) continue; /* all equal in this byte */
        for (int b = 0; b < 256; b++) cnt[b + 1] += cnt[b];
        for (int64_t a = 0; a < m; a++) {
            int64_t d = cnt[(k[a] >> shift) & 255u]++;
            k2[d] = k[a]; i2[d] = idx[a];
        }
        key_t_ *tk = k; k = k2; k2 = tk;
        memcpy(idx, i2, sizeof(int64_t) * (size_t)m);
    }
    free(k); free(k2); free(i2);
    return 0;
}

int64_t cn_render(const real *means, const real *cov, const real *opac, const real *col, int64_t n, const real *viewmat,
                  const real *intr, int64_t width, int64_t height, real near_plane, real eps2d, int64_t nthreads,
                  real *out_rgb, real *out_alpha, int64_t *stats) {
    if (nthreads < 1) nthreads = 1;
    if (nthreads > MAX_THREADS) nthreads = MAX_THREADS;
    job_t j;
    memset(&j, 0, sizeof j);
    j.means = means; j.cov = cov; j.opac = opac; j.col = col; j.V = viewmat; j.n = n;
    j.width = width; j.height = height; j.tiles_x = (width + TILE - 1) / TILE; j.tiles_y = (height + TILE - 1) / TILE;
    j.fx = intr[0]; j.fy = intr[1]; j.cx = intr[2]; j.cy = intr[3]; j.near_plane = near_plane; j.eps2d = eps2d;
    const int64_t ntiles = j.tiles_x * j.tiles_y;
    size_t nn = (size_t)(n ? n : 1);
    j.sp = malloc(sizeof(splat_t) * nn);
    j.depth = malloc(sizeof(real) * nn);
    j.valid = malloc(nn);
    int64_t *order = malloc(sizeof(int64_t) * nn);
    int64_t *start = calloc((size_t)ntiles + 1, sizeof(int64_t)), *list = NULL;
    splat_t *sorted = NULL;
    int64_t rc = -1;
    if (!j.sp || !j.depth || !j.valid || !order || !start) goto done;
    run_threads(&j, n < 4096 ? 1 : nthreads, 1);
    int64_t m = 0;
    for (int64_t i = 0; i < n; i++)
        if (j.valid[i]) order[m++] = i;
    if (sort_by_depth(j.depth, order, m) != 0) goto done;
    /* the visible splats copied in depth order: a tile's list is then increasing positions in one compact array (the
       rasteriser reads them in memory order instead of jumping through all n) */
    sorted = malloc(sizeof(splat_t) * (size_t)(m ? m : 1));
    if (!sorted) goto done;
    for (int64_t a = 0; a < m; a++) sorted[a] = j.sp[order[a]];
    int64_t x0, x1, y0, y1;
    for (int64_t a = 0; a < m; a++) { /* count, prefix sum, fill: each tile's list stays depth-ordered */
        tile_box(sorted + a, j.tiles_x, j.tiles_y, &x0, &x1, &y0, &y1);
        for (int64_t ty = y0; ty < y1; ty++)
            for (int64_t tx = x0; tx < x1; tx++) start[ty * j.tiles_x + tx + 1]++;
    }
    for (int64_t t = 0; t < ntiles; t++) start[t + 1] += start[t];
    list = malloc(sizeof(int64_t) * (size_t)(start[ntiles] ? start[ntiles] : 1));
    int64_t *fill = malloc(sizeof(int64_t) * (size_t)(ntiles ? ntiles : 1));
    if (!list || !fill) { free(fill); goto done; }
    memcpy(fill, start, sizeof(int64_t) * (size_t)ntiles);
    for (int64_t a = 0; a < m; a++) {
        tile_box(sorted + a, j.tiles_x, j.tiles_y, &x0, &x1, &y0, &y1);
        for (int64_t ty = y0; ty < y1; ty++)
            for (int64_t tx = x0; tx < x1; tx++) list[fill[ty * j.tiles_x + tx]++] = a;
    }
    free(fill);
    volatile int64_t next = 0;
    j.sp_sorted = sorted;
    j.tile_start = start; j.tile_list = list; j.out_rgb = out_rgb; j.out_alpha = out_alpha; j.next_tile = &next;
    run_threads(&j, nthreads, 0);
    if (stats) { stats[0] = m; stats[1] = start[ntiles]; }
    rc = m;
done:
    free(j.sp); free(j.depth); free(j.valid); free(order); free(start); free(list); free(sorted);
    return rc;
}
