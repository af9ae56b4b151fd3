"""The tabulated-distribution kernel shared by ``srbf`` and ``curve``: a p(h) table over the
upper hemisphere times the static function of inverse-brdf-modeling eq. 11,

    f_s(ωi, ωo) = p(h) · F(ωi·h) / (cosθi + cosθo − cosθi cosθo),

with Schlick's F. The table is sampled in hemi-octahedral coordinates (one division per lookup
instead of an acos and an atan2) and read bilinearly, here and in the C kernel's ``table``
branch alike.
"""
from __future__ import annotations

import numpy as np

from .base import TABLE_N, Geometry


def schlick(f0: float, cos_d: np.ndarray) -> np.ndarray:
    m = np.clip(1.0 - cos_d, 0.0, 1.0)
    return f0 + (1.0 - f0) * m ** 5


def distribution_static(cos_i, cos_o, cos_d, f0):
    """The static function s of inverse-brdf-modeling eq. 11: F(ωi·h)/(ci + co − ci·co)."""
    return schlick(f0, cos_d) / np.maximum(cos_i + cos_o - cos_i * cos_o, 1e-12)


def octa_uv(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hemi-octahedral coordinates (u, v) ∈ [−1, 1]² of upper-hemisphere unit vectors (…, 3):
    project onto |x| + |y| + z = 1, then rotate the diamond by 45° onto the square."""
    s = np.abs(h[..., 0]) + np.abs(h[..., 1]) + np.maximum(h[..., 2], 0.0)
    s = np.maximum(s, 1e-30)
    px, py = h[..., 0] / s, h[..., 1] / s
    return px + py, px - py


def hemisphere_table_dirs(n: int = TABLE_N) -> np.ndarray:
    """(n, n, 3) local unit directions at the table's samples: u_i, v_j = −1 + 2i/(n − 1)."""
    g = np.linspace(-1.0, 1.0, n)
    U, V = np.meshgrid(g, g, indexing="ij")
    px, py = 0.5 * (U + V), 0.5 * (U - V)
    z = np.maximum(1.0 - np.abs(px) - np.abs(py), 0.0)
    d = np.stack([px, py, z], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def table_lookup(table: np.ndarray, h_local: np.ndarray) -> np.ndarray:
    """Bilinear lookup of an (n, n, 3) p(h) table at local half vectors h (…, 3)."""
    n = table.shape[0]
    u, v = octa_uv(h_local)
    fu = np.clip((u + 1.0) * (0.5 * (n - 1)), 0.0, n - 1.0)
    fv = np.clip((v + 1.0) * (0.5 * (n - 1)), 0.0, n - 1.0)
    i0 = np.minimum(fu.astype(np.int64), n - 2); a = (fu - i0)[..., None]
    j0 = np.minimum(fv.astype(np.int64), n - 2); b = (fv - j0)[..., None]
    t0 = table[i0, j0] * (1 - b) + table[i0, j0 + 1] * b
    t1 = table[i0 + 1, j0] * (1 - b) + table[i0 + 1, j0 + 1] * b
    return t0 * (1 - a) + t1 * a


def table_specular(table: np.ndarray, f0: float):
    """The NumPy reference of the kernel's ``table`` branch for one packed table."""
    table = np.asarray(table, np.float64)

    def spec(g: Geometry) -> np.ndarray:
        return table_lookup(table, g.h) * distribution_static(g.ci, g.co, g.cd, f0)[..., None]
    return spec
