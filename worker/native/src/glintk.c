/* Glint's multithreaded C kernels (OpenMP). Each has a NumPy reference of the same name in
 * worker/core (cuts.py, render.py, tonemap.py); tests/core/test_native.py checks they agree.
 *
 * Loaded through ctypes (worker/native/__init__.py): plain C ABI, arrays are C-contiguous.
 * The BRDF model ids and parameter layout match worker/core/brdf.py (pack / eval_packed).
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include "glint_common.h"
#include "brdf_kernels.h"

/* BRDF kernel branches by name (ids and packed layout in brdf_kernels.h; the shading kernel
 * that evaluates them is in shade.c). */
static const char *const K_NAMES[K_COUNT] = {"lambert", "ggx", "blinn-phong", "lobes", "table",
                                              "ashikhmin-shirley"};

/* id of a BRDF kernel branch by name, −1 when this library has none */
int glk_model_id(const char *name) {
    for (int k = 0; k < K_COUNT; k++)
        if (strcmp(name, K_NAMES[k]) == 0) return k;
    return -1;
}

/* the packed layout this library was built with: 0 → N_PARAMS, 1 → TABLE_N */
int glk_layout(int what) { return what == 0 ? N_PARAMS : (what == 1 ? TABLE_N : -1); }

int glk_max_threads(void) {
#ifdef _OPENMP
    return omp_get_max_threads();
#else
    return 1;
#endif
}

void glk_set_threads(int n) {
#ifdef _OPENMP
    if (n > 0) omp_set_num_threads(n);
#endif
}

/* ---------------------------------------------------------------------------------------
 * Cut building (cyber-worlds §V, inverse-brdf-modeling §4.1). For each vertex, the leaf
 * values v (N = 2^H floats, cosine-weighted visibility) are clustered: a node is kept when
 * err = sqrt(n · Σ(v_i − mean)²) ≤ tau, which bounds its L1 error Σ|v_i − mean| ≤ tau
 * (Cauchy-Schwarz); err only shrinks towards the leaves, so the cut is the set of kept nodes
 * whose parent is not kept, emitted left to right as (height, quantised mean).
 */
void glk_build_cuts(const float *vals, int64_t B, int H, double tau, uint8_t *heights,
                    uint8_t *quant, int32_t *counts) {
    const int64_t N = (int64_t)1 << H;
#pragma omp parallel
    {
        double *S = (double *)malloc(sizeof(double) * 2 * N);
        double *Q = (double *)malloc(sizeof(double) * 2 * N);
        int64_t *lev = (int64_t *)malloc(sizeof(int64_t) * (H + 2));
        int64_t *stack = (int64_t *)malloc(sizeof(int64_t) * 2 * (H + 2));
        lev[0] = 0;
        for (int h = 0; h <= H; h++) lev[h + 1] = lev[h] + (N >> h);
#pragma omp for schedule(dynamic, 4)
        for (int64_t b = 0; b < B; b++) {
            const float *v = vals + b * N;
            for (int64_t i = 0; i < N; i++) { S[i] = v[i]; Q[i] = (double)v[i] * v[i]; }
            for (int h = 1; h <= H; h++) {
                double *s0 = S + lev[h - 1], *q0 = Q + lev[h - 1];
                double *s1 = S + lev[h], *q1 = Q + lev[h];
                for (int64_t j = 0; j < (N >> h); j++) {
                    s1[j] = s0[2 * j] + s0[2 * j + 1];
                    q1[j] = q0[2 * j] + q0[2 * j + 1];
                }
            }
            uint8_t *ho = heights + b * N, *qo = quant + b * N;
            int32_t c = 0;
            int sp = 0;
            stack[sp++] = H; stack[sp++] = 0;  /* (height, index within level) */
            while (sp) {
                int64_t j = stack[--sp];
                int h = (int)stack[--sp];
                double n = (double)((int64_t)1 << h);
                double s = S[lev[h] + j], q = Q[lev[h] + j];
                double sse = q - s * s / n;
                double err = sse > 0 ? sqrt(n * sse) : 0.0;
                if (h == 0 || err <= tau) {
                    double m = s / n;
                    m = m < 0 ? 0 : (m > 1 ? 1 : m);
                    ho[c] = (uint8_t)h;
                    qo[c] = (uint8_t)lrint(m * 255.0);
                    c++;
                } else {  /* right child first so the left one pops first */
                    stack[sp++] = h - 1; stack[sp++] = 2 * j + 1;
                    stack[sp++] = h - 1; stack[sp++] = 2 * j;
                }
            }
            counts[b] = c;
        }
        free(S); free(Q); free(lev); free(stack);
    }
}

/* ---------------------------------------------------------------------------------------
 * Coarsening a cut set for interaction (worker/core/cuts.py coarsen, its NumPy reference):
 * per vertex, nodes are pushed left to right; while the top two are siblings whose merge error
 * sqrt(n · Σ n_i (m_i − m)²) stays within tau they are replaced by their parent. Writes each
 * vertex's coarse cut in place of its input range (it is never longer) and its length to counts.
 */
void glk_coarsen(int64_t V, const int64_t *offsets, const uint8_t *heights, const uint8_t *quant, double tau,
                 uint8_t *out_h, uint8_t *out_q, int32_t *counts) {
#pragma omp parallel
    {
        int sh[64]; int64_t ss[64]; double sm[64], sb[64];
#pragma omp for schedule(dynamic, 256)
        for (int64_t v = 0; v < V; v++) {
            int64_t a = offsets[v], b = offsets[v + 1], start = 0;
            int64_t c = a;                 /* next output slot */
            int sp = 0;
            for (int64_t k = a; k < b; k++) {
                int h = heights[k];
                sh[sp] = h; ss[sp] = start; sm[sp] = quant[k] / 255.0; sb[sp] = 0.0; sp++;
                start += (int64_t)1 << h;
                while (sp >= 2) {
                    int hl = sh[sp - 2], hr = sh[sp - 1];
                    if (hl != hr || ((ss[sp - 2] >> hl) & 1) || ss[sp - 1] != ss[sp - 2] + ((int64_t)1 << hl)) break;
                    double n = (double)((int64_t)1 << hl);
                    double mm = 0.5 * (sm[sp - 2] + sm[sp - 1]);
                    double dl = sm[sp - 2] - mm, dr = sm[sp - 1] - mm;
                    double bb = sb[sp - 2] + sb[sp - 1] + n * (dl * dl + dr * dr);
                    if (sqrt(2.0 * n * bb) > tau) break;
                    sp--;
                    sh[sp - 1] = hl + 1; sm[sp - 1] = mm; sb[sp - 1] = bb;
                }
                /* nodes below the stack's bottom two can no longer merge: flush them */
                if (sp == 64) { out_h[c] = (uint8_t)sh[0]; out_q[c] = (uint8_t)lrint(sm[0] * 255.0); c++;
                    memmove(sh, sh + 1, sizeof(int) * 63); memmove(ss, ss + 1, sizeof(int64_t) * 63);
                    memmove(sm, sm + 1, sizeof(double) * 63); memmove(sb, sb + 1, sizeof(double) * 63); sp--; }
            }
            for (int i = 0; i < sp; i++) {
                double m = sm[i] < 0 ? 0 : (sm[i] > 1 ? 1 : sm[i]);
                out_h[c] = (uint8_t)sh[i]; out_q[c] = (uint8_t)lrint(m * 255.0); c++;
            }
            counts[v] = (int32_t)(c - a);
        }
    }
}

/* Barycentric interpolation of per-vertex radiance to pixels (Embree's u, v: hit =
 * (1−u−v)·v0 + u·v1 + v·v2). tri < 0 leaves the pixel untouched. */
void glk_interpolate(int64_t P, const int32_t *tri, const float *uv, const int32_t *faces,
                     const float *vert_rgb, float *out) {
#pragma omp parallel for schedule(static)
    for (int64_t p = 0; p < P; p++) {
        int32_t f = tri[p];
        if (f < 0) continue;
        float u = uv[2 * p], v = uv[2 * p + 1], w = 1.0f - u - v;
        const float *a = vert_rgb + 3 * (int64_t)faces[3 * f], *b = vert_rgb + 3 * (int64_t)faces[3 * f + 1],
                    *c = vert_rgb + 3 * (int64_t)faces[3 * f + 2];
        for (int k = 0; k < 3; k++) out[3 * p + k] = w * a[k] + u * b[k] + v * c[k];
    }
}

/* Bilinear lookup of an equirectangular map (docs/design/conventions.md) for world directions, with the
 * environment rotated by rot_rad about +Y (world φ reads map φ + rot) and scaled. */
void glk_env_lookup(int64_t P, const float *dirs, const uint8_t *mask, const float *map, int Hm,
                    int Wm, double rot_rad, double intensity, float *out) {
#pragma omp parallel for schedule(static)
    for (int64_t p = 0; p < P; p++) {
        if (mask && !mask[p]) continue;
        double x = dirs[3 * p], y = dirs[3 * p + 1], z = dirs[3 * p + 2];
        double u = atan2(x, -z) / (2 * PI) + rot_rad / (2 * PI);
        u -= floor(u);
        double v = acos(fmax(-1.0, fmin(1.0, y))) / PI;
        double fx = u * Wm - 0.5, fy = v * Hm - 0.5;
        int x0 = (int)floor(fx), y0 = (int)floor(fy);
        double ax = fx - x0, ay = fy - y0;
        int x1 = x0 + 1, y1 = y0 + 1;
        x0 = ((x0 % Wm) + Wm) % Wm; x1 = ((x1 % Wm) + Wm) % Wm;
        y0 = y0 < 0 ? 0 : (y0 >= Hm ? Hm - 1 : y0); y1 = y1 < 0 ? 0 : (y1 >= Hm ? Hm - 1 : y1);
        for (int k = 0; k < 3; k++) {
            double a = map[((int64_t)y0 * Wm + x0) * 3 + k] * (1 - ax) + map[((int64_t)y0 * Wm + x1) * 3 + k] * ax;
            double b = map[((int64_t)y1 * Wm + x0) * 3 + k] * (1 - ax) + map[((int64_t)y1 * Wm + x1) * 3 + k] * ax;
            out[3 * p + k] = (float)(intensity * (a * (1 - ay) + b * ay));
        }
    }
}

/* Tone mapping (worker/core/tonemap.py): exposure (stops), curve, sRGB OETF, 8-bit. */
static inline double tm_curve(int curve, double x) {
    if (x <= 0) return 0;
    if (curve == 1) { /* ACES filmic fit (Narkowicz 2015) */
        double y = (x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14);
        return y < 0 ? 0 : (y > 1 ? 1 : y);
    }
    if (curve == 2) { /* neutral: identity up to 0.8, then a smooth shoulder to 1 */
        const double k = 0.8;
        if (x <= k) return x;
        double t = x - k;
        return k + (1 - k) * t / (t + (1 - k));
    }
    return x > 1 ? 1 : x;
}

static inline double srgb_oetf(double c) {
    return c <= 0.0031308 ? 12.92 * c : 1.055 * pow(c, 1.0 / 2.4) - 0.055;
}

/* The sRGB OETF (a pow per channel) is read from a 16384-entry table over the curve's [0, 1]
 * output, filled at first use: within 0.2 of an 8-bit level of the exact value. */
#define OETF_N 16384
static uint8_t oetf_lut[OETF_N + 1];
static int oetf_ready = 0;

void glk_tonemap(int64_t P, const float *rgb, double exposure, int curve, uint8_t *out) {
    if (!oetf_ready) {
        for (int i = 0; i <= OETF_N; i++) {
            int v = (int)lrint(srgb_oetf((double)i / OETF_N) * 255.0);
            oetf_lut[i] = (uint8_t)(v < 0 ? 0 : (v > 255 ? 255 : v));
        }
        oetf_ready = 1;
    }
    double scale = pow(2.0, exposure);
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < 3 * P; i++) {
        double y = tm_curve(curve, rgb[i] * scale);
        out[i] = oetf_lut[(int)(y * OETF_N + 0.5)];
    }
}

/* A frame and its half-resolution copy for display (worker/publish/frames.py): the (2H, 2W)
 * linear frame tone-mapped to out2, and the mean of each 2 × 2 block of it, in linear radiance
 * (the pixel's mean radiance over its footprint: four samples per pixel), tone-mapped to out1
 * (H, W). One pass over the frame instead of a tone mapping, a NumPy block mean and another
 * tone mapping. Reference: tonemap_pair_numpy (core/tonemap.py).
 *
 * The tone mapping itself is one table read per value: lut (TM_LUT_N bytes, glk_tonemap_lut,
 * made once per exposure and curve by the caller) indexed by the float's top 19 bits (sign,
 * exponent and 10 mantissa bits), read at the bucket's middle: within 0.05% of the value, so
 * within 0.05 of an 8-bit level of evaluating the curve (the sRGB curve's slope in log terms is
 * at most 106 levels per unit), at a fraction of its cost per value. */
#define TM_LUT_SHIFT 13
#define TM_LUT_N (1 << (32 - TM_LUT_SHIFT))

int64_t glk_tonemap_lut_size(void) { return TM_LUT_N; }

void glk_tonemap_lut(double exposure, int curve, uint8_t *lut) {
    if (!oetf_ready) {
        for (int i = 0; i <= OETF_N; i++) {
            int v = (int)lrint(srgb_oetf((double)i / OETF_N) * 255.0);
            oetf_lut[i] = (uint8_t)(v < 0 ? 0 : (v > 255 ? 255 : v));
        }
        oetf_ready = 1;
    }
    double scale = pow(2.0, exposure);
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < TM_LUT_N; i++) {
        uint32_t bits = ((uint32_t)i << TM_LUT_SHIFT) | (1u << (TM_LUT_SHIFT - 1));   /* the bucket's middle */
        float x;
        memcpy(&x, &bits, sizeof x);
        if (x != x) x = 0.0f;                                  /* NaN: black */
        double y = (double)x * scale;
        if (y > 1e30) y = 1e30;                                 /* +inf: white */
        lut[i] = oetf_lut[(int)(tm_curve(curve, y) * OETF_N + 0.5)];
    }
}

static inline uint8_t tm_lookup(const uint8_t *lut, float x) {
    uint32_t bits;
    memcpy(&bits, &x, sizeof bits);
    return lut[bits >> TM_LUT_SHIFT];
}

/* n values of a linear frame tone-mapped through lut (glk_tonemap_lut): one table read each,
 * where glk_tonemap evaluates the curve and the sRGB table (3.4 ms for a 640×480 frame, ten
 * times this) — a session's frames, whose exposure and curve stay for many frames. */
void glk_tonemap_apply(int64_t n, const float *rgb, const uint8_t *lut, uint8_t *out) {
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < n; i++) out[i] = tm_lookup(lut, rgb[i]);
}

void glk_tonemap_pair(int64_t H, int64_t W, const float *rgb, const uint8_t *lut, uint8_t *out2, uint8_t *out1) {
    int64_t W2 = 2 * W;
#pragma omp parallel for schedule(static)
    for (int64_t y = 0; y < H; y++) {
        const float *r0 = rgb + (2 * y) * W2 * 3, *r1 = r0 + W2 * 3;
        uint8_t *o0 = out2 + (2 * y) * W2 * 3, *o1 = o0 + W2 * 3, *h = out1 + y * W * 3;
        for (int64_t j = 0; j < 6 * W; j++) {
            o0[j] = tm_lookup(lut, r0[j]);
            o1[j] = tm_lookup(lut, r1[j]);
        }
        for (int64_t x = 0; x < W; x++) {
            for (int k = 0; k < 3; k++) {
                int64_t a = (2 * x) * 3 + k, b = a + 3;
                h[3 * x + k] = tm_lookup(lut, 0.25f * ((r0[a] + r0[b]) + (r1[a] + r1[b])));
            }
        }
    }
}

/* The transfer functions of the SRBF basis (paint to BRDF) are in fit.c (glk_fit_transfer). */
