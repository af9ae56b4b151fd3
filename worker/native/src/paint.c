/* Car-paint kernels (cacad-cosine-lobes §5): prefiltering an equirectangular map with a
 * normalised cosine lobe, and shading pixels by summing prefiltered maps at the reflected view
 * direction. NumPy references: worker/paint/prefilter.py (prefilter_numpy) and
 * worker/paint/render.py (shade_numpy); tests/paint/test_native_paint.py checks they agree.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include "glint_common.h"

#define GLP_SUPPORT 1e-3

/* out[i, l] = Σ_j Σ_d k_ij[d] img[j, l + d] / Σ_j Σ_d k_ij[d],  k_ij[d] = max(0, ω_il·ω_j,l+d)^E · Ω_j
 * over input rows j and column offsets d inside the lobe's support (cos ≥ SUPPORT^(1/E)).
 * The kernel of a row pair depends only on d, so it is tabulated once per pair. */
void glp_prefilter(const float *img, int H, int W, double E, float *out) {
    double *th = (double *)malloc(sizeof(double) * H), *sa = (double *)malloc(sizeof(double) * H);
    for (int i = 0; i < H; i++) {
        double a = PI * i / H, b = PI * (i + 1) / H;
        th[i] = 0.5 * (a + b);
        sa[i] = (2 * PI / W) * (cos(a) - cos(b));
    }
    double cmin = pow(GLP_SUPPORT, 1.0 / (E > 1e-6 ? E : 1e-6));
    double rmax = acos(cmin);
#pragma omp parallel
    {
        double *k = (double *)malloc(sizeof(double) * W);
        double *acc = (double *)malloc(sizeof(double) * 3 * W);
        float *ext = (float *)malloc(sizeof(float) * 3 * 2 * W);
        float *racc = (float *)malloc(sizeof(float) * 3 * W);
#pragma omp for schedule(dynamic, 1)
        for (int i = 0; i < H; i++) {
            memset(acc, 0, sizeof(double) * 3 * W);
            double norm = 0, si = sin(th[i]), ci = cos(th[i]);
            for (int j = 0; j < H; j++) {
                if (fabs(th[j] - th[i]) > rmax + PI / H) continue;
                double ss = si * sin(th[j]), cc = ci * cos(th[j]);
                /* taps d = 0, ±1, … while inside the support (c decreases with |d| up to W/2) */
                int D = -1;
                for (int d = 0; d <= W / 2; d++) {
                    double c = ss * cos(2 * PI * d / W) + cc;
                    if (c < cmin) break;
                    k[d] = pow(c > 0 ? c : 0, E) * sa[j];
                    D = d;
                }
                if (D < 0) continue;
                const float *row = img + (int64_t)j * W * 3;
                int full = (2 * D + 1 >= W);
                int dlo = full ? -(W / 2) + (W % 2 == 0 ? 1 : 0) : -D, dhi = full ? W / 2 : D;
                int pad = -dlo > dhi ? -dlo : dhi;
                /* the row with `pad` columns wrapped around on both sides: the tap loop is then a
                 * contiguous multiply-add over the interleaved RGB row (vectorised) */
                for (int c = -pad; c < W + pad; c++) {
                    int cc = ((c % W) + W) % W;
                    ext[3 * (c + pad)] = row[3 * cc]; ext[3 * (c + pad) + 1] = row[3 * cc + 1];
                    ext[3 * (c + pad) + 2] = row[3 * cc + 2];
                }
                /* symmetric taps: k[0]·row[l] + Σ_{d>0} k[d]·(row[l+d] + row[l−d]); float
                 * accumulation per row pair (≤ W taps), double across row pairs */
                const float *mid = ext + 3 * pad;
                float k0 = (float)k[0];
                for (int l = 0; l < 3 * W; l++) racc[l] = k0 * mid[l];
                norm += k[0];
                for (int d = 1; d <= dhi; d++) {
                    int dd = d;
                    int both = (-d >= dlo);
                    float kk = (float)k[dd];
                    const float *sp = mid + 3 * d, *sm = mid - 3 * d;
                    if (both) {
                        norm += 2 * k[dd];
                        for (int l = 0; l < 3 * W; l++) racc[l] += kk * (sp[l] + sm[l]);
                    } else {
                        norm += k[dd];
                        for (int l = 0; l < 3 * W; l++) racc[l] += kk * sp[l];
                    }
                }
                for (int l = 0; l < 3 * W; l++) acc[l] += racc[l];
            }
            float *o = out + (int64_t)i * W * 3;
            for (int l = 0; l < 3 * W; l++) o[l] = norm > 0 ? (float)(acc[l] / norm) : img[(int64_t)i * W * 3 + l];
        }
        free(k); free(acc); free(ext); free(racc);
    }
    free(th); free(sa);
}

/* atan2 by a minimax polynomial of atan on [0, 1] (|error| < 2e-6 rad, a 3000th of a texel
 * of a 1K map); libm's atan2 and acos were a third of the shading time. */
static inline double glp_atan2(double y, double x) {
    double ax = fabs(x), ay = fabs(y);
    double mx = ax > ay ? ax : ay, mn = ax > ay ? ay : ax;
    if (mx == 0) return 0;
    double a = mn / mx, s = a * a;
    double r = ((((((-0.0040540580 * s + 0.0218612288) * s - 0.0559098861) * s + 0.0964200441) * s
                  - 0.1390853351) * s + 0.1994653599) * s - 0.3332985605) * s * a + a;
    if (ay > ax) r = 1.5707963267948966 - r;
    if (x < 0) r = PI - r;
    return y < 0 ? -r : r;
}

/* Equirectangular coordinates of a world direction (docs/design/conventions.md), the environment rotated by
 * rot about +Y: u in [0, 1), v in [0, 1]. Computed once per direction, shared by every map. */
static inline void glp_uv(v3 d, double rot, double *u, double *v) {
    double uu = glp_atan2(d.x, -d.z) / (2 * PI) + rot / (2 * PI);
    *u = uu - floor(uu);
    double y = fmax(-1.0, fmin(1.0, d.y));
    *v = glp_atan2(sqrt(fmax(0.0, 1.0 - y * y)), y) / PI;      /* acos(y) */
}

/* Bilinear lookup of an (Hm, Wm, 3) map at (u, v), as glk_env_lookup. */
static inline void glp_bilerp(const float *map, int Hm, int Wm, double u, double v, double *rgb) {
    double fx = u * Wm - 0.5, fy = v * Hm - 0.5;
    int x0 = (int)floor(fx), y0 = (int)floor(fy);
    double ax = fx - x0, ay = fy - y0;
    int x1 = x0 + 1, y1 = y0 + 1;
    x0 = x0 < 0 ? x0 + Wm : x0; x1 = x1 >= Wm ? x1 - Wm : x1;
    y0 = y0 < 0 ? 0 : (y0 >= Hm ? Hm - 1 : y0); y1 = y1 < 0 ? 0 : (y1 >= Hm ? Hm - 1 : y1);
    const float *p00 = map + ((int64_t)y0 * Wm + x0) * 3, *p01 = map + ((int64_t)y0 * Wm + x1) * 3;
    const float *p10 = map + ((int64_t)y1 * Wm + x0) * 3, *p11 = map + ((int64_t)y1 * Wm + x1) * 3;
    for (int k = 0; k < 3; k++) {
        double a = p00[k] * (1 - ax) + p01[k] * ax;
        double b = p10[k] * (1 - ax) + p11[k] * ax;
        rgb[k] = a * (1 - ay) + b * ay;
    }
}

/* The same for a 9-channel vector map ((x, y, z) × RGB). */
static inline void glp_bilerp9(const float *map, int Hm, int Wm, double u, double v, double *out) {
    double fx = u * Wm - 0.5, fy = v * Hm - 0.5;
    int x0 = (int)floor(fx), y0 = (int)floor(fy);
    double ax = fx - x0, ay = fy - y0;
    int x1 = x0 + 1, y1 = y0 + 1;
    x0 = x0 < 0 ? x0 + Wm : x0; x1 = x1 >= Wm ? x1 - Wm : x1;
    y0 = y0 < 0 ? 0 : (y0 >= Hm ? Hm - 1 : y0); y1 = y1 < 0 ? 0 : (y1 >= Hm ? Hm - 1 : y1);
    const float *p00 = map + ((int64_t)y0 * Wm + x0) * 9, *p01 = map + ((int64_t)y0 * Wm + x1) * 9;
    const float *p10 = map + ((int64_t)y1 * Wm + x0) * 9, *p11 = map + ((int64_t)y1 * Wm + x1) * 9;
    for (int k = 0; k < 9; k++)
        out[k] = (p00[k] * (1 - ax) + p01[k] * ax) * (1 - ay) + (p10[k] * (1 - ax) + p11[k] * ax) * ay;
}

/* Background: the (rotated, scaled) map at precomputed unrotated (u, v) per pixel (P, 2),
 * written to out[dst[p]] (dst NULL: out[p]), so a frame needs no scatter afterwards. */
void glp_background(int64_t P, const float *uv, const float *map, int Hm, int Wm, double rot,
                    double intensity, const int64_t *dst, float *out) {
#pragma omp parallel for schedule(static)
    for (int64_t p = 0; p < P; p++) {
        double u = uv[2 * p] + rot / (2 * PI), rgb[3];
        u -= floor(u);
        glp_bilerp(map, Hm, Wm, u, uv[2 * p + 1], rgb);
        int64_t o = dst ? dst[p] : p;
        for (int k = 0; k < 3; k++) out[3 * o + k] = (float)(intensity * rgb[k]);
    }
}

/* Real SH basis up to l = 2 (same order and constants as worker/paint/visibility.py sh9). */
static inline void glp_sh9(v3 d, double *y) {
    y[0] = 0.28209479177387814;
    y[1] = 0.4886025119029199 * d.y; y[2] = 0.4886025119029199 * d.z; y[3] = 0.4886025119029199 * d.x;
    y[4] = 1.0925484305920792 * d.x * d.y; y[5] = 1.0925484305920792 * d.y * d.z;
    y[6] = 0.31539156525252005 * (3 * d.z * d.z - 1);
    y[7] = 1.0925484305920792 * d.x * d.z; y[8] = 0.5462742152960396 * (d.x * d.x - d.y * d.y);
}

/* Lobe-and-cosine-weighted visibility: Σ k̂_l Ṽ_lm Y_lm(D) / Σ k̂_l U_lm Y_lm(D), clamped to [0, 1]. */
static inline double glp_vis(const float *vsh, const double *y, const float *zon) {
    double num = 0, den = 0;
    for (int i = 0; i < 9; i++) {
        double z = zon[i == 0 ? 0 : (i < 4 ? 1 : 2)];
        num += z * vsh[i] * y[i];
        den += z * vsh[9 + i] * y[i];
    }
    if (den <= 1e-6) return 1.0;
    double r = num / den;
    return r < 0 ? 0 : (r > 1 ? 1 : r);
}

/* Per pixel (cacad eq. 7-9 in Glint's reciprocal lobes form):
 *   L = albedo · P_1(N) · V_0 + Σ_i (g_i Fg + dd_i Fd) · c_i(μ) · P_Ei(R) · V_i,   R = 2(N·V)N − V
 * mat table row: albedo (3), then per lobe g, dd_r, dd_g, dd_b. mode 0: c_i = A_Ei(μ) from the
 * tables (directional albedo of the clipped lobe); mode 1 (the paper): c_i = (E+2)/(E+1)·μ;
 * mode 2: as 0, but lobes with a vector map use (E+2)/(E+1)·N'·I(R) + (A(μ) − μ)·P(R), N' the
 * normal in the rotated map's frame.
 * Fresnel (flag): Fg = F(μ)/F0, Fd = (1 − F(μ))/(1 − F0), Schlick's F. */
void glp_shade(int64_t P, const float *normals, const float *views, const int32_t *mat_of,
               const float *mats, int n_mat, int M, const float *maps, const int64_t *offs,
               const int32_t *hs, const int32_t *ws, const float *vmaps, const int64_t *voffs,
               const float *tables, int T, int mode,
               const float *expo, int fresnel, double f0, const float *vsh, const float *zonal,
               double rot, double intensity, const int64_t *dst, float *out) {
    (void)n_mat;
    const int stride = 3 + 4 * M;
#pragma omp parallel for schedule(static)
    for (int64_t p = 0; p < P; p++) {
        int m = mat_of[p];
        int64_t o = dst ? dst[p] : p;
        if (m < 0) { out[3 * o] = out[3 * o + 1] = out[3 * o + 2] = 0; continue; }
        const float *w = mats + (int64_t)m * stride;
        v3 n = mk(normals[3 * p], normals[3 * p + 1], normals[3 * p + 2]);
        v3 v = mk(views[3 * p], views[3 * p + 1], views[3 * p + 2]);
        double nv = dot(n, v);
        v3 r = nrm(add(scl(n, 2 * nv), scl(v, -1.0)));
        double mu = nv > 0 ? (nv < 1 ? nv : 1) : 0;
        double fg = 1, fd = 1;
        if (fresnel) {
            double q = 1 - mu, q5 = q * q * q * q * q;
            double F = f0 + (1 - f0) * q5;
            fg = F / f0; fd = (1 - F) / (1 - f0);
        }
        double yn[9], yr[9];
        const float *vp = vsh ? vsh + p * 18 : NULL;
        if (vp) { glp_sh9(n, yn); glp_sh9(r, yr); }
        double rgb[3], acc[3], un, vn, ur, vr;
        glp_uv(n, rot, &un, &vn);
        glp_uv(r, rot, &ur, &vr);
        glp_bilerp(maps + offs[0], hs[0], ws[0], un, vn, rgb);
        double v0 = vp ? glp_vis(vp, yn, zonal) : 1.0;
        for (int k = 0; k < 3; k++) acc[k] = w[k] * rgb[k] * v0;
        double cr = cos(rot), sr = sin(rot);
        double nx = n.x * cr - n.z * sr, nz = n.z * cr + n.x * sr;   /* normal in the map's frame */
        double x = mu * (T - 1);
        int t0 = (int)x; if (t0 > T - 2) t0 = T - 2;
        double ft = x - t0;
        for (int i = 0; i < M; i++) {
            const float *li = w + 3 + 4 * i;
            double g = li[0] * fg;
            if (g == 0 && li[1] == 0 && li[2] == 0 && li[3] == 0) continue;
            double e = expo[i + 1];
            double a = tables[(i + 1) * T + t0] * (1 - ft) + tables[(i + 1) * T + t0 + 1] * ft;
            double val[3];
            glp_bilerp(maps + offs[i + 1], hs[i + 1], ws[i + 1], ur, vr, rgb);
            if (mode == 1) {
                double c = (e + 2) / (e + 1) * mu;
                for (int k = 0; k < 3; k++) val[k] = c * rgb[k];
            } else if (mode == 2 && voffs[i + 1] >= 0) {
                double iv[9];
                glp_bilerp9(vmaps + voffs[i + 1], hs[i + 1], ws[i + 1], ur, vr, iv);
                double s = (e + 2) / (e + 1);
                for (int k = 0; k < 3; k++)
                    val[k] = s * (nx * iv[k] + n.y * iv[3 + k] + nz * iv[6 + k]) + (a - mu) * rgb[k];
            } else {
                for (int k = 0; k < 3; k++) val[k] = a * rgb[k];
            }
            double vi = vp ? glp_vis(vp, yr, zonal + 3 * (i + 1)) : 1.0;
            for (int k = 0; k < 3; k++) acc[k] += (g + li[1 + k] * fd) * val[k] * vi;
        }
        for (int k = 0; k < 3; k++) out[3 * o + k] = (float)(intensity * acc[k]);
    }
}
