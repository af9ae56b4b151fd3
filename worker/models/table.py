"""The tabulated-distribution kernel shared by ``srbf`` and ``curve``: a p(h) table over the
upper hemisphere times a static function s(ωi, ωo) (inverse-brdf-modeling eq. 4),

    f_s(ωi, ωo) = p(h) · s(ωi, ωo),

s the paper's F(ωi·h)/(cosθi + cosθo − cosθi cosθo) (eq. 11; ``curve`` always, ``srbf`` by
default) or the microfacet one with Smith-GGX shadowing (``smith``, srbf only), with Schlick's F.
Packed parameters: [*albedo, F0, static id (STATICS), the smith static's α]. The table is
sampled in hemi-octahedral coordinates (one division per lookup instead of an acos and an
atan2) and read bilinearly, here and in the C kernel's ``table`` branch alike.
"""
from __future__ import annotations

import numpy as np

from .base import TABLE_N, Geometry


def schlick(f0: float, cos_d: np.ndarray) -> np.ndarray:
    m = np.clip(1.0 - cos_d, 0.0, 1.0)
    return f0 + (1.0 - f0) * m ** 5


# static functions of the table kernel (packed param 4); ids match the ``table`` branch in C
# (shade.c brdf_eval and sum_table, fit.c fit_static)
STATICS = {"paper": 0, "smith": 1}


def smith_lambda(cos_v, alpha):
    """√(α² + (1 − α²) cos²θ): G1(ω) = 2 cosθ / (cosθ + this) for GGX's separable Smith G1
    (Mitsuba's 2/(1 + √(1 + α² tan²θ)), multiplied through by cosθ so it has no 1/cosθ)."""
    return np.sqrt(alpha * alpha + (1.0 - alpha * alpha) * cos_v * cos_v)


def distribution_static(cos_i, cos_o, cos_d, f0, static: str = "paper", alpha: float = 0.1):
    """The static function s(ωi, ωo) of the distribution BRDF f_s = p(h)·s (inverse-brdf-modeling
    eq. 4, 11), in 1/sr per unit p, for cosines (…,) ≥ 0.

    ``paper``: F(ωi·h)/(ci + co − ci·co), eq. 11 (Ashikhmin's distribution-based BRDF).
    ``smith``: F(ωi·h)·G1(ωi)G1(ωo)/(4 ci co) = F/((ci + Λi)(co + Λo)) with Λ = smith_lambda(·, α):
    the microfacet form (Walter et al. 2007 eq. 20) with GGX's separable Smith shadowing, so that
    p = specular·D_GGX(α) reproduces the ``ggx`` model exactly. Unlike eq. 11's denominator,
    which falls only to ci + co at grazing angles, it keeps the 1/(ci co) growth of a microfacet
    surface's mirror-direction radiance until shadowing sets in at cosθ ≈ α."""
    F = schlick(f0, cos_d)
    if static == "paper":
        return F / np.maximum(cos_i + cos_o - cos_i * cos_o, 1e-12)
    if static == "smith":
        return F / ((cos_i + smith_lambda(cos_i, alpha)) * (cos_o + smith_lambda(cos_o, alpha)))
    raise ValueError(f"unknown static function {static!r} (paper or smith)")


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


def table_specular(table: np.ndarray, f0: float, static: str = "paper", alpha: float = 0.1):
    """The NumPy reference of the kernel's ``table`` branch for one packed table (cosines are
    clamped at 0: f is zero below either horizon anyway, and the smith static's root stays real)."""
    table = np.asarray(table, np.float64)

    def spec(g: Geometry) -> np.ndarray:
        s = distribution_static(np.maximum(g.ci, 0.0), np.maximum(g.co, 0.0), g.cd, f0, static, alpha)
        return table_lookup(table, g.h) * s[..., None]
    return spec
