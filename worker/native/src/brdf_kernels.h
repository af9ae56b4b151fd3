/* The BRDF kernel branches and the packed material layout shared by the C files that evaluate
 * materials (glintk.c: glk_model_id; shade.c: glk_shade_points). Python never copies these
 * ids: each model names its branch (worker/models, ``kernel``) and the binding asks
 * glk_model_id at load time; the layout is checked against worker/models/base.py. */
#ifndef GLINT_BRDF_KERNELS_H
#define GLINT_BRDF_KERNELS_H

enum { K_LAMBERT, K_GGX, K_BLINN, K_LOBES, K_TABLE, K_AS, K_COUNT };
#define N_PARAMS 132    /* floats per packed material (worker/models/base.py N_PARAMS) */
#define TABLE_N 160     /* p(h) table edge (worker/models/base.py TABLE_N) */

#endif
