/* Per-node light tables for one lighting (rotation, intensity) of an environment map, the C
 * kernel of worker/core/lighting.py (LeafLighting.leaf_radiance + node_lighting, its NumPy
 * reference; tests/core/test_lighting.py checks they agree).
 *
 * cyber-worlds §V eq. 3: l_k = ∫_{Ω_k} L(ω) dω. The leaf × pixel assignment (sub-pixels with
 * their exact solid angle, lighting.py _assignment) is one CSR pattern with four weights per
 * entry: solid angle and solid angle × direction (x, y, z). A rotation about +Y by α is a
 * column shift of the map by α·W/2π (linear between columns for a fractional shift, as
 * rotate_map does), applied while reading: no rotated copy of the map is made, and the four
 * sparse products of the reference become one pass over the entries.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include "glint_common.h"

static const double LUMA_R = 0.2126, LUMA_G = 0.7152, LUMA_B = 0.0722;

/* parent rows j0..j1 of a level (dst) as the sums of their two children (src) */
static void sum_level(const double *src, double *dst, int64_t j0, int64_t j1) {
    for (int64_t j = j0; j < j1; j++)
        for (int c = 0; c < 6; c++) dst[6 * j + c] = src[12 * j + c] + src[12 * j + 6 + c];
}

/* the output rows i0..i1 from the scratch sums: radiance, the light-weighted centroid direction
 * (node_dir's where the light has no direction) */
static void out_rows(const double *scratch, const float *node_dir, int64_t i0, int64_t i1, float *node_l,
                     float *node_w, float *node8) {
    for (int64_t i = i0; i < i1; i++) {
        const double *s = scratch + 6 * i;
        double lum = fabs(LUMA_R * s[0] + LUMA_G * s[1] + LUMA_B * s[2]);
        double dl = sqrt(s[3] * s[3] + s[4] * s[4] + s[5] * s[5]);
        float wx, wy, wz;
        if (dl > 1e-3 * lum && dl > 1e-300) {
            wx = (float)(s[3] / dl); wy = (float)(s[4] / dl); wz = (float)(s[5] / dl);
        } else {
            wx = node_dir[3 * i]; wy = node_dir[3 * i + 1]; wz = node_dir[3 * i + 2];
        }
        float lr = (float)s[0], lg = (float)s[1], lb = (float)s[2];
        node_l[3 * i] = lr; node_l[3 * i + 1] = lg; node_l[3 * i + 2] = lb;
        node_w[3 * i] = wx; node_w[3 * i + 1] = wy; node_w[3 * i + 2] = wz;
        float *p = node8 + 8 * i;
        p[0] = lr; p[1] = lg; p[2] = lb; p[3] = wx; p[4] = wy; p[5] = wz; p[6] = 0.0f; p[7] = 0.0f;
    }
}

/* N leaves; indptr (N+1,) int64, pix (nnz,) int32 the pixel's index y·Wm + x, wts (nnz, 4) float32
 * (sr, sr·x, sr·y, sr·z); map (Hm, Wm, 3) float32; the environment rotated by rot radians about
 * +Y, a shift of rot·Wm/2π columns (world column x reads map column x + shift), scaled by
 * intensity.
 * Tree of height H over the N = 2^H leaves, node_dir (2N−1, 3) float32 the fallback directions.
 * Writes node_l, node_w (2N−1, 3) float32 (lighting.node_lighting) and node8 (2N−1, 8) float32,
 * the shading kernel's streaming layout: (l_r, l_g, l_b, w_x, w_y, w_z, 0, 0) per node.
 * scratch: (2N−1, 6) float64; rmap: (Hm·Wm, 4) float32, the rotated map with its luminance.
 *
 * The map is rotated once (Hm·Wm texels) and the entries (~2 per texel: sub-pixels split
 * between leaves) then read one 16-byte texel each in float: shifting and interpolating per
 * entry, in double, made the pass compute-bound (~30 cycles an entry). A leaf sums ~8 entries,
 * so float sums stay within 1e-6 of the reference; levels above are summed in double. */
void glk_light_tables(int64_t N, const int64_t *indptr, const int32_t *pix, const float *wts,
                      const float *map, int Hm, int Wm, double rot, double intensity,
                      int H, const float *node_dir, double *scratch, float *node_l, float *node_w,
                      float *node8, float *rmap) {
    const double shift = (rot / (2 * PI)) * Wm;
    const int64_t s0 = (int64_t)floor(shift);
    const double frac = shift - (double)s0;
    const int lerp = frac >= 1e-6;            /* rotate_map: an integer shift is a plain roll */
    const float f1 = (float)frac, f0 = 1.0f - f1, k = (float)intensity;
    const float lr = (float)LUMA_R, lg = (float)LUMA_G, lb = (float)LUMA_B;
    int64_t sh = s0 % Wm; if (sh < 0) sh += Wm;
    const int hb = H < 6 ? H : 6;             /* B = 64 subtrees: dealt to the threads as they free up */
    const int64_t B = (int64_t)1 << hb;
#pragma omp parallel
    {
#pragma omp for schedule(static)
        for (int64_t y = 0; y < Hm; y++) {
            const float *row = map + y * Wm * 3;
            float *o = rmap + y * Wm * 4;
            for (int64_t x = 0; x < Wm; x++) {
                int64_t xa = x + sh; if (xa >= Wm) xa -= Wm;
                const float *a = row + 3 * xa;
                float r = a[0], g = a[1], b = a[2];
                if (lerp) {      /* float32 like the reference's rotated map */
                    int64_t xb = xa + 1; if (xb >= Wm) xb -= Wm;
                    const float *c = row + 3 * xb;
                    r = f0 * a[0] + f1 * c[0]; g = f0 * a[1] + f1 * c[1]; b = f0 * a[2] + f1 * c[2];
                }
                r *= k; g *= k; b *= k;
                o[4 * x] = r; o[4 * x + 1] = g; o[4 * x + 2] = b; o[4 * x + 3] = lr * r + lg * g + lb * b;
            }
        }
        /* B subtrees of N/B leaves each (B a power of two, a tree being complete): per subtree
         * its leaves, l (3) and the luminance-weighted direction sum (3), into scratch rows
         * 0..N−1, then its nodes level by level (a node is the sum of its two children), then
         * their output rows; the top levels above the subtrees serially after */
#pragma omp for schedule(dynamic, 1)
        for (int64_t b = 0; b < B; b++) {
            const int64_t nb = N / B;
            for (int64_t n = b * nb; n < (b + 1) * nb; n++) {
                float l0 = 0, l1 = 0, l2 = 0, dx = 0, dy = 0, dz = 0;
                for (int64_t e = indptr[n]; e < indptr[n + 1]; e++) {
                    const float *t = rmap + 4 * (int64_t)pix[e];
                    const float *w = wts + 4 * e;
                    l0 += w[0] * t[0]; l1 += w[0] * t[1]; l2 += w[0] * t[2];
                    dx += w[1] * t[3]; dy += w[2] * t[3]; dz += w[3] * t[3];
                }
                double *o = scratch + 6 * n;
                o[0] = l0; o[1] = l1; o[2] = l2; o[3] = dx; o[4] = dy; o[5] = dz;
            }
            out_rows(scratch, node_dir, b * nb, (b + 1) * nb, node_l, node_w, node8);
            int64_t lo = 0, n = N, m = nb;
            for (int h = 1; h <= H - hb; h++) {
                sum_level(scratch + 6 * lo, scratch + 6 * (lo + n), b * m / 2, (b + 1) * m / 2);
                lo += n; n /= 2; m /= 2;
                out_rows(scratch, node_dir, lo + b * m, lo + (b + 1) * m, node_l, node_w, node8);
            }
        }
    }
    int64_t lo = 0, n = N;
    for (int h = 1; h <= H; h++) {
        if (h > H - hb) {
            sum_level(scratch + 6 * lo, scratch + 6 * (lo + n), 0, n / 2);
            out_rows(scratch, node_dir, lo + n, lo + n + n / 2, node_l, node_w, node8);
        }
        lo += n; n /= 2;
    }
}
