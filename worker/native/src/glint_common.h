/* Shared inline helpers of Glint's C kernels (every .c file in this folder is compiled into one library,
 * worker/native/_glintk*.so): 3-vectors in double precision and the tangent frame of a normal.
 * Each kernel file keeps its NumPy reference beside its Python binding (see worker/native).
 */
#ifndef GLINT_COMMON_H
#define GLINT_COMMON_H
#include <math.h>
#include <stdint.h>

#define INV_PI 0.31830988618379067
#define PI 3.141592653589793

typedef struct { double x, y, z; } v3;
static inline v3 mk(double x, double y, double z) { v3 r = {x, y, z}; return r; }
static inline double dot(v3 a, v3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static inline v3 add(v3 a, v3 b) { return mk(a.x + b.x, a.y + b.y, a.z + b.z); }
static inline v3 scl(v3 a, double s) { return mk(a.x * s, a.y * s, a.z * s); }
static inline v3 nrm(v3 a) { double l = sqrt(dot(a, a)); return l > 1e-30 ? scl(a, 1.0 / l) : a; }

/* A shading point is shaded only where the camera sees its surface, but its shading normal (a
 * vertex normal, or one interpolated across a face) may face away from the eye at a silhouette:
 * there ωo is taken just above the normal's horizon (ωo + n(GRAZE_COS − cosθo), normalised),
 * the surface's grazing radiance, instead of none (a black vertex interpolated across the faces
 * of a silhouette). core/render.py facing_view is the reference. */
#define GRAZE_COS 1e-3
static inline v3 facing_view(v3 n, v3 wo) {
    double co = dot(n, wo);
    return co >= GRAZE_COS ? wo : nrm(add(wo, scl(n, GRAZE_COS - co)));
}

/* Duff et al. 2017 orthonormal basis, as worker/core/brdf.py onb. */
static inline void onb(v3 n, v3 *t, v3 *b) {
    double s = n.z >= 0 ? 1.0 : -1.0;
    double a = -1.0 / (s + n.z);
    double bb = n.x * n.y * a;
    *t = mk(1.0 + s * n.x * n.x * a, s * bb, -s * n.x);
    *b = mk(bb, s + n.y * n.y * a, -n.y);
}

#endif
