"""BRDF models of DESIGN.md §3, evaluable on arrays of local-frame directions.

Every model is written as ``f = albedo/π + specular part`` and evaluated from a handful of
cosines, so the NumPy reference and the C kernel share one parameterisation (``pack``):

* ``lambert``      albedo/π
* ``ggx``          albedo/π + specular·D(h)·G1(ωi)G1(ωo)/(4 cosθi cosθo); D and the separable
                   Smith G exactly as Mitsuba 3 ``roughconductor`` (GGX, ``material: none``,
                   i.e. Fresnel = 1 scaled by ``specular_reflectance``).
* ``blinn-phong``  albedo/π + specular·(e+8)/(8π)·cos^e θh
* ``lobes``        cacad-cosine-lobes eq. 1-3 in reciprocal form (see scene.Lobes)
* ``srbf``         inverse-brdf-modeling eq. 11-12: p(h)·s(ωi, ωo), s the paper's static
                   F(ωi·h)/(cosθi + cosθo − cosθi cosθo) or the microfacet (Smith) one
* ``curve``        the paper's quotient form with p a piecewise-constant function of θh

Directions are unit (…, 3) arrays in a local frame with the normal along +z, or given as cosines.
Returns radiance-per-irradiance in 1/sr, float64 (…, 3) RGB. Below the horizon f = 0.
"""
from __future__ import annotations

import numpy as np

from ..scene import GGX, SRBF, BlinnPhong, Curve, Lambert, Lobes

INV_PI = 1.0 / np.pi

# kernel model ids (must match worker/native/src/glintk.c)
K_LAMBERT, K_GGX, K_BLINN, K_LOBES, K_TABLE = 0, 1, 2, 3, 4
N_PARAMS = 72
# p(h) tables over the upper hemisphere in hemi-octahedral coordinates (hemisphere_table_dirs):
# N×N samples, ~0.9° apart; a lookup costs one division instead of an acos and an atan2
TABLE_N = 160


def ggx_D(cos_h: np.ndarray, alpha: float) -> np.ndarray:
    """GGX normal distribution D(h) (1/sr), Mitsuba's MicrofacetDistribution::eval."""
    c2 = np.clip(cos_h, 0.0, 1.0) ** 2
    a2 = alpha * alpha
    denom = c2 * (a2 - 1.0) + 1.0
    return np.where(cos_h > 0, a2 / (np.pi * denom * denom), 0.0)


def ggx_G1(cos_v: np.ndarray, cos_vh: np.ndarray, alpha: float) -> np.ndarray:
    """Smith G1 for GGX: 2/(1 + sqrt(1 + α² tan²θ)), zero when ω·h and cosθ disagree in sign."""
    c2 = np.maximum(cos_v * cos_v, 1e-20)
    tan2 = np.maximum(1.0 - c2, 0.0) / c2
    g = 2.0 / (1.0 + np.sqrt(1.0 + alpha * alpha * tan2))
    return np.where(cos_vh * cos_v > 0, g, 0.0)


def schlick(f0: float, cos_d: np.ndarray) -> np.ndarray:
    m = np.clip(1.0 - cos_d, 0.0, 1.0)
    return f0 + (1.0 - f0) * m ** 5


# static functions of the srbf model (scene.SRBF.static); ids match the K_TABLE branch in C
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


def srbf_p(h_local: np.ndarray, centers: np.ndarray, bandwidth, coef: np.ndarray) -> np.ndarray:
    """p(h) = Σ_j c_j exp(λ_j(h·ξ_j − 1)) (inverse-brdf-modeling eq. 12).

    h_local (…, 3), centers (J, 3), bandwidth λ (scalar, or (J,) per centre), coef (J, 3) -> (…, 3)."""
    g = np.exp(np.asarray(bandwidth, np.float64) * (h_local @ centers.T - 1.0))
    return g @ coef


def srbf_material_p(m: SRBF, h_local: np.ndarray) -> np.ndarray:
    """p(h) (…, 3) of an srbf material at local unit half vectors (…, 3), every centre with its
    own λ (multi-scale materials; for plots such as the studio's half-angle curve)."""
    c = np.asarray(m.centers, np.float64)
    c = c / np.linalg.norm(c, axis=1, keepdims=True)
    return srbf_p(np.asarray(h_local, np.float64), c, np.asarray(m.lambdas()), np.asarray(m.coefficients, np.float64))


def curve_p(cos_h: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Box basis over θh ∈ [0, π/2]: values (K, 3) -> p (…, 3)."""
    k = len(values)
    th = np.arccos(np.clip(cos_h, 0.0, 1.0))
    idx = np.clip((th * (2.0 * k / np.pi)).astype(np.int64), 0, k - 1)
    return values[idx]


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


class PackedBRDF:
    """A material in the kernel's flat form: model id, (N_PARAMS,) float32 params, optional
    (TABLE_N, TABLE_N, 3) float32 p(h) table (hemi-octahedral), and how the renderer refines
    clusters for it: a cluster of radius R (radians) at angle a from the mirror direction is split while
    R > ``refine_radius`` and a < R + ``extent`` (the specular part is non-zero only within
    ``extent`` of the mirror direction). By default ``lobe_width`` w gives (w/2, 2w)."""

    def __init__(self, kind: int, params, table=None, lobe_width: float = np.inf,
                 refine_radius: float | None = None, extent: float | None = None):
        self.kind = kind
        self.params = np.zeros(N_PARAMS, np.float32)
        self.params[: len(params)] = params
        self.table = None if table is None else np.ascontiguousarray(table, dtype=np.float32)
        self.refine_radius = float(0.5 * lobe_width if refine_radius is None else refine_radius)
        self.extent = float(2.0 * lobe_width if extent is None else extent)


def pack(m) -> PackedBRDF:
    """Scene material model -> PackedBRDF."""
    if isinstance(m, Lambert):
        return PackedBRDF(K_LAMBERT, [*m.albedo])
    if isinstance(m, GGX):
        # most of D's mass lies within θh ≲ 2α; ωi moves twice as fast as h
        return PackedBRDF(K_GGX, [*m.albedo, *m.specular, m.alpha], lobe_width=min(np.pi, 2 * np.arctan(2 * m.alpha)))
    if isinstance(m, BlinnPhong):
        width = min(np.pi, 2 * 2.0 / np.sqrt(m.exponent + 2.0))
        return PackedBRDF(K_BLINN, [*m.albedo, *m.specular, m.exponent], lobe_width=width)
    if isinstance(m, Lobes):
        if not (len(m.exponents) == len(m.gloss) == len(m.directional_diffuse)):
            raise ValueError("lobes: exponents, gloss and directional_diffuse must have equal length")
        p = [*m.albedo, float(len(m.exponents))]
        for e, g, dd in zip(m.exponents, m.gloss, m.directional_diffuse):
            p += [e, g + dd[0], g + dd[1], g + dd[2]]
        width = min(np.pi, 2.0 / np.sqrt(max(m.exponents) + 2.0))
        return PackedBRDF(K_LOBES, p, lobe_width=width)
    if isinstance(m, SRBF):
        d = hemisphere_table_dirs()
        c = np.asarray(m.centers, np.float64)
        c /= np.linalg.norm(c, axis=1, keepdims=True)
        coef = np.asarray(m.coefficients, np.float64)
        lam = np.asarray(m.lambdas(), np.float64)
        table = srbf_p(d, c, lam, coef)
        return PackedBRDF(K_TABLE, [*m.albedo, m.fresnel_f0, STATICS[m.static], m.static_alpha], table,
                          **srbf_refinement(c, lam, coef))
    if isinstance(m, Curve):
        d = hemisphere_table_dirs()
        v = np.asarray(m.values, np.float64)
        table = curve_p(d[..., 2], v)
        nz = np.nonzero(v.max(axis=1) > 0.05 * v.max())[0]
        width = np.pi if len(nz) == 0 else min(np.pi, 2 * (nz.max() + 1) * (np.pi / 2) / len(v))
        return PackedBRDF(K_TABLE, [*m.albedo, m.fresnel_f0], table, lobe_width=width)
    raise TypeError(f"unknown material {type(m).__name__}")


def srbf_refinement(centers: np.ndarray, bandwidth, coef: np.ndarray | None = None) -> dict:
    """Refinement of an SRBF p(h) (centres (J, 3) local unit vectors, λ scalar or (J,),
    coefficients (J, 3)) for the renderer's one (refine radius, extent) pair.

    A Gaussian SRBF exp(λ(h·ξ − 1)) has angular standard deviation ≈ 1/√λ in h, twice that in
    ωi, so clusters are split to radius 2/√λ. Off-normal centres put highlights away from the
    mirror direction: a half vector at angle θ from the normal moves ωi up to 2θ from the mirror
    direction, so the extent is twice the largest centre angle plus three deviations, over the
    centres that matter (peak ≥ 1e-3 of the largest). With several bandwidths (a multi-scale
    basis) the pair is that of the narrowest level in use: it needs the finest clusters, and only
    near the mirror direction, where that level's cone lies. Refining the whole hemisphere to its
    radius cost 4× the frame (bunny under a sun) for no measurable change: 0.39% against 0.40%
    from the transfer functions' prediction, which refine every level (tests/fit/test_transfer)."""
    lam = np.broadcast_to(np.asarray(bandwidth, np.float64), (len(centers),))
    use = np.ones(len(centers), bool)
    if coef is not None and np.max(coef) > 0:
        use = np.max(coef, axis=1) > 1e-3 * np.max(coef)
    if not use.any():
        use[:] = True
    top = lam[use].max()
    sel = use & (lam == top)
    sd = 1.0 / np.sqrt(top)
    th = np.arccos(np.clip(centers[sel, 2], -1.0, 1.0)).max() + 3.0 * sd
    return {"refine_radius": min(np.pi, 2.0 * sd), "extent": min(2.0 * np.pi, 2.0 * float(th))}


def eval_packed(b: PackedBRDF, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """f(ωi, ωo) for local-frame unit directions wi, wo (…, 3) -> (…, 3) float64 1/sr."""
    wi = np.asarray(wi, np.float64); wo = np.asarray(wo, np.float64)
    ci, co = wi[..., 2], wo[..., 2]
    hv = wi + wo
    h = hv / np.maximum(np.linalg.norm(hv, axis=-1, keepdims=True), 1e-20)
    ch, cd = h[..., 2], np.einsum("...i,...i->...", wi, h)
    p = b.params.astype(np.float64)
    out = np.broadcast_to(p[0:3] * INV_PI, ci.shape + (3,)).copy()
    if b.kind == K_GGX:
        a = p[6]
        spec = ggx_D(ch, a) * ggx_G1(ci, cd, a) * ggx_G1(co, np.einsum("...i,...i->...", wo, h), a)
        spec = spec / np.maximum(4.0 * ci * co, 1e-20)
        out += spec[..., None] * p[3:6]
    elif b.kind == K_BLINN:
        e = p[6]
        out += ((e + 8.0) / (8.0 * np.pi) * np.clip(ch, 0, 1) ** e)[..., None] * p[3:6]
    elif b.kind == K_LOBES:
        rv = np.clip(2.0 * ci * co - np.einsum("...i,...i->...", wi, wo), 0.0, 1.0)
        for k in range(int(p[3])):
            e, w = p[4 + 4 * k], p[5 + 4 * k: 8 + 4 * k]
            out += ((e + 2.0) / (2.0 * np.pi) * rv ** e)[..., None] * w
    elif b.kind == K_TABLE:
        static = "smith" if int(round(p[4])) == STATICS["smith"] else "paper"
        s = distribution_static(np.maximum(ci, 0.0), np.maximum(co, 0.0), cd, p[3], static, p[5])
        out += table_lookup(b.table, h) * s[..., None]
    valid = (ci > 0) & (co > 0)
    return np.where(valid[..., None], out, 0.0)


def evaluate(material, wi, wo) -> np.ndarray:
    """Evaluate a scene material (scene.Lambert, GGX, …) at local directions (…, 3)."""
    return eval_packed(pack(material), wi, wo)


def srbf_exact(m: SRBF, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """SRBF BRDF by the exact sum over centres (no table), for testing the table."""
    wi = np.asarray(wi, np.float64); wo = np.asarray(wo, np.float64)
    ci, co = wi[..., 2], wo[..., 2]
    hv = wi + wo
    h = hv / np.linalg.norm(hv, axis=-1, keepdims=True)
    c = np.asarray(m.centers); c = c / np.linalg.norm(c, axis=1, keepdims=True)
    p = srbf_p(h, c, np.asarray(m.lambdas()), np.asarray(m.coefficients))
    s = distribution_static(np.maximum(ci, 0.0), np.maximum(co, 0.0), np.einsum("...i,...i->...", wi, h),
                            m.fresnel_f0, m.static, m.static_alpha)
    f = np.asarray(m.albedo) * INV_PI + p * s[..., None]
    return np.where(((ci > 0) & (co > 0))[..., None], f, 0.0)


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
