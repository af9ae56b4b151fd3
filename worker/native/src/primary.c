/* Primary hits by face projection (worker/core/primary.py primary_hits_numpy is the NumPy
 * reference; tests/core/test_primary.py checks they agree, and that both agree with Embree).
 *
 * A pinhole camera's primary rays all start at the eye, so instead of walking a BVH per ray the
 * faces are projected into the image: each face's projection (clipped to the half-space in
 * front of the eye) selects the samples whose rays can meet it, row by row within the
 * projected polygon's span on that row (its bounding box picks the rows), and each such ray is
 * intersected with the face exactly (Möller–Trumbore in double precision, with the same float32
 * ray directions the tracer would take), keeping the nearest t per sample (a z-buffer in ray
 * distance). The hit face, its barycentrics (u, v) (hit = (1−u−v)·v0 + u·v1 + v·v2, Embree's
 * convention) and t are therefore those of a ray tracer except where a sample lies on a shared
 * edge or silhouette within rounding, where either neighbour (or a miss) may be reported.
 *
 * Threads own bands of image rows (the z-buffer needs no atomics); every band walks the faces'
 * precomputed bounds and skips those outside it.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include "glint_common.h"

#define NEAR_EPS 1e-7

/* Column/row bounds of face f's projection in continuous pixel coordinates (x right, y down,
 * pixel (i, j) spans [i, i+1) × [j, j+1)); returns 0 when no part of the face lies in front of
 * the eye. cam: eye (3), right (3), up (3), fwd (3), sx = W/(2·tan·aspect), sy = H/(2·tan). */
static int face_bounds(const float *V, const int32_t *F, int64_t f, const double *cam, double W, double H,
                       double *bx, double *pg) {
    double q[3][3];   /* camera-space (x right, y up, z forward) */
    for (int k = 0; k < 3; k++) {
        const float *p = V + 3 * (int64_t)F[3 * f + k];
        double d0 = p[0] - cam[0], d1 = p[1] - cam[1], d2 = p[2] - cam[2];
        q[k][0] = d0 * cam[3] + d1 * cam[4] + d2 * cam[5];
        q[k][1] = d0 * cam[6] + d1 * cam[7] + d2 * cam[8];
        q[k][2] = d0 * cam[9] + d1 * cam[10] + d2 * cam[11];
    }
    /* clip the triangle against z ≥ near (Sutherland–Hodgman, one plane: at most 4 vertices) */
    double scale = fabs(q[0][2]) + fabs(q[1][2]) + fabs(q[2][2]) + 1e-30;
    double near = NEAR_EPS * scale;
    double poly[4][3];
    int n = 0;
    for (int k = 0; k < 3; k++) {
        const double *a = q[k], *b = q[(k + 1) % 3];
        int ain = a[2] >= near, bin = b[2] >= near;
        if (ain) { poly[n][0] = a[0]; poly[n][1] = a[1]; poly[n][2] = a[2]; n++; }
        if (ain != bin) {
            double s = (near - a[2]) / (b[2] - a[2]);
            poly[n][0] = a[0] + s * (b[0] - a[0]);
            poly[n][1] = a[1] + s * (b[1] - a[1]);
            poly[n][2] = near;
            n++;
        }
    }
    if (n == 0) return 0;
    double x0 = 1e300, x1 = -1e300, y0 = 1e300, y1 = -1e300;
    pg[8] = n;
    for (int k = 0; k < n; k++) {
        double px = (poly[k][0] / poly[k][2]) * cam[12] + 0.5 * W;
        double py = 0.5 * H - (poly[k][1] / poly[k][2]) * cam[13];
        pg[2 * k] = px; pg[2 * k + 1] = py;
        if (px < x0) x0 = px;
        if (px > x1) x1 = px;
        if (py < y0) y0 = py;
        if (py > y1) y1 = py;
    }
    bx[0] = x0; bx[1] = x1; bx[2] = y0; bx[3] = y1;
    return 1;
}

/* The x-extent [*xa, *xb] of the projected convex polygon pg (n = pg[8] points (x, y)) within
 * the horizontal slab ylo ≤ y ≤ yhi; returns 0 when they do not meet. The slab's extent is
 * reached at a vertex inside it or where an edge crosses one of its two lines. */
static int slab_span(const double *pg, double ylo, double yhi, double *xa, double *xb) {
    const int n = (int)pg[8];
    double x0 = 1e300, x1 = -1e300;
    for (int k = 0; k < n; k++) {
        const double ax = pg[2 * k], ay = pg[2 * k + 1];
        const int j = k + 1 < n ? k + 1 : 0;
        const double bx = pg[2 * j], by = pg[2 * j + 1];
        double s0 = 0.0, s1 = 1.0;        /* the part of the edge a + s (b − a) inside the slab */
        if (ay == by) {
            if (ay < ylo || ay > yhi) continue;
        } else {
            double ta = (ylo - ay) / (by - ay), tb = (yhi - ay) / (by - ay);
            if (ta > tb) { double tmp = ta; ta = tb; tb = tmp; }
            if (ta > s0) s0 = ta;
            if (tb < s1) s1 = tb;
            if (s0 > s1) continue;
        }
        const double xs = ax + s0 * (bx - ax), xe = ax + s1 * (bx - ax);
        if (xs < x0) x0 = xs;
        if (xs > x1) x1 = xs;
        if (xe < x0) x0 = xe;
        if (xe > x1) x1 = xe;
    }
    *xa = x0; *xb = x1;
    return x0 <= x1;
}

/* Primary hits of the rays from eye (3) float32 along dirs (H·W·S, 3) float32 (rows p·S + s,
 * p = y·W + x, through sub-pixel offsets within ±omax pixels of the centre) against the mesh
 * V (nv, 3) float32, F (nf, 3) int32. cam (14) float64: eye, right, up, fwd (unit world axes),
 * W/(2·tan(fov/2)·aspect), H/(2·tan(fov/2)). Writes tri (H·W·S) int32 (−1 miss), uv (·, 2)
 * float32, t (·) float32 (+inf miss); box (nf, 4) int32 scratch. init = 0: (tri, uv, t) already
 * hold nearer hits of other geometry (the static scene under a moved object): they are kept
 * where they are not farther, and the mesh's face f is written as fbase + f. */
void glk_primary_hits(int64_t nv, const float *V, int64_t nf, const int32_t *F, const double *cam,
                      const float *dirs, int W, int H, int S, double omax, int32_t *tri, float *uv, float *t,
                      int32_t *box, int init, int32_t fbase) {
    (void)nv;
    const int64_t P = (int64_t)W * H * S;
    const double mg = omax + 0.01;     /* sample offsets, and rounding of the float32 rays (~1e-6 px) */
    const double ex = cam[0], ey = cam[1], ez = cam[2];
    /* bands of rows: enough of them for the dynamic schedule to even out dense regions */
    const int band = H >= 64 ? 8 : 1;
    const int nb = (H + band - 1) / band;
    int64_t *band_off = NULL;
    int32_t *band_faces = NULL;
    /* each face's projected polygon: a row tests only the samples within the polygon's span
     * on it (a long thin face's bounding box holds many times the samples it covers) */
    double *polys = (double *)malloc(sizeof(double) * 9 * (size_t)(nf > 0 ? nf : 1));
#pragma omp parallel
    {
        if (init) {
#pragma omp for schedule(static)
            for (int64_t i = 0; i < P; i++) { tri[i] = -1; t[i] = INFINITY; uv[2 * i] = 0.0f; uv[2 * i + 1] = 0.0f; }
        }
#pragma omp for schedule(static)
        for (int64_t f = 0; f < nf; f++) {
            double bx[4];
            int32_t *b = box + 4 * f;
            if (!face_bounds(V, F, f, cam, W, H, bx, polys + 9 * f) || bx[1] < -mg || bx[0] > W + mg || bx[3] < -mg ||
                bx[2] > H + mg) {
                b[0] = 1; b[1] = 0; b[2] = 1; b[3] = 0;    /* empty */
                continue;
            }
            /* the samples whose pixel centre x + ½ lies within the bounds widened by mg: a face
             * under a pixel wide is tested at one or two samples, not the nine a rounded-out box
             * of its pixels holds (rows the same) */
            double c0 = ceil(bx[0] - 0.5 - mg), c1 = floor(bx[1] - 0.5 + mg);
            double r0 = ceil(bx[2] - 0.5 - mg), r1 = floor(bx[3] - 0.5 + mg);
            if (c0 > c1 || r0 > r1) {
                b[0] = 1; b[1] = 0; b[2] = 1; b[3] = 0;    /* between sample centres: none */
                continue;
            }
            b[0] = (int32_t)(c0 < 0 ? 0 : c0);
            b[1] = (int32_t)(c1 > W - 1 ? W - 1 : c1);
            b[2] = (int32_t)(r0 < 0 ? 0 : r0);
            b[3] = (int32_t)(r1 > H - 1 ? H - 1 : r1);
        }
        /* bands of rows, each with the list of the faces that reach it (counting sort) */
#pragma omp single
        {
            int64_t *cnt = (int64_t *)calloc((size_t)nb + 1, sizeof(int64_t));
            for (int64_t f = 0; f < nf; f++) {
                const int32_t *b = box + 4 * f;
                if (b[0] > b[1] || b[2] > b[3]) continue;
                for (int k = b[2] / band; k <= b[3] / band; k++) cnt[k + 1]++;
            }
            for (int k = 0; k < nb; k++) cnt[k + 1] += cnt[k];
            band_off = (int64_t *)malloc(sizeof(int64_t) * ((size_t)nb + 1));
            for (int k = 0; k <= nb; k++) band_off[k] = cnt[k];
            band_faces = (int32_t *)malloc(sizeof(int32_t) * (size_t)(cnt[nb] > 0 ? cnt[nb] : 1));
            for (int64_t f = 0; f < nf; f++) {
                const int32_t *b = box + 4 * f;
                if (b[0] > b[1] || b[2] > b[3]) continue;
                for (int k = b[2] / band; k <= b[3] / band; k++) band_faces[cnt[k]++] = (int32_t)f;
            }
            free(cnt);
        }
#pragma omp for schedule(dynamic, 1)
        for (int bi = 0; bi < nb; bi++) {
            const int y0 = bi * band, y1 = (y0 + band < H ? y0 + band : H) - 1;
            for (int64_t fi = band_off[bi]; fi < band_off[bi + 1]; fi++) {
                const int64_t f = band_faces[fi];
                const int32_t *b = box + 4 * f;
                const float *A = V + 3 * (int64_t)F[3 * f], *B = V + 3 * (int64_t)F[3 * f + 1],
                            *C = V + 3 * (int64_t)F[3 * f + 2];
                const double e1x = (double)B[0] - A[0], e1y = (double)B[1] - A[1], e1z = (double)B[2] - A[2];
                const double e2x = (double)C[0] - A[0], e2y = (double)C[1] - A[1], e2z = (double)C[2] - A[2];
                const double sx = ex - A[0], sy = ey - A[1], sz = ez - A[2];
                /* Möller–Trumbore with the ray-independent cross products hoisted out of the loop:
                 * det = e1·(d×e2) = d·(e2×e1), u·det = s·(d×e2) = d·(e2×s), v·det = d·(s×e1),
                 * t·det = e2·(s×e1); a sample then costs three dot products and a division */
                const double qx = sy * e1z - sz * e1y, qy = sz * e1x - sx * e1z, qz = sx * e1y - sy * e1x;
                const double qe2 = qx * e2x + qy * e2y + qz * e2z;
                const double nx = e2y * e1z - e2z * e1y, ny = e2z * e1x - e2x * e1z, nz = e2x * e1y - e2y * e1x;
                const double ax = e2y * sz - e2z * sy, ay = e2z * sx - e2x * sz, az = e2x * sy - e2y * sx;
                const int ya = b[2] > y0 ? b[2] : y0, yb = b[3] < y1 ? b[3] : y1;
                const double *pg = polys + 9 * f;
                for (int y = ya; y <= yb; y++) {
                    /* the samples of row y lie within mg of its centre line y + ½, and a sample
                     * inside the polygon lies within the polygon's span on that slab */
                    double sa, sb;
                    if (!slab_span(pg, y + 0.5 - mg, y + 0.5 + mg, &sa, &sb)) continue;
                    const double c0 = ceil(sa - 0.5 - mg), c1 = floor(sb - 0.5 + mg);
                    const double xa_d = c0 > b[0] ? c0 : b[0], xb_d = c1 < b[1] ? c1 : b[1];
                    if (!(xa_d <= xb_d)) continue;            /* (compared in double: no overflow) */
                    const int xa = (int)xa_d, xb = (int)xb_d;
                    for (int x = xa; x <= xb; x++) {
                        int64_t row = ((int64_t)y * W + x) * S;
                        for (int s = 0; s < S; s++, row++) {
                            const float *d = dirs + 3 * row;
                            const double dx = d[0], dy = d[1], dz = d[2];
                            const double det = dx * nx + dy * ny + dz * nz;
                            /* one branch on all the tests (a face's few samples hit or miss at
                             * random: a branch per test mispredicted most of the time); det = 0
                             * gives u infinite or NaN, which every test rejects */
                            const double inv = 1.0 / det;
                            const double u = (dx * ax + dy * ay + dz * az) * inv;
                            const double v = (qx * dx + qy * dy + qz * dz) * inv;
                            const double tt = qe2 * inv;
                            const int hit = (u >= 0.0) & (u <= 1.0) & (v >= 0.0) & (u + v <= 1.0) & (tt > 0.0) &
                                            (tt < t[row]);
                            if (!hit) continue;
                            t[row] = (float)tt;
                            tri[row] = fbase + (int32_t)f;
                            uv[2 * row] = (float)u;
                            uv[2 * row + 1] = (float)v;
                        }
                    }
                }
            }
        }
    }
    free(band_off);
    free(band_faces);
    free(polys);
}
