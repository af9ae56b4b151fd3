/* Paint-to-BRDF kernels (inverse-brdf-modeling §3-4). NumPy references beside their Python
 * wrappers: glk_fit_transfer ↔ worker/fit/transfer.py transfer_numpy, glk_energy_rows ↔
 * worker/fit/basis.py energy_rows_at; tests/fit checks that they agree.
 *
 * Static functions s(ωi, ωo) (worker/core/brdf.py distribution_static):
 *   0 paper: F / (ci + co − ci co)                              (eq. 11)
 *   1 smith: F / ((ci + Λ(ci)) (co + Λ(co))), Λ(c) = √(α² + (1 − α²) c²)
 *            = F G1(ωi) G1(ωo) / (4 ci co) with GGX's separable Smith G1
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include "glint_common.h"

static inline double fit_static(int kind, double alpha, double f0, double ci, double co, double cd) {
    double m = 1.0 - cd; m = m < 0 ? 0 : (m > 1 ? 1 : m);
    double m2 = m * m;
    double F = f0 + (1.0 - f0) * m2 * m2 * m;
    if (kind == 1) {
        double a2 = alpha * alpha;
        return F / ((ci + sqrt(a2 + (1.0 - a2) * ci * ci)) * (co + sqrt(a2 + (1.0 - a2) * co * co)));
    }
    double den = ci + co - ci * co; if (den < 1e-12) den = 1e-12;
    return F / den;
}

/* ---------------------------------------------------------------------------------------
 * Walking one cut node down to the clusters to evaluate, with several refinement pairs (one
 * per basis level): a node of radius R at angle a from the mirror direction r is split when,
 * for any pair l, R > refine_r[l] and a < R + extent[l]; children inherit the parent's
 * visibility. With one pair this is the renderer's walk (shade.c refine_node). node_cs holds
 * (cos R, sin R) per tree node and ext_cs (cos e, sin e) per pair.
 */
typedef struct { int64_t stack[2 * 64]; int sp; } fit_walk;

static inline int64_t fit_walk_next(fit_walk *w, const int64_t *level_off, const float *node_dir,
                                    const float *node_radius, const float *node_cs, v3 r, int n_ref,
                                    const double *refine_r, const double *extent, const double *ext_cs) {
    while (w->sp) {
        int64_t s = w->stack[--w->sp];
        int h = (int)w->stack[--w->sp];
        int64_t idx = level_off[h] + (s >> h);
        if (h > 0) {
            double R = node_radius[idx], d = 2.0;
            int split = 0;
            for (int l = 0; l < n_ref && !split; l++) {
                if (R <= refine_r[l]) continue;
                if (R + extent[l] >= PI) { split = 1; break; }   /* every angle is within reach */
                if (d > 1.5) d = node_dir[3 * idx] * r.x + node_dir[3 * idx + 1] * r.y + node_dir[3 * idx + 2] * r.z;
                /* angle < R + e  ⟺  cos(angle) > cos R cos e − sin R sin e (no acos per node) */
                split = d > node_cs[2 * idx] * ext_cs[2 * l] - node_cs[2 * idx + 1] * ext_cs[2 * l + 1];
            }
            if (split) {
                int64_t half = (int64_t)1 << (h - 1);
                w->stack[w->sp++] = h - 1; w->stack[w->sp++] = s + half;
                w->stack[w->sp++] = h - 1; w->stack[w->sp++] = s;
                continue;
            }
        }
        return idx;
    }
    return -1;
}

static inline int fit_cube_cell(double x, double y, double z, int C) {
    double ax = fabs(x), ay = fabs(y), az = fabs(z), u, v, major;
    int face;
    if (az >= ax && az >= ay) { face = z > 0 ? 4 : 5; major = az; u = x; v = y; }
    else if (ax >= ay) { face = x > 0 ? 0 : 1; major = ax; u = y; v = z; }
    else { face = y > 0 ? 2 : 3; major = ay; u = x; v = z; }
    int iu = (int)((u / major + 1.0) * (C / 2)), iv = (int)((v / major + 1.0) * (C / 2));
    iu = iu < 0 ? 0 : (iu > C - 1 ? C - 1 : iu);
    iv = iv < 0 ? 0 : (iv > C - 1 ? C - 1 : iv);
    return face * C * C + iu * C + iv;
}

/* ---------------------------------------------------------------------------------------
 * Transfer functions of an SRBF basis at pixels (inverse-brdf-modeling eq. 21):
 *   T_j(x) = Σ_k l_k v_k s(ω_k, ω_o) G_j(h_k),   E(x) = Σ_k l_k v_k / π,
 *   G_j(h) = exp(−λ_j (1 − h·ξ_j)), zero when λ_j (1 − h·ξ_j) > xcut,
 * with v_k the barycentric blend of the three vertex cuts of the pixel's triangle and clusters
 * refined for every level of the basis. Speed: the three corners share the pixel's normal and
 * view, so equal clusters are merged before the basis loop (a per-thread node-weight array);
 * only the centres listed for the half vector's cube-map cell are tested (basis.py
 * kernel_tables); exp(−x) comes from a table over [0, xcut].
 * T is (3, P, J) float32 (channel-major, so each channel's rows are one matrix), E (P, 3).
 */
void glk_fit_transfer(
    int64_t P, const float *normals, const float *wo_dirs, const int32_t *verts, const float *bary,
    const int64_t *cut_off, const uint8_t *cut_h, const uint8_t *cut_q, const float *node_l,
    const float *node_w, const float *node_dir, const float *node_radius, const float *node_cs,
    const int64_t *level_off, int H, int n_ref, const double *refine_r, const double *extent, int J,
    double xcut, int static_kind, double static_alpha, double f0,
    int C, const int32_t *cell_off, const int32_t *cell_idx, const float *cell_cand, const float *gtab,
    int NG, float *T, float *E) {
    const int64_t n_nodes = level_off[H] + 1;
    double ext_cs[2 * 16];
    for (int l = 0; l < n_ref && l < 16; l++) { ext_cs[2 * l] = cos(extent[l]); ext_cs[2 * l + 1] = sin(extent[l]); }
    if (n_ref > 16) n_ref = 16;
#pragma omp parallel
    {
        fit_walk walk;
        /* single precision: each entry sums ~10³ positive terms (relative error ~1e-6) */
        float *acc = (float *)malloc(sizeof(float) * 3 * J);
        double *wsum = (double *)calloc(n_nodes, sizeof(double));
        int64_t cap = 4096, nt;
        int64_t *touched = (int64_t *)malloc(sizeof(int64_t) * cap);
        const float gscale = (float)((NG - 1) / xcut), fxcut = (float)xcut;
#pragma omp for schedule(dynamic, 8)
        for (int64_t p = 0; p < P; p++) {
            v3 n = mk(normals[3 * p], normals[3 * p + 1], normals[3 * p + 2]);
            v3 wo = facing_view(n, mk(wo_dirs[3 * p], wo_dirs[3 * p + 1], wo_dirs[3 * p + 2]));
            double e[3] = {0, 0, 0};
            memset(acc, 0, sizeof(float) * 3 * J);
            double co = dot(n, wo);
            nt = 0;
            if (co > 0) {
                v3 r = add(scl(n, 2.0 * co), scl(wo, -1.0));
                /* gather: blended visibility per (refined) cluster over the three corners */
                for (int corner = 0; corner < 3; corner++) {
                    int32_t vtx = verts[3 * p + corner];
                    double bw = bary[3 * p + corner];
                    if (vtx < 0 || bw == 0.0) continue;
                    int64_t c0 = cut_off[vtx], c1 = cut_off[vtx + 1];
                    int64_t start = 0;
                    for (int64_t m = c0; m < c1; m++) {
                        int h0 = cut_h[m];
                        int64_t s0 = start;
                        start += (int64_t)1 << h0;
                        if (cut_q[m] == 0) continue;
                        double q = cut_q[m] * (1.0 / 255.0) * bw;
                        walk.sp = 0; walk.stack[walk.sp++] = h0; walk.stack[walk.sp++] = s0;
                        for (int64_t idx; (idx = fit_walk_next(&walk, level_off, node_dir, node_radius, node_cs, r, n_ref, refine_r, extent, ext_cs)) >= 0;) {
                            if (wsum[idx] == 0.0) {
                                if (nt == cap) { cap *= 2; touched = (int64_t *)realloc(touched, sizeof(int64_t) * cap); }
                                touched[nt++] = idx;
                            }
                            wsum[idx] += q;
                        }
                    }
                }
                v3 t, bt; onb(n, &t, &bt);
                v3 wol = mk(dot(wo, t), dot(wo, bt), co);
                for (int64_t k = 0; k < nt; k++) {
                    int64_t idx = touched[k];
                    double q = wsum[idx];
                    wsum[idx] = 0.0;
                    const float *L = node_l + 3 * idx;
                    if (L[0] <= 0 && L[1] <= 0 && L[2] <= 0) continue;
                    v3 wi = mk(node_w[3 * idx], node_w[3 * idx + 1], node_w[3 * idx + 2]);
                    double ci = dot(wi, n);
                    /* a cluster straddling the horizon may have its centroid below it: its
                     * visibility already carries the cosine, so evaluate just above */
                    if (ci < 1e-3) { wi = nrm(add(wi, scl(n, 1e-3 - ci))); ci = dot(wi, n); }
                    double a0 = L[0] * q, a1 = L[1] * q, a2 = L[2] * q;
                    e[0] += a0; e[1] += a1; e[2] += a2;
                    v3 wil = mk(dot(wi, t), dot(wi, bt), ci);
                    v3 hl = nrm(add(wil, wol));
                    double sf = fit_static(static_kind, static_alpha, f0, ci, co, dot(wil, hl));
                    const float b0 = (float)(a0 * sf), b1 = (float)(a1 * sf), b2 = (float)(a2 * sf);
                    int cell = fit_cube_cell(hl.x, hl.y, hl.z, C);
                    /* the cell's candidates, packed (ξx, ξy, ξz, λ) in float: λ(1 − h·ξ) to ~5e-4 */
                    const float *cc = cell_cand + 4 * (int64_t)cell_off[cell];
                    const int32_t *jj = cell_idx + cell_off[cell];
                    const int nc = cell_off[cell + 1] - cell_off[cell];
                    const float hx = (float)hl.x, hy = (float)hl.y, hz = (float)hl.z;
                    for (int c = 0; c < nc; c++) {
                        float x = cc[4 * c + 3] * (1.0f - (cc[4 * c] * hx + cc[4 * c + 1] * hy + cc[4 * c + 2] * hz));
                        if (x >= fxcut) continue;
                        x *= gscale;
                        int i0 = (int)x;
                        if (i0 > NG - 2) i0 = NG - 2;
                        float g = gtab[i0] + (gtab[i0 + 1] - gtab[i0]) * (x - (float)i0);
                        float *A = acc + 3 * jj[c];
                        A[0] += b0 * g; A[1] += b1 * g; A[2] += b2 * g;
                    }
                }
            }
            for (int c = 0; c < 3; c++) {
                float *Tp = T + ((int64_t)c * P + p) * J;
                for (int j = 0; j < J; j++) Tp[j] = acc[3 * j + c];
            }
            E[3 * p] = (float)(e[0] * INV_PI); E[3 * p + 1] = (float)(e[1] * INV_PI); E[3 * p + 2] = (float)(e[2] * INV_PI);
        }
        free(acc); free(wsum); free(touched);
    }
}

/* ---------------------------------------------------------------------------------------
 * Energy rows (inverse-brdf-modeling eq. 15 with eq. 13's cosine): the directional albedo of
 * each basis function at K outgoing directions,
 *   g_j(ωo) = ∫ G_j(h) s(ωi, ωo) cosθi 4(ωo·h) dωh,   ωi = reflect(ωo, h),
 * in polar coordinates around ξ_j: u = 1 − h·ξ_j, t = λ_j u, with nt Gauss-Legendre nodes
 * tn (on [0, 1], weights tw) scaled to [0, tcut_j] and nphi azimuths (basis.py energy_rows_at).
 * out is (K, J) float64.
 */
void glk_energy_rows(int64_t K, const double *wo, int J, const double *centers, const double *lam,
                     double xcut, int static_kind, double static_alpha, double f0, int nt,
                     const double *tn, const double *tw, int nphi, double *out) {
#pragma omp parallel
    {
        double *hx = (double *)malloc(sizeof(double) * 4 * nt * nphi);
#pragma omp for schedule(dynamic, 1)
        for (int j = 0; j < J; j++) {
            v3 xi = mk(centers[3 * j], centers[3 * j + 1], centers[3 * j + 2]);
            v3 a = fabs(xi.z) < 0.9 ? mk(0, 0, 1) : mk(1, 0, 0);
            v3 e1 = nrm(mk(a.y * xi.z - a.z * xi.y, a.z * xi.x - a.x * xi.z, a.x * xi.y - a.y * xi.x));
            v3 e2 = mk(xi.y * e1.z - xi.z * e1.y, xi.z * e1.x - xi.x * e1.z, xi.x * e1.y - xi.y * e1.x);
            double L = lam[j], tcut = xcut < 2.0 * L ? xcut : 2.0 * L;
            int n = 0;
            for (int it = 0; it < nt; it++) {
                double t = tn[it] * tcut, u = t / L;
                double w = tw[it] * tcut * exp(-t) / L * (2.0 * PI / nphi);
                double cz = 1.0 - u, sz = sqrt(fmax(u * (2.0 - u), 0.0));
                for (int ip = 0; ip < nphi; ip++) {
                    double ph = (ip + 0.5) * (2.0 * PI / nphi);
                    double cx = sz * cos(ph), cy = sz * sin(ph);
                    hx[4 * n] = cx * e1.x + cy * e2.x + cz * xi.x;
                    hx[4 * n + 1] = cx * e1.y + cy * e2.y + cz * xi.y;
                    hx[4 * n + 2] = cx * e1.z + cy * e2.z + cz * xi.z;
                    hx[4 * n + 3] = w;
                    n++;
                }
            }
            for (int64_t k = 0; k < K; k++) {
                double ox = wo[3 * k], oy = wo[3 * k + 1], oz = wo[3 * k + 2], s = 0.0;
                for (int i = 0; i < n; i++) {
                    double od = ox * hx[4 * i] + oy * hx[4 * i + 1] + oz * hx[4 * i + 2];
                    if (od <= 0) continue;
                    double ci = 2.0 * od * hx[4 * i + 2] - oz;
                    if (ci <= 0) continue;
                    s += hx[4 * i + 3] * fit_static(static_kind, static_alpha, f0, ci, oz, od) * ci * 4.0 * od;
                }
                out[k * J + j] = s;
            }
        }
        free(hx);
    }
}
