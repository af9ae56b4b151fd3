/* HDR merge of bracketed 8-bit photos (worker/capture/hdr.py merge_numpy is the reference).
 *
 * Per pixel and channel: the weighted mean of the brackets' radiance estimates
 *     E = Σ_k w_k(z_k) · v_k(z_k) / Σ_k w_k(z_k)
 * where v_k(z) = f⁻¹(z)/e_k (inverse response over relative exposure) and w_k(z) the bracket's
 * weight table (hat × inverse variance of the estimate, see hdr.py), both tabulated per bracket
 * as K×256×3 floats. Brackets come in order of increasing exposure. A pixel whose weights are
 * all zero (clipped or black in every bracket) takes the estimate of the bracket whose value is
 * nearest mid-range, ties going to the shortest exposure on the bright side (a lower bound for a
 * clipped light) and the longest on the dark side; its status bit says which.
 *
 * status (per pixel, OR over channels): 1 bright fallback (clipped in every bracket),
 * 2 dark fallback, 4 no valid bracket (outside the image circle or shifted out by alignment).
 */
#include "glint_common.h"
#include <stdint.h>

void glk_hdr_merge(int64_t n, int K, const uint8_t *z, const uint8_t *valid, const float *val,
                   const float *wt, float *out, uint8_t *status)
{
    #pragma omp parallel for schedule(static, 4096)
    for (int64_t p = 0; p < n; p++) {
        uint8_t st = 0;
        for (int c = 0; c < 3; c++) {
            double sw = 0.0, sv = 0.0, bestd = 1e9;
            int best = -1, bestz = 0;
            for (int k = 0; k < K; k++) {
                if (valid && !valid[(int64_t)k * n + p]) continue;
                int zz = z[((int64_t)k * n + p) * 3 + c];
                const int t = (k * 256 + zz) * 3 + c;
                double w = wt[t];
                sw += w;
                sv += w * val[t];
                double d = fabs(zz - 127.5);
                if (d < bestd || (d == bestd && zz < 127.5)) { bestd = d; best = k; bestz = zz; }
            }
            float r;
            if (sw > 0.0) r = (float)(sv / sw);
            else if (best >= 0) {
                r = val[(best * 256 + bestz) * 3 + c];
                st |= bestz > 127.5 ? 1 : 2;
            } else { r = 0.0f; st |= 4; }
            out[p * 3 + c] = r;
        }
        status[p] = st;
    }
}

/* Where each pixel of an equirectangular map (docs/design/conventions.md: direction of pixel (i, j) at
 * θ = (i+½)π/h from +Y, φ = (j+½)2π/w, d = (sinθ sinφ, cosθ, −sinθ cosφ)) lands in a fisheye
 * photo taken at yaw (radians, about +Y): cv2.remap coordinates (pixel centres at integers),
 * −10 outside the image circle (θ_cam > theta_max). projection 0 equidistant r = fθ,
 * 1 equisolid r = 2f sin(θ/2). Reference: worker/capture/stitch.py fisheye_map_numpy. */
void glk_fisheye_map(int h, int w, double yaw, int projection, double focal, double cx, double cy,
                     double theta_max, float *map_x, float *map_y)
{
    const double c = cos(yaw), s = sin(yaw);
    #pragma omp parallel for schedule(static)
    for (int i = 0; i < h; i++) {
        const double th = (i + 0.5) * PI / h, st = sin(th), ct = cos(th);
        for (int j = 0; j < w; j++) {
            const double ph = (j + 0.5) * 2.0 * PI / w;
            const double dx = st * sin(ph), dy = ct, dz = -st * cos(ph);
            const double xc = c * dx - s * dz, yc = dy, zc = s * dx + c * dz;
            double tc = acos(fmin(1.0, fmax(-1.0, -zc)));
            const int64_t o = (int64_t)i * w + j;
            if (tc > theta_max) { map_x[o] = -10.0f; map_y[o] = -10.0f; continue; }
            const double rho = sqrt(xc * xc + yc * yc);
            const double r = projection == 0 ? focal * tc : 2.0 * focal * sin(0.5 * tc);
            const double k = rho > 1e-12 ? r / rho : 0.0;
            map_x[o] = (float)(cx + xc * k - 0.5);
            map_y[o] = (float)(cy - yc * k - 0.5);
        }
    }
}
