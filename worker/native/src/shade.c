/* Shading at points from visibility cuts: the C kernel of worker/core/render.py
 * shade_points_numpy (its NumPy reference; tests/core/test_native.py and
 * tests/models/test_conformance.py check that they agree).
 *
 * cyber-worlds eq. 3, inverse-brdf-modeling eq. 22:   B = Σ_k l_k v_k f_r(ω_k, ω_o)
 * over point p's cut (cut index cut_of[p]). Per tree node and per light change, node8 holds the
 * radiance l_k and the light-weighted centroid direction ω_k (lighting.c glk_light_tables).
 * Nodes wider than the material's refine radius whose angle to the mirror direction is below
 * their radius plus the material's extent (PackedBRDF) are refined: their children inherit the
 * parent's visibility but have their own light and direction, so glossy highlights stay sharp
 * (docs/design/conventions.md, precomputed data).
 *
 * How it is fast: each point first lists its clusters (node index, visibility) in a
 * scalar pass over the height-encoded cut, then evaluates the BRDF over that list eight
 * clusters at a time (AVX2/FMA, node records of 8 floats gathered by index), when the CPU has
 * AVX2 and FMA (checked once at run time; glk_shade_simd forces the scalar path for tests).
 * Every model's albedo/π part is the same for every cluster, so the vector paths sum
 * E = Σ l_k v_k once and add albedo/π·E: the Lambert path needs no directions at all. GGX's
 * D·G1(ωi)/cosθi is one division per eight clusters (the half vector stays unnormalised:
 * D = α²|h|⁴ / (π (α² h_n² + h_t²)²), and G1(ωi)/cosθi = 2 / (cosθi + √(cos²θi (1−α²) + α²))).
 * Cosine lobes (paints) run four clusters at a time in double precision (an exponent of 10⁴
 * needs it): one log per cluster, one exp per lobe (sum_lobes).
 * Blinn-Phong and Ashikhmin-Shirley likewise (sum_half: a pow of the half vector's cosine).
 * The scalar path evaluates f exactly as the reference does, for CPUs without AVX2 and for
 * the tests.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#if defined(__x86_64__)
#include <immintrin.h>
#define GLK_X86 1
#endif
#include "glint_common.h"
#include "brdf_kernels.h"

/* ---------------------------------------------------------------------------------------
 * BRDF evaluation in the shared packed form (worker/models: PackedBRDF.eval), scalar.
 */
static inline double ggx_G1(double c, double ch, double a) {
    if (c * ch <= 0) return 0.0;
    double c2 = c * c; if (c2 < 1e-20) c2 = 1e-20;
    double t2 = (1.0 - c2) / c2; if (t2 < 0) t2 = 0;
    return 2.0 / (1.0 + sqrt(1.0 + a * a * t2));
}

/* p(h) table in hemi-octahedral coordinates (worker/models/base.py octa_uv, table_lookup):
 * bilinear over TABLE_N × TABLE_N samples, the three channels at once. */
static inline void table_lookup3(const float *tab, v3 hl, double *out) {
    double s = fabs(hl.x) + fabs(hl.y) + (hl.z > 0 ? hl.z : 0.0);
    if (s < 1e-30) s = 1e-30;
    double px = hl.x / s, py = hl.y / s;
    double fu = (px + py + 1.0) * (0.5 * (TABLE_N - 1)), fv = (px - py + 1.0) * (0.5 * (TABLE_N - 1));
    fu = fu < 0 ? 0 : (fu > TABLE_N - 1 ? TABLE_N - 1 : fu);
    fv = fv < 0 ? 0 : (fv > TABLE_N - 1 ? TABLE_N - 1 : fv);
    int i0 = (int)fu; if (i0 > TABLE_N - 2) i0 = TABLE_N - 2;
    int j0 = (int)fv; if (j0 > TABLE_N - 2) j0 = TABLE_N - 2;
    double a = fu - i0, b = fv - j0;
    const float *r0 = tab + ((int64_t)i0 * TABLE_N + j0) * 3, *r1 = r0 + TABLE_N * 3;
    for (int c = 0; c < 3; c++) {
        double t0 = r0[c] * (1 - b) + r0[3 + c] * b;
        double t1 = r1[c] * (1 - b) + r1[3 + c] * b;
        out[c] = t0 * (1 - a) + t1 * a;
    }
}

/* wi, wo, n, t, b world-space unit vectors; writes f (1/sr) to out[3]. gpo: GGX's per-point
 * factor G1(ωo)/(4 cosθo). */
static inline void brdf_eval(int kind, const float *p, const float *tab, v3 wi, v3 wo, v3 n,
                             v3 t, v3 bt, double gpo, double *out) {
    double ci = dot(wi, n), co = dot(wo, n);
    out[0] = out[1] = out[2] = 0.0;
    if (ci <= 0 || co <= 0) return;
    out[0] = p[0] * INV_PI; out[1] = p[1] * INV_PI; out[2] = p[2] * INV_PI;
    if (kind == K_LAMBERT) return;
    if (kind == K_LOBES) {
        /* cosine lobes about the mirror direction: (e+2)/(2π)·(ωr·ωi)^e per lobe. One log for
         * all lobes, then one exp each (a pow per lobe cost most of a paint's still); a lobe
         * below 1e-30 of its peak adds nothing a float image keeps */
        double rv = 2.0 * ci * co - dot(wi, wo);
        if (rv <= 0) return;
        double lr = rv < 1 ? log(rv) : 0.0;
        int m = (int)p[3];
        for (int k = 0; k < m; k++) {
            double e = p[4 + 4 * k], x = e * lr;
            if (x < -69.0) continue;
            double s = (e + 2.0) / (2.0 * PI) * exp(x);
            out[0] += s * p[5 + 4 * k]; out[1] += s * p[6 + 4 * k]; out[2] += s * p[7 + 4 * k];
        }
        return;
    }
    v3 h = nrm(add(wi, wo));
    double chh = dot(h, n), cd = dot(wi, h);
    if (kind == K_GGX) {
        /* D(h)·G1(ωi)·[G1(ωo)/(4 cosθo)] / cosθi; the bracket is per point (gpo) */
        double a = p[6], a2 = a * a;
        double c2 = chh > 0 ? chh * chh : 0.0;
        double den = c2 * (a2 - 1.0) + 1.0;
        double D = chh > 0 ? a2 / (PI * den * den) : 0.0;
        double s = D * ggx_G1(ci, cd, a) / ci * gpo;
        out[0] += s * p[3]; out[1] += s * p[4]; out[2] += s * p[5];
    } else if (kind == K_BLINN) {
        double e = p[6];
        double s = (e + 8.0) / (8.0 * PI) * pow(chh > 0 ? (chh < 1 ? chh : 1) : 0, e);
        out[0] += s * p[3]; out[1] += s * p[4]; out[2] += s * p[5];
    } else if (kind == K_AS) {
        /* Ashikhmin-Shirley (models/ashikhmin_shirley.py): p[3], p[4] = n_u, n_v about the
         * point's tangent frame (t, bt); p[5..7] = F0 */
        double hx = dot(h, t), hy = dot(h, bt), s2 = hx * hx + hy * hy;
        double cos2 = s2 > 1e-24 ? hx * hx / s2 : 1.0;
        double e = p[3] * cos2 + p[4] * (1.0 - cos2);
        double c = chh < 1e-12 ? 1e-12 : (chh > 1.0 ? 1.0 : chh);
        double hd = cd > 1e-12 ? cd : 1e-12, mx = ci > co ? ci : co;
        double f = sqrt(((double)p[3] + 1.0) * ((double)p[4] + 1.0)) / (8.0 * PI) * exp(e * log(c)) / (hd * mx);
        double m = 1.0 - cd; m = m < 0 ? 0 : (m > 1 ? 1 : m);
        double m5 = m * m; m5 = m5 * m5 * m;
        for (int k = 0; k < 3; k++) out[k] += f * (p[5 + k] + (1.0 - p[5 + k]) * m5);
    } else if (kind == K_TABLE) {
        /* p(h)·s(ωi, ωo); p[3] = F0, p[4] = static (0 paper, 1 smith), p[5] = its α
         * (worker/models/table.py distribution_static) */
        v3 hl = mk(dot(h, t), dot(h, bt), chh);
        double m = 1.0 - cd; m = m < 0 ? 0 : (m > 1 ? 1 : m);
        double m2 = m * m;
        double F = p[3] + (1.0 - p[3]) * m2 * m2 * m;
        double s;
        if (p[4] > 0.5) {
            double a2 = (double)p[5] * p[5];
            s = F / ((ci + sqrt(a2 + (1.0 - a2) * ci * ci)) * (co + sqrt(a2 + (1.0 - a2) * co * co)));
        } else {
            double den = ci + co - ci * co; if (den < 1e-12) den = 1e-12;
            s = F / den;
        }
        double pt[3];
        table_lookup3(tab, hl, pt);
        out[0] += s * pt[0]; out[1] += s * pt[1]; out[2] += s * pt[2];
    }
}

/* ---------------------------------------------------------------------------------------
 * The cluster walk.
 */
/* What a point's cluster walk needs to split nodes about its mirror direction r: the tree's
 * level offsets, node directions, radii R and (cos R, sin R), the material's refine radius and
 * extent e with (cos e, sin e). The cone test angle < R + e is r·dir > cos R cos e − sin R sin e
 * for R + e < π (always true beyond): no acos or cos per node. A per-node libm cos() here cost
 * more than the shading itself for a fitted srbf (refine radius ~0.03 rad: every cut entry is
 * tested), 80 of 122 CPU ms on the demo chair. */
typedef struct {
    const int64_t *lev;
    const float *node_radius, *geo;   /* geo (2N−1, 8): cos R, sin R, dir xyz, R, 0, 0 */
    v3 r;
    double refine_r, extent, ce, se;
} refine_ctx;

static inline refine_ctx make_ctx(const int64_t *lev, const float *node_radius, const float *geo, v3 r,
                                  double refine_r, double extent) {
    refine_ctx c = {lev, node_radius, geo, r, refine_r, extent, cos(extent), sin(extent)};
    return c;
}

/* whether node id (radius R > refine_r) is split: its cone reaches within the extent of r */
static inline int cone_reaches(const refine_ctx *c, int64_t id) {
    const float *g = c->geo + 8 * id;
    double R = g[5];
    if (R + c->extent >= PI) return 1;
    double d = g[2] * c->r.x + g[3] * c->r.y + g[4] * c->r.z;
    return d > g[0] * c->ce - g[1] * c->se;
}

/* refine_node with the children's visibility written as q8 to qv, or (qv NULL) as the float qf to
 * qfo: a blended cut's visibilities are not multiples of 1/255 (glk_shade_blend) */
static int64_t refine_node_q(int h0, int64_t s0, unsigned q8, float qf, const refine_ctx *c,
                             int32_t *idx, uint8_t *qv, float *qfo, int64_t n) {
    int64_t st[2 * 64];
    int sp = 0;
    st[sp++] = h0; st[sp++] = s0;
    while (sp) {
        int64_t s = st[--sp];
        int h = (int)st[--sp];
        int64_t id = c->lev[h] + (s >> h);
        if (h > 0 && c->geo[8 * id + 5] > c->refine_r && cone_reaches(c, id)) {
            int64_t half = (int64_t)1 << (h - 1);   /* right child first: the left pops first */
            st[sp++] = h - 1; st[sp++] = s + half;
            st[sp++] = h - 1; st[sp++] = s;
            continue;
        }
        idx[n] = (int32_t)id;
        if (qv) qv[n] = (uint8_t)q8; else qfo[n] = qf;
        n++;
    }
    return n;
}

static int64_t refine_node(int h0, int64_t s0, unsigned q8, const refine_ctx *c, int32_t *idx, uint8_t *qv,
                           int64_t n) {
    return refine_node_q(h0, s0, q8, 0.0f, c, idx, qv, NULL, n);
}

/* The clusters a point shades: its cut's nodes with non-zero visibility, in order, where a
 * node wider than refine_r is split while its angle to the mirror direction r is below its
 * radius plus the extent (angle < R + e  ⇔  r·dir > cos(R + e) for R + e < π, so no acos);
 * children inherit the parent's visibility. Writes node indices and quantised visibilities
 * (v = q/255); returns their number (at most 2^H: the clusters partition the leaves).
 * hr: the lowest level with a node wider than refine_r (no node below it is ever split). */
static int64_t collect(int64_t c0, int64_t c1, const uint8_t *cut_h, const uint8_t *cut_q, const refine_ctx *c,
                       int hr, int32_t *idx, uint8_t *qv) {
    int64_t n = 0, start = 0;
    for (int64_t m = c0; m < c1; m++) {
        int h = cut_h[m];
        unsigned q8 = cut_q[m];
        int64_t id = c->lev[h] + (start >> h);
        if (__builtin_expect(h >= hr, 0) && q8 && c->node_radius[id] > c->refine_r) {
            n = refine_node(h, start, q8, c, idx, qv, n);
        } else {
            /* branch-free: written always, kept when visible (occluded nodes are common and random) */
            idx[n] = (int32_t)id; qv[n] = (uint8_t)q8;
            n += q8 != 0;
        }
        start += (int64_t)1 << h;
    }
    return n;
}

/* A face's three vertex cuts merged (merge_cuts), per node of their common refinement: height
 * uh, first leaf us, tree node uid, whether the face's material may split it about a mirror
 * direction uf (h ≥ hr and radius > refine radius), and the three cuts' visibilities there
 * q0, q1, q2 (q/255). Arrays of cap entries, grown as needed (one per thread). */
typedef struct {
    int64_t cap;
    uint8_t *uh, *uf;
    int64_t *us;
    int32_t *uid;
    float *q0, *q1, *q2;
} merged_cuts;

static void merged_reserve(merged_cuts *m, int64_t need) {
    if (need <= m->cap) return;
    m->cap = need;
    m->uh = (uint8_t *)realloc(m->uh, need);
    m->uf = (uint8_t *)realloc(m->uf, need);
    m->us = (int64_t *)realloc(m->us, sizeof(int64_t) * need);
    m->uid = (int32_t *)realloc(m->uid, sizeof(int32_t) * need);
    m->q0 = (float *)realloc(m->q0, sizeof(float) * need);
    m->q1 = (float *)realloc(m->q1, sizeof(float) * need);
    m->q2 = (float *)realloc(m->q2, sizeof(float) * need);
}

static void merged_free(merged_cuts *m) {
    free(m->uh); free(m->uf); free(m->us); free(m->uid); free(m->q0); free(m->q1); free(m->q2);
}

/* The common refinement of a face's three vertex cuts (c: their first entries), walked in
 * leaf order (core/render.py blend_cut_entries is the reference): at each leaf position every
 * cut has one entry covering it; the finest of the three starts there and is the union's
 * node, carrying the three cuts' visibilities there (a coarser cut's entry gives its
 * visibility to each of its parts). Returns the number of nodes (≤ the three cuts' lengths
 * summed; m must hold that many). Made once per face: every pixel of the face blends the same
 * list with its own weights (blend_list). */
static int64_t merge_cuts(const int64_t c[3], const uint8_t *cut_h, const uint8_t *cut_q, int H, const int64_t *lev,
                          const float *node_radius, double refine_r, int hr, merged_cuts *mc) {
    const int64_t total = (int64_t)1 << H;
    const float k = 1.0f / 255.0f;
    /* locals, not mc's fields: the loop is one dependency chain (the next node's height needs
     * this one's end), so every spill and every mispredicted branch is on it. A cut advances
     * when its node ends here: a data-dependent branch, as a select (the dragon's 12,855
     * refined pixels at 640×480: blend 22.9 → 21.0 ms) */
    uint8_t *restrict uh = mc->uh, *restrict uf = mc->uf;
    int64_t *restrict us = mc->us;
    int32_t *restrict uid = mc->uid;
    float *restrict q0 = mc->q0, *restrict q1 = mc->q1, *restrict q2 = mc->q2;
    int64_t m0 = c[0], m1 = c[1], m2 = c[2];
    int h0 = cut_h[m0], h1 = cut_h[m1], h2 = cut_h[m2];
    int64_t e0 = (int64_t)1 << h0, e1 = (int64_t)1 << h1, e2 = (int64_t)1 << h2;
    int64_t u = 0, cur = 0;
    while (cur < total) {
        int hh = h0 < h1 ? h0 : h1;
        if (h2 < hh) hh = h2;
        int64_t id = lev[hh] + (cur >> hh);
        uh[u] = (uint8_t)hh; us[u] = cur; uid[u] = (int32_t)id;
        uf[u] = (uint8_t)(hh >= hr && node_radius[id] > refine_r);
        q0[u] = k * cut_q[m0]; q1[u] = k * cut_q[m1]; q2[u] = k * cut_q[m2];
        u++;
        cur += (int64_t)1 << hh;
        if (cur >= total) break;
        m0 += e0 == cur; m1 += e1 == cur; m2 += e2 == cur;
        h0 = cut_h[m0]; h1 = cut_h[m1]; h2 = cut_h[m2];
        e0 = e0 == cur ? cur + ((int64_t)1 << h0) : e0;
        e1 = e1 == cur ? cur + ((int64_t)1 << h1) : e1;
        e2 = e2 == cur ? cur + ((int64_t)1 << h2) : e2;
    }
    return u;
}

/* node u of merged cuts for one pixel of weights w: appended when its visibility is positive,
 * split about the mirror direction r when its material may split it */
static inline int64_t blend_one(const merged_cuts *mc, int64_t u, float w0, float w1, float w2, const refine_ctx *c,
                                int32_t *idx, float *qf, int64_t n) {
    float q = w0 * mc->q0[u] + w1 * mc->q1[u] + w2 * mc->q2[u];
    if (!(q > 0.0f)) return n;
    if (mc->uf[u])
        return refine_node_q(mc->uh[u], mc->us[u], 0, q, c, idx, NULL, qf, n);
    idx[n] = mc->uid[u]; qf[n] = q;
    return n + 1;
}

/* One pixel's clusters from its face's merged cuts: visibility v = Σ_i w_i q_i per node (B is
 * linear in v, inverse-brdf-modeling eq. 22, so shading the blend equals blending the three
 * cuts' shading where they agree; where one cut is coarser its clusters are evaluated at the
 * finer cut's light centroids, closer to the integral and exact for the diffuse part), nodes
 * with v > 0 kept and split about the mirror direction r as ``collect`` does. Writes node
 * indices and float visibilities; returns their number (≤ 2^H). */
static int64_t blend_list(int64_t U, const merged_cuts *mc, const double w[3], const refine_ctx *c, int32_t *idx,
                          float *qf) {
    int64_t n = 0;
    for (int64_t u = 0; u < U; u++)
        n = blend_one(mc, u, (float)w[0], (float)w[1], (float)w[2], c, idx, qf, n);
    return n;
}

/* the lowest tree level holding a node wider than refine_r (H + 1 when none is) */
static int refine_level(const float *node_radius, const int64_t *lev, int H, double refine_r) {
    for (int h = 1; h <= H; h++)
        for (int64_t i = lev[h]; i < lev[h + 1]; i++)
            if (node_radius[i] > refine_r) return h;
    return H + 1;
}

/* ---------------------------------------------------------------------------------------
 * Run-time choice of the vector paths.
 */
static int simd_mode = -1;       /* −1: not chosen yet; 0: scalar; 1: AVX2 + FMA */

static int cpu_has_avx2(void) {
#ifdef GLK_X86
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
#else
    return 0;
#endif
}

/* want −1: keep the current choice (the best the CPU has, at first use); 0: scalar only;
 * 1: the best the CPU has. Returns the mode in use (0 scalar, 1 AVX2). */
static void init_pack_perm(void);

int glk_shade_simd(int want) {
    if (want >= 0 || simd_mode < 0) {
        simd_mode = want != 0 && cpu_has_avx2();
#ifdef GLK_X86
        if (simd_mode) init_pack_perm();
#endif
    }
    return simd_mode;
}

#ifdef GLK_X86
#define T_AVX2 __attribute__((target("avx2,fma")))

T_AVX2 static inline double hsum8(__m256 v) {
    float f[8];
    _mm256_storeu_ps(f, v);
    return ((double)f[0] + f[1]) + ((double)f[2] + f[3]) + (((double)f[4] + f[5]) + ((double)f[6] + f[7]));
}

/* Sum over the clusters (count a multiple of 8, padding with visibility 0) of
 * E = l·q and of the model's specular weight: S_c = l_c q s(ωi) (ggx: s without the
 * per-point factor gpo; table: s = F/den·p_c(h), den the paper's or the smith static's).
 * Local frame (t, b, n) of the point; wol the local view direction. */
typedef struct { __m256 tx, ty, tz, bx, by, bz, nx, ny, nz; } frame8;

/* eight quantised visibilities as floats q/255 */
T_AVX2 static inline __m256 load_q(const uint8_t *q) {
    __m256i v = _mm256_cvtepu8_epi32(_mm_loadl_epi64((const __m128i *)q));
    return _mm256_mul_ps(_mm256_cvtepi32_ps(v), _mm256_set1_ps(1.0f / 255.0f));
}

/* The records (l rgb, ω xyz, 0, 0) of eight clusters idx[0..8) as six columns c[0..6): each
 * record is one aligned 32-byte row of node8, so eight row loads and an 8×8 transpose replace six
 * 8-lane gathers, which re-read the same eight rows lane by lane (they were about a third of a
 * sharp srbf's cluster sums on this machine's Zen 4). */
T_AVX2 static inline void cluster_rows(const float *node8, const int32_t *idx, __m256 c[6]) {
    __m256 r0 = _mm256_loadu_ps(node8 + 8 * (int64_t)idx[0]), r1 = _mm256_loadu_ps(node8 + 8 * (int64_t)idx[1]);
    __m256 r2 = _mm256_loadu_ps(node8 + 8 * (int64_t)idx[2]), r3 = _mm256_loadu_ps(node8 + 8 * (int64_t)idx[3]);
    __m256 r4 = _mm256_loadu_ps(node8 + 8 * (int64_t)idx[4]), r5 = _mm256_loadu_ps(node8 + 8 * (int64_t)idx[5]);
    __m256 r6 = _mm256_loadu_ps(node8 + 8 * (int64_t)idx[6]), r7 = _mm256_loadu_ps(node8 + 8 * (int64_t)idx[7]);
    /* rows i = (a_i b_i c_i d_i | e_i f_i g_i h_i); lanes 0-3 of the output from rows 0-3, 4-7 from rows 4-7 */
    __m256 t0 = _mm256_unpacklo_ps(r0, r1), t1 = _mm256_unpackhi_ps(r0, r1);     /* a0 a1 b0 b1 | e0 e1 f0 f1 ; c0 c1 d0 d1 | g0 g1 h0 h1 */
    __m256 t2 = _mm256_unpacklo_ps(r2, r3), t3 = _mm256_unpackhi_ps(r2, r3);
    __m256 t4 = _mm256_unpacklo_ps(r4, r5), t5 = _mm256_unpackhi_ps(r4, r5);
    __m256 t6 = _mm256_unpacklo_ps(r6, r7), t7 = _mm256_unpackhi_ps(r6, r7);
    __m256 a03 = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(1, 0, 1, 0));              /* a0-3 | e0-3 */
    __m256 b03 = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(3, 2, 3, 2));              /* b0-3 | f0-3 */
    __m256 c03 = _mm256_shuffle_ps(t1, t3, _MM_SHUFFLE(1, 0, 1, 0));              /* c0-3 | g0-3 */
    __m256 a47 = _mm256_shuffle_ps(t4, t6, _MM_SHUFFLE(1, 0, 1, 0));
    __m256 b47 = _mm256_shuffle_ps(t4, t6, _MM_SHUFFLE(3, 2, 3, 2));
    __m256 c47 = _mm256_shuffle_ps(t5, t7, _MM_SHUFFLE(1, 0, 1, 0));
    __m256 d03 = _mm256_shuffle_ps(t1, t3, _MM_SHUFFLE(3, 2, 3, 2)), d47 = _mm256_shuffle_ps(t5, t7, _MM_SHUFFLE(3, 2, 3, 2));
    c[0] = _mm256_permute2f128_ps(a03, a47, 0x20);      /* l_r */
    c[1] = _mm256_permute2f128_ps(b03, b47, 0x20);      /* l_g */
    c[2] = _mm256_permute2f128_ps(c03, c47, 0x20);      /* l_b */
    c[3] = _mm256_permute2f128_ps(d03, d47, 0x20);      /* ω_x */
    c[4] = _mm256_permute2f128_ps(a03, a47, 0x31);      /* ω_y */
    c[5] = _mm256_permute2f128_ps(b03, b47, 0x31);      /* ω_z */
}

T_AVX2 static inline void local_dirs(const float *node8, const int32_t *idx, const frame8 *f, __m256 *lr, __m256 *lg,
                                     __m256 *lb, __m256 *wt, __m256 *wb, __m256 *wn) {
    __m256 col[6];
    cluster_rows(node8, idx, col);
    *lr = col[0]; *lg = col[1]; *lb = col[2];
    __m256 x = col[3], y = col[4], z = col[5];
    __m256 ci = _mm256_fmadd_ps(x, f->nx, _mm256_fmadd_ps(y, f->ny, _mm256_mul_ps(z, f->nz)));
    __m256 t = _mm256_fmadd_ps(x, f->tx, _mm256_fmadd_ps(y, f->ty, _mm256_mul_ps(z, f->tz)));
    __m256 b = _mm256_fmadd_ps(x, f->bx, _mm256_fmadd_ps(y, f->by, _mm256_mul_ps(z, f->bz)));
    /* a cluster straddling the horizon may have its centroid below it: its visibility already
     * carries the cosine, so f is evaluated just above (world ω + n(1e-3 − cosθ), normalised:
     * in the local frame, the normal component becomes 1e-3) */
    const __m256 lo = _mm256_set1_ps(1e-3f);
    __m256 low = _mm256_cmp_ps(ci, lo, _CMP_LT_OQ);
    if (_mm256_movemask_ps(low)) {
        __m256 l2 = _mm256_fmadd_ps(t, t, _mm256_fmadd_ps(b, b, _mm256_set1_ps(1e-6f)));
        __m256 inv = _mm256_div_ps(_mm256_set1_ps(1.0f), _mm256_sqrt_ps(l2));
        t = _mm256_blendv_ps(t, _mm256_mul_ps(t, inv), low);
        b = _mm256_blendv_ps(b, _mm256_mul_ps(b, inv), low);
        ci = _mm256_blendv_ps(ci, _mm256_mul_ps(lo, inv), low);
    }
    *wt = t; *wb = b; *wn = ci;
}

/* left-packing permutations: for each 8-bit mask, the indices of its set lanes, in order */
static int32_t pack_perm[256][8];

static void init_pack_perm(void) {
    for (int m = 0; m < 256; m++) {
        int k = 0;
        for (int i = 0; i < 8; i++) if (m >> i & 1) pack_perm[m][k++] = i;
        for (; k < 8; k++) pack_perm[m][k] = 0;
    }
}

/* The lanes of eight nodes (ids) that may be split about c->r (radius > refine radius, cone
 * within reach of the extent), among the candidate lanes cand (a movemask of 8 bits). Single
 * precision with a margin: it never misses a node the scalar walk would split (the group then
 * goes through the scalar walk, which decides exactly); it only lets groups of nodes far from
 * the mirror direction, most of them for a sharp lobe, take the vector path. */
T_AVX2 static inline int cone_mask8(const refine_ctx *c, __m256i id, int cand) {
    if (!cand) return 0;
    /* the eight nodes' geometry rows, transposed (as the clusters' records: cluster_rows) */
    int32_t ids[8];
    _mm256_storeu_si256((__m256i *)ids, id);
    __m256 g[6];
    cluster_rows(c->geo, ids, g);
    __m256 cr = g[0], sr = g[1], dx = g[2], dy = g[3], dz = g[4], R = g[5];
    __m256 d = _mm256_fmadd_ps(dx, _mm256_set1_ps((float)c->r.x),
                               _mm256_fmadd_ps(dy, _mm256_set1_ps((float)c->r.y),
                                               _mm256_mul_ps(dz, _mm256_set1_ps((float)c->r.z))));
    __m256 lim = _mm256_fmsub_ps(cr, _mm256_set1_ps((float)c->ce), _mm256_mul_ps(sr, _mm256_set1_ps((float)c->se)));
    __m256 reach = _mm256_or_ps(_mm256_cmp_ps(d, _mm256_sub_ps(lim, _mm256_set1_ps(1e-4f)), _CMP_GT_OQ),
                                _mm256_cmp_ps(_mm256_add_ps(R, _mm256_set1_ps((float)c->extent)),
                                              _mm256_set1_ps((float)PI - 1e-4f), _CMP_GE_OQ));
    __m256 wide = _mm256_cmp_ps(R, _mm256_set1_ps((float)c->refine_r * (1.0f - 1e-6f)), _CMP_GT_OQ);
    return _mm256_movemask_ps(_mm256_and_ps(reach, wide)) & cand;
}

/* collect() eight cut entries at a time: node index = level offset + (start >> h) with the
 * starts from a prefix sum of 2^h, visible entries left-packed by a permutation; a group
 * holding a node that may be refined (cone_mask8) goes through the scalar path. Needs H ≤ 15
 * (level offsets in two registers, starts in 32 bits). */
T_AVX2 static int64_t collect_avx2(int64_t c0, int64_t c1, const uint8_t *cut_h, const uint8_t *cut_q, int H,
                                   const refine_ctx *c, int hr, uint64_t amask, int alevel, int32_t *idx,
                                   uint8_t *qv) {
    const int64_t *lev = c->lev;
    int32_t l32[16];
    for (int i = 0; i < 16; i++) l32[i] = i <= H + 1 ? (int32_t)lev[i] : 0;
    const __m256i levlo = _mm256_loadu_si256((const __m256i *)l32), levhi = _mm256_loadu_si256((const __m256i *)(l32 + 8));
    const __m256i one = _mm256_set1_epi32(1), seven = _mm256_set1_epi32(7), eight = _mm256_set1_epi32(8);
    const __m256i hrm1 = _mm256_set1_epi32(hr - 1), zero = _mm256_setzero_si256();
    const __m256i bcast3 = _mm256_set1_epi32(3);
    const __m256i byte0 = _mm256_setr_epi8(0, 4, 8, 12, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1,
                                           0, 4, 8, 12, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1);
    const __m256i gather04 = _mm256_setr_epi32(0, 4, 0, 0, 0, 0, 0, 0);
    int64_t n = 0, m = c0;
    int32_t start = 0;
    for (; m + 8 <= c1; m += 8) {
        __m256i h = _mm256_cvtepu8_epi32(_mm_loadl_epi64((const __m128i *)(cut_h + m)));
        __m256i q = _mm256_cvtepu8_epi32(_mm_loadl_epi64((const __m128i *)(cut_q + m)));
        __m256i w = _mm256_sllv_epi32(one, h);
        __m256i x = _mm256_add_epi32(w, _mm256_slli_si256(w, 4));
        x = _mm256_add_epi32(x, _mm256_slli_si256(x, 8));
        x = _mm256_add_epi32(x, _mm256_blend_epi32(zero, _mm256_permutevar8x32_epi32(x, bcast3), 0xF0));
        __m256i s = _mm256_add_epi32(_mm256_set1_epi32(start), _mm256_sub_epi32(x, w));
        __m256i lv = _mm256_blendv_epi8(_mm256_permutevar8x32_epi32(levlo, h),
                                        _mm256_permutevar8x32_epi32(levhi, _mm256_sub_epi32(h, eight)),
                                        _mm256_cmpgt_epi32(h, seven));
        __m256i id = _mm256_add_epi32(lv, _mm256_srlv_epi32(s, h));
        __m256i need = _mm256_and_si256(_mm256_cmpgt_epi32(h, hrm1), _mm256_cmpgt_epi32(q, zero));
        int cand = _mm256_movemask_ps(_mm256_castsi256_ps(need));
        if (cand) {         /* the group's leaves lie under ancestors none of whose nodes may be split */
            const int a0 = start >> alevel, a1 = (start + _mm256_extract_epi32(x, 7) - 1) >> alevel;
            const uint64_t span = a1 - a0 >= 63 ? ~(uint64_t)0 : (((uint64_t)2 << (a1 - a0)) - 1);
            if (!((amask >> a0) & span)) cand = 0;
        }
        if (__builtin_expect(cone_mask8(c, id, cand) != 0, 0)) {
            for (int64_t k = m; k < m + 8; k++) {     /* the scalar path for this group */
                int hh = cut_h[k];
                unsigned q8 = cut_q[k];
                int64_t nid = lev[hh] + (start >> hh);
                if (hh >= hr && q8 && c->node_radius[nid] > c->refine_r) {
                    n = refine_node(hh, start, q8, c, idx, qv, n);
                } else {
                    idx[n] = (int32_t)nid; qv[n] = (uint8_t)q8;
                    n += q8 != 0;
                }
                start += (int32_t)1 << hh;
            }
            continue;
        }
        start += _mm256_extract_epi32(x, 7);
        int mask = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(q, zero)));
        __m256i perm = _mm256_loadu_si256((const __m256i *)pack_perm[mask]);
        _mm256_storeu_si256((__m256i *)(idx + n), _mm256_permutevar8x32_epi32(id, perm));
        __m256i qp = _mm256_shuffle_epi8(_mm256_permutevar8x32_epi32(q, perm), byte0);
        _mm_storel_epi64((__m128i *)(qv + n), _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(qp, gather04)));
        n += __builtin_popcount(mask);
    }
    for (; m < c1; m++) {
        int hh = cut_h[m];
        unsigned q8 = cut_q[m];
        int64_t id = lev[hh] + (start >> hh);
        if (hh >= hr && q8 && c->node_radius[id] > c->refine_r) {
            n = refine_node(hh, start, q8, c, idx, qv, n);
        } else {
            idx[n] = (int32_t)id; qv[n] = (uint8_t)q8;
            n += q8 != 0;
        }
        start += (int32_t)1 << hh;
    }
    return n;
}

/* blend_list eight merged nodes at a time: v = w·q in one FMA chain, positive ones left-packed
 * (pack_perm); a group of eight holding a node to split (cone_mask8) goes through blend_one. */
T_AVX2 static int64_t blend_list_avx2(int64_t U, const merged_cuts *mc, const double w[3], const refine_ctx *c,
                                      int32_t *idx, float *qf) {
    const float f0 = (float)w[0], f1 = (float)w[1], f2 = (float)w[2];
    const __m256 w0 = _mm256_set1_ps(f0), w1 = _mm256_set1_ps(f1), w2 = _mm256_set1_ps(f2);
    const __m256 zero = _mm256_setzero_ps();
    int64_t n = 0, u = 0;
    for (; u + 8 <= U; u += 8) {
        __m256 q = _mm256_fmadd_ps(w2, _mm256_loadu_ps(mc->q2 + u),
                                   _mm256_fmadd_ps(w1, _mm256_loadu_ps(mc->q1 + u),
                                                   _mm256_mul_ps(w0, _mm256_loadu_ps(mc->q0 + u))));
        int pos = _mm256_movemask_ps(_mm256_cmp_ps(q, zero, _CMP_GT_OQ));
        __m256i uid = _mm256_loadu_si256((const __m256i *)(mc->uid + u));
        uint64_t fl;
        memcpy(&fl, mc->uf + u, 8);
        if (__builtin_expect(fl != 0, 0)) {
            int flagged = 0;
            for (int k = 0; k < 8; k++) flagged |= (mc->uf[u + k] != 0) << k;
            if (cone_mask8(c, uid, flagged & pos)) {
                for (int64_t k = u; k < u + 8; k++)
                    n = blend_one(mc, k, f0, f1, f2, c, idx, qf, n);
                continue;
            }
        }
        __m256i perm = _mm256_loadu_si256((const __m256i *)pack_perm[pos]);
        _mm256_storeu_si256((__m256i *)(idx + n), _mm256_permutevar8x32_epi32(uid, perm));
        _mm256_storeu_ps(qf + n, _mm256_permutevar8x32_ps(q, perm));
        n += __builtin_popcount(pos);
    }
    for (; u < U; u++)
        n = blend_one(mc, u, f0, f1, f2, c, idx, qf, n);
    return n;
}

/* a point's eight visibilities: quantised (qv) or, when qf is given, float (a blended cut) */
T_AVX2 static inline __m256 get_q(const uint8_t *qv, const float *qf, int64_t j) {
    return qf ? _mm256_loadu_ps(qf + j) : load_q(qv + j);
}

T_AVX2 static void sum_lambert(int64_t cnt, const int32_t *idx, const uint8_t *qv, const float *qf, const float *node8,
                               double *E) {
    __m256 er = _mm256_setzero_ps(), eg = er, eb = er;
    for (int64_t j = 0; j < cnt; j += 8) {
        __m256i off = _mm256_slli_epi32(_mm256_loadu_si256((const __m256i *)(idx + j)), 3);
        __m256 q = get_q(qv, qf, j);
        er = _mm256_fmadd_ps(_mm256_i32gather_ps(node8 + 0, off, 4), q, er);
        eg = _mm256_fmadd_ps(_mm256_i32gather_ps(node8 + 1, off, 4), q, eg);
        eb = _mm256_fmadd_ps(_mm256_i32gather_ps(node8 + 2, off, 4), q, eb);
    }
    E[0] = hsum8(er); E[1] = hsum8(eg); E[2] = hsum8(eb);
}

T_AVX2 static void sum_ggx(int64_t cnt, const int32_t *idx, const uint8_t *qv, const float *qf, const float *node8,
                           const frame8 *f,
                           v3 wol, float alpha, double *E, double *S) {
    const float a2 = alpha * alpha;
    const __m256 va2 = _mm256_set1_ps(a2), v1ma2 = _mm256_set1_ps(1.0f - a2);
    const __m256 k = _mm256_set1_ps((float)(2.0 * a2 / PI)), zero = _mm256_setzero_ps();
    const __m256 ot = _mm256_set1_ps((float)wol.x), ob = _mm256_set1_ps((float)wol.y), on = _mm256_set1_ps((float)wol.z);
    __m256 er = zero, eg = zero, eb = zero, sr = zero, sg = zero, sb = zero;
    for (int64_t j = 0; j < cnt; j += 8) {
        __m256 q = get_q(qv, qf, j);
        __m256 lr, lg, lb, wt, wb, ci;
        local_dirs(node8, idx + j, f, &lr, &lg, &lb, &wt, &wb, &ci);
        lr = _mm256_mul_ps(lr, q); lg = _mm256_mul_ps(lg, q); lb = _mm256_mul_ps(lb, q);
        er = _mm256_add_ps(er, lr); eg = _mm256_add_ps(eg, lg); eb = _mm256_add_ps(eb, lb);
        __m256 ht = _mm256_add_ps(wt, ot), hb = _mm256_add_ps(wb, ob), hn = _mm256_add_ps(ci, on);
        __m256 ht2 = _mm256_fmadd_ps(ht, ht, _mm256_mul_ps(hb, hb));
        __m256 hn2 = _mm256_mul_ps(hn, hn);
        __m256 hh = _mm256_add_ps(hn2, ht2);
        __m256 dd = _mm256_fmadd_ps(va2, hn2, ht2);                          /* |h|²·(cos²θh (α²−1) + 1) */
        __m256 gd = _mm256_add_ps(ci, _mm256_sqrt_ps(_mm256_fmadd_ps(_mm256_mul_ps(ci, ci), v1ma2, va2)));
        __m256 s = _mm256_div_ps(_mm256_mul_ps(k, _mm256_mul_ps(hh, hh)), _mm256_mul_ps(_mm256_mul_ps(dd, dd), gd));
        /* D needs cosθh > 0, G1(ωi) needs ωi·h > 0 */
        __m256 wh = _mm256_fmadd_ps(wt, ht, _mm256_fmadd_ps(wb, hb, _mm256_mul_ps(ci, hn)));
        __m256 ok = _mm256_and_ps(_mm256_cmp_ps(hn, zero, _CMP_GT_OQ), _mm256_cmp_ps(wh, zero, _CMP_GT_OQ));
        s = _mm256_and_ps(s, ok);
        sr = _mm256_fmadd_ps(lr, s, sr); sg = _mm256_fmadd_ps(lg, s, sg); sb = _mm256_fmadd_ps(lb, s, sb);
    }
    E[0] = hsum8(er); E[1] = hsum8(eg); E[2] = hsum8(eb);
    S[0] = hsum8(sr); S[1] = hsum8(sg); S[2] = hsum8(sb);
}

T_AVX2 static void sum_table(int64_t cnt, const int32_t *idx, const uint8_t *qv, const float *qf, const float *node8,
                             const frame8 *f,
                             v3 wol, const float *prm, const float *tab, double *E, double *S) {
    const __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.0f);
    /* prm[3] = F0; prm[4] = static (0 paper, 1 smith), prm[5] = the smith static's α */
    const float f0 = prm[3];
    const int smith = prm[4] > 0.5f;
    const int neutral = prm[6] > 0.5f;
    const float *quads = neutral ? tab + 3 * TABLE_N * TABLE_N : NULL;   /* core/render.py texel_quads */
    const float sa2 = prm[5] * prm[5];
    const __m256 va2 = _mm256_set1_ps(sa2), v1ma2 = _mm256_set1_ps(1.0f - sa2);
    /* the smith static's ωo factor (cosθo + Λ(cosθo)) is the same for every cluster of the point */
    const __m256 dco = _mm256_set1_ps((float)(wol.z + sqrt((double)sa2 + (1.0 - sa2) * wol.z * wol.z)));
    const __m256 ot = _mm256_set1_ps((float)wol.x), ob = _mm256_set1_ps((float)wol.y), on = _mm256_set1_ps((float)wol.z);
    const __m256 half = _mm256_set1_ps(0.5f * (TABLE_N - 1)), top = _mm256_set1_ps((float)(TABLE_N - 1));
    const __m256i imax = _mm256_set1_epi32(TABLE_N - 2), row = _mm256_set1_epi32(3 * TABLE_N);
    const __m256i three = _mm256_set1_epi32(3), tn = _mm256_set1_epi32(TABLE_N);
    const __m256 vf0 = _mm256_set1_ps(f0), v1mf0 = _mm256_set1_ps(1.0f - f0);
    const __m256 absmask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
    const float co = (float)wol.z;
    __m256 er = zero, eg = zero, eb = zero, sr = zero, sg = zero, sb = zero;
    for (int64_t j = 0; j < cnt; j += 8) {
        __m256 q = get_q(qv, qf, j);
        __m256 lr, lg, lb, wt, wb, ci;
        local_dirs(node8, idx + j, f, &lr, &lg, &lb, &wt, &wb, &ci);
        lr = _mm256_mul_ps(lr, q); lg = _mm256_mul_ps(lg, q); lb = _mm256_mul_ps(lb, q);
        er = _mm256_add_ps(er, lr); eg = _mm256_add_ps(eg, lg); eb = _mm256_add_ps(eb, lb);
        __m256 ht = _mm256_add_ps(wt, ot), hb = _mm256_add_ps(wb, ob), hn = _mm256_add_ps(ci, on);
        /* hemi-octahedral table coordinates (scale-invariant: h need not be unit) */
        __m256 s1 = _mm256_add_ps(_mm256_add_ps(_mm256_and_ps(ht, absmask), _mm256_and_ps(hb, absmask)),
                                  _mm256_max_ps(hn, zero));
        __m256 inv = _mm256_div_ps(one, _mm256_max_ps(s1, _mm256_set1_ps(1e-30f)));
        __m256 px = _mm256_mul_ps(ht, inv), py = _mm256_mul_ps(hb, inv);
        __m256 fu = _mm256_mul_ps(_mm256_add_ps(_mm256_add_ps(px, py), one), half);
        __m256 fv = _mm256_mul_ps(_mm256_add_ps(_mm256_sub_ps(px, py), one), half);
        fu = _mm256_min_ps(_mm256_max_ps(fu, zero), top);
        fv = _mm256_min_ps(_mm256_max_ps(fv, zero), top);
        __m256i i0 = _mm256_min_epi32(_mm256_cvttps_epi32(fu), imax);
        __m256i j0 = _mm256_min_epi32(_mm256_cvttps_epi32(fv), imax);
        __m256 a = _mm256_sub_ps(fu, _mm256_cvtepi32_ps(i0)), b = _mm256_sub_ps(fv, _mm256_cvtepi32_ps(j0));
        __m256i base = _mm256_mullo_epi32(_mm256_add_epi32(_mm256_mullo_epi32(i0, tn), j0), three);
        __m256i base1 = _mm256_add_epi32(base, row);
        /* Schlick's F at ωi·h and the static denominator (inverse-brdf-modeling eq. 9, or smith) */
        __m256 hh = _mm256_fmadd_ps(ht, ht, _mm256_fmadd_ps(hb, hb, _mm256_mul_ps(hn, hn)));
        __m256 wh = _mm256_fmadd_ps(wt, ht, _mm256_fmadd_ps(wb, hb, _mm256_mul_ps(ci, hn)));
        __m256 cd = _mm256_div_ps(wh, _mm256_sqrt_ps(_mm256_max_ps(hh, _mm256_set1_ps(1e-30f))));
        __m256 m = _mm256_min_ps(_mm256_max_ps(_mm256_sub_ps(one, cd), zero), one);
        __m256 m2 = _mm256_mul_ps(m, m);
        __m256 F = _mm256_fmadd_ps(v1mf0, _mm256_mul_ps(_mm256_mul_ps(m2, m2), m), vf0);
        __m256 den;
        if (smith) {       /* (cosθi + Λ(cosθi))(cosθo + Λ(cosθo)), Λ(c) = √(α² + (1 − α²) c²) */
            __m256 di = _mm256_add_ps(ci, _mm256_sqrt_ps(_mm256_fmadd_ps(_mm256_mul_ps(ci, ci), v1ma2, va2)));
            den = _mm256_mul_ps(di, dco);
        } else {
            __m256 vco = _mm256_set1_ps(co);
            den = _mm256_sub_ps(_mm256_add_ps(ci, vco), _mm256_mul_ps(ci, vco));
        }
        __m256 sf = _mm256_div_ps(F, _mm256_max_ps(den, _mm256_set1_ps(1e-12f)));
        __m256 wa = _mm256_mul_ps(sf, _mm256_sub_ps(one, a)), wa1 = _mm256_mul_ps(sf, a);
        __m256 w1b = _mm256_sub_ps(one, b);
        if (neutral) {
            /* the channels' tables are equal (a white specular part): one lookup for all three,
             * each lane's four texels one 16-byte row of the quads after the table
             * (core/render.py texel_quads), transposed */
            int32_t tx[8];
            _mm256_storeu_si256((__m256i *)tx, _mm256_add_epi32(_mm256_mullo_epi32(i0, tn), j0));
            __m256 R[4];
            for (int k = 0; k < 4; k++)
                R[k] = _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_loadu_ps(quads + 4 * (int64_t)tx[k])),
                                            _mm_loadu_ps(quads + 4 * (int64_t)tx[k + 4]), 1);
            __m256 u0 = _mm256_unpacklo_ps(R[0], R[1]), u1 = _mm256_unpackhi_ps(R[0], R[1]);
            __m256 u2 = _mm256_unpacklo_ps(R[2], R[3]), u3 = _mm256_unpackhi_ps(R[2], R[3]);
            __m256 t00 = _mm256_shuffle_ps(u0, u2, _MM_SHUFFLE(1, 0, 1, 0));
            __m256 t01 = _mm256_shuffle_ps(u0, u2, _MM_SHUFFLE(3, 2, 3, 2));
            __m256 t10 = _mm256_shuffle_ps(u1, u3, _MM_SHUFFLE(1, 0, 1, 0));
            __m256 t11 = _mm256_shuffle_ps(u1, u3, _MM_SHUFFLE(3, 2, 3, 2));
            __m256 r0 = _mm256_fmadd_ps(t01, b, _mm256_mul_ps(t00, w1b));
            __m256 r1 = _mm256_fmadd_ps(t11, b, _mm256_mul_ps(t10, w1b));
            __m256 p = _mm256_fmadd_ps(r1, wa1, _mm256_mul_ps(r0, wa));
            sr = _mm256_fmadd_ps(lr, p, sr); sg = _mm256_fmadd_ps(lg, p, sg); sb = _mm256_fmadd_ps(lb, p, sb);
            continue;
        }
        __m256 lq[3] = {lr, lg, lb};
        __m256 *acc[3] = {&sr, &sg, &sb};
        for (int c = 0; c < 3; c++) {
            __m256i o0 = _mm256_add_epi32(base, _mm256_set1_epi32(c)), o1 = _mm256_add_epi32(base1, _mm256_set1_epi32(c));
            __m256 t00 = _mm256_i32gather_ps(tab, o0, 4);
            __m256 t01 = _mm256_i32gather_ps(tab, _mm256_add_epi32(o0, three), 4);
            __m256 t10 = _mm256_i32gather_ps(tab, o1, 4);
            __m256 t11 = _mm256_i32gather_ps(tab, _mm256_add_epi32(o1, three), 4);
            __m256 r0 = _mm256_fmadd_ps(t01, b, _mm256_mul_ps(t00, w1b));
            __m256 r1 = _mm256_fmadd_ps(t11, b, _mm256_mul_ps(t10, w1b));
            __m256 p = _mm256_fmadd_ps(r1, wa1, _mm256_mul_ps(r0, wa));
            *acc[c] = _mm256_fmadd_ps(lq[c], p, *acc[c]);
        }
    }
    E[0] = hsum8(er); E[1] = hsum8(eg); E[2] = hsum8(eb);
    S[0] = hsum8(sr); S[1] = hsum8(sg); S[2] = hsum8(sb);
}

/* Natural log of x > 0 (normal doubles), four at a time: x = m·2^k with m in [√½, √2), and
 * log m = 2 atanh(z), z = (m − 1)/(m + 1), |z| ≤ 0.172, by its series to z^17 (error < 1e-14).
 * Hand-written because AVX2 has no vector log and the lobes' pow needs double precision: an
 * exponent of 10⁴ turns a float's 1e-7 in log(ωr·ωi) into 1e-3 of the lobe. */
T_AVX2 static inline __m256d log_pd(__m256d x) {
    const __m256d magic = _mm256_set1_pd(4503599627370496.0);        /* 2^52 */
    __m256i bits = _mm256_castpd_si256(x);
    __m256i ex = _mm256_srli_epi64(bits, 52);
    __m256d m = _mm256_castsi256_pd(_mm256_or_si256(_mm256_and_si256(bits, _mm256_set1_epi64x(0x000FFFFFFFFFFFFFLL)),
                                                    _mm256_set1_epi64x(0x3FF0000000000000LL)));
    __m256d k = _mm256_sub_pd(_mm256_castsi256_pd(_mm256_or_si256(ex, _mm256_castpd_si256(magic))), magic);
    __m256d big = _mm256_cmp_pd(m, _mm256_set1_pd(1.4142135623730951), _CMP_GT_OQ);
    m = _mm256_blendv_pd(m, _mm256_mul_pd(m, _mm256_set1_pd(0.5)), big);
    k = _mm256_add_pd(_mm256_sub_pd(k, _mm256_set1_pd(1023.0)), _mm256_and_pd(big, _mm256_set1_pd(1.0)));
    const __m256d one = _mm256_set1_pd(1.0);
    __m256d z = _mm256_div_pd(_mm256_sub_pd(m, one), _mm256_add_pd(m, one));
    __m256d z2 = _mm256_mul_pd(z, z);
    __m256d p = _mm256_set1_pd(1.0 / 17);
    p = _mm256_fmadd_pd(p, z2, _mm256_set1_pd(1.0 / 15));
    p = _mm256_fmadd_pd(p, z2, _mm256_set1_pd(1.0 / 13));
    p = _mm256_fmadd_pd(p, z2, _mm256_set1_pd(1.0 / 11));
    p = _mm256_fmadd_pd(p, z2, _mm256_set1_pd(1.0 / 9));
    p = _mm256_fmadd_pd(p, z2, _mm256_set1_pd(1.0 / 7));
    p = _mm256_fmadd_pd(p, z2, _mm256_set1_pd(1.0 / 5));
    p = _mm256_fmadd_pd(p, z2, _mm256_set1_pd(1.0 / 3));
    p = _mm256_fmadd_pd(p, z2, one);
    return _mm256_fmadd_pd(k, _mm256_set1_pd(0.6931471805599453), _mm256_mul_pd(_mm256_add_pd(z, z), p));
}

/* exp(x) for x in [−80, 0], four at a time: x = n ln2 + r, |r| ≤ ln2/2 (ln2 in two parts), e^r by
 * its Taylor series to r^12 (error < 1e-15), 2^n put into the exponent bits. */
T_AVX2 static inline __m256d exp_pd(__m256d x) {
    __m256d n = _mm256_round_pd(_mm256_mul_pd(x, _mm256_set1_pd(1.4426950408889634)),
                                _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m256d r = _mm256_fnmadd_pd(n, _mm256_set1_pd(0.6931471803691238), x);
    r = _mm256_fnmadd_pd(n, _mm256_set1_pd(1.9082149292705877e-10), r);
    __m256d p = _mm256_set1_pd(1.0 / 479001600.0);                    /* 1/12! */
    static const double inv_fact[12] = {1.0 / 39916800.0, 1.0 / 3628800.0, 1.0 / 362880.0, 1.0 / 40320.0,
                                        1.0 / 5040.0, 1.0 / 720.0, 1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5, 1.0, 1.0};
    for (int i = 0; i < 12; i++) p = _mm256_fmadd_pd(p, r, _mm256_set1_pd(inv_fact[i]));
    /* 2^n: n + 1023 (in 943..1023) is the exponent field */
    const __m256d magic = _mm256_set1_pd(4503599627370496.0);
    __m256i e = _mm256_slli_epi64(_mm256_castpd_si256(_mm256_add_pd(_mm256_add_pd(n, _mm256_set1_pd(1023.0)), magic)), 52);
    return _mm256_mul_pd(p, _mm256_castsi256_pd(e));
}

/* Cosine lobes (models/lobes.py; reciprocal form (e+2)/(2π)·(ωr·ωi)^e per lobe, ωr the mirror
 * direction) over a point's clusters, four at a time in double precision: E_c = Σ l_c q and
 * S_c = Σ l_c q Σ_k s_k w_kc, with ωi nudged above the horizon as the scalar path does. One log per
 * cluster, one exp per lobe, and a lobe's exp skipped for four clusters all below 1e-30 of its
 * peak (most clusters of a sharp lobe). n world normal, r = 2(n·ωo)n − ωo, co = n·ωo. */
/* pad a cluster list to a multiple of eight with visibility 0 (the vector paths read eight at a time) */
static void pad8(int64_t cnt, int32_t *idx, uint8_t *qv, float *qf) {
    for (int64_t j = cnt; j < ((cnt + 7) & ~(int64_t)7); j++) {
        idx[j] = idx[0];
        if (qf) qf[j] = 0.0f; else qv[j] = 0;
    }
}

/* one half (four lanes) of eight gathered clusters as doubles: v = (l_r, l_g, l_b, ω_x, ω_y, ω_z),
 * q the visibilities */
T_AVX2 static inline void clusters_pd(const __m256 g8[6], __m256 q8, int half, __m256d v[6], __m256d *q) {
    for (int c = 0; c < 6; c++)
        v[c] = _mm256_cvtps_pd(half ? _mm256_extractf128_ps(g8[c], 1) : _mm256_castps256_ps128(g8[c]));
    *q = _mm256_cvtps_pd(half ? _mm256_extractf128_ps(q8, 1) : _mm256_castps256_ps128(q8));
}

/* eight clusters' records (l rgb, ω xyz) gathered into g8[6] from entries idx[j..j+8); returns
 * their visibilities */
T_AVX2 static inline __m256 gather_clusters(const float *node8, const int32_t *idx, const uint8_t *qv, const float *qf,
                                            int64_t j, __m256 g8[6]) {
    cluster_rows(node8, idx + j, g8);
    return get_q(qv, qf, j);
}

/* lq = l_c q of four clusters (v from clusters_pd), added to the diffuse sums E r, g, b */
T_AVX2 static inline void light_q(const __m256d v[6], __m256d q, __m256d lq[3], __m256d *er, __m256d *eg,
                                  __m256d *eb) {
    lq[0] = _mm256_mul_pd(v[0], q); lq[1] = _mm256_mul_pd(v[1], q); lq[2] = _mm256_mul_pd(v[2], q);
    *er = _mm256_add_pd(*er, lq[0]); *eg = _mm256_add_pd(*eg, lq[1]); *eb = _mm256_add_pd(*eb, lq[2]);
}

/* E_c and S_c from four-lane double accumulators (E r, g, b, S r, g, b) */
T_AVX2 static inline void store_sums(const __m256d acc[6], double *E, double *S) {
    double buf[4];
    double *outs[6] = {&E[0], &E[1], &E[2], &S[0], &S[1], &S[2]};
    for (int c = 0; c < 6; c++) {
        _mm256_storeu_pd(buf, acc[c]);
        *outs[c] = (buf[0] + buf[1]) + (buf[2] + buf[3]);
    }
}

T_AVX2 __attribute__((noinline)) static void sum_lobes(int64_t cnt, const int32_t *idx, const uint8_t *qv, const float *qf, const float *node8,
                             v3 n, v3 r, double co, const float *prm, double *E, double *S) {
    const int m = (int)prm[3];
    double ck[32];
    for (int k = 0; k < m; k++) ck[k] = (prm[4 + 4 * k] + 2.0) / (2.0 * PI);
    const __m256d nx = _mm256_set1_pd(n.x), ny = _mm256_set1_pd(n.y), nz = _mm256_set1_pd(n.z);
    const __m256d rx = _mm256_set1_pd(r.x), ry = _mm256_set1_pd(r.y), rz = _mm256_set1_pd(r.z);
    const __m256d vco = _mm256_set1_pd(co), lo = _mm256_set1_pd(1e-3), zero = _mm256_setzero_pd();
    const __m256d floor_x = _mm256_set1_pd(-69.0), tiny = _mm256_set1_pd(1e-300);
    __m256d er = zero, eg = zero, eb = zero, sr = zero, sg = zero, sb = zero;
    for (int64_t j = 0; j < cnt; j += 8) {
        __m256 g8[6];
        const __m256 q8 = gather_clusters(node8, idx, qv, qf, j, g8);
        for (int half = 0; half < 2; half++) {
            __m256d v[6], q;
            clusters_pd(g8, q8, half, v, &q);
            __m256d x = v[3], y = v[4], z = v[5];
            __m256d ci = _mm256_fmadd_pd(x, nx, _mm256_fmadd_pd(y, ny, _mm256_mul_pd(z, nz)));
            __m256d rv = _mm256_fmadd_pd(x, rx, _mm256_fmadd_pd(y, ry, _mm256_mul_pd(z, rz)));
            __m256d low = _mm256_cmp_pd(ci, lo, _CMP_LT_OQ);
            if (_mm256_movemask_pd(low)) {     /* ωi + n(1e-3 − cosθi), normalised: ωr· it */
                __m256d d = _mm256_sub_pd(lo, ci);
                __m256d ax = _mm256_fmadd_pd(nx, d, x), ay = _mm256_fmadd_pd(ny, d, y), az = _mm256_fmadd_pd(nz, d, z);
                __m256d len = _mm256_sqrt_pd(_mm256_fmadd_pd(ax, ax, _mm256_fmadd_pd(ay, ay, _mm256_mul_pd(az, az))));
                rv = _mm256_blendv_pd(rv, _mm256_div_pd(_mm256_fmadd_pd(vco, d, rv), len), low);
            }
            __m256d lq[3];
            light_q(v, q, lq, &er, &eg, &eb);
            __m256d valid = _mm256_cmp_pd(rv, zero, _CMP_GT_OQ);
            if (!_mm256_movemask_pd(valid)) continue;
            /* log of ωr·ωi clamped to (0, 1] as the reference clips it */
            __m256d L = _mm256_min_pd(log_pd(_mm256_max_pd(rv, tiny)), zero);
            __m256d t0 = zero, t1 = zero, t2 = zero;
            for (int k = 0; k < m; k++) {
                __m256d xk = _mm256_mul_pd(_mm256_set1_pd(prm[4 + 4 * k]), L);
                __m256d on = _mm256_and_pd(valid, _mm256_cmp_pd(xk, floor_x, _CMP_GE_OQ));
                if (!_mm256_movemask_pd(on)) continue;
                __m256d s = _mm256_and_pd(_mm256_mul_pd(_mm256_set1_pd(ck[k]), exp_pd(_mm256_max_pd(xk, floor_x))), on);
                t0 = _mm256_fmadd_pd(s, _mm256_set1_pd(prm[5 + 4 * k]), t0);
                t1 = _mm256_fmadd_pd(s, _mm256_set1_pd(prm[6 + 4 * k]), t1);
                t2 = _mm256_fmadd_pd(s, _mm256_set1_pd(prm[7 + 4 * k]), t2);
            }
            sr = _mm256_fmadd_pd(lq[0], t0, sr); sg = _mm256_fmadd_pd(lq[1], t1, sg); sb = _mm256_fmadd_pd(lq[2], t2, sb);
        }
    }
    const __m256d acc[6] = {er, eg, eb, sr, sg, sb};
    store_sums(acc, E, S);
}

/* Blinn-Phong and Ashikhmin-Shirley (half-vector lobes with a pow) over a point's clusters, four
 * at a time in double precision as sum_lobes, in the point's local frame: wol the view direction
 * there, fr the frame (t, bt, n) as nine doubles. Blinn-Phong: s = (e+8)/(8π) cos^e θh, S_c =
 * Σ l_c q s (F0_c applied by the caller); Ashikhmin-Shirley: S_c = Σ l_c q f F_c (eq. of
 * models/ashikhmin_shirley.py, exponent n_u cos²φh + n_v sin²φh about the tangent). */
T_AVX2 __attribute__((noinline)) static void sum_half(int kind, int64_t cnt, const int32_t *idx, const uint8_t *qv, const float *qf,
                            const float *node8, const double *fr, v3 wol, const float *prm, double *E, double *S) {
    const __m256d tx = _mm256_set1_pd(fr[0]), ty = _mm256_set1_pd(fr[1]), tz = _mm256_set1_pd(fr[2]);
    const __m256d bx = _mm256_set1_pd(fr[3]), by = _mm256_set1_pd(fr[4]), bz = _mm256_set1_pd(fr[5]);
    const __m256d nx = _mm256_set1_pd(fr[6]), ny = _mm256_set1_pd(fr[7]), nz = _mm256_set1_pd(fr[8]);
    const __m256d ot = _mm256_set1_pd(wol.x), ob = _mm256_set1_pd(wol.y), on = _mm256_set1_pd(wol.z);
    const __m256d zero = _mm256_setzero_pd(), one = _mm256_set1_pd(1.0), lo = _mm256_set1_pd(1e-3);
    const __m256d tiny = _mm256_set1_pd(1e-300), eps = _mm256_set1_pd(1e-12);
    const int as = kind == K_AS;
    /* Blinn: e and its normalisation; AS: n_u, n_v, the normalisation, F0 */
    const double e = prm[6];
    const __m256d ve = _mm256_set1_pd(as ? 0.0 : e), vb = _mm256_set1_pd((e + 8.0) / (8.0 * PI));
    const __m256d nu = _mm256_set1_pd(prm[3]), nv = _mm256_set1_pd(prm[4]);
    const __m256d van = _mm256_set1_pd(sqrt(((double)prm[3] + 1.0) * ((double)prm[4] + 1.0)) / (8.0 * PI));
    const __m256d f0[3] = {_mm256_set1_pd(prm[5]), _mm256_set1_pd(prm[6]), _mm256_set1_pd(prm[7])};
    __m256d er = zero, eg = zero, eb = zero, sr = zero, sg = zero, sb = zero;
    for (int64_t j = 0; j < cnt; j += 8) {
        __m256 g8[6];
        const __m256 q8 = gather_clusters(node8, idx, qv, qf, j, g8);
        for (int half = 0; half < 2; half++) {
            __m256d v[6], q;
            clusters_pd(g8, q8, half, v, &q);
            __m256d x = v[3], y = v[4], z = v[5];
            __m256d wt = _mm256_fmadd_pd(x, tx, _mm256_fmadd_pd(y, ty, _mm256_mul_pd(z, tz)));
            __m256d wb = _mm256_fmadd_pd(x, bx, _mm256_fmadd_pd(y, by, _mm256_mul_pd(z, bz)));
            __m256d ci = _mm256_fmadd_pd(x, nx, _mm256_fmadd_pd(y, ny, _mm256_mul_pd(z, nz)));
            __m256d low = _mm256_cmp_pd(ci, lo, _CMP_LT_OQ);
            if (_mm256_movemask_pd(low)) {     /* ωi + n(1e-3 − cosθi), normalised (local_dirs) */
                __m256d len = _mm256_sqrt_pd(_mm256_fmadd_pd(wt, wt, _mm256_fmadd_pd(wb, wb, _mm256_set1_pd(1e-6))));
                wt = _mm256_blendv_pd(wt, _mm256_div_pd(wt, len), low);
                wb = _mm256_blendv_pd(wb, _mm256_div_pd(wb, len), low);
                ci = _mm256_blendv_pd(ci, _mm256_div_pd(lo, len), low);
            }
            __m256d lq[3];
            light_q(v, q, lq, &er, &eg, &eb);
            __m256d hx = _mm256_add_pd(wt, ot), hy = _mm256_add_pd(wb, ob), hz = _mm256_add_pd(ci, on);
            __m256d hxy = _mm256_fmadd_pd(hx, hx, _mm256_mul_pd(hy, hy));
            __m256d inv = _mm256_div_pd(one, _mm256_sqrt_pd(_mm256_max_pd(_mm256_fmadd_pd(hz, hz, hxy), tiny)));
            __m256d chh = _mm256_mul_pd(hz, inv);
            if (!as) {
                __m256d pos = _mm256_cmp_pd(chh, zero, _CMP_GT_OQ);
                __m256d L = _mm256_min_pd(log_pd(_mm256_max_pd(chh, tiny)), zero);
                __m256d xk = _mm256_max_pd(_mm256_mul_pd(ve, L), _mm256_set1_pd(-80.0));
                __m256d sv = _mm256_and_pd(_mm256_mul_pd(vb, exp_pd(xk)), pos);
                sr = _mm256_fmadd_pd(lq[0], sv, sr); sg = _mm256_fmadd_pd(lq[1], sv, sg); sb = _mm256_fmadd_pd(lq[2], sv, sb);
                continue;
            }
            __m256d cos2 = _mm256_blendv_pd(one, _mm256_div_pd(_mm256_mul_pd(hx, hx), _mm256_max_pd(hxy, tiny)),
                                            _mm256_cmp_pd(hxy, _mm256_set1_pd(1e-24), _CMP_GT_OQ));
            /* the reference's thresholds are on the unit h; hxy scales with |h|², so compare unit values */
            cos2 = _mm256_blendv_pd(one, cos2, _mm256_cmp_pd(_mm256_mul_pd(hxy, _mm256_mul_pd(inv, inv)),
                                                             _mm256_set1_pd(1e-24), _CMP_GT_OQ));
            __m256d ee = _mm256_fmadd_pd(nu, cos2, _mm256_mul_pd(nv, _mm256_sub_pd(one, cos2)));
            __m256d c = _mm256_min_pd(_mm256_max_pd(chh, eps), one);
            __m256d L = _mm256_min_pd(log_pd(c), zero);
            __m256d xk = _mm256_max_pd(_mm256_mul_pd(ee, L), _mm256_set1_pd(-80.0));
            __m256d cd = _mm256_mul_pd(_mm256_fmadd_pd(wt, hx, _mm256_fmadd_pd(wb, hy, _mm256_mul_pd(ci, hz))), inv);
            __m256d den = _mm256_mul_pd(_mm256_max_pd(cd, eps), _mm256_max_pd(ci, on));
            __m256d f = _mm256_div_pd(_mm256_mul_pd(van, exp_pd(xk)), den);
            __m256d mm = _mm256_min_pd(_mm256_max_pd(_mm256_sub_pd(one, cd), zero), one);
            __m256d m2 = _mm256_mul_pd(mm, mm), m5 = _mm256_mul_pd(_mm256_mul_pd(m2, m2), mm);
            __m256d *acc[3] = {&sr, &sg, &sb};
            for (int k = 0; k < 3; k++) {
                __m256d F = _mm256_fmadd_pd(_mm256_sub_pd(one, f0[k]), m5, f0[k]);
                *acc[k] = _mm256_fmadd_pd(lq[k], _mm256_mul_pd(f, F), *acc[k]);
            }
        }
    }
    const __m256d acc[6] = {er, eg, eb, sr, sg, sb};
    store_sums(acc, E, S);
}

/* the vector path of one point (not inlined into the generic caller: it is compiled for AVX2) */
T_AVX2 __attribute__((noinline)) static void sum_avx2(int kind, int64_t cnt, int32_t *idx, uint8_t *qv, float *qf,
                                                      const float *node8, const float *fr, v3 wol, const float *prm,
                                                      const float *tab, double *E, double *S) {
    frame8 f;
    f.tx = _mm256_set1_ps(fr[0]); f.ty = _mm256_set1_ps(fr[1]); f.tz = _mm256_set1_ps(fr[2]);
    f.bx = _mm256_set1_ps(fr[3]); f.by = _mm256_set1_ps(fr[4]); f.bz = _mm256_set1_ps(fr[5]);
    f.nx = _mm256_set1_ps(fr[6]); f.ny = _mm256_set1_ps(fr[7]); f.nz = _mm256_set1_ps(fr[8]);
    if (kind == K_LAMBERT) sum_lambert(cnt, idx, qv, qf, node8, E);
    else if (kind == K_GGX) sum_ggx(cnt, idx, qv, qf, node8, &f, wol, prm[6], E, S);
    else sum_table(cnt, idx, qv, qf, node8, &f, wol, prm, tab, E, S);
}
#endif

/* ---------------------------------------------------------------------------------------
 * One point's radiance from its cluster list (idx with visibilities qv q/255, or qf floats when
 * qf is given): the vector path when the model has one, else f evaluated as the reference does.
 * n, wo unit; (t, bt, n) its frame; co = n·ωo > 0; gpo GGX's per-point factor. */
static void sum_point(int simd, int kind, const float *prm, const float *tab, v3 n, v3 wo, v3 t, v3 bt, double co,
                      double gpo, int64_t cnt, int32_t *idx, uint8_t *qv, float *qf, const float *node8,
                      double acc[3]) {
    acc[0] = acc[1] = acc[2] = 0.0;
    if (cnt <= 0) return;
#ifdef GLK_X86
    if (simd && (kind == K_LAMBERT || kind == K_GGX || kind == K_BLINN || kind == K_LOBES || kind == K_AS ||
                 (kind == K_TABLE && tab))) {
        double E[3], S[3] = {0, 0, 0};
        v3 wol = mk(dot(wo, t), dot(wo, bt), co);
        pad8(cnt, idx, qv, qf);
        if (kind == K_LOBES) {
            sum_lobes(cnt, idx, qv, qf, node8, n, add(scl(n, 2.0 * co), scl(wo, -1.0)), co, prm, E, S);
        } else if (kind == K_BLINN || kind == K_AS) {
            const double fr[9] = {t.x, t.y, t.z, bt.x, bt.y, bt.z, n.x, n.y, n.z};
            sum_half(kind, cnt, idx, qv, qf, node8, fr, wol, prm, E, S);
            if (kind == K_BLINN) { S[0] *= prm[3]; S[1] *= prm[4]; S[2] *= prm[5]; }
        } else {
            const float fr[9] = {(float)t.x, (float)t.y, (float)t.z, (float)bt.x, (float)bt.y, (float)bt.z,
                                 (float)n.x, (float)n.y, (float)n.z};
            sum_avx2(kind, cnt, idx, qv, qf, node8, fr, wol, prm, tab, E, S);
            if (kind == K_GGX) { S[0] *= gpo * prm[3]; S[1] *= gpo * prm[4]; S[2] *= gpo * prm[5]; }
        }
        for (int c = 0; c < 3; c++) acc[c] = prm[c] * INV_PI * E[c] + S[c];
        return;
    }
#else
    (void)simd;
#endif
    for (int64_t j = 0; j < cnt; j++) {
        const float *L = node8 + 8 * (int64_t)idx[j];
        if (L[0] <= 0 && L[1] <= 0 && L[2] <= 0) continue;
        v3 wi = mk(L[3], L[4], L[5]);
        double ci = dot(wi, n);
        if (ci < 1e-3) wi = nrm(add(wi, scl(n, 1e-3 - ci)));
        double fr[3];
        brdf_eval(kind, prm, tab, wi, wo, n, t, bt, gpo, fr);
        double q = qf ? (double)qf[j] : qv[j] * (1.0 / 255.0);
        acc[0] += L[0] * q * fr[0]; acc[1] += L[1] * q * fr[1]; acc[2] += L[2] * q * fr[2];
    }
}

/* ---------------------------------------------------------------------------------------
 * The ancestor test: which nodes of level alevel (at most 64, one bit each) have a descendant
 * the cluster walk may split about mirror direction r. anc (2^(H − alevel), 3) float32 holds
 * per such node (cos, sin, value) of the angle B bounding every descendant's cone (the angle
 * between their directions plus the descendant's radius: kernels.py _ancestor_bounds). A
 * descendant D is split only where angle(dir_D, r) < R_D + e (cone_reaches), and
 * angle(dir_D, r) ≥ angle(dir_A, r) − (B − R_D): none is when angle(dir_A, r) ≥ B + e (a margin
 * ANC_MARGIN over it covers the float directions). The vector walk skips the cone tests of the
 * groups of entries under such ancestors (8 gathers a group, and their cache lines: with a sharp
 * fitted srbf, a third of the shading); which nodes are split does not change. anc NULL: every bit.
 */
#define ANC_MARGIN 1e-3
static uint64_t ancestors_reaching(const float *anc, int alevel, int H, const int64_t *lev, const float *node_dir,
                                   v3 r, double extent, double ce, double se) {
    if (!anc || H - alevel > 6) return ~(uint64_t)0;
    const int NA = 1 << (H - alevel);
    uint64_t m = 0;
    for (int a = 0; a < NA; a++) {
        const float *b = anc + 3 * a;
        const int64_t id = lev[alevel] + a;
        if ((double)b[2] + extent + ANC_MARGIN >= PI) { m |= (uint64_t)1 << a; continue; }
        double d = node_dir[3 * id] * r.x + node_dir[3 * id + 1] * r.y + node_dir[3 * id + 2] * r.z;
        if (d > (double)b[0] * ce - (double)b[1] * se) m |= (uint64_t)1 << a;
    }
    return m;
}

/* ---------------------------------------------------------------------------------------
 * normals, wo_dirs (P, 3) float32 unit; cut_of, mat_of (P,) int32 (cut −1: none → 0);
 * cut_off (V+1,) int64, cut_h, cut_q (entries) uint8; node8 (2N−1, 8) float32 (l rgb, ω xyz,
 * 0, 0); node_dir (2N−1, 3), node_radius (2N−1,) float32; node_geo (2N−1, 8) float32 (cos R,
 * sin R, direction, R, 0, 0: kernels.py _node_geo); level_off (H+2,) int64; materials
 * mat_kind (M,) int32, mat_params (M, N_PARAMS), mat_refine, mat_extent (M,) float32 radians,
 * tables float32 with table_off (M,) int64 (−1 none). Writes out (P, 3) float32 radiance.
 */
void glk_shade_points(
    int64_t P, const float *normals, const float *wo_dirs, const int32_t *cut_of,
    const int32_t *mat_of, const int64_t *cut_off, const uint8_t *cut_h, const uint8_t *cut_q,
    const float *node8, const float *node_dir, const float *node_radius, const float *node_geo,
    const int64_t *level_off, int H, const int32_t *mat_kind, const float *mat_params,
    const float *mat_refine, const float *mat_extent, const float *tables, const int64_t *table_off,
    const float *anc, int alevel, float *out) {
    const int simd = glk_shade_simd(-1);
    const int64_t cap = ((int64_t)1 << H) + 8;
    int M = 0;
    for (int64_t p = 0; p < P; p++) if (mat_of[p] + 1 > M) M = mat_of[p] + 1;
    int *hr = (int *)malloc(sizeof(int) * (M > 0 ? M : 1));
    double *ae = (double *)malloc(sizeof(double) * 2 * (M > 0 ? M : 1));
    for (int i = 0; i < M; i++) {
        hr[i] = refine_level(node_radius, level_off, H, mat_refine[i]);
        /* the ancestor test's angle: the extent and a margin over the walk's exact test */
        ae[2 * i] = cos(mat_extent[i] + ANC_MARGIN); ae[2 * i + 1] = sin(mat_extent[i] + ANC_MARGIN);
    }
#pragma omp parallel
    {
        int32_t *idx = (int32_t *)malloc(sizeof(int32_t) * cap);
        uint8_t *qv = (uint8_t *)malloc(cap);
#pragma omp for schedule(dynamic, 16)
        for (int64_t p = 0; p < P; p++) {
            v3 n = mk(normals[3 * p], normals[3 * p + 1], normals[3 * p + 2]);
            v3 wo = facing_view(n, mk(wo_dirs[3 * p], wo_dirs[3 * p + 1], wo_dirs[3 * p + 2]));
            double acc[3] = {0, 0, 0};
            double co = dot(n, wo);
            int mi = mat_of[p];
            if (co > 0 && cut_of[p] >= 0) {
                int kind = mat_kind[mi];
                const float *prm = mat_params + (int64_t)mi * N_PARAMS;
                const float *tab = table_off[mi] >= 0 ? tables + table_off[mi] : NULL;
                v3 r = add(scl(n, 2.0 * co), scl(wo, -1.0));
                v3 t, bt; onb(n, &t, &bt);
                /* GGX's per-point factor G1(ωo)/(4 cosθo): h·ωo > 0 always holds for h of ωi, ωo
                 * in the upper hemisphere, so G1(ωo) does not depend on the cluster */
                double gpo = kind == K_GGX ? ggx_G1(co, 1.0, prm[6]) / (4.0 * co) : 0.0;
                int64_t c0 = cut_off[cut_of[p]], c1 = cut_off[cut_of[p] + 1], cnt;
#ifdef GLK_X86
                const refine_ctx rc = make_ctx(level_off, node_radius, node_geo, r, mat_refine[mi],
                                               mat_extent[mi]);
                if (simd && H <= 15)
                    cnt = collect_avx2(c0, c1, cut_h, cut_q, H, &rc, hr[mi],
                                       ancestors_reaching(anc, alevel, H, level_off, node_dir, r, mat_extent[mi],
                                                          ae[2 * mi], ae[2 * mi + 1]),
                                       alevel, idx, qv);
                else
#endif
                    cnt = collect(c0, c1, cut_h, cut_q, &rc, hr[mi], idx, qv);
                sum_point(simd, kind, prm, tab, n, wo, t, bt, co, gpo, cnt, idx, qv, NULL, node8, acc);
            }
            out[3 * p] = (float)acc[0]; out[3 * p + 1] = (float)acc[1]; out[3 * p + 2] = (float)acc[2];
        }
        free(idx); free(qv);
    }
    free(hr); free(ae);
}

/* ---------------------------------------------------------------------------------------
 * Per-pixel shading inside faces (pixel mode, the refined mode's rows): point p shades the
 * blend of its face's three vertex cuts verts[3p..3p+2] with weights bary[3p..3p+2] (one
 * cluster list instead of three) with its own normal and view direction. Points come in G
 * groups [group[g], group[g+1]) of one face each (the same three vertices): the cuts are merged
 * once per group (merge_cuts), each point blends the merged list (blend_list). Same arrays as
 * glk_shade_points otherwise; core/render.py shade_blend_numpy is the reference. */
void glk_shade_blend(
    int64_t P, const float *normals, const float *wo_dirs, const int32_t *verts, const float *bary,
    const int32_t *mat_of, int64_t G, const int64_t *group, const int64_t *cut_off, const uint8_t *cut_h,
    const uint8_t *cut_q, const float *node8, const float *node_radius, const float *node_geo,
    const int64_t *level_off, int H, const int32_t *mat_kind, const float *mat_params,
    const float *mat_refine, const float *mat_extent, const float *tables, const int64_t *table_off,
    float *out) {
    const int simd = glk_shade_simd(-1);
    const int64_t cap = ((int64_t)1 << H) + 8;
    int M = 0;
    for (int64_t p = 0; p < P; p++) if (mat_of[p] + 1 > M) M = mat_of[p] + 1;
    int *hr = (int *)malloc(sizeof(int) * (M > 0 ? M : 1));
    for (int i = 0; i < M; i++) hr[i] = refine_level(node_radius, level_off, H, mat_refine[i]);
#pragma omp parallel
    {
        int32_t *idx = (int32_t *)malloc(sizeof(int32_t) * cap);
        float *qf = (float *)malloc(sizeof(float) * cap);
        merged_cuts mc = {0, NULL, NULL, NULL, NULL, NULL, NULL, NULL};
#pragma omp for schedule(dynamic, 4)
        for (int64_t g = 0; g < G; g++) {
            int64_t U = -1;                     /* merged lazily: a group's points may have no cuts */
            for (int64_t p = group[g]; p < group[g + 1]; p++) {
                v3 n = mk(normals[3 * p], normals[3 * p + 1], normals[3 * p + 2]);
                v3 wo = facing_view(n, mk(wo_dirs[3 * p], wo_dirs[3 * p + 1], wo_dirs[3 * p + 2]));
                double acc[3] = {0, 0, 0};
                double co = dot(n, wo);
                int mi = mat_of[p];
                if (co > 0 && verts[3 * p] >= 0) {
                    if (U < 0) {
                        const int64_t c3[3] = {cut_off[verts[3 * p]], cut_off[verts[3 * p + 1]],
                                               cut_off[verts[3 * p + 2]]};
                        int64_t need = 0;
                        for (int i = 0; i < 3; i++) need += cut_off[verts[3 * p + i] + 1] - c3[i];
                        merged_reserve(&mc, need);
                        U = merge_cuts(c3, cut_h, cut_q, H, level_off, node_radius, mat_refine[mi], hr[mi], &mc);
                    }
                    int kind = mat_kind[mi];
                    const float *prm = mat_params + (int64_t)mi * N_PARAMS;
                    const float *tab = table_off[mi] >= 0 ? tables + table_off[mi] : NULL;
                    v3 r = add(scl(n, 2.0 * co), scl(wo, -1.0));
                    v3 t, bt; onb(n, &t, &bt);
                    double gpo = kind == K_GGX ? ggx_G1(co, 1.0, prm[6]) / (4.0 * co) : 0.0;
                    const double w3[3] = {bary[3 * p], bary[3 * p + 1], bary[3 * p + 2]};
                    int64_t cnt;
                    const refine_ctx rc = make_ctx(level_off, node_radius, node_geo, r, mat_refine[mi],
                                                   mat_extent[mi]);
#ifdef GLK_X86
                    if (simd)
                        cnt = blend_list_avx2(U, &mc, w3, &rc, idx, qf);
                    else
#endif
                        cnt = blend_list(U, &mc, w3, &rc, idx, qf);
                    sum_point(simd, kind, prm, tab, n, wo, t, bt, co, gpo, cnt, idx, NULL, qf, node8, acc);
                }
                out[3 * p] = (float)acc[0]; out[3 * p + 1] = (float)acc[1]; out[3 * p + 2] = (float)acc[2];
            }
        }
        free(idx); free(qf); merged_free(&mc);
    }
    free(hr);
}
