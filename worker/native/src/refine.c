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
