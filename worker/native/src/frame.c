/* Frame assembly kernels of the cut renderer (worker/core/render.py background_numpy and
 * resolve_numpy are their NumPy references; tests/perf/test_kernels.py checks they agree).
 *
 * glk_background: the environment seen through the background samples of a view, rotated and
 * scaled, darkened by the ground shadow where a sample's ray meets the shadow-catcher plane
 * (worker/renderers/cuts/ground.py). The map coordinates of each ray are computed once per
 * view (render.py env_coords), so a light change costs a bilinear lookup per sample, not an
 * atan2 and an acos.
 * glk_resolve: per pixel, the mean over its S samples of the barycentric interpolation of
 * per-vertex radiance (object samples) or of the background (the others): vertex-mode shading
 * with S-sample anti-aliasing costs S interpolations per pixel and no extra shading.
 */
#include <math.h>
#include <stdint.h>
#include "glint_common.h"

/* n background samples: sample (n,) int64 index into out (rows of 3), dirs (n, 3) float32 unit
 * world ray directions, uv0 (n, 2) float32 map coordinates without rotation (u in [0, 1),
 * v = acos(y)/π); map (Hm, Wm, 3) float32; the environment rotated by rot radians about +Y
 * and scaled by intensity (docs/design/conventions.md, as glk_env_lookup). shadow: NULL, or a (G, G, 3)
 * float32 factor grid over the plane y = gy with node (i, j) at (gx0 + i·gstep, gy, gz0 + j·gstep),
 * applied (bilinear, 1 outside the grid) to rays from eye that go down through the plane. */
void glk_background(int64_t n, const int64_t *sample, const float *dirs, const float *uv0, const float *map,
                    int Hm, int Wm, double rot, double intensity, const float *shadow, int G, double gx0,
                    double gz0, double gstep, double gy, double ex, double ey, double ez, float *out) {
    const double turns = rot / (2 * PI), rt = turns - floor(turns);
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < n; i++) {
        double u = uv0[2 * i] + rt;            /* both in [0, 1) */
        if (u >= 1.0) u -= 1.0;
        double v = uv0[2 * i + 1];
        double fx = u * Wm - 0.5, fy = v * Hm - 0.5;     /* ≥ −0.5: floor by truncation of x + 1 */
        int x0 = (int)(fx + 1.0) - 1, y0 = (int)(fy + 1.0) - 1;
        double ax = fx - x0, ay = fy - y0;
        /* x0 in [−1, Wm − 1]: wrap without a division */
        int x1 = x0 + 1;
        if (x0 < 0) x0 += Wm;
        if (x1 >= Wm) x1 -= Wm;
        int y1 = y0 + 1;
        y0 = y0 < 0 ? 0 : (y0 >= Hm ? Hm - 1 : y0); y1 = y1 < 0 ? 0 : (y1 >= Hm ? Hm - 1 : y1);
        double f[3] = {1.0, 1.0, 1.0};
        if (shadow) {
            double dy = dirs[3 * i + 1];
            if (ey > gy && dy < 0) {
                double t = (gy - ey) / dy;
                double gx = (ex + t * dirs[3 * i] - gx0) / gstep, gz = (ez + t * dirs[3 * i + 2] - gz0) / gstep;
                if (gx >= 0 && gz >= 0 && gx <= G - 1 && gz <= G - 1) {
                    int i0 = (int)gx, j0 = (int)gz;
                    if (i0 > G - 2) i0 = G - 2;
                    if (j0 > G - 2) j0 = G - 2;
                    double a = gx - i0, b = gz - j0;
                    const float *s00 = shadow + ((int64_t)i0 * G + j0) * 3, *s10 = s00 + 3 * G;
                    for (int k = 0; k < 3; k++)
                        f[k] = (s00[k] * (1 - b) + s00[3 + k] * b) * (1 - a) + (s10[k] * (1 - b) + s10[3 + k] * b) * a;
                }
            }
        }
        float *o = out + 3 * sample[i];
        for (int k = 0; k < 3; k++) {
            double c0 = map[((int64_t)y0 * Wm + x0) * 3 + k] * (1 - ax) + map[((int64_t)y0 * Wm + x1) * 3 + k] * ax;
            double c1 = map[((int64_t)y1 * Wm + x0) * 3 + k] * (1 - ax) + map[((int64_t)y1 * Wm + x1) * 3 + k] * ax;
            o[k] = (float)(intensity * (c0 * (1 - ay) + c1 * ay) * f[k]);
        }
    }
}

/* P pixels of S samples each (sample s of pixel p at p·S + s): tri (P·S,) int32 face or −1,
 * uv (P·S, 2) float32 Embree barycentrics, faces (F, 3) int32, vert_rgb (V, 3) float32,
 * bg (P·S, 3) float32 (read where tri < 0). Writes out (P, 3) float32. */
void glk_resolve(int64_t P, int S, const int32_t *tri, const float *uv, const int32_t *faces, const float *vert_rgb,
                 const float *bg, float *out) {
    const float inv = 1.0f / (float)S;
#pragma omp parallel for schedule(static)
    for (int64_t p = 0; p < P; p++) {
        float acc[3] = {0, 0, 0};
        for (int s = 0; s < S; s++) {
            int64_t k = p * S + s;
            int32_t f = tri[k];
            if (f < 0) {
                for (int c = 0; c < 3; c++) acc[c] += bg[3 * k + c];
                continue;
            }
            float u = uv[2 * k], v = uv[2 * k + 1], w = 1.0f - u - v;
            const float *a = vert_rgb + 3 * (int64_t)faces[3 * f], *b = vert_rgb + 3 * (int64_t)faces[3 * f + 1],
                        *c = vert_rgb + 3 * (int64_t)faces[3 * f + 2];
            for (int j = 0; j < 3; j++) acc[j] += w * a[j] + u * b[j] + v * c[j];
        }
        for (int c = 0; c < 3; c++) out[3 * p + c] = S == 1 ? acc[c] : acc[c] * inv;
    }
}

/* Camera rays: the cached camera-frame directions (P, 3) rotated into the world by the rows of
 * basis (3 × 3: right, up, forward), out (P, 3) float32 (render.py camera_rays). */
void glk_rotate_dirs(int64_t P, const float *src, const float *basis, float *out) {
    const float b0 = basis[0], b1 = basis[1], b2 = basis[2], b3 = basis[3], b4 = basis[4], b5 = basis[5],
                b6 = basis[6], b7 = basis[7], b8 = basis[8];
#pragma omp parallel for schedule(static)
    for (int64_t p = 0; p < P; p++) {
        float x = src[3 * p], y = src[3 * p + 1], z = src[3 * p + 2];
        out[3 * p] = x * b0 + y * b3 + z * b6;
        out[3 * p + 1] = x * b1 + y * b4 + z * b7;
        out[3 * p + 2] = x * b2 + y * b5 + z * b8;
    }
}

/* Equirectangular coordinates of world directions (n, 3), unrotated (docs/design/conventions.md):
 * out (n, 2) float32 u = atan2(x, −z)/2π wrapped into [0, 1), v = acos(y)/π (render.py env_coords). */
void glk_env_coords(int64_t n, const float *dirs, float *out) {
#pragma omp parallel for schedule(static)
    for (int64_t i = 0; i < n; i++) {
        /* single precision: 1e-7 of a turn is 1e-4 of a texel of a 1024-wide map */
        float x = dirs[3 * i], y = dirs[3 * i + 1], z = dirs[3 * i + 2];
        float u = atan2f(x, -z) * (float)(0.5 / PI);
        if (u < 0) u += 1.0f;
        if (u >= 1.0f) u -= 1.0f;
        out[2 * i] = u;
        out[2 * i + 1] = acosf(y < -1 ? -1 : (y > 1 ? 1 : y)) * (float)(1.0 / PI);
    }
}
