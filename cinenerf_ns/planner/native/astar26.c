/* A* on a 26-connected voxel grid: the compiled twin of astar.py's pure-Python search.
 *
 * Same graph, costs, heuristic and tie-breaking as astar.py: moves cost 1, sqrt 2, sqrt 3 (voxel units);
 * the heuristic is the (weighted) 3D octile distance computed with the same operations in the same order;
 * the open list is a binary heap ordered by (f, h, flat index), the order of Python's tuples; a node is
 * closed when first popped. So both return the same path (tests check cost against Dijkstra and the paths
 * against each other).
 *
 * search26 also answers "shortest path to the nearest of a set of voxels" (Dijkstra, for coarse_path.py).
 *
 * Landmarks (ALT: A*, landmarks, triangle inequality), search26_ws_lm: with the exact shortest-path distances D_l of
 * a few landmark voxels (dist26, float32 tables), |D_l(goal) - D_l(n)| <= dist(n, goal) for every n, so the largest
 * of these and the octile distance is still a lower bound of the remaining cost (and consistent, up to the float32
 * rounding, which is taken off: each table value is within 2^-24 relative of the float64 distance, so subtracting
 * (D_l(goal) + D_l(n)) 2^-23 keeps the bound below the true distance). Around walls the octile distance is far below
 * the true cost and A* floods the free space in front of the wall; the landmark bound sees the detour. The result
 * is still a minimum-cost path (among equal-cost paths it may pick another one than plain A*).
 *
 * blocked: uint8 [X+2][Y+2][Z+2], C order, the grid padded with a ring of occupied voxels (no bounds checks).
 * Returns the number of path voxels written to out (flat padded indices, start first), or
 *   -1 no path (the free component of the start is exhausted), -2 more than max_expansions expansions,
 *   -3 out_cap too small, -4 out of memory.
 * Memory: per-voxel state, g and parent arrays of the padded size. search26 / astar26 calloc them per call;
 * search26_ws takes them from the caller (astar.py keeps one set per grid and thread) and marks state with a
 * generation number instead of clearing it: voxel n is open when stamp[n] == 2 gen, closed when
 * stamp[n] == 2 gen + 1, unseen otherwise (any older stamp), so g and parent are read only for voxels seen in this
 * call. Why: glibc serves repeated ~10 MB callocs from the heap once the first is freed, and then clears every
 * byte: ~0.3 ms per call on a 96 x 96 x 57 grid even for a search of ten voxels, several calls per plan.
 * search26_wsr also keeps the open list in a caller's buffer when its budget runs out, and a later call with the same
 * search resumes it (astar.py: a fine A* over its budget whose coarse route fails goes on from where it stopped
 * instead of starting again: the same path).
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    double f, h;
    int64_t n;
} item_t;

static int less(const item_t *a, const item_t *b) {
    if (a->f != b->f) return a->f < b->f;
    if (a->h != b->h) return a->h < b->h;
    return a->n < b->n;
}

/* *owned == 0: *heap is the caller's buffer (search26_wsr), never realloc'd: a full one is copied into a new one */
static int push(item_t **heap, int64_t *size, int64_t *cap, int *owned, item_t it) {
    if (*size == *cap) {
        int64_t nc = *cap * 2;
        item_t *nh;
        if (*owned) {
            nh = (item_t *)realloc(*heap, (size_t)nc * sizeof(item_t));
        } else {
            nh = (item_t *)malloc((size_t)nc * sizeof(item_t));
            if (nh) memcpy(nh, *heap, (size_t)*size * sizeof(item_t));
        }
        if (!nh) return -1;
        *heap = nh;
        *cap = nc;
        *owned = 1;
    }
    item_t *hp = *heap;
    int64_t i = (*size)++;
    while (i > 0) {
        int64_t p = (i - 1) >> 1;
        if (!less(&it, &hp[p])) break;
        hp[i] = hp[p];
        i = p;
    }
    hp[i] = it;
    return 0;
}

/* Floyd's pop: the hole left by the top goes down along the smaller children to a leaf (one comparison a level), then
   the last item rises from there (it usually belongs near the bottom). Items are distinct (f, h, n): a node is pushed
   again only with a smaller g, so a smaller f: the heap's order is total and every pop returns the same item as with
   the usual sift-down, whatever the layout. */
static item_t pop(item_t *hp, int64_t *size) {
    item_t top = hp[0];
    item_t last = hp[--(*size)];
    int64_t n = *size, i = 0;
    if (n == 0) return top;
    for (;;) {
        int64_t c = 2 * i + 1;
        if (c >= n) break;
        if (c + 1 < n && less(&hp[c + 1], &hp[c])) c++;
        hp[i] = hp[c];
        i = c;
    }
    while (i > 0) {
        int64_t p = (i - 1) >> 1;
        if (!less(&last, &hp[p])) break;
        hp[i] = hp[p];
        i = p;
    }
    hp[i] = last;
    return top;
}

/* target == NULL: A* from start to goal. target != NULL (uint8, same layout as blocked): Dijkstra (no
 * heuristic, goal ignored) from start to the nearest voxel whose target byte is set. */
/* The 26 moves: flat offsets (strides sx, sy, 1), step costs 1, sqrt 2, sqrt 3, and (when di != NULL) the moves. */
static void moves26(int64_t sx, int64_t sy, int64_t *off, double *cost, int *di_, int *dj_, int *dk_) {
    int m = 0;
    for (int di = -1; di <= 1; di++)
        for (int dj = -1; dj <= 1; dj++)
            for (int dk = -1; dk <= 1; dk++) {
                if (!(di || dj || dk)) continue;
                off[m] = di * sx + dj * sy + dk;
                cost[m] = sqrt((double)(di * di + dj * dj + dk * dk));
                if (di_) {
                    di_[m] = di;
                    dj_[m] = dj;
                    dk_[m] = dk;
                }
                m++;
            }
}

#define LM_MAX 16
#define LM_REL 1.1920928955078125e-07 /* 2^-23 */

static int64_t search_core(const uint8_t *blocked, int64_t PX, int64_t PY, int64_t PZ, int64_t start, int64_t goal,
                           const uint8_t *target, double weight, int64_t max_expansions, int64_t *out, int64_t out_cap,
                           uint32_t *stamp, uint32_t gen, double *g, int64_t *parent, const float *lm, int64_t L,
                           item_t *ext_heap, int64_t ext_cap, int64_t *state) {
    const uint32_t OPEN = 2u * gen, CLOSED = 2u * gen + 1u;
    const double SQ2 = sqrt(2.0), SQ3 = sqrt(3.0);
    const double c1 = weight * (SQ2 - 1.0), c2 = weight * (SQ3 - SQ2);
    const int64_t sy = PZ, sx = PY * PZ, N = PX * PY * PZ;
    int64_t off[26];
    double cost[26];
    int di_[26], dj_[26], dk_[26];
    moves26(sx, sy, off, cost, di_, dj_, dk_);
    /* landmarks whose table reaches the goal (a landmark in another free component has +inf there) */
    const float *lt[LM_MAX];
    double lg[LM_MAX];
    int nl = 0;
    if (!target && lm)
        for (int64_t l = 0; l < L && nl < LM_MAX; l++) {
            const float *t = lm + l * N;
            if (isfinite(t[goal])) {
                lt[nl] = t;
                lg[nl] = (double)t[goal];
                nl++;
            }
        }
    const int resume = ext_heap && state && state[0] > 0;
    int64_t cap = ext_heap ? ext_cap : 1024, size = resume ? state[0] : 0;
    int owned = !ext_heap;
    item_t *heap = ext_heap ? ext_heap : (item_t *)malloc((size_t)cap * sizeof(item_t));
    int64_t result = -1, expansions = resume ? state[1] : 0;
    if (state) state[0] = 0; /* not resumable unless set again below */
    if (!heap || cap < 1) {
        result = -4;
        goto done;
    }
    const int64_t gi = goal / sx, gj = (goal % sx) / sy, gk = goal % sy;
    if (!resume) {
        g[start] = 0.0;
        parent[start] = -1;
        stamp[start] = OPEN;
        item_t s0 = {0.0, 0.0, start};
        if (push(&heap, &size, &cap, &owned, s0)) {
            result = -4;
            goto done;
        }
    }
    int found = 0;
    while (size > 0) {
        item_t it = pop(heap, &size);
        int64_t cur = it.n;
        if (stamp[cur] == CLOSED) continue;
        if (target ? target[cur] != 0 : cur == goal) {
            goal = cur; /* the target reached (unchanged for A*) */
            found = 1;
            break;
        }
        if (max_expansions >= 0 && expansions >= max_expansions) {
            /* the budget is spent before cur is expanded: cur goes back (it was the minimum, so the open list is the
               one an unbounded search has here) and a resumed call continues exactly where this one stopped */
            push(&heap, &size, &cap, &owned, it); /* cannot grow: it was just popped */
            result = -2;
            goto done;
        }
        stamp[cur] = CLOSED;
        expansions++;
        const double gc = g[cur];
        const int64_t ci = cur / sx, cj = (cur % sx) / sy, ck = cur % sy;
        const int64_t dgi = gi - ci, dgj = gj - cj, dgk = gk - ck;
        for (int q = 0; q < 26; q++) {
            int64_t n = cur + off[q];
            if (blocked[n] || stamp[n] == CLOSED) continue;
            double ng = gc + cost[q];
            if (stamp[n] != OPEN || ng < g[n]) {
                g[n] = ng;
                parent[n] = cur;
                stamp[n] = OPEN;
                double a = (double)llabs(dgi - di_[q]), b = (double)llabs(dgj - dj_[q]), e = (double)llabs(dgk - dk_[q]);
                double hi = a > b ? (a > e ? a : e) : (b > e ? b : e);
                double lo = a < b ? (a < e ? a : e) : (b < e ? b : e);
                /* same expression and order as astar.py: wgt*hi + c1*(a+b+e-hi-lo) + c2*lo */
                double h = target ? 0.0 : weight * hi + c1 * (a + b + e - hi - lo) + c2 * lo;
                for (int l = 0; l < nl; l++) {
                    double dn = (double)lt[l][n];
                    if (!isfinite(dn)) continue;
                    double v = weight * (fabs(lg[l] - dn) - (lg[l] + dn) * LM_REL);
                    if (v > h) h = v;
                }
                item_t ni = {ng + h, h, n};
                if (push(&heap, &size, &cap, &owned, ni)) {
                    result = -4;
                    goto done;
                }
            }
        }
    }
    if (!found) {
        result = -1;
        goto done;
    }
    {
        int64_t k = 0;
        for (int64_t f = goal; f != -1; f = parent[f]) k++;
        if (k > out_cap) {
            result = -3;
            goto done;
        }
        int64_t i = k - 1;
        for (int64_t f = goal; f != -1; f = parent[f]) out[i--] = f;
        result = k;
    }
done:
    if (result == -2 && state && ext_heap) { /* keep the open list for a resumed call (search26_wsr) */
        if (!owned) {
            state[0] = size, state[1] = expansions;
        } else if (size <= ext_cap) {
            memcpy(ext_heap, heap, (size_t)size * sizeof(item_t));
            state[0] = size, state[1] = expansions;
        }
    }
    if (owned) free(heap);
    return result;
}

int64_t search26(const uint8_t *blocked, int64_t PX, int64_t PY, int64_t PZ, int64_t start, int64_t goal,
                 const uint8_t *target, double weight, int64_t max_expansions, int64_t *out, int64_t out_cap) {
    const int64_t N = PX * PY * PZ;
    uint32_t *stamp = (uint32_t *)calloc((size_t)N, sizeof(uint32_t)); /* 0: unseen for gen 1 */
    double *g = (double *)malloc((size_t)N * sizeof(double));
    int64_t *parent = (int64_t *)malloc((size_t)N * sizeof(int64_t));
    int64_t r = -4;
    if (stamp && g && parent)
        r = search_core(blocked, PX, PY, PZ, start, goal, target, weight, max_expansions, out, out_cap, stamp, 1u, g,
                        parent, NULL, 0, NULL, 0, NULL);
    free(stamp);
    free(g);
    free(parent);
    return r;
}

/* search26 with the caller's workspace: stamp uint32 [N] holding no value above 2 gen - 1 (zeros at first),
 * g float64 [N], parent int64 [N]; 1 <= gen < 2^31. The caller passes gen + 1 next time (and clears stamp
 * before gen would pass 2^31 - 1). Returns what search26 returns; -5 for a gen out of range. */
int64_t search26_ws(const uint8_t *blocked, int64_t PX, int64_t PY, int64_t PZ, int64_t start, int64_t goal,
                    const uint8_t *target, double weight, int64_t max_expansions, int64_t *out, int64_t out_cap,
                    uint32_t *stamp, int64_t gen, double *g, int64_t *parent) {
    if (gen < 1 || gen >= 2147483647LL) return -5;
    return search_core(blocked, PX, PY, PZ, start, goal, target, weight, max_expansions, out, out_cap, stamp,
                       (uint32_t)gen, g, parent, NULL, 0, NULL, 0, NULL);
}

/* search26_ws with landmark tables lm float32 [L][PX PY PZ] (dist26's output per landmark; see the header): the same
 * minimum cost, fewer expansions around walls. Only the A* (target NULL) reads them. */
int64_t search26_ws_lm(const uint8_t *blocked, int64_t PX, int64_t PY, int64_t PZ, int64_t start, int64_t goal,
                       const uint8_t *target, double weight, int64_t max_expansions, int64_t *out, int64_t out_cap,
                       uint32_t *stamp, int64_t gen, double *g, int64_t *parent, const float *lm, int64_t L) {
    if (gen < 1 || gen >= 2147483647LL) return -5;
    return search_core(blocked, PX, PY, PZ, start, goal, target, weight, max_expansions, out, out_cap, stamp,
                       (uint32_t)gen, g, parent, lm, L, NULL, 0, NULL);
}

/* search26_ws_lm (lm NULL: no landmarks) that a budget may interrupt and a later call resume. heap: the caller's
 * buffer of heap_cap items (24 bytes each: double f, double h, int64 n); state int64 [2] (open-list size, expansions):
 * state[0] == 0 starts a new search; after a -2 (max_expansions spent) state[0] > 0 when the open list was kept in
 * heap (it fit), and a call with the SAME blocked, start, goal, weight, landmarks, stamp, gen, g and parent (nothing
 * else searched with them in between) and that state continues the search where it stopped, expansions counted
 * from the first call: the same pops, hence the same result, as one call with the larger budget. Any other return
 * sets state[0] = 0. */
int64_t search26_wsr(const uint8_t *blocked, int64_t PX, int64_t PY, int64_t PZ, int64_t start, int64_t goal,
                     const uint8_t *target, double weight, int64_t max_expansions, int64_t *out, int64_t out_cap,
                     uint32_t *stamp, int64_t gen, double *g, int64_t *parent, const float *lm, int64_t L,
                     void *heap, int64_t heap_cap, int64_t *state) {
    if (gen < 1 || gen >= 2147483647LL) return -5;
    return search_core(blocked, PX, PY, PZ, start, goal, target, weight, max_expansions, out, out_cap, stamp,
                       (uint32_t)gen, g, parent, lm, L, (item_t *)heap, heap_cap, state);
}

/* Shortest 26-connected path cost (1, sqrt 2, sqrt 3 per step) from start to every voxel, as float32 dist
 * [PX PY PZ] (+inf: occupied or not reachable); Dijkstra in float64. Returns the number of voxels reached, -4 out
 * of memory. */
int64_t dist26(const uint8_t *blocked, int64_t PX, int64_t PY, int64_t PZ, int64_t start, float *dist) {
    const int64_t sy = PZ, sx = PY * PZ, N = PX * PY * PZ;
    int64_t off[26];
    double cost[26];
    moves26(sx, sy, off, cost, NULL, NULL, NULL);
    double *g = (double *)malloc((size_t)N * sizeof(double));
    uint8_t *done = (uint8_t *)calloc((size_t)N, 1);
    int64_t cap = 1024, size = 0, reached = -4;
    int owned = 1;
    item_t *heap = (item_t *)malloc((size_t)cap * sizeof(item_t));
    if (!g || !done || !heap) goto out;
    for (int64_t i = 0; i < N; i++) g[i] = INFINITY;
    reached = 0;
    if (!blocked[start]) {
        g[start] = 0.0;
        item_t s0 = {0.0, 0.0, start};
        if (push(&heap, &size, &cap, &owned, s0)) {
            reached = -4;
            goto out;
        }
    }
    while (size > 0) {
        item_t it = pop(heap, &size);
        int64_t cur = it.n;
        if (done[cur]) continue;
        done[cur] = 1;
        reached++;
        for (int q = 0; q < 26; q++) {
            int64_t n = cur + off[q];
            if (blocked[n] || done[n]) continue;
            double ng = g[cur] + cost[q];
            if (ng < g[n]) {
                g[n] = ng;
                item_t ni = {ng, 0.0, n};
                if (push(&heap, &size, &cap, &owned, ni)) {
                    reached = -4;
                    goto out;
                }
            }
        }
    }
    for (int64_t i = 0; i < N; i++) dist[i] = (float)g[i];
out:
    free(g);
    free(done);
    free(heap);
    return reached;
}

int64_t astar26(const uint8_t *blocked, int64_t PX, int64_t PY, int64_t PZ, int64_t start, int64_t goal,
                double weight, int64_t max_expansions, int64_t *out, int64_t out_cap) {
    return search26(blocked, PX, PY, PZ, start, goal, NULL, weight, max_expansions, out, out_cap);
}
