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
#if defined(__x86_64__)
#include <immintrin.h>
#define GLK_X86 1
#endif
#include "glint_common.h"

int glk_env_simd(int want);

#ifdef GLK_X86
/* glk_background's samples [i0, i1) eight at a time in single precision (the map is float32;
 * the coordinates' rounding is ~1e-7 of a turn, 1e-4 of a texel): the twelve map taps and, for
 * rays that meet the shadow plane, the twelve grid taps by gathers. The scalar loop (double)
 * is the reference's arithmetic and takes the tail. Returns the first sample not done. */
/* The texel coordinate of eight map coordinates c (float32): f = (c + add, wrapped into [0, 1)
 * when wrap) · n − ½ in double precision, as the scalar loop (a float's 1e-7 of a turn is 5e-5
 * of a texel of a 512-wide map: 2e-4 of the radiance across the sun's edge); its floor i (f ≥
 * −½: truncation of f + 1, minus 1) and the fraction f − i as float32. */
__attribute__((target("avx2,fma"))) static inline void texel_pd(__m256 c, double add, int n, int wrap, __m256i *i,
                                                              __m256 *frac) {
    const __m256d one = _mm256_set1_pd(1.0), vadd = _mm256_set1_pd(add), vn = _mm256_set1_pd((double)n);
    const __m256d half = _mm256_set1_pd(0.5);
    __m256d h[2] = {_mm256_cvtps_pd(_mm256_castps256_ps128(c)), _mm256_cvtps_pd(_mm256_extractf128_ps(c, 1))};
    __m128i k[2];
    __m128 fr[2];
    for (int j = 0; j < 2; j++) {
        __m256d x = _mm256_add_pd(h[j], vadd);
        if (wrap) x = _mm256_blendv_pd(x, _mm256_sub_pd(x, one), _mm256_cmp_pd(x, one, _CMP_GE_OQ));
        __m256d f = _mm256_fmsub_pd(x, vn, half);
        k[j] = _mm_sub_epi32(_mm256_cvttpd_epi32(_mm256_add_pd(f, one)), _mm_set1_epi32(1));
        fr[j] = _mm256_cvtpd_ps(_mm256_sub_pd(f, _mm256_cvtepi32_pd(k[j])));
    }
    *i = _mm256_set_m128i(k[1], k[0]);
    *frac = _mm256_set_m128(fr[1], fr[0]);
}

__attribute__((target("avx2,fma"))) static int64_t background_avx2(
    int64_t i0, int64_t i1, const int64_t *sample, const float *dirs, const float *uv0, const float *map, int Hm,
    int Wm, double rt, float intensity, const float *shadow, int G, float gx0, float gz0, float gstep, float gy,
    float ex, float ey, float ez, float *out) {
    const __m256 one = _mm256_set1_ps(1.0f), zero = _mm256_setzero_ps();
    const __m256i iw = _mm256_set1_epi32(Wm), ihm1 = _mm256_set1_epi32(Hm - 1), izero = _mm256_setzero_si256();
    const __m256i i1v = _mm256_set1_epi32(1), three = _mm256_set1_epi32(3);
    const __m256 vint = _mm256_set1_ps(intensity);
    const int down = shadow && ey > gy;
    int64_t i = i0;
    for (; i + 8 <= i1; i += 8) {
        /* (u, v) pairs of eight samples, deinterleaved */
        __m256 a = _mm256_loadu_ps(uv0 + 2 * i), b = _mm256_loadu_ps(uv0 + 2 * i + 8);
        __m256 u = _mm256_castpd_ps(_mm256_permute4x64_pd(_mm256_castps_pd(_mm256_shuffle_ps(a, b, _MM_SHUFFLE(2, 0, 2, 0))), 0xD8));
        __m256 v = _mm256_castpd_ps(_mm256_permute4x64_pd(_mm256_castps_pd(_mm256_shuffle_ps(a, b, _MM_SHUFFLE(3, 1, 3, 1))), 0xD8));
        __m256i x0, y0;
        __m256 ax, ay;
        texel_pd(u, rt, Wm, 1, &x0, &ax);
        texel_pd(v, 0.0, Hm, 0, &y0, &ay);
        __m256i x1 = _mm256_add_epi32(x0, i1v);
        x0 = _mm256_add_epi32(x0, _mm256_and_si256(_mm256_cmpgt_epi32(izero, x0), iw));           /* x0 < 0: + W */
        x1 = _mm256_sub_epi32(x1, _mm256_andnot_si256(_mm256_cmpgt_epi32(iw, x1), iw));           /* x1 ≥ W: − W */
        __m256i y1 = _mm256_add_epi32(y0, i1v);
        y0 = _mm256_min_epi32(_mm256_max_epi32(y0, izero), ihm1);
        y1 = _mm256_min_epi32(_mm256_max_epi32(y1, izero), ihm1);
        __m256i r0 = _mm256_mullo_epi32(y0, iw), r1 = _mm256_mullo_epi32(y1, iw);
        __m256i p00 = _mm256_mullo_epi32(_mm256_add_epi32(r0, x0), three), p01 = _mm256_mullo_epi32(_mm256_add_epi32(r0, x1), three);
        __m256i p10 = _mm256_mullo_epi32(_mm256_add_epi32(r1, x0), three), p11 = _mm256_mullo_epi32(_mm256_add_epi32(r1, x1), three);
        __m256 bx = _mm256_sub_ps(one, ax), by = _mm256_sub_ps(one, ay);
        __m256 f[3] = {one, one, one};
        if (down) {
            int32_t rows[8];
            for (int k = 0; k < 8; k++) rows[k] = (int32_t)(3 * sample[i + k]);
            __m256i ro = _mm256_loadu_si256((const __m256i *)rows);
            __m256 dx = _mm256_i32gather_ps(dirs, ro, 4), dy = _mm256_i32gather_ps(dirs + 1, ro, 4);
            __m256 dz = _mm256_i32gather_ps(dirs + 2, ro, 4);
            __m256 neg = _mm256_cmp_ps(dy, zero, _CMP_LT_OQ);
            if (_mm256_movemask_ps(neg)) {
                __m256 t = _mm256_div_ps(_mm256_set1_ps(gy - ey), _mm256_blendv_ps(_mm256_set1_ps(-1.0f), dy, neg));
                __m256 inv = _mm256_set1_ps(1.0f / gstep);
                __m256 gx = _mm256_mul_ps(_mm256_sub_ps(_mm256_fmadd_ps(t, dx, _mm256_set1_ps(ex)), _mm256_set1_ps(gx0)), inv);
                __m256 gz = _mm256_mul_ps(_mm256_sub_ps(_mm256_fmadd_ps(t, dz, _mm256_set1_ps(ez)), _mm256_set1_ps(gz0)), inv);
                __m256 top = _mm256_set1_ps((float)(G - 1));
                __m256 in = _mm256_and_ps(neg, _mm256_and_ps(
                    _mm256_and_ps(_mm256_cmp_ps(gx, zero, _CMP_GE_OQ), _mm256_cmp_ps(gz, zero, _CMP_GE_OQ)),
                    _mm256_and_ps(_mm256_cmp_ps(gx, top, _CMP_LE_OQ), _mm256_cmp_ps(gz, top, _CMP_LE_OQ))));
                if (_mm256_movemask_ps(in)) {
                    gx = _mm256_and_ps(gx, in); gz = _mm256_and_ps(gz, in);        /* outside: texel 0, unused */
                    __m256i gm2 = _mm256_set1_epi32(G - 2);
                    __m256i ig = _mm256_min_epi32(_mm256_cvttps_epi32(gx), gm2), jg = _mm256_min_epi32(_mm256_cvttps_epi32(gz), gm2);
                    __m256 ga = _mm256_sub_ps(gx, _mm256_cvtepi32_ps(ig)), gb = _mm256_sub_ps(gz, _mm256_cvtepi32_ps(jg));
                    __m256i o0 = _mm256_mullo_epi32(_mm256_add_epi32(_mm256_mullo_epi32(ig, _mm256_set1_epi32(G)), jg), three);
                    __m256i o1 = _mm256_add_epi32(o0, _mm256_set1_epi32(3 * G));
                    __m256 gna = _mm256_sub_ps(one, ga), gnb = _mm256_sub_ps(one, gb);
                    for (int c = 0; c < 3; c++) {
                        __m256i cc = _mm256_set1_epi32(c);
                        __m256i q0 = _mm256_add_epi32(o0, cc), q1 = _mm256_add_epi32(o1, cc);
                        __m256 s00 = _mm256_i32gather_ps(shadow, q0, 4), s01 = _mm256_i32gather_ps(shadow, _mm256_add_epi32(q0, three), 4);
                        __m256 s10 = _mm256_i32gather_ps(shadow, q1, 4), s11 = _mm256_i32gather_ps(shadow, _mm256_add_epi32(q1, three), 4);
                        __m256 g0 = _mm256_fmadd_ps(s01, gb, _mm256_mul_ps(s00, gnb));
                        __m256 g1 = _mm256_fmadd_ps(s11, gb, _mm256_mul_ps(s10, gnb));
                        f[c] = _mm256_blendv_ps(one, _mm256_fmadd_ps(g1, ga, _mm256_mul_ps(g0, gna)), in);
                    }
                }
            }
        }
        float res[3][8];
        for (int c = 0; c < 3; c++) {
            __m256i cc = _mm256_set1_epi32(c);
            __m256 t00 = _mm256_i32gather_ps(map, _mm256_add_epi32(p00, cc), 4);
            __m256 t01 = _mm256_i32gather_ps(map, _mm256_add_epi32(p01, cc), 4);
            __m256 t10 = _mm256_i32gather_ps(map, _mm256_add_epi32(p10, cc), 4);
            __m256 t11 = _mm256_i32gather_ps(map, _mm256_add_epi32(p11, cc), 4);
            __m256 c0 = _mm256_fmadd_ps(t01, ax, _mm256_mul_ps(t00, bx));
            __m256 c1 = _mm256_fmadd_ps(t11, ax, _mm256_mul_ps(t10, bx));
            __m256 val = _mm256_fmadd_ps(c1, ay, _mm256_mul_ps(c0, by));
            _mm256_storeu_ps(res[c], _mm256_mul_ps(_mm256_mul_ps(vint, val), f[c]));
        }
        for (int k = 0; k < 8; k++) {
            float *o = out + 3 * sample[i + k];
            o[0] = res[0][k]; o[1] = res[1][k]; o[2] = res[2][k];
        }
    }
    return i;
}
#endif

/* n background samples: sample (n,) int64 index into out (rows of 3) and into dirs (every row's
 * float32 unit world ray direction, read at the samples' rows), uv0 (n, 2) float32 map
 * coordinates without rotation (u in [0, 1), v = acos(y)/π); map (Hm, Wm, 3) float32; the
 * environment rotated by rot radians about +Y and scaled by intensity (docs/design/conventions.md,
 * as glk_env_lookup). shadow: NULL, or a (G, G, 3) float32 factor grid over the plane y = gy with
 * node (i, j) at (gx0 + i·gstep, gy, gz0 + j·gstep), applied (bilinear, 1 outside the grid) to
 * rays from eye that go down through the plane. */
void glk_background(int64_t n, const int64_t *sample, const float *dirs, const float *uv0, const float *map,
                    int Hm, int Wm, double rot, double intensity, const float *shadow, int G, double gx0,
                    double gz0, double gstep, double gy, double ex, double ey, double ez, float *out) {
    const double turns = rot / (2 * PI), rt = turns - floor(turns);
    /* chunks dealt in turn: the samples come in image order, and the rays that go down through
     * the shadow plane (twice the work) are the lower rows, which halves would give one thread */
    const int simd = glk_env_simd(-1);
    enum { B = 4096 };
#pragma omp parallel for schedule(static, 1)
    for (int64_t blk = 0; blk < (n + B - 1) / B; blk++) {
    const int64_t b0 = blk * B, b1 = b0 + B < n ? b0 + B : n;
    int64_t i = b0;
#ifdef GLK_X86
    if (simd)
        i = background_avx2(b0, b1, sample, dirs, uv0, map, Hm, Wm, rt, (float)intensity, shadow, G,
                            (float)gx0, (float)gz0, (float)gstep, (float)gy, (float)ex, (float)ey, (float)ez, out);
#else
    (void)simd;
#endif
    for (; i < b1; i++) {
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
            const float *dr = dirs + 3 * sample[i];
            double dy = dr[1];
            if (ey > gy && dy < 0) {
                double t = (gy - ey) / dy;
                double gx = (ex + t * dr[0] - gx0) / gstep, gz = (ez + t * dr[2] - gz0) / gstep;
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
 * out (n, 2) float32 u = atan2(x, −z)/2π wrapped into [0, 1), v = acos(y)/π (render.py env_coords).
 *
 * Once per view over every background sample (a million at 640×480 with 4 samples), so the
 * library calls are replaced by branch-free single-precision polynomials (Cephes atanf and asinf:
 * ≤ 2e-7 rad, 3e-8 of a turn, 1e-4 of a texel of a 4096-wide map) that the compiler vectorises;
 * the loop is built twice, for AVX2 + FMA and for the baseline ISA, and the CPU picks at run
 * time (glk_env_simd forces the baseline for tests). */
__attribute__((always_inline, optimize("no-trapping-math"))) static inline float atan_unit(float a) {
    /* atan(a) for a in [0, 1]: a > tan(π/8) maps to π/4 + atan((a − 1)/(a + 1)) */
    /* both branches computed and selected, so that the loop has no control flow to vectorise */
    const int big = a > 0.41421356f;
    const float tb = (a - 1.0f) / (a + 1.0f);
    const float t = big ? tb : a;
    const float z = t * t;
    const float p = (((8.05374449538e-2f * z - 1.38776856032e-1f) * z + 1.99777106478e-1f) * z -
                     3.33329491539e-1f) * z * t + t;
    return big ? p + 0.78539816f : p;
}

__attribute__((always_inline, optimize("no-trapping-math"))) static inline float acos_poly(float y) {
    /* acos(y), y in [−1, 1]: |y| ≤ 1/2 as π/2 − asin(y), else 2·asin(sqrt((1 − |y|)/2)) mirrored */
    const float ay = fabsf(y);
    const int big = ay > 0.5f;
    const float xb = sqrtf(0.5f * (1.0f - ay));
    const float x = big ? xb : y;
    const float z = x * x;
    const float s = ((((4.2163199048e-2f * z + 2.4181311049e-2f) * z + 4.5470025998e-2f) * z + 7.4953002686e-2f) * z +
                     1.6666752422e-1f) * z * x + x;
    const float r = big ? 2.0f * s : 1.57079633f - s;
    return (big & (y < 0.0f)) ? 3.14159265f - r : r;
}

#define ENV_COORDS_BODY                                                                            \
    for (int64_t i = i0; i < i1; i++) {                                                            \
        const float x = dirs[3 * i], y = dirs[3 * i + 1], z = -dirs[3 * i + 2];                    \
        const float ax = fabsf(x), az = fabsf(z);                                                  \
        const float mx = ax > az ? ax : az, mn = ax > az ? az : ax;                                \
        float a = atan_unit(mn / (mx > 0.0f ? mx : 1.0f));     /* atan2(x, z) by octant */        \
        a = ax > az ? 1.57079633f - a : a;                                                         \
        a = copysignf(1.0f, z) < 0.0f ? 3.14159265f - a : a;   /* z = −0 too, as atan2 */         \
        a = x < 0.0f ? -a : a;                                                                     \
        float u = a * (float)(0.5 / PI);                                                           \
        u = u < 0.0f ? u + 1.0f : u;                                                               \
        u = u >= 1.0f ? u - 1.0f : u;                                                              \
        const float yc = y < -1.0f ? -1.0f : (y > 1.0f ? 1.0f : y);                                \
        out[2 * i] = u;                                                                            \
        out[2 * i + 1] = acos_poly(yc) * (float)(1.0 / PI);                                        \
    }

/* no-trapping-math: the selects between branches computed in full may then be vectorised
 * (the values are the same; only floating-point exception flags could differ) */
__attribute__((target("avx2,fma"), optimize("no-trapping-math"))) static void env_coords_avx2(
    int64_t i0, int64_t i1, const float *dirs, float *out) {
#pragma omp simd
    ENV_COORDS_BODY
}

__attribute__((optimize("no-trapping-math"))) static void env_coords_base(int64_t i0, int64_t i1,
                                                                          const float *dirs, float *out) {
#pragma omp simd
    ENV_COORDS_BODY
}

static int env_simd = -1;     /* −1: not chosen yet; 0: baseline; 1: AVX2 + FMA */

/* The env_coords path: want −1 asks, 0 forces the baseline, 1 the best the CPU has. */
int glk_env_simd(int want) {
    if (want >= 0 || env_simd < 0) {
#if defined(__GNUC__) && (defined(__x86_64__) || defined(__i386__))
        env_simd = want != 0 && __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
#else
        env_simd = 0;
#endif
    }
    return env_simd;
}

/* glk_env_coords of the directions at rows (n,) int64 of dirs (a view's background rows among
 * all its rays): each thread copies a block of them into its own buffer and converts that, so
 * no (n, 3) copy of the rows is made first (2.7 ms of a 640×480 orbit frame as a NumPy gather). */
void glk_env_coords_rows(int64_t n, const int64_t *rows, const float *dirs, float *out) {
    const int simd = glk_env_simd(-1);
    enum { B = 1024 };
#pragma omp parallel
    {
        float buf[3 * B];
#pragma omp for schedule(static)
        for (int64_t b = 0; b < (n + B - 1) / B; b++) {
            const int64_t i0 = b * B, m = i0 + B < n ? B : n - i0;
            for (int64_t k = 0; k < m; k++) {
                const float *d = dirs + 3 * rows[i0 + k];
                buf[3 * k] = d[0]; buf[3 * k + 1] = d[1]; buf[3 * k + 2] = d[2];
            }
            if (simd) env_coords_avx2(0, m, buf, out + 2 * i0);
            else env_coords_base(0, m, buf, out + 2 * i0);
        }
    }
}

void glk_env_coords(int64_t n, const float *dirs, float *out) {
    const int simd = glk_env_simd(-1);
    const int64_t B = 4096;
#pragma omp parallel for schedule(static)
    for (int64_t b = 0; b < (n + B - 1) / B; b++) {
        const int64_t i0 = b * B, i1 = i0 + B < n ? i0 + B : n;
        if (simd) env_coords_avx2(i0, i1, dirs, out);
        else env_coords_base(i0, i1, dirs, out);
    }
}
