/* shade_driver DIR MODEL REPS: glk_shade_points on the arrays bench/shade_inputs.py wrote;
 * prints the CPU time per call (best and mean of REPS) and a checksum; SCALAR=1 forces the
 * scalar path. For callgrind instruction counts without Python in the count. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

void glk_shade_points(int64_t P, const float *normals, const float *wo_dirs, const int32_t *cut_of,
                      const int32_t *mat_of, const int64_t *cut_off, const uint8_t *cut_h, const uint8_t *cut_q,
                      const float *node8, const float *node_dir, const float *node_radius, const int64_t *level_off,
                      int H, const int32_t *mat_kind, const float *mat_params, const float *mat_refine,
                      const float *mat_extent, const float *tables, const int64_t *table_off, float *out);
int glk_shade_simd(int want);

static void *rd(const char *dir, const char *name, long *n) {
    char p[1024];
    snprintf(p, sizeof p, "%s/%s.bin", dir, name);
    FILE *f = fopen(p, "rb");
    if (!f) { perror(p); exit(1); }
    fseek(f, 0, SEEK_END);
    long s = ftell(f);
    fseek(f, 0, SEEK_SET);
    void *b = malloc(s + 64);
    if (fread(b, 1, s, f) != (size_t)s) { perror(p); exit(1); }
    fclose(f);
    if (n) *n = s;
    return b;
}

int main(int argc, char **argv) {
    if (argc < 3) { fprintf(stderr, "usage: %s DIR MODEL [REPS]\n", argv[0]); return 2; }
    const char *dir = argv[1], *m = argv[2];
    int reps = argc > 3 ? atoi(argv[3]) : 1;
    long nb, nl;
    float *n = rd(dir, "n", &nb), *wo = rd(dir, "wo", 0);
    long P = nb / 12;
    int32_t *vi = rd(dir, "vi", 0);
    int64_t *off = rd(dir, "off", 0), *lev = rd(dir, "lev", &nl);
    uint8_t *h = rd(dir, "h", 0), *q = rd(dir, "q", 0);
    float *n8 = rd(dir, "node8", 0), *nd = rd(dir, "ndir", 0), *nr = rd(dir, "nrad", 0);
    char k[64];
    snprintf(k, 64, "%s_kind", m); int32_t *kind = rd(dir, k, 0);
    snprintf(k, 64, "%s_params", m); float *prm = rd(dir, k, 0);
    snprintf(k, 64, "%s_refine", m); float *ref = rd(dir, k, 0);
    snprintf(k, 64, "%s_extent", m); float *ext = rd(dir, k, 0);
    snprintf(k, 64, "%s_tables", m); float *tab = rd(dir, k, 0);
    snprintf(k, 64, "%s_toff", m); int64_t *toff = rd(dir, k, 0);
    int H = (int)(nl / 8) - 2;
    if (getenv("SCALAR")) glk_shade_simd(0);
    int32_t *mo = calloc(P, 4);
    float *out = malloc(P * 12);
    double best = 1e30, tot = 0;
    for (int r = 0; r < reps; r++) {
        struct timespec a, b;
        clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &a);
        glk_shade_points(P, n, wo, vi, mo, off, h, q, n8, nd, nr, lev, H, kind, prm, ref, ext, tab, toff, out);
        clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &b);
        double ms = (b.tv_sec - a.tv_sec) * 1e3 + (b.tv_nsec - a.tv_nsec) * 1e-6;
        tot += ms;
        if (ms < best) best = ms;
    }
    double cs = 0;
    for (long i = 0; i < 3 * P; i++) cs += out[i];
    printf("%s: %ld points, CPU ms per call best %.1f mean %.1f, checksum %.6g\n", m, P, best, tot / reps, cs);
    return 0;
}
