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

/* N leaves; indptr (N+1,) int64, prow, pcol (nnz,) int32 the pixel's row y and column x, wts (nnz, 4)
 * float64 (sr, sr·x, sr·y, sr·z); map (Hm, Wm, 3) float32; the environment rotated by rot
 * radians about +Y, a shift of rot·Wm/2π columns (world column x reads map column x + shift),
 * scaled by intensity.
 * Tree of height H over the N = 2^H leaves, node_dir (2N−1, 3) float32 the fallback directions.
 * Writes node_l, node_w (2N−1, 3) float32 (lighting.node_lighting) and node8 (2N−1, 8) float32,
 * the shading kernel's streaming layout: (l_r, l_g, l_b, w_x, w_y, w_z, 0, 0) per node.
 * scratch: (2N−1, 6) float64. */
void glk_light_tables(int64_t N, const int64_t *indptr, const int32_t *prow, const int32_t *pcol, const double *wts,
                      const float *map, int Hm, int Wm, double rot, double intensity,
                      int H, const float *node_dir, double *scratch, float *node_l, float *node_w,
                      float *node8) {
    const double shift = (rot / (2 * PI)) * Wm;
    const int64_t s0 = (int64_t)floor(shift);
    const double frac = shift - (double)s0;
    const int lerp = frac >= 1e-6;            /* rotate_map: an integer shift is a plain roll */
    const float f1 = (float)frac, f0 = 1.0f - f1;
    int64_t sh = s0 % Wm; if (sh < 0) sh += Wm;
    /* leaves: l (3) and the luminance-weighted direction sum (3) into scratch rows 0..N−1 */
#pragma omp parallel for schedule(static, 256)
    for (int64_t k = 0; k < N; k++) {
        double l0 = 0, l1 = 0, l2 = 0, dx = 0, dy = 0, dz = 0;
        for (int64_t e = indptr[k]; e < indptr[k + 1]; e++) {
            int32_t y = prow[e];
            int64_t xa = pcol[e] + sh; if (xa >= Wm) xa -= Wm;
            const float *a = map + ((int64_t)y * Wm + xa) * 3;
            double r, g, b;
            if (lerp) {
                int64_t xb = xa + 1; if (xb >= Wm) xb -= Wm;
                const float *c = map + ((int64_t)y * Wm + xb) * 3;
                /* float32 like the reference's rotated map, then widened */
                r = (float)(f0 * a[0] + f1 * c[0]); g = (float)(f0 * a[1] + f1 * c[1]); b = (float)(f0 * a[2] + f1 * c[2]);
            } else {
                r = a[0]; g = a[1]; b = a[2];
            }
            r *= intensity; g *= intensity; b *= intensity;
            const double *w = wts + 4 * e;
            l0 += w[0] * r; l1 += w[0] * g; l2 += w[0] * b;
            double lum = LUMA_R * r + LUMA_G * g + LUMA_B * b;
            dx += w[1] * lum; dy += w[2] * lum; dz += w[3] * lum;
        }
        double *o = scratch + 6 * k;
        o[0] = l0; o[1] = l1; o[2] = l2; o[3] = dx; o[4] = dy; o[5] = dz;
    }
    /* levels bottom-up: a node is the sum of its two children (serial: a fraction of the leaf
     * pass, and every parallel region costs a barrier that waits for a core on a busy machine) */
    int64_t lo = 0, n = N;
    for (int h = 1; h <= H; h++) {
        const double *src = scratch + 6 * lo;
        double *dst = scratch + 6 * (lo + n);
        for (int64_t j = 0; j < n / 2; j++)
            for (int c = 0; c < 6; c++) dst[6 * j + c] = src[12 * j + c] + src[12 * j + 6 + c];
        lo += n; n /= 2;
    }
    const int64_t M = 2 * N - 1;
    for (int64_t i = 0; i < M; i++) {
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
