"""BRDF evaluation on arrays of local-frame directions, for any registered model.

The models themselves live in worker/models (one module each: schema, packing, NumPy
reference, kernel branch). This module keeps the functions the rest of the science core calls:

* ``pack(material)`` -> PackedBRDF, the kernels' flat form;
* ``eval_packed(packed, wi, wo)`` and ``evaluate(material, wi, wo)``: f(ωi, ωo) (…, 3)
  float64 in 1/sr for unit local directions (…, 3) (z = normal), zero below either horizon;
* tangent frames (``onb``, ``to_local``);
* the shared pieces of particular models, re-exported for their users (GGX D and G1, the
  p(h) table machinery of srbf and curve).
"""
from __future__ import annotations

import numpy as np

from ..models.base import INV_PI, N_PARAMS, TABLE_N, Geometry, PackedBRDF  # noqa: F401
from ..models.curve import curve_p  # noqa: F401
from ..models.ggx import ggx_D, ggx_G1  # noqa: F401
from ..models.srbf import srbf_material_p, srbf_p, srbf_refinement  # noqa: F401
from ..models.table import (STATICS, distribution_static, hemisphere_table_dirs, octa_uv, schlick,  # noqa: F401
                            smith_lambda, table_lookup)


def pack(m) -> PackedBRDF:
    """Scene material (any registered model) -> PackedBRDF."""
    return m.pack()


def eval_packed(b: PackedBRDF, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """f(ωi, ωo) for local-frame unit directions wi, wo (…, 3) -> (…, 3) float64 1/sr, as the
    kernels evaluate the packed form (e.g. srbf through its p(h) table)."""
    return b.eval(wi, wo)


def evaluate(material, wi, wo) -> np.ndarray:
    """Evaluate a scene material (scene.Lambert, GGX, …) at local directions (…, 3) (its pack
    shared with the renderer's, models.base.packed)."""
    from ..models.base import packed

    return packed(material).eval(wi, wo)


def srbf_exact(m, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """SRBF BRDF by the exact sum over centres (no table), for testing the table."""
    return m.exact(wi, wo)


def onb(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangent frames for unit normals (…, 3): Duff et al. 2017 branchless basis (as pbrt-v4).
    Returns (t, b) with (t, b, n) right-handed."""
    nx, ny, nz = n[..., 0], n[..., 1], n[..., 2]
    s = np.where(nz >= 0, 1.0, -1.0)
    a = -1.0 / (s + nz)
    bb = nx * ny * a
    t = np.stack([1.0 + s * nx * nx * a, s * bb, -s * nx], axis=-1)
    b = np.stack([bb, s + ny * ny * a, -ny], axis=-1)
    return t, b


def to_local(v: np.ndarray, n: np.ndarray) -> np.ndarray:
    """World directions v (…, 3) into the frame (t, b, n) of normals n (…, 3)."""
    t, b = onb(n)
    return np.stack([(v * t).sum(-1), (v * b).sum(-1), (v * n).sum(-1)], axis=-1)
