/* Where Gouraud interpolation of vertex shading fails (worker/native/refine.py mirror_spread_numpy
 * is the reference).
 *
 * Per face: the largest angle between the mirror directions of its three vertices,
 *     r_i = 2 (n_i · o_i) n_i − o_i,   o_i = unit(eye − x_i),
 * the angle acos(clamp(r_i · r_j, −1, 1)) maximised over the three pairs. A glossy lobe is a
 * function of the angle to r (inverse-brdf-modeling eq. 22: f_r evaluated at each cut node's
 * direction), so a face whose mirror directions span more than a fraction of the lobe width
 * carries a highlight that barycentric interpolation of its corners cannot reproduce.
 */
#include "glint_common.h"
#include <stdint.h>

static inline v3 ld(const float *a, int64_t i) { return mk(a[3 * i], a[3 * i + 1], a[3 * i + 2]); }

static inline double ang(v3 a, v3 b) {
    double d = dot(a, b);
    return acos(d > 1.0 ? 1.0 : (d < -1.0 ? -1.0 : d));
}

void glk_mirror_spread(int64_t F, const int32_t *faces, const float *vx, const float *vn,
                       double ex, double ey, double ez, float *out)
{
    const v3 e = mk(ex, ey, ez);
    #pragma omp parallel for schedule(static, 2048)
    for (int64_t f = 0; f < F; f++) {
        v3 r[3];
        for (int k = 0; k < 3; k++) {
            const int64_t v = faces[3 * f + k];
            v3 n = nrm(ld(vn, v));
            v3 x = ld(vx, v);
            v3 o = nrm(mk(e.x - x.x, e.y - x.y, e.z - x.z));
            r[k] = add(scl(n, 2.0 * dot(n, o)), scl(o, -1.0));
        }
        double s = ang(r[0], r[1]), t = ang(r[1], r[2]), u = ang(r[0], r[2]);
        out[f] = (float)(s > t ? (s > u ? s : u) : (t > u ? t : u));
    }
}

/* Per face: the largest difference between its vertices' radiance in any channel,
 *     max_c (max_i L_ic − min_i L_ic),
 * the size of the variation Gouraud interpolation spreads linearly over the face. */
void glk_face_contrast(int64_t F, const int32_t *faces, const float *vert_rgb, float *out)
{
    #pragma omp parallel for schedule(static, 4096)
    for (int64_t f = 0; f < F; f++) {
        const float *a = vert_rgb + 3 * (int64_t)faces[3 * f];
        const float *b = vert_rgb + 3 * (int64_t)faces[3 * f + 1];
        const float *d = vert_rgb + 3 * (int64_t)faces[3 * f + 2];
        float m = 0.0f;
        for (int c = 0; c < 3; c++) {
            float hi = fmaxf(a[c], fmaxf(b[c], d[c])), lo = fminf(a[c], fminf(b[c], d[c]));
            m = fmaxf(m, hi - lo);
        }
        out[f] = m;
    }
}

/* Per pixel of a one-sample hit buffer tri (H·W, row-major; −1 background): 1 when one of its
 * 8 neighbours sees another surface: the background against the mesh, another object's face,
 * or a face sharing no vertex with its own (worker/renderers/cuts/edges.py edge_pixels is the
 * reference): the pixels where one sample is not the pixel's mean. */
static inline int other_surface(int32_t a, int32_t b, const int32_t *faces, const int32_t *obj)
{
    if (a == b) return 0;
    if (a < 0 || b < 0) return 1;
    if (obj[a] != obj[b]) return 1;
    const int32_t *fa = faces + 3 * (int64_t)a, *fb = faces + 3 * (int64_t)b;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            if (fa[i] == fb[j]) return 0;
    return 1;
}

void glk_edge_pixels(int32_t H, int32_t W, const int32_t *tri, const int32_t *faces, const int32_t *obj,
                     uint8_t *out)
{
    #pragma omp parallel for schedule(static, 16)
    for (int32_t y = 0; y < H; y++) {
        for (int32_t x = 0; x < W; x++) {
            const int32_t a = tri[(int64_t)y * W + x];
            uint8_t e = 0;
            for (int dy = -1; dy <= 1 && !e; dy++) {
                const int32_t yy = y + dy;
                if (yy < 0 || yy >= H) continue;
                for (int dx = -1; dx <= 1; dx++) {
                    const int32_t xx = x + dx;
                    if ((dy == 0 && dx == 0) || xx < 0 || xx >= W) continue;
                    if (other_surface(a, tri[(int64_t)yy * W + xx], faces, obj)) { e = 1; break; }
                }
            }
            out[(int64_t)y * W + x] = e;
        }
    }
}
