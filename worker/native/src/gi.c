/* GI renderer kernels (polynomial-gi, worker/renderers/gi). Each has a NumPy reference:
 *   gi_sample        <- trace.sample_numpy   (light and mixture directions, both pdfs at both)
 *   gi_emit          <- trace.emit_numpy     (a vertex's MIS-weighted light into the tile's
 *                                             per-pixel hash tables, and the continuing prefix)
 *   gi_occupancy,
 *   gi_compact       <- trace.compact        (zeros dropped, half floats, sorted by key)
 *   gi_freeze,
 *   gi_powslots      <- freeze.freeze_numpy  (object freezing, eq. 27)
 *   gi_frame,
 *   gi_frame_dense   <- freeze.frame_numpy   (the per-pixel dot product, eq. 28-29; AVX2/F16C
 *                                             when the CPU has them)
 *   gi_half          <- NumPy's float16 conversions (round to nearest even)
 * tests/gi/test_gi_native.py and test_gi_basis.py check that they agree. Arrays are
 * C-contiguous; loaded via ctypes (worker/renderers/gi/native.py sets the argtypes).
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define GI_X86 1
#endif
#include "glint_common.h"

#define MIX_DIFFUSE 0.7
#define GLOSS_E 200.0
#define ZMAX 3
#define ZEMPTY 32767
#define J2_NODES 4          /* basis.J2_NODES */

static inline v3 ld3(const double *p) { return mk(p[0], p[1], p[2]); }
static inline void st3(double *p, v3 a) { p[0] = a.x; p[1] = a.y; p[2] = a.z; }
static inline v3 sub(v3 a, v3 b) { return mk(a.x - b.x, a.y - b.y, a.z - b.z); }
static inline v3 cross(v3 a, v3 b) { return mk(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x); }
static inline v3 nrm30(v3 a) { double l = sqrt(dot(a, a)); if (l < 1e-30) l = 1e-30; return scl(a, 1.0 / l); }
static inline double clampd(double x, double a, double b) { return x < a ? a : (x > b ? b : x); }

/* --- sampling --------------------------------------------------------------------------------- */

/* first index i in [0, n) with a[i] > x, n if none (numpy searchsorted side="right") */
static inline int64_t upper(const double *a, int64_t n, double x) {
    int64_t lo = 0, hi = n;
    while (lo < hi) { int64_t m = (lo + hi) >> 1; if (a[m] > x) hi = m; else lo = m + 1; }
    return lo;
}

static inline double env_pdf(v3 d, const double *tp, int H, int W, double rot) {
    double y = clampd(d.y, -1.0, 1.0);
    double th = acos(y), st = sin(th);
    double uu = fmod(atan2(d.x, -d.z) / (2 * PI) + rot, 1.0);
    if (uu < 0) uu += 1.0;
    int64_t c = (int64_t)(uu * W), r = (int64_t)(th / PI * H);
    c = c < 0 ? 0 : (c > W - 1 ? W - 1 : c);
    r = r < 0 ? 0 : (r > H - 1 ? H - 1 : r);
    return st > 1e-9 ? tp[r * W + c] * W * H / (2 * PI * PI * (st > 1e-9 ? st : 1e-9)) : 0.0;
}

static inline double mix_pdf(v3 n, v3 wo, v3 d) {
    double cd = dot(n, d);
    v3 h = nrm30(add(d, wo));
    double ch = clampd(dot(n, h), 0.0, 1.0), oh = dot(wo, h);
    double q = 4.0 * oh; if (q < 1e-12) q = 1e-12;
    double pg = (GLOSS_E + 1.0) / (2 * PI) * pow(ch, GLOSS_E) / q;
    double p = MIX_DIFFUSE * (cd > 0 ? cd : 0.0) / PI + (1.0 - MIX_DIFFUSE) * (oh > 0 ? pg : 0.0);
    return cd > 0 ? p : 0.0;
}

void gi_sample(int64_t R, const double *pos, const double *ng, const double *ns, const double *wo,
               const double *u, int nu, const double *row_cdf, const double *col_cdf, const double *tp,
               int H, int W, double rot_rad, double *dl, double *db, double *pdf_ll, double *pdf_bl,
               double *pdf_bb, double *pdf_lb, uint8_t *valid_l, uint8_t *valid_b) {
    (void)pos; (void)ng;
    const double rot = rot_rad / (2 * PI);      /* in turns, as the map's u */
#pragma omp parallel for schedule(static)
    for (int64_t r = 0; r < R; r++) {
        const double *ur = u + r * nu;
        v3 n = ld3(ns + 3 * r), o = ld3(wo + 3 * r);
        /* environment by luminance */
        int64_t row = upper(row_cdf, H + 1, ur[0]) - 1;
        row = row < 0 ? 0 : (row > H - 1 ? H - 1 : row);
        int64_t col = upper(col_cdf + row * (W + 1), W + 1, ur[1]) - 1;
        col = col < 0 ? 0 : (col > W - 1 ? W - 1 : col);
        double uu = (col + ur[2]) / W, vv = (row + ur[3]) / H;
        double th = vv * PI, ph = 2 * PI * (uu - rot), st = sin(th);
        v3 l = mk(st * sin(ph), cos(th), -st * cos(ph));
        double pll = env_pdf(l, tp, H, W, rot);
        /* the BRDF-independent mixture */
        v3 t, b; onb(n, &t, &b);
        double phi = 2 * PI * ur[6];
        int diff = ur[4] < MIX_DIFFUSE;
        double z = diff ? sqrt(fmax(1.0 - ur[5], 0.0)) : pow(ur[5], 1.0 / (GLOSS_E + 1.0));
        double rr = sqrt(fmax(1.0 - z * z, 0.0));
        v3 loc = add(add(scl(t, rr * cos(phi)), scl(b, rr * sin(phi))), scl(n, z));
        v3 d = diff ? loc : sub(scl(loc, 2.0 * dot(o, loc)), o);
        d = nrm30(d);
        double pbb = mix_pdf(n, o, d);
        st3(dl + 3 * r, l); st3(db + 3 * r, d);
        pdf_ll[r] = pll; pdf_bb[r] = pbb;
        pdf_bl[r] = mix_pdf(n, o, l);
        pdf_lb[r] = env_pdf(d, tp, H, W, rot);
        valid_l[r] = dot(n, l) > 0 && pll > 0;
        valid_b[r] = dot(n, d) > 0 && pbb > 0;
    }
}

/* --- emission ----------------------------------------------------------------------------------- */

/* basis.quotient_s */
static inline double qs(double ci, double co, int kind) {
    ci = ci > 0 ? ci : 0; co = co > 0 ? co : 0;
    double x = kind == 1 ? 4.0 * ci * co : ci + co - ci * co;
    return 1.0 / (x > 1e-12 ? x : 1e-12);
}

static inline int half_band_c(double hz, int J) {
    int b = (int)(acos(clampd(hz, -1.0, 1.0)) * (2.0 * J / PI));
    return b < 0 ? 0 : (b > J - 1 ? J - 1 : b);
}

/* trace.first_weights */
static inline int first_w(v3 n, v3 o, v3 d, double nu, v3 axis, int J, int layers, int qk, double *w) {
    double ci = dot(n, d), co = dot(n, o);
    v3 h = nrm30(add(d, o));
    double ch = clampd(dot(n, h), 1e-12, 1.0), cd = clampd(dot(d, h), 0.0, 1.0);
    double m = 1.0 - cd, m5 = m * m * m * m * m;
    int band = half_band_c(ch, J);
    double qA = qs(ci, co, qk);
    if (nu > 0) {
        v3 t = sub(axis, scl(n, dot(axis, n)));
        double tl = sqrt(dot(t, t));
        if (tl > 1e-6) t = scl(t, 1.0 / (tl > 1e-30 ? tl : 1e-30));
        else { v3 t0, b0; onb(n, &t0, &b0); t = t0; }
        v3 b = cross(n, t);
        double hx = dot(h, t), hy = dot(h, b), s2 = hx * hx + hy * hy, lc = log(ch);
        double sin2 = s2 > 1e-24 ? hy * hy / (s2 > 1e-24 ? s2 : 1e-24) : 0.0;
        double g = exp(nu * sin2 * lc);
        int bb = (int)(g * J); band = bb < 0 ? 0 : (bb > J - 1 ? J - 1 : bb);
        double mx = ci > co ? ci : co;
        qA = exp(nu * (1.0 - sin2) * lc) / ((cd > 1e-12 ? cd : 1e-12) * (mx > 1e-12 ? mx : 1e-12));
    }
    if (ci > 0 && co > 0) {
        w[0] = ci / PI; w[1] = qA * ci; w[2] = layers == 2 ? qA * m5 * ci : 0.0;
    } else { w[0] = w[1] = w[2] = 0.0; }
    return band;
}

/* trace.second_weights: returns band·J2_NODES + k0; w = [cos/π, s·cos·(1 − t), s·cos·t] */
static inline int second_w(v3 n, v3 o, v3 d, int J2, int qk, double *w) {
    double ci = dot(n, d), co = dot(n, o);
    v3 h = nrm30(add(d, o));
    int band = half_band_c(dot(n, h), J2);
    /* basis.node_interp over J2_NODES view-angle nodes */
    double x = acos(clampd(co, 0.0, 1.0)) * (2.0 * J2_NODES / PI) - 0.5;
    x = clampd(x, 0.0, J2_NODES - 1.0);
    int k0 = (int)x; if (k0 > J2_NODES - 2) k0 = J2_NODES - 2;
    double t = x - k0;
    if (ci > 0 && co > 0) {
        double sc = qs(ci, co, qk) * ci;
        w[0] = ci / PI; w[1] = sc * (1.0 - t); w[2] = sc * t;
    } else { w[0] = w[1] = w[2] = 0.0; }
    return band * J2_NODES + k0;
}

static inline void z_insert(int32_t *z, int32_t *zc, int32_t unit) {
    int k = *zc < ZMAX - 1 ? *zc : ZMAX - 1;
    z[k] = unit;
    for (int i = 1; i < ZMAX; i++)       /* insertion sort of 3 */
        for (int j = i; j > 0 && z[j - 1] > z[j]; j--) { int32_t x = z[j]; z[j] = z[j - 1]; z[j - 1] = x; }
    *zc += 1;
}

static inline int64_t z_index(const int32_t *z, int32_t zc, const int64_t *C, int64_t Ccols, int64_t Crows,
                              const int64_t *off) {
    int64_t r = off[zc];
    for (int i = 0; i < zc && i < ZMAX; i++) {
        int64_t b = (int64_t)z[i] + i;
        if (b > Crows - 1) b = Crows - 1;
        r += C[b * Ccols + i + 1];
    }
    return r;
}

/* The entries of a pixel and bounce live in an open-addressing table (keys −1 when empty) of
 * capacity cap (a power of two at least twice the number of distinct keys the pixel can reach,
 * so it never fills). Returns the slot of key, claiming it if new. */
static inline int64_t h_slot(int32_t *keys, int64_t cap, int32_t key) {
    uint64_t h = ((uint64_t)(uint32_t)key * 2654435761u) & (uint64_t)(cap - 1);
    while (keys[h] != key) {
        if (keys[h] < 0) { keys[h] = key; break; }
        h = (h + 1) & (uint64_t)(cap - 1);
    }
    return (int64_t)h;
}

void gi_emit(int64_t P, const int64_t *starts, int k, int J, int J2, int layers, const int32_t *oq, int K1, int64_t Tk,
             int64_t W2, int64_t Zs,
             const int32_t *unit, const int32_t *obj, const double *ns, const double *wo, const double *beta,
             const int32_t *p1b, const double *p1w, const int32_t *p2c, const int32_t *p2b, const double *p2w,
             const int32_t *z, const int32_t *zc, const double *onu, const double *oaxis,
             const double *dl, const double *db, const double *Ll, const double *Lb, const double *wl,
             const double *wb, const double *pdf_bb, const double *fl, const double *fb,
             const int64_t *C, int64_t Crows, const int64_t *zoff, int32_t *hkeys, float *hvals, int64_t cap,
             double *o_beta, int32_t *o_p1b, double *o_p1w, int32_t *o_p2c, int32_t *o_p2b, double *o_p2w,
             int32_t *o_z, int32_t *o_zc) {
    const int first = k == 1, second = (J2 > 1) && k == 2;
    const int diffuse_vertex = (k >= 2 && J2 <= 1) || k >= 3;
    const int64_t Ccols = ZMAX + 1;
    (void)K1;
#pragma omp parallel for schedule(dynamic, 4)
    for (int64_t p = 0; p < P; p++) {
        int32_t *hk = hkeys + p * cap;
        float *hv = hvals + p * cap * 3;
        for (int64_t r = starts[p]; r < starts[p + 1]; r++) {
            v3 n = ld3(ns + 3 * r), o = ld3(wo + 3 * r);
            int fixed = unit[r] < 0;
            double nu = onu[obj[r]];
            int qk = oq[obj[r]];
            v3 axis = ld3(oaxis + 3 * obj[r]);
            for (int e = 0; e < 2; e++) {
                const double *dd = e == 0 ? dl + 3 * r : db + 3 * r;
                const double *L = e == 0 ? Ll + 3 * r : Lb + 3 * r;
                const double *f = e == 0 ? fl + 3 * r : fb + 3 * r;
                double wg = e == 0 ? wl[r] : wb[r];
                if (wg == 0.0 || (L[0] == 0.0 && L[1] == 0.0 && L[2] == 0.0)) continue;
                v3 d = ld3(dd);
                double ci = dot(n, d); if (ci < 0) ci = 0;
                double val[3];
                for (int c = 0; c < 3; c++) val[c] = L[c] * (wg * beta[3 * r + c]);
                int b1; double w1[3];
                if (first) {
                    if (fixed) { b1 = -1; w1[0] = 1; w1[1] = w1[2] = 0; for (int c = 0; c < 3; c++) val[c] *= f[c] * ci; }
                    else b1 = first_w(n, o, d, nu, axis, J, layers, qk, w1);
                } else { b1 = p1b[r]; w1[0] = p1w[3 * r]; w1[1] = p1w[3 * r + 1]; w1[2] = p1w[3 * r + 2]; }
                int64_t sl[3] = {0, 1 + b1, 1 + J + b1};
                double sw[3] = {w1[0], b1 >= 0 ? w1[1] : 0.0, b1 >= 0 ? w1[2] : 0.0};
                int nsl = layers == 2 ? 3 : 2;
                int64_t tl[3] = {0, 0, 0}; double tw[3] = {1.0, 0.0, 0.0}; int ntl = 1;
                if (!first) {
                    int32_t zz[ZMAX] = {z[3 * r], z[3 * r + 1], z[3 * r + 2]}, zcc = zc[r];
                    if (diffuse_vertex) {
                        if (fixed) for (int c = 0; c < 3; c++) val[c] *= f[c] * ci;
                        else { for (int c = 0; c < 3; c++) val[c] *= ci / PI; z_insert(zz, &zcc, unit[r]); }
                    }
                    int64_t zi = z_index(zz, zcc, C, Ccols, Crows, zoff);
                    if (J2 > 1) {
                        int64_t code; int b2; double w2[3];
                        if (second) {
                            if (fixed) { code = W2 - 1; b2 = -1; w2[0] = 1; w2[1] = w2[2] = 0; for (int c = 0; c < 3; c++) val[c] *= f[c] * ci; }
                            else { b2 = second_w(n, o, d, J2, qk, w2); code = (int64_t)unit[r] * (1 + J2 * J2_NODES); }
                        } else { code = p2c[r]; b2 = p2b[r]; w2[0] = p2w[3 * r]; w2[1] = p2w[3 * r + 1]; w2[2] = p2w[3 * r + 2]; }
                        tl[0] = code * Zs + zi; tw[0] = w2[0];
                        tl[1] = (b2 >= 0 ? code + 1 + b2 : 0) * Zs + zi; tw[1] = b2 >= 0 ? w2[1] : 0.0;
                        tl[2] = (b2 >= 0 ? code + 2 + b2 : 0) * Zs + zi; tw[2] = b2 >= 0 ? w2[2] : 0.0;
                        ntl = 3;
                    } else { tl[0] = zi; tw[0] = 1.0; }
                }
                for (int a = 0; a < nsl; a++)
                    for (int q = 0; q < ntl; q++) {
                        double ww = sw[a] * tw[q];
                        if (ww == 0.0) continue;
                        float *cell = hv + 3 * h_slot(hk, cap, (int32_t)(sl[a] * Tk + tl[q]));
                        for (int c = 0; c < 3; c++) cell[c] += (float)(val[c] * ww);
                    }
            }
            /* prefix of the path continuing along db */
            v3 d = ld3(db + 3 * r);
            double pb = pdf_bb[r]; double inv = 1.0 / (pb > 1e-300 ? pb : 1e-300);
            double ci = dot(n, d); if (ci < 0) ci = 0;
            for (int c = 0; c < 3; c++) o_beta[3 * r + c] = beta[3 * r + c];
            o_p1b[r] = p1b[r]; for (int c = 0; c < 3; c++) o_p1w[3 * r + c] = p1w[3 * r + c];
            o_p2c[r] = p2c[r]; o_p2b[r] = p2b[r];
            for (int c = 0; c < 3; c++) o_p2w[3 * r + c] = p2w[3 * r + c];
            for (int c = 0; c < ZMAX; c++) o_z[3 * r + c] = z[3 * r + c];
            o_zc[r] = zc[r];
            if (first) {
                if (fixed) {
                    o_p1b[r] = -1; o_p1w[3 * r] = 1; o_p1w[3 * r + 1] = o_p1w[3 * r + 2] = 0;
                    for (int c = 0; c < 3; c++) o_beta[3 * r + c] *= fb[3 * r + c] * ci * inv;
                } else {
                    double w1[3];
                    o_p1b[r] = first_w(n, o, d, nu, axis, J, layers, qk, w1);
                    for (int c = 0; c < 3; c++) o_p1w[3 * r + c] = w1[c] * inv;
                }
            } else if (second) {
                if (fixed) {
                    o_p2c[r] = (int32_t)(W2 - 1); o_p2b[r] = -1; o_p2w[3 * r] = 1; o_p2w[3 * r + 1] = o_p2w[3 * r + 2] = 0;
                    for (int c = 0; c < 3; c++) o_beta[3 * r + c] *= fb[3 * r + c] * ci * inv;
                } else {
                    double w2[3];
                    o_p2b[r] = second_w(n, o, d, J2, qk, w2);
                    o_p2c[r] = unit[r] * (1 + J2 * J2_NODES);
                    for (int c = 0; c < 3; c++) o_p2w[3 * r + c] = w2[c] * inv;
                }
            } else {
                if (fixed) for (int c = 0; c < 3; c++) o_beta[3 * r + c] *= fb[3 * r + c] * ci * inv;
                else {
                    for (int c = 0; c < 3; c++) o_beta[3 * r + c] *= ci / PI * inv;
                    z_insert(o_z + 3 * r, o_zc + r, unit[r]);
                }
            }
        }
    }
}

/* --- compaction of the hash tables --------------------------------------------------------------- */

static int cmp_pair(const void *a, const void *b) {
    int32_t x = ((const int32_t *)a)[0], y = ((const int32_t *)b)[0];
    return (x > y) - (x < y);
}

void gi_occupancy(int64_t P, int64_t cap, const int32_t *keys, int32_t *occ) {
#pragma omp parallel for schedule(static)
    for (int64_t p = 0; p < P; p++) {
        int32_t n = 0;
        for (int64_t h = 0; h < cap; h++) n += keys[p * cap + h] >= 0;
        occ[p] = n;
    }
}

static inline uint16_t f2h(float f);

/* trace.compact on the tables: values × inv_spp (float), a scale per pixel (largest entry stored
 * as 16384), half floats, zeros dropped, sorted by key = slot·Tk + tail. Output at ub[p] (the
 * pixel's occupancy prefix), cnt[p] entries written. */
void gi_compact(int64_t P, int64_t cap, const int32_t *keys, const float *vals, float inv_spp, int64_t Tk,
                const int64_t *ub, int32_t *cnt, uint16_t *slot, uint32_t *tail, uint16_t *val, float *scale) {
#pragma omp parallel
    {
        int32_t *pairs = (int32_t *)malloc(sizeof(int32_t) * 2 * (size_t)cap);
#pragma omp for schedule(dynamic, 16)
        for (int64_t p = 0; p < P; p++) {
            const int32_t *k = keys + p * cap;
            const float *v = vals + p * cap * 3;
            int64_t n = 0;
            float amax = 0.0f;
            for (int64_t h = 0; h < cap; h++)
                if (k[h] >= 0) {
                    pairs[2 * n] = k[h]; pairs[2 * n + 1] = (int32_t)h; n++;
                    for (int c = 0; c < 3; c++) { float a = fabsf(v[3 * h + c] * inv_spp); if (a > amax) amax = a; }
                }
            qsort(pairs, (size_t)n, 2 * sizeof(int32_t), cmp_pair);
            float sc = amax > 0 ? amax / 16384.0f : 1.0f;
            scale[p] = sc;
            int64_t w = ub[p];
            int32_t m = 0;
            for (int64_t j = 0; j < n; j++) {
                const float *x = v + 3 * (int64_t)pairs[2 * j + 1];
                uint16_t hh[3];
                for (int c = 0; c < 3; c++) hh[c] = f2h((x[c] * inv_spp) / sc);
                if (!((hh[0] & 0x7fff) | (hh[1] & 0x7fff) | (hh[2] & 0x7fff))) continue;
                slot[w + m] = (uint16_t)(pairs[2 * j] / Tk);
                tail[w + m] = (uint32_t)(pairs[2 * j] % Tk);
                val[3 * (w + m)] = hh[0]; val[3 * (w + m) + 1] = hh[1]; val[3 * (w + m) + 2] = hh[2];
                m++;
            }
            cnt[p] = m;
        }
        free(pairs);
    }
}

/* --- half floats (IEEE binary16, round to nearest even), as NumPy's float16 ------------------- */

static inline float h2f(uint16_t h) {
    uint32_t s = (uint32_t)(h & 0x8000) << 16, e = (h >> 10) & 0x1f, m = h & 0x3ff, bits;
    if (e == 0) {
        if (m == 0) bits = s;
        else { /* subnormal */
            e = 127 - 15 + 1;
            while (!(m & 0x400)) { m <<= 1; e--; }
            m &= 0x3ff;
            bits = s | (e << 23) | (m << 13);
        }
    } else if (e == 31) bits = s | 0x7f800000 | (m << 13);
    else bits = s | ((e + 127 - 15) << 23) | (m << 13);
    float f; memcpy(&f, &bits, 4); return f;
}

static inline uint16_t f2h(float f) {
    uint32_t x; memcpy(&x, &f, 4);
    uint32_t s = (x >> 16) & 0x8000;
    int32_t e = (int32_t)((x >> 23) & 0xff) - 127 + 15;
    uint32_t m = x & 0x7fffff;
    if (((x >> 23) & 0xff) == 0xff) return (uint16_t)(s | 0x7c00 | (m ? 0x200 : 0));
    if (e >= 31) return (uint16_t)(s | 0x7c00);
    if (e <= 0) {
        if (e < -10) return (uint16_t)s;
        m |= 0x800000;
        int shift = 14 - e;
        uint32_t hm = m >> shift, rem = m & ((1u << shift) - 1), half = 1u << (shift - 1);
        if (rem > half || (rem == half && (hm & 1))) hm++;
        return (uint16_t)(s | hm);
    }
    uint32_t hm = m >> 13, rem = m & 0x1fff;
    uint32_t out = s | ((uint32_t)e << 10) | hm;
    if (rem > 0x1000 || (rem == 0x1000 && (hm & 1))) out++;
    return (uint16_t)out;
}

void gi_half(int64_t n, const float *in, uint16_t *out, int to_half, float *back) {
    for (int64_t i = 0; i < n; i++) { if (to_half) out[i] = f2h(in[i]); else back[i] = h2f(out[i]); }
}

/* --- freezing (eq. 27) ------------------------------------------------------------------------------ */

/* half -> float by table: the freeze converts every stored value (tens of millions of entries at
 * 640×480), where the branchy h2f above costs more than the rest of the entry's work */
static float H2F[65536];
__attribute__((constructor)) static void gi_h2f_table(void) {
    for (uint32_t h = 0; h < 65536; h++) H2F[h] = h2f((uint16_t)h);
}

/* float -> half, n values: F16C eight at a time when the CPU has it (round to nearest even, as f2h) */
#ifdef GI_X86
__attribute__((target("f16c,avx"))) static void to_half_f16c(const float *in, uint16_t *out, int n) {
    int i = 0;
    for (; i + 8 <= n; i += 8)
        _mm_storeu_si128((__m128i *)(out + i), _mm256_cvtps_ph(_mm256_loadu_ps(in + i), _MM_FROUND_TO_NEAREST_INT));
    for (; i < n; i++) out[i] = f2h(in[i]);
}
#endif
static void to_half(const float *in, uint16_t *out, int n) {
#ifdef GI_X86
    static int f16c = -1;
    if (f16c < 0) f16c = __builtin_cpu_supports("f16c") && __builtin_cpu_supports("avx");
    if (f16c) { to_half_f16c(in, out, n); return; }
#endif
    for (int i = 0; i < n; i++) out[i] = f2h(in[i]);
}

static int cmp_i32(const void *a, const void *b) { int32_t x = *(const int32_t *)a, y = *(const int32_t *)b; return (x > y) - (x < y); }

/* bounce arrays come as tables of addresses (uint64) per bounce:
 * off[nb] -> int64 (P+1), slot -> uint16, tail -> uint32, val -> uint16 (n,3) half, scale -> float (P),
 * kk -> int32 (T), pw -> int32 (T), A -> float (T,3).
 * Sparse live output (dense = 0) uses upper-bound positions ub (Q+1) (caller: Σ entries of the
 * pixel, capped at K1·K2·NP); writes cnt (Q) entries (m,4) uint16 [key, r, g, b] and scale (Q).
 * Dense live output (dense = 1, K2 = 1): Fd (Q, Wd) half floats, for each power n < NB a block of
 * 3·bw[n] columns at boff[n], [channel][slot − blo[n]] (freeze.Frozen); every live entry of power n
 * has its slot in [blo[n], blo[n] + bw[n]) (gi_powslots).
 * sel (may be NULL): the P pixels to freeze are sel[0 … P−1] (indices into the per-pixel arrays
 * and V), every live pixel among them; V's other rows are left as they are (the caller's, from a
 * freeze whose units were the same there). */
void gi_freeze(int64_t P, int nb, const uint64_t *a_off, const uint64_t *a_slot, const uint64_t *a_tail,
               const uint64_t *a_val, const uint64_t *a_scale, const uint64_t *a_kk, const uint64_t *a_pw,
               const uint64_t *a_A, int L, const int32_t *units, const float *weights, const int32_t *k0,
               const float *tt, const float *C1, int KT, int K1, int K2, int NP, int iu,
               const int64_t *qpos, const int64_t *ub, float *V, uint16_t *F, int32_t *cnt, float *fscale,
               int dense, int NB, const int32_t *blo, const int32_t *bw, const int32_t *boff, int Wd, uint16_t *Fd,
               const int64_t *sel) {
    const int64_t ncell = (int64_t)K1 * K2 * NP;
#pragma omp parallel
    {
        double *cf = (double *)malloc(sizeof(double) * K1 * 3);
        double *sc = (double *)calloc((size_t)ncell * 3, sizeof(double));
        uint8_t *seen = (uint8_t *)calloc((size_t)ncell, 1);
        int32_t *touched = (int32_t *)malloc(sizeof(int32_t) * (size_t)ncell);
        double *Vl = (double *)malloc(sizeof(double) * K2 * NP * 3);
        double *Vb = (double *)malloc(sizeof(double) * 2 * NP * 3);
        float *fbuf = (float *)malloc(sizeof(float) * (Wd > 0 ? Wd : 1));
#pragma omp for schedule(dynamic, 64)
        for (int64_t jp = 0; jp < P; jp++) {
            const int64_t p = sel ? sel[jp] : jp;
            /* frozen first-vertex coefficients of the other units, and this unit's weight */
            memset(cf, 0, sizeof(double) * K1 * 3);
            int live = qpos[p] >= 0;
            for (int l = 0; l < L; l++) {
                int32_t u = units[p * L + l];
                if (u < 0 || u == iu) continue;
                double wgt = weights[p * L + l], t = tt[p];
                const float *c0 = C1 + ((int64_t)u * KT + k0[p]) * K1 * 3, *c1 = c0 + K1 * 3;
                for (int s = 0; s < K1 * 3; s++) cf[s] += wgt * ((double)c0[s] * (1.0 - t) + (double)c1[s] * t);
            }
            memset(Vl, 0, sizeof(double) * K2 * NP * 3);
            int nt = 0;
            /* the dense layout needs no record of the cells touched: its blocks are scanned */
            int track = live && !dense;
            for (int b = 0; b < nb; b++) {
                const int64_t *off = (const int64_t *)(uintptr_t)a_off[b];
                const uint16_t *slot = (const uint16_t *)(uintptr_t)a_slot[b];
                const uint32_t *tail = (const uint32_t *)(uintptr_t)a_tail[b];
                const uint16_t *val = (const uint16_t *)(uintptr_t)a_val[b];
                const float *scale = (const float *)(uintptr_t)a_scale[b];
                const int32_t *kk = (const int32_t *)(uintptr_t)a_kk[b];
                const int32_t *pw = (const int32_t *)(uintptr_t)a_pw[b];
                const float *A = (const float *)(uintptr_t)a_A[b];
                double s0 = scale[p];
                if (!live && K2 == 1) {
                    /* most pixels are not live and (J, 1, …) series have one second-vertex
                     * factor: V alone, the pixel's scale applied once per bounce. Consecutive
                     * entries mostly add to the same power: two accumulators (even and odd
                     * entries) halve the chain of dependent additions through memory */
                    for (int x = 0; x < 2 * NP * 3; x++) Vb[x] = 0.0;
                    for (int64_t e = off[p]; e < off[p + 1]; e++) {
                        uint32_t t = tail[e];
                        const double *cs = cf + 3 * slot[e];
                        const float *At = A + 3 * t;
                        const uint16_t *h = val + 3 * e;
                        double *vv = Vb + ((e & 1) * NP + pw[t]) * 3;
                        vv[0] += cs[0] * ((double)H2F[h[0]] * (double)At[0]);
                        vv[1] += cs[1] * ((double)H2F[h[1]] * (double)At[1]);
                        vv[2] += cs[2] * ((double)H2F[h[2]] * (double)At[2]);
                    }
                    for (int x = 0; x < NP * 3; x++) Vl[x] += s0 * (Vb[x] + Vb[NP * 3 + x]);
                    continue;
                }
                if (dense) {
                    /* a live pixel of the dense layout: only the cells; V is taken from them
                     * while the blocks are written (every live entry's cell is in a block) */
                    for (int64_t e = off[p]; e < off[p + 1]; e++) {
                        uint32_t t = tail[e];
                        const float *At = A + 3 * t;
                        const uint16_t *h = val + 3 * e;
                        double *x = sc + ((int64_t)slot[e] * NP + pw[t]) * 3;
                        x[0] += (double)H2F[h[0]] * s0 * (double)At[0];
                        x[1] += (double)H2F[h[1]] * s0 * (double)At[1];
                        x[2] += (double)H2F[h[2]] * s0 * (double)At[2];
                    }
                    continue;
                }
                for (int64_t e = off[p]; e < off[p + 1]; e++) {
                    uint32_t t = tail[e];
                    int s = slot[e], kq = kk[t], n = pw[t];
                    double v[3];
                    for (int c = 0; c < 3; c++) v[c] = (double)H2F[val[3 * e + c]] * s0 * (double)A[3 * t + c];
                    double *vv = Vl + ((int64_t)kq * NP + n) * 3;
                    for (int c = 0; c < 3; c++) vv[c] += cf[s * 3 + c] * v[c];
                    if (live) {
                        int32_t cell = (int32_t)(((int64_t)s * K2 + kq) * NP + n);
                        if (track && !seen[cell]) { seen[cell] = 1; touched[nt++] = cell; }
                        for (int c = 0; c < 3; c++) sc[(int64_t)cell * 3 + c] += v[c];
                    }
                }
            }
            for (int x = 0; x < K2 * NP * 3; x++) V[p * K2 * NP * 3 + x] = (float)Vl[x];
            if (!live) continue;
            int64_t q = qpos[p];
            if (dense) {   /* K2 = 1: cell = s·NP + n */
                double amax = 0;
                for (int n = 0; n < NB; n++)
                    for (int j = 0; j < bw[n] && blo[n] + j < K1; j++)
                        for (int c = 0; c < 3; c++) {
                            double a = fabs(sc[((int64_t)(blo[n] + j) * NP + n) * 3 + c]);
                            if (a > amax) amax = a;
                        }
                float fs = amax > 0 ? (float)(amax / 16384.0) : 1.0f;
                fscale[q] = fs;
                /* gather the blocks' cells as floats, then convert them in one pass (F16C when
                 * the CPU has it: the same round-to-nearest-even as f2h) */
                double inv = 1.0 / (double)fs;
                int x = 0;
                for (int n = 0; n < NB; n++)
                    for (int c = 0; c < 3; c++) {
                        double vsum = 0.0;
                        for (int j = 0; j < bw[n]; j++, x++) {
                            int s = blo[n] + j;
                            if (s >= K1) { fbuf[x] = 0.0f; continue; }   /* padding */
                            double *y = sc + ((int64_t)s * NP + n) * 3 + c;
                            vsum += cf[s * 3 + c] * *y;
                            fbuf[x] = (float)(*y * inv);
                            *y = 0.0;
                        }
                        V[(p * NP + n) * 3 + c] = (float)vsum;     /* K2 = 1; Vl is 0 here */
                    }
                to_half(fbuf, Fd + q * (int64_t)Wd, Wd);
                continue;
            }
            /* sorted cells: a scan of the seen flags when many are touched, else a sort */
            if ((int64_t)nt * 16 > ncell) {
                int m = 0;
                for (int64_t x = 0; x < ncell; x++) if (seen[x]) touched[m++] = (int32_t)x;
            } else {
                qsort(touched, nt, sizeof(int32_t), cmp_i32);
            }
            double amax = 0;
            for (int j = 0; j < nt; j++)
                for (int c = 0; c < 3; c++) { double a = fabs(sc[(int64_t)touched[j] * 3 + c]); if (a > amax) amax = a; }
            float fs = amax > 0 ? (float)(amax / 16384.0) : 1.0f;
            fscale[q] = fs;
            int64_t w = ub[q];
            int m = 0;
            for (int j = 0; j < nt; j++) {
                int32_t cell = touched[j];
                uint16_t h[3];
                for (int c = 0; c < 3; c++) h[c] = f2h((float)(sc[(int64_t)cell * 3 + c] / (double)fs));
                if ((h[0] & 0x7fff) | (h[1] & 0x7fff) | (h[2] & 0x7fff)) {   /* ±0 dropped, as NumPy's != 0 */
                    uint16_t *o = F + (w + m) * 4;
                    o[0] = (uint16_t)cell; o[1] = h[0]; o[2] = h[1]; o[3] = h[2];
                    m++;
                }
                for (int c = 0; c < 3; c++) sc[(int64_t)cell * 3 + c] = 0.0;
                seen[cell] = 0;
            }
            cnt[q] = m;
        }
        free(cf); free(sc); free(seen); free(touched); free(Vl); free(Vb); free(fbuf);
    }
}

/* per power n < NP of the edited unit's d, the smallest and largest slot of the entries of the live
 * pixels (qpos ≥ 0): lo[n], hi[n] (lo = K1, hi = −1 where no entry has that power); returns the
 * largest power present (0 if none). The dense live layout keeps only these slot ranges: with
 * denoised tensors the powers ≥ 1 reach only the indirect bounces' hat components. */
int gi_powslots(int64_t P, int nb, const uint64_t *a_off, const uint64_t *a_slot, const uint64_t *a_tail,
                const uint64_t *a_pw, const int64_t *qpos, int NP, int K1, int32_t *lo, int32_t *hi) {
    for (int n = 0; n < NP; n++) { lo[n] = K1; hi[n] = -1; }
#pragma omp parallel
    {
        int32_t *l = (int32_t *)malloc(sizeof(int32_t) * NP), *h = (int32_t *)malloc(sizeof(int32_t) * NP);
        for (int n = 0; n < NP; n++) { l[n] = K1; h[n] = -1; }
#pragma omp for schedule(dynamic, 256)
        for (int64_t p = 0; p < P; p++) {
            if (qpos[p] < 0) continue;
            for (int b = 0; b < nb; b++) {
                const int64_t *off = (const int64_t *)(uintptr_t)a_off[b];
                const uint16_t *slot = (const uint16_t *)(uintptr_t)a_slot[b];
                const uint32_t *tail = (const uint32_t *)(uintptr_t)a_tail[b];
                const int32_t *pw = (const int32_t *)(uintptr_t)a_pw[b];
                for (int64_t e = off[p]; e < off[p + 1]; e++) {
                    int n = pw[tail[e]], s = slot[e];
                    if (s < l[n]) l[n] = s;
                    if (s > h[n]) h[n] = s;
                }
            }
        }
#pragma omp critical
        for (int n = 0; n < NP; n++) { if (l[n] < lo[n]) lo[n] = l[n]; if (h[n] > hi[n]) hi[n] = h[n]; }
        free(l); free(h);
    }
    int best = 0;
    for (int n = 0; n < NP; n++) if (hi[n] >= 0) best = n;
    return best;
}

/* --- the frame (eq. 28-29) -------------------------------------------------------------------------- */

/* B[p] = Σ_{k,n} ckn[k,n]·V[p,k,n] (+ h·Σ_e (lerp of Tab over the view-angle nodes)[key_e]·val_e·scale
 * for live pixels), Tab (KT, K1·K2·NP, 3) = C1_i[node, slot]·ckn[k, n] built by the caller.
 * Live entries are 8 bytes [key, r, g, b] (uint16, half floats): one F16C conversion each. */
#define GI_FRAME_LOOP(LOAD_H3)                                                                        \
    _Pragma("omp parallel for schedule(dynamic, 256)")                                               \
    for (int64_t p = 0; p < P; p++) {                                                                 \
        float b[3] = {0, 0, 0};                                                                       \
        const float *v = V + p * K2NP * 3;                                                            \
        for (int x = 0; x < K2NP; x++)                                                                \
            for (int c = 0; c < 3; c++) b[c] += ckn[3 * x + c] * v[3 * x + c];                        \
        int64_t q = qpos[p];                                                                          \
        if (q >= 0) {                                                                                 \
            const float *T0 = Tab + (int64_t)k0[p] * nkeys * 3, *T1 = T0 + nkeys * 3;                 \
            float t = tt[p], a0 = 1.0f - t, acc[3] = {0, 0, 0};                                       \
            for (int64_t e = offs[q]; e < offs[q + 1]; e++) {                                         \
                const uint16_t *en = F + 4 * e;                                                       \
                int key = en[0];                                                                      \
                float hv[3];                                                                          \
                LOAD_H3(en, hv);                                                                      \
                for (int c = 0; c < 3; c++) acc[c] += (a0 * T0[key * 3 + c] + t * T1[key * 3 + c]) * hv[c]; \
            }                                                                                         \
            float s = hq[q] * fscale[q];                                                              \
            for (int c = 0; c < 3; c++) b[c] += s * acc[c];                                           \
        }                                                                                             \
        for (int c = 0; c < 3; c++) out[3 * pix[p] + c] = b[c];                                       \
    }

#define LOAD_SOFT(en, hv) do { hv[0] = h2f(en[1]); hv[1] = h2f(en[2]); hv[2] = h2f(en[3]); } while (0)

#define GI_FRAME_ARGS int64_t P, int K2NP, const float *V, const float *ckn, const int64_t *qpos,           \
    const int64_t *offs, const uint16_t *F, const float *fscale, const float *hq, const int32_t *k0,          \
    const float *tt, const float *Tab, int64_t nkeys, const int64_t *pix, float *out

static void frame_soft(GI_FRAME_ARGS) { GI_FRAME_LOOP(LOAD_SOFT) }

#ifdef GI_X86
#define LOAD_F16C(en, hv) do {                                                                        \
        float tmp_[4];                                                                                \
        _mm_storeu_ps(tmp_, _mm_cvtph_ps(_mm_loadl_epi64((const __m128i *)(en))));                   \
        hv[0] = tmp_[1]; hv[1] = tmp_[2]; hv[2] = tmp_[3];                                            \
    } while (0)
__attribute__((target("f16c,avx2,fma"))) static void frame_f16c(GI_FRAME_ARGS) { GI_FRAME_LOOP(LOAD_F16C) }
#endif

void gi_frame(GI_FRAME_ARGS) {
#ifdef GI_X86
    if (__builtin_cpu_supports("f16c") && __builtin_cpu_supports("avx2")) {
        frame_f16c(P, K2NP, V, ckn, qpos, offs, F, fscale, hq, k0, tt, Tab, nkeys, pix, out);
        return;
    }
#endif
    frame_soft(P, K2NP, V, ckn, qpos, offs, F, fscale, hq, k0, tt, Tab, nkeys, pix, out);
}

/* Dense live pixels ((J, 1, …) series): B[p] = Σ_n ckn[n]·V[p, n] for every pixel, plus for live
 * pixels h·scale·Σ_n dpow[n]·Σ_s cv[s]·F[q, n, c, s] with cv the edited unit's coefficients at the
 * pixel's view angle, lerped between two rows of CT (KT, Wd), which holds them in Fd's column
 * layout (power n's block of 3·bw[n] columns at boff[n], [channel][slot − lo[n]], zero padded;
 * freeze.Frozen). The two nodes' dot products are accumulated separately and lerped at the end,
 * so the coefficients are not rewritten per pixel. The radiance is written into the image at pix[p]. */
#define GI_DENSE_ARGS int64_t P, int NP, const float *V, const float *ckn, const int64_t *qpos, int NB,        \
    const int32_t *bw, const int32_t *boff, int Wd, const uint16_t *Fd, const float *fscale, const float *hq,    \
    const int32_t *k0, const float *tt, const float *CT, const float *dpow, const int64_t *pix, float *img

static void dense_soft(GI_DENSE_ARGS) {
#pragma omp parallel for schedule(dynamic, 256)
    for (int64_t p = 0; p < P; p++) {
        float b[3] = {0, 0, 0};
        const float *v = V + p * NP * 3;
        for (int x = 0; x < NP; x++)
            for (int c = 0; c < 3; c++) b[c] += ckn[3 * x + c] * v[3 * x + c];
        int64_t q = qpos[p];
        if (q >= 0) {
            const float *c0 = CT + (int64_t)k0[p] * Wd, *c1 = c0 + Wd;
            float t = tt[p], a0 = 1.0f - t;
            const uint16_t *f = Fd + q * (int64_t)Wd;
            float sc = hq[q] * fscale[q];
            for (int n = 0; n < NB; n++)
                for (int c = 0; c < 3; c++) {
                    float x0 = 0, x1 = 0;
                    int o = boff[n] + c * bw[n];
                    for (int s = 0; s < bw[n]; s++) { float h = h2f(f[o + s]); x0 += c0[o + s] * h; x1 += c1[o + s] * h; }
                    b[c] += sc * dpow[3 * n + c] * (a0 * x0 + t * x1);
                }
        }
        float *o = img + 3 * pix[p];
        for (int c = 0; c < 3; c++) o[c] = b[c];
    }
}

#ifdef GI_X86
static inline float hsum8(__m256 a) __attribute__((target("avx2")));
static inline float hsum8(__m256 a) {
    __m128 h = _mm_add_ps(_mm256_castps256_ps128(a), _mm256_extractf128_ps(a, 1));
    h = _mm_hadd_ps(h, h); h = _mm_hadd_ps(h, h);
    return _mm_cvtss_f32(h);
}

__attribute__((target("f16c,avx2,fma"))) static void dense_avx2(GI_DENSE_ARGS) {
#pragma omp parallel for schedule(dynamic, 256)
    for (int64_t p = 0; p < P; p++) {
        float b[3] = {0, 0, 0};
        const float *v = V + p * NP * 3;
        for (int x = 0; x < NP; x++)
            for (int c = 0; c < 3; c++) b[c] += ckn[3 * x + c] * v[3 * x + c];
        int64_t q = qpos[p];
        if (q >= 0) {
            const float *c0 = CT + (int64_t)k0[p] * Wd, *c1 = c0 + Wd;
            float t = tt[p], a0 = 1.0f - t;
            const uint16_t *f = Fd + q * (int64_t)Wd;
            float sc = hq[q] * fscale[q];
            for (int n = 0; n < NB; n++)
                for (int c = 0; c < 3; c++) {
                    __m256 x0 = _mm256_setzero_ps(), x1 = _mm256_setzero_ps();
                    int o = boff[n] + c * bw[n];
                    for (int s = 0; s < bw[n]; s += 8) {
                        __m256 h = _mm256_cvtph_ps(_mm_loadu_si128((const __m128i *)(f + o + s)));
                        x0 = _mm256_fmadd_ps(_mm256_loadu_ps(c0 + o + s), h, x0);
                        x1 = _mm256_fmadd_ps(_mm256_loadu_ps(c1 + o + s), h, x1);
                    }
                    b[c] += sc * dpow[3 * n + c] * (a0 * hsum8(x0) + t * hsum8(x1));
                }
        }
        float *o = img + 3 * pix[p];
        for (int c = 0; c < 3; c++) o[c] = b[c];
    }
}
#endif

void gi_frame_dense(GI_DENSE_ARGS) {
#ifdef GI_X86
    int aligned = 1;
    for (int n = 0; n < NB; n++) aligned &= bw[n] % 8 == 0;
    if (aligned && __builtin_cpu_supports("f16c") && __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")) {
        dense_avx2(P, NP, V, ckn, qpos, NB, bw, boff, Wd, Fd, fscale, hq, k0, tt, CT, dpow, pix, img);
        return;
    }
#endif
    dense_soft(P, NP, V, ckn, qpos, NB, bw, boff, Wd, Fd, fscale, hq, k0, tt, CT, dpow, pix, img);
}
