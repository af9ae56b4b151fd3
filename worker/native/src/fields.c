/* Visibility cut fields (cyber-worlds §V.A.3-4): sample lookup, rotation of binary sample cuts
 * into another frame, and the counter-based cut product of a vertex's cut with interpolated
 * field cuts. NumPy references: worker/renderers/cuts/grid.py (lookup_numpy),
 * rotate.py (rotate_samples_numpy), combine.py (combine_numpy); tests/fields checks they agree.
 *
 * Cuts are sequences of node heights over the 2^H leaves of the direction tree (a node of
 * height h covers 2^h consecutive leaves); values are uint8, value/255.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include "glint_common.h"

/* Small calls stay on the calling thread (``if`` clauses): waking the team costs more than the
 * work, and far more on a loaded machine, where a parallel region waits for a time slice.
 *
 * Output of the variable-length kernels: each item is built in a per-thread scratch buffer, then
 * copied to a shared buffer at an offset taken with an atomic add (items land in any order; a
 * gather puts them in item order). pos[i] = −1 when the buffer was too small: the caller
 * retries with *used (the room all items needed). */
static inline int64_t bump(int64_t *used, int64_t c) {
    int64_t p;
#pragma omp atomic capture
    { p = *used; *used += c; }
    return p;
}

/* ---------------------------------------------------------------------------------------
 * Trilinear stencil of points in an object's field (grid.py lookup_numpy; §V.A.4 "eight
 * sample points neighbor to the vertex"). Points come in the receiver's frame; m (3×4,
 * row-major) maps them to the field's local frame and is a similarity, so the normal's local
 * direction is its rotation part, normalised. grid = cx, cy, cz, ρ0, ρmax, log q, K, n.
 * Output: the cell ((k·6 + face)·n + i)·n + j holding the point and the weights of its 8
 * corners (grid.py cell_corners order). A point is culled (cell −1, weights 0) when it is
 * outside the outermost shell or when the bounding sphere (centre c, radius r = grid[8]) lies
 * wholly below its horizon (§V.B). With clearance (per sample, the distance to the nearest
 * surface; may be NULL), bit c of test[p] says that corner c of weight > 0 lies farther from the
 * point than 0.9 × its clearance, so the segment between them may cross the object: the caller
 * traces it (combine.py validate). Corner c's position: centre + radii[k] · dirs[id].
 */
static const double FACE[6][3][3] = {
    {{1, 0, 0}, {0, 0, -1}, {0, 1, 0}},  {{-1, 0, 0}, {0, 0, 1}, {0, 1, 0}},
    {{0, 1, 0}, {1, 0, 0}, {0, 0, -1}},  {{0, -1, 0}, {1, 0, 0}, {0, 0, 1}},
    {{0, 0, 1}, {1, 0, 0}, {0, 1, 0}},   {{0, 0, -1}, {-1, 0, 0}, {0, 1, 0}}};

void glf_lookup(int64_t P, const float *pos, const float *nrm, const double *m, const double *grid,
                const double *dirs, const double *radii, const int32_t *face_table, const float *clearance,
                int32_t *cells, float *w, uint8_t *test) {
    const double cx = grid[0], cy = grid[1], cz = grid[2], rho0 = grid[3], rhomax = grid[4], logq = grid[5];
    const int K = (int)grid[6], n = (int)grid[7];
    const double rad = grid[8];
#pragma omp parallel for schedule(static) if (P > 4096)
    for (int64_t p = 0; p < P; p++) {
        float *wp = w + 8 * p;
        double x = pos[3 * p], y = pos[3 * p + 1], z = pos[3 * p + 2];
        double lx = m[0] * x + m[1] * y + m[2] * z + m[3] - cx;
        double ly = m[4] * x + m[5] * y + m[6] * z + m[7] - cy;
        double lz = m[8] * x + m[9] * y + m[10] * z + m[11] - cz;
        double nx = nrm[3 * p], ny = nrm[3 * p + 1], nz = nrm[3 * p + 2];
        double ax = m[0] * nx + m[1] * ny + m[2] * nz, ay = m[4] * nx + m[5] * ny + m[6] * nz,
               az = m[8] * nx + m[9] * ny + m[10] * nz;
        double an = sqrt(ax * ax + ay * ay + az * az);
        double rho = sqrt(lx * lx + ly * ly + lz * lz);
        /* horizon: n·(c − x) < −r  (in local units, n normalised) */
        int culled = rho > rhomax * (1 + 1e-9) || (an > 0 && -(ax * lx + ay * ly + az * lz) / an < -rad);
        test[p] = 0;
        if (culled) {
            cells[p] = -1;
            for (int k = 0; k < 8; k++) wp[k] = 0.0f;
            continue;
        }
        double s = log((rho > 1e-300 ? rho : 1e-300) / rho0) / logq;
        s = s < 0 ? 0 : (s > K - 1 ? K - 1 : s);
        int k0 = (int)floor(s);
        if (k0 > K - 2) k0 = K - 2;
        double ts = s - k0;
        double bx = fabs(lx), by = fabs(ly), bz = fabs(lz);
        int major = (bx >= by && bx >= bz) ? 0 : (by >= bz ? 1 : 2);
        double comp = major == 0 ? lx : (major == 1 ? ly : lz);
        int face = 2 * major + (comp < 0);
        const double (*F)[3] = FACE[face];
        double am = lx * F[0][0] + ly * F[0][1] + lz * F[0][2];
        if (am < 1e-300) am = 1e-300;
        double u = (4.0 / PI) * atan((lx * F[1][0] + ly * F[1][1] + lz * F[1][2]) / am);
        double v = (4.0 / PI) * atan((lx * F[2][0] + ly * F[2][1] + lz * F[2][2]) / am);
        double gu = (u + 1) * 0.5 * n, gv = (v + 1) * 0.5 * n;
        gu = gu < 0 ? 0 : (gu > n ? n : gu);
        gv = gv < 0 ? 0 : (gv > n ? n : gv);
        int i0 = (int)floor(gu), j0 = (int)floor(gv);
        if (i0 > n - 1) i0 = n - 1;
        if (j0 > n - 1) j0 = n - 1;
        double a = gu - i0, b = gv - j0;
        cells[p] = (int32_t)((((int64_t)k0 * 6 + face) * n + i0) * n + j0);
        int c = 0;
        const int n1 = n + 1, M = 6 * n * n + 2;
        for (int dk = 0; dk < 2; dk++) {
            double wk = dk ? ts : 1 - ts;
            for (int di = 0; di < 2; di++) {
                double wi = di ? a : 1 - a;
                for (int dj = 0; dj < 2; dj++) {
                    wp[c] = (float)(wk * wi * (dj ? b : 1 - b));
                    if (clearance && wp[c] > 0.0f) {
                        int32_t d = face_table[((int64_t)face * n1 + i0 + di) * n1 + j0 + dj];
                        int64_t id = (int64_t)(k0 + dk) * M + d;
                        double rk = radii[k0 + dk];
                        double ex = rk * dirs[3 * d] - lx, ey = rk * dirs[3 * d + 1] - ly, ez = rk * dirs[3 * d + 2] - lz;
                        double cl = 0.9 * clearance[id];
                        if (ex * ex + ey * ey + ez * ez >= cl * cl) test[p] |= (uint8_t)(1 << c);
                    }
                    c++;
                }
            }
        }
    }
}

/* ---------------------------------------------------------------------------------------
 * Nearest leaf of each direction (rotate.py nearest_leaves): the leaf stored for the
 * direction's cell of an equi-angular cube-map table (6 × R × R), then the nearest among that
 * leaf's k listed neighbours (neigh, (N, k), itself first).
 */
void glf_nearest_leaves(int64_t P, const double *dirs, const int32_t *table, int R, const int32_t *neigh, int k,
                        const float *leaves, int32_t *out) {
#pragma omp parallel for schedule(static) if (P > 4096)
    for (int64_t p = 0; p < P; p++) {
        double x = dirs[3 * p], y = dirs[3 * p + 1], z = dirs[3 * p + 2];
        double bx = fabs(x), by = fabs(y), bz = fabs(z);
        int major = (bx >= by && bx >= bz) ? 0 : (by >= bz ? 1 : 2);
        double comp = major == 0 ? x : (major == 1 ? y : z);
        int face = 2 * major + (comp < 0);
        const double (*F)[3] = FACE[face];
        double am = x * F[0][0] + y * F[0][1] + z * F[0][2];
        double u = (4.0 / PI) * atan((x * F[1][0] + y * F[1][1] + z * F[1][2]) / am);
        double v = (4.0 / PI) * atan((x * F[2][0] + y * F[2][1] + z * F[2][2]) / am);
        int i = (int)((u + 1) * 0.5 * R), j = (int)((v + 1) * 0.5 * R);
        i = i < 0 ? 0 : (i > R - 1 ? R - 1 : i);
        j = j < 0 ? 0 : (j > R - 1 ? R - 1 : j);
        const int32_t *cand = neigh + (int64_t)table[((int64_t)face * R + i) * R + j] * k;
        int32_t best = cand[0];
        double bd = -2.0;
        for (int c = 0; c < k; c++) {
            const float *l = leaves + 3 * (int64_t)cand[c];
            double d = (double)l[0] * x + (double)l[1] * y + (double)l[2] * z;
            if (d > bd) { bd = d; best = cand[c]; }
        }
        out[p] = best;
    }
}

/* ---------------------------------------------------------------------------------------
 * Rotation of binary sample cuts into the receiver's frame (rotate.py rotate_samples_numpy).
 * Receiver leaf j reads source leaf π(j), the source leaf nearest to its direction; the
 * inverse map (CSR inv_off/inv_idx: the receiver leaves j with π(j) = l) lets the kernel touch
 * only the blocked source leaves. The receiver's leaves go into a bitset (1 = free), and the
 * cut is rebuilt top-down: a node is emitted when it is uniform (all free or all blocked), or
 * at height hmin with its free fraction (coarser than the leaves: the interpolation of §V.A.4
 * blurs shadows over more than 2^hmin leaves anyway, and the cuts get 2-3× shorter).
 * The source cuts come packed as stored: 4-bit heights (two per byte, low nibble first) and
 * 1-bit values (np.packbits order). identity: π is the identity (no inverse map needed).
 * Output: only the nodes that are not wholly free (the rest of the cut is implied), as
 * (first leaf, height, value), sample i at pos[i] in (out_s, out_h, out_q), counts[i] nodes.
 */
/* popcount without -mpopcnt (the library is built for any x86-64 / ARM): __builtin_popcountll
 * would be a libgcc call per word */
static inline int pop64(uint64_t x) {
    x = x - ((x >> 1) & 0x5555555555555555ULL);
    x = (x & 0x3333333333333333ULL) + ((x >> 2) & 0x3333333333333333ULL);
    x = (x + (x >> 4)) & 0x0F0F0F0F0F0F0F0FULL;
    return (int)((x * 0x0101010101010101ULL) >> 56);
}

static inline int nib(const uint8_t *hp, int64_t k) { return (hp[k >> 1] >> ((k & 1) * 4)) & 15; }
static inline int bitv(const uint8_t *bits, int64_t k) { return (bits[k >> 3] >> (7 - (k & 7))) & 1; }

void glf_rotate(int64_t n, const int32_t *ids, const int64_t *f_off, const uint8_t *f_hp, const uint8_t *f_bits,
                int H, int hmin, int identity, const int32_t *inv_off, const int32_t *inv_idx,
                int64_t cap, int32_t *out_s, uint8_t *out_h, uint8_t *out_q, int64_t *pos, int32_t *counts,
                int64_t *used) {
    const int64_t N = (int64_t)1 << H, NW = N >> 6;
#pragma omp parallel if (n > 16)
    {
        uint64_t *W = (uint64_t *)malloc(sizeof(uint64_t) * NW);
        int32_t *Z = (int32_t *)malloc(sizeof(int32_t) * 2 * NW);  /* zero counts, levels ≥ 6 */
        int64_t lev[64];
        int64_t stack[2 * 64];
        int64_t o = 0;
        const int64_t maxn = N >> hmin;
        int32_t *os = (int32_t *)malloc(sizeof(int32_t) * maxn);
        uint8_t *oh = (uint8_t *)malloc(maxn), *oq = (uint8_t *)malloc(maxn);
        for (int h = 6; h <= H; h++) { lev[h] = o; o += N >> h; }
#pragma omp for schedule(dynamic, 16)
        for (int64_t i = 0; i < n; i++) {
            int64_t a = f_off[ids[i]], b = f_off[ids[i] + 1];
            for (int64_t k = 0; k < NW; k++) W[k] = ~(uint64_t)0;
            int64_t start = 0, blocked = 0, rs = -1;      /* rs: start of the current blocked run */
            for (int64_t k = a; k <= b; k++) {
                /* consecutive blocked nodes are cleared as one run [rs, start) */
                int blk = k < b && !bitv(f_bits, k);
                if (blk) { if (rs < 0) rs = start; }
                else if (rs >= 0) {
                    blocked += start - rs;
                    if (identity) {
                        for (int64_t l = rs; l < start;) {
                            if ((l & 63) == 0 && l + 64 <= start) { W[l >> 6] = 0; l += 64; }
                            else { W[l >> 6] &= ~((uint64_t)1 << (l & 63)); l++; }
                        }
                    } else {
                        for (int32_t q = inv_off[rs]; q < inv_off[start]; q++) {
                            int32_t j = inv_idx[q];
                            W[j >> 6] &= ~((uint64_t)1 << (j & 63));
                        }
                    }
                    rs = -1;
                }
                if (k < b) start += (int64_t)1 << nib(f_hp, k);
            }
            if (blocked == 0) { counts[i] = 0; pos[i] = 0; continue; }
            for (int64_t k = 0; k < NW; k++) Z[lev[6] + k] = 64 - pop64(W[k]);
            for (int h = 7; h <= H; h++)
                for (int64_t j = 0; j < (N >> h); j++) Z[lev[h] + j] = Z[lev[h - 1] + 2 * j] + Z[lev[h - 1] + 2 * j + 1];
            int32_t c = 0;
            int sp = 0;
            stack[sp++] = H; stack[sp++] = 0;
            while (sp) {
                int64_t j = stack[--sp];
                int h = (int)stack[--sp];
                int64_t len = (int64_t)1 << h, zeros;
                if (h >= 6) zeros = Z[lev[h] + j];
                else {
                    int64_t l0 = j << h;
                    uint64_t mask = (((uint64_t)1 << len) - 1) << (l0 & 63);
                    zeros = len - pop64(W[l0 >> 6] & mask);
                }
                if (zeros == 0) continue;                                   /* free: implied */
                else if (zeros == len) { os[c] = (int32_t)(j << h); oh[c] = (uint8_t)h; oq[c] = 0; c++; }
                else if (h <= hmin) {
                    os[c] = (int32_t)(j << h); oh[c] = (uint8_t)h;
                    oq[c] = (uint8_t)lrint(255.0 * (double)(len - zeros) / (double)len); c++;
                }
                else { stack[sp++] = h - 1; stack[sp++] = 2 * j + 1; stack[sp++] = h - 1; stack[sp++] = 2 * j; }
            }
            counts[i] = c;
            int64_t p = bump(used, c);
            if (p + c <= cap) {
                memcpy(out_s + p, os, sizeof(int32_t) * c); memcpy(out_h + p, oh, c); memcpy(out_q + p, oq, c);
                pos[i] = p;
            } else pos[i] = -1;
        }
        free(W); free(Z); free(os); free(oh); free(oq);
    }
}

/* ---------------------------------------------------------------------------------------
 * Cells (combine.py cells_numpy): the eight rotated sample cuts at a cell's corners merged
 * once, for every vertex in the cell. Each sample cut comes as its non-free nodes (glf_rotate);
 * a cell is the list of stretches [start, end) where any corner is inside a non-free node,
 * split where the eight corner values (uint8, 255 free) change. Adjacent nodes of equal value
 * (a blocked region is many aligned nodes) make one stretch: the product walks every stretch
 * bound of every occluder, and a bound splits the base node it falls in (a chair over the
 * floor and beside a table: ~600 stretches per vertex; 12% of the floor's were merged).
 * corners[8·i + c] is the pool slot of corner c of cell i.
 */
#define FAR ((int64_t)1 << 62)

void glf_cells(int64_t n, const int32_t *corners, const int64_t *p_off, const int32_t *p_cnt, const int32_t *p_s,
               const uint8_t *p_h, const uint8_t *p_q, int H, int64_t cap, int32_t *out_a, int32_t *out_b,
               uint8_t *out_v, int64_t *pos, int32_t *counts, int64_t *used) {
    const int64_t N = (int64_t)1 << H;
#pragma omp parallel if (n > 16)
    {
        const int32_t *os[8]; const uint8_t *oh[8], *oq[8];
        int64_t len[8], ptr[8], nxt[8];
        int in[8];
        uint8_t val[8];
        int64_t maxn = 16 * N / 8 + 16;
        int32_t *ta = (int32_t *)malloc(sizeof(int32_t) * maxn), *tb = (int32_t *)malloc(sizeof(int32_t) * maxn);
        uint8_t *tv = (uint8_t *)malloc(8 * maxn);
#pragma omp for schedule(dynamic, 16)
        for (int64_t i = 0; i < n; i++) {
            int64_t next = FAR;
            for (int c = 0; c < 8; c++) {
                int32_t sl = corners[8 * i + c];
                int64_t so = p_off[sl];
                os[c] = p_s + so; oh[c] = p_h + so; oq[c] = p_q + so; len[c] = p_cnt[sl];
                ptr[c] = 0; in[c] = 0; val[c] = 255; nxt[c] = len[c] ? os[c][0] : FAR;
                if (nxt[c] < next) next = nxt[c];
            }
            int64_t k = 0;
            while (next < FAR) {
                int64_t x = next;
                int busy = 0;
                next = FAR;
                for (int c = 0; c < 8; c++) {
                    while (nxt[c] <= x) {
                        int64_t p = ptr[c];
                        if (!in[c]) { in[c] = 1; val[c] = oq[c][p]; nxt[c] = os[c][p] + ((int64_t)1 << oh[c][p]); }
                        else { in[c] = 0; val[c] = 255; ptr[c] = ++p; nxt[c] = p < len[c] ? os[c][p] : FAR; }
                    }
                    busy |= in[c];
                    if (nxt[c] < next) next = nxt[c];
                }
                if (busy) {
                    if (k && tb[k - 1] == x && !memcmp(tv + 8 * (k - 1), val, 8)) {
                        tb[k - 1] = (int32_t)next;       /* the same eight values: one stretch */
                    } else {
                        ta[k] = (int32_t)x; tb[k] = (int32_t)next;
                        memcpy(tv + 8 * k, val, 8);
                        k++;
                    }
                }
            }
            counts[i] = (int32_t)k;
            int64_t p = bump(used, k);
            if (p + k <= cap) {
                memcpy(out_a + p, ta, sizeof(int32_t) * k); memcpy(out_b + p, tb, sizeof(int32_t) * k);
                memcpy(out_v + 8 * p, tv, 8 * k);
                pos[i] = p;
            } else pos[i] = -1;
        }
        free(ta); free(tb); free(tv);
    }
}

/* ---------------------------------------------------------------------------------------
 * The cut product (§V.A.3, cuts.combine) of each vertex's base cut with the trilinear
 * interpolation of the eight corner cuts of its cell, for each occluder (§V.A.4, eq. 4):
 *   v = v_base · Π_o F_o,   F_o = Σ_c w_oc v_oc / Σ_c w_oc  inside a busy stretch, else 1.
 * The base cut is copied node by node, scaled by the current F, and split only where a cell's
 * stretch starts or ends inside it (each piece a maximal aligned tree node): the counter walk of
 * §V.A.3 with the all-free parts of the field cuts skipped and the eight corners merged once
 * per cell. Base nodes of value 0 (below the horizon, self-occluded) are kept whole.
 * Occluder o of vertex v: cslot[v·n_occ + o] (−1: culled) indexes its cell pool (c_off, c_cnt,
 * c_a, c_b, c_v: arrays of n_occ pointers), weights wts[(v·n_occ + o)·8 + c].
 * Output: vertex v at pos[v] in (out_h, out_q), counts[v] nodes (see bump).
 * b_skip (delta only, may be NULL): the leaf where node g·SKIP of the base cuts' node array starts
 * within its cut, so runs untouched by any stretch are passed a block at a time.
 * delta = 1 writes what the occluders take away instead, v_base − v_base · Π_o F_o: a renderer
 * that knows the radiance of the base cut subtracts the radiance of this cut. Its non-zero nodes
 * are only those the occluders shade; every run of untouched base nodes becomes 0-valued
 * maximal aligned nodes (a few, where the base cut has hundreds), so the cut stays short.
 */
#define SKIP 32

/* [a, b) as maximal aligned 0-valued nodes appended at c; returns the new count. */
static int64_t zero_run(int64_t a, int64_t b, int H, uint8_t *dh, uint8_t *dq, int64_t c) {
    while (a < b) {
        int h = a ? __builtin_ctzll((uint64_t)a) : H;
        while (a + ((int64_t)1 << h) > b) h--;
        dh[c] = (uint8_t)h; dq[c] = 0; c++;
        a += (int64_t)1 << h;
    }
    return c;
}

void glf_combine(int64_t V, const int32_t *cut_of, const int64_t *b_off, const uint8_t *b_h, const uint8_t *b_q,
                 const int32_t *b_skip, int H, int n_occ, int delta, const int32_t *cslot, const float *wts, const int64_t *const *c_off,
                 const int32_t *const *c_cnt, const int32_t *const *c_a, const int32_t *const *c_b,
                 const uint8_t *const *c_v, int64_t cap, uint8_t *out_h, uint8_t *out_q, int64_t *pos, int32_t *counts,
                 int64_t *used) {
    const int64_t N = (int64_t)1 << H;
#pragma omp parallel if (V > 64)
    {
        const int32_t **ca = (const int32_t **)malloc(sizeof(void *) * (n_occ + 1));
        const int32_t **cb = (const int32_t **)malloc(sizeof(void *) * (n_occ + 1));
        const uint8_t **cv = (const uint8_t **)malloc(sizeof(void *) * (n_occ + 1));
        int64_t *len = (int64_t *)malloc(sizeof(int64_t) * (n_occ + 1));
        int64_t *ptr = (int64_t *)malloc(sizeof(int64_t) * (n_occ + 1));
        int64_t *nxt = (int64_t *)malloc(sizeof(int64_t) * (n_occ + 1));
        double *f = (double *)malloc(sizeof(double) * (n_occ + 1));
        double *w = (double *)malloc(sizeof(double) * 8 * (n_occ + 1));
        uint8_t *dh = (uint8_t *)malloc(N), *dq = (uint8_t *)malloc(N);
#pragma omp for schedule(dynamic, 32)
        for (int64_t v = 0; v < V; v++) {
            int m = 0;
            for (int o = 0; o < n_occ; o++) {
                int32_t sl = cslot[v * n_occ + o];
                if (sl < 0) continue;
                int64_t co = c_off[o][sl];
                ca[m] = c_a[o] + co; cb[m] = c_b[o] + co; cv[m] = c_v[o] + 8 * co; len[m] = c_cnt[o][sl];
                const float *ww = wts + ((int64_t)v * n_occ + o) * 8;
                double ws = 0.0;
                for (int c = 0; c < 8; c++) ws += ww[c];
                for (int c = 0; c < 8; c++) w[8 * m + c] = ww[c] / (255.0 * ws);
                ptr[m] = 0; f[m] = 1.0; nxt[m] = len[m] ? ca[m][0] : FAR;
                m++;
            }
            int64_t next = FAR;
            for (int j = 0; j < m; j++) if (nxt[j] < next) next = nxt[j];
            double F = 1.0;                   /* exactly 1 outside every busy stretch */
            int64_t bo = b_off[cut_of[v]], bn = b_off[cut_of[v] + 1] - bo;
            const uint8_t *bh = b_h + bo, *bq = b_q + bo;
            int64_t c = 0, x = 0, z = -1;     /* delta: start of the pending run of zeros (−1: none) */
            /* pass: every base node before the next event comes out whole, valued qb & keep:
             * F = 1, or (product) where the fields block everything (255 F < 0.5: every piece
             * rounds to 0, as the split below would give for a node before the event) */
            int pass = 1;
            uint8_t keep = 0xFF;
            if (m == 0 && !delta) {           /* no field reaches it: its own cut as is */
                memcpy(dh, bh, bn); memcpy(dq, bq, bn);
                c = bn; bn = 0;
            }
            for (int64_t k = 0; k < bn; k++) {
                if (b_skip && F == 1.0 && ((bo + k) & (SKIP - 1)) == 0) {
                    /* delta: whole blocks of SKIP base nodes before the next event add zeros only */
                    int64_t g = (bo + k) / SKIP + 1;
                    while (k + SKIP < bn && b_skip[g] <= next) {
                        if (z < 0) z = x;
                        x = b_skip[g]; k += SKIP; g++;
                    }
                }
                int h0 = bh[k];
                int64_t e = x + ((int64_t)1 << h0);
                int qb = bq[k];
                /* dark, or untouched: the base node as is (bitwise |, &: one well-predicted branch
                 * where dark and lit nodes alternate) */
                if ((qb == 0) | ((e <= next) & pass)) {
                    if (delta) { if (z < 0) z = x; }
                    else { dh[c] = (uint8_t)h0; dq[c] = (uint8_t)qb & keep; c++; }
                    x = e;
                    continue;
                }
                if (z >= 0) { c = zero_run(z, x, H, dh, dq, c); z = -1; }
                while (x < e) {
                    int64_t b = e < next ? e : next;
                    long q = lrint(qb * F);
                    q = q < 0 ? 0 : (q > 255 ? 255 : q);
                    uint8_t qq = (uint8_t)(delta ? qb - q : q);
                    while (x < b) {          /* [x, b) as maximal aligned nodes */
                        int h = x ? __builtin_ctzll((uint64_t)x) : H;
                        int hb = 63 - __builtin_clzll((uint64_t)(b - x));     /* largest 2^h ≤ b − x */
                        if (h > hb) h = hb;
                        if (h > h0) h = h0;
                        dh[c] = (uint8_t)h; dq[c] = qq; c++;
                        x += (int64_t)1 << h;
                    }
                    if (x < next) break;
                    /* x reached a stretch boundary of some occluder: update those at or past it */
                    next = FAR;
                    F = 1.0;
                    for (int j = 0; j < m; j++) {
                        while (nxt[j] <= x) {
                            int64_t p = ptr[j];
                            if (p < len[j] && ca[j][p] <= x && x < cb[j][p]) {   /* inside stretch p */
                                const uint8_t *vv = cv[j] + 8 * p;
                                const double *ww = w + 8 * j;
                                double s = 0.0;
                                for (int q8 = 0; q8 < 8; q8++) s += ww[q8] * vv[q8];
                                f[j] = s; nxt[j] = cb[j][p];
                            } else if (p < len[j] && x >= cb[j][p]) {           /* past it */
                                /* past several (x jumped over dark base nodes): the first stretch
                                 * ending after x, by bisection (stretches are sorted, disjoint) */
                                if (p + 1 < len[j] && cb[j][p + 1] <= x) {
                                    int64_t lo = p + 1, hi = len[j];
                                    while (lo < hi) { int64_t mid = (lo + hi) >> 1; if (cb[j][mid] <= x) lo = mid + 1; else hi = mid; }
                                    p = lo - 1;
                                }
                                ptr[j] = ++p; f[j] = 1.0; nxt[j] = p < len[j] ? ca[j][p] : FAR;
                            } else { f[j] = 1.0; nxt[j] = p < len[j] ? ca[j][p] : FAR; }  /* before it */
                        }
                        F *= f[j];
                        if (nxt[j] < next) next = nxt[j];
                    }
                    pass = F == 1.0 || (!delta && 255.0 * F < 0.5);
                    keep = F == 1.0 ? 0xFF : 0;
                }
            }
            if (z >= 0) c = zero_run(z, x, H, dh, dq, c);
            counts[v] = (int32_t)c;
            int64_t p = bump(used, c);
            if (p + c <= cap) { memcpy(out_h + p, dh, c); memcpy(out_q + p, dq, c); pos[v] = p; }
            else pos[v] = -1;
        }
        free(dh); free(dq); free(ca); free(cb); free(cv); free(len); free(ptr); free(nxt); free(f); free(w);
    }
}

/* Gather items placed at pos[i] (counts[i] elements of esize bytes) into item order at dst_off[i]. */
void glf_gather(int64_t n, const int64_t *pos, const int32_t *counts, const uint8_t *src, int64_t esize,
                const int64_t *dst_off, uint8_t *dst) {
#pragma omp parallel for schedule(static) if (n > 4096)
    for (int64_t i = 0; i < n; i++)
        if (counts[i]) memcpy(dst + esize * dst_off[i], src + esize * pos[i], (size_t)(esize * counts[i]));
}
