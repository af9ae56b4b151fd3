"""Anisotropy editing (polynomial-gi Appendix A, eq. 33-35): an Ashikhmin-Shirley lobe whose
ratio r = n_v / n_u is edited through one 1D factor.

With φh the azimuth of h from the brushing tangent t (local frame: t = x, binormal = y, n = z),

    (cos θh)^(n_u cos²φh + n_v sin²φh) = (cos θh)^(n_u cos²φh) · γ^r,   γ = (cos θh)^(n_u sin²φh),

so the quotient ρ_qu = (cos θh)^(n_u cos²φh) / ((h·ωi) max(cos θi, cos θo)) is fixed by n_u at
precomputation, the bands are uniform in γ ∈ [0, 1], and the editable factor is f(γ) = γ^r times
the normalisation √((n_u+1)(n_v+1))/(8π); Schlick's Fresnel with F0 = ``specular`` is split
into the two layers of eq. 31-32. The diffuse part is Lambertian (albedo/π) like every Glint
model (Ashikhmin and Shirley's coupled diffuse term is not used).
"""
from __future__ import annotations

import numpy as np

# the model itself is one of Glint's BRDF models (worker/models/ashikhmin_shirley.py)
from ...models.ashikhmin_shirley import AshikhminShirley  # noqa: F401


def _half(wi, wo):
    hv = wi + wo
    return hv / np.maximum(np.linalg.norm(hv, axis=-1, keepdims=True), 1e-20)


def gamma(h: np.ndarray, n_u: float) -> np.ndarray:
    """γ = cos θh^(n_u sin²φh) ∈ (0, 1] for local half vectors h (…, 3) (eq. 35)."""
    c = np.clip(h[..., 2], 1e-12, 1.0)
    s2 = h[..., 0] ** 2 + h[..., 1] ** 2
    sin2phi = np.where(s2 > 1e-24, h[..., 1] ** 2 / np.maximum(s2, 1e-24), 0.0)
    return np.exp(n_u * sin2phi * np.log(c))


def quotient(wi: np.ndarray, wo: np.ndarray, n_u: float) -> np.ndarray:
    """ρ_qu(ωi, ωo) = cos θh^(n_u cos²φh) / ((h·ωi) max(cos θi, cos θo)) (eq. 35), 1/sr."""
    h = _half(wi, wo)
    c = np.clip(h[..., 2], 1e-12, 1.0)
    s2 = h[..., 0] ** 2 + h[..., 1] ** 2
    cos2phi = np.where(s2 > 1e-24, h[..., 0] ** 2 / np.maximum(s2, 1e-24), 1.0)
    hd = np.maximum((wi * h).sum(-1), 1e-12)
    return np.exp(n_u * cos2phi * np.log(c)) / (hd * np.maximum(np.maximum(wi[..., 2], wo[..., 2]), 1e-12))


def evaluate_as(m: AshikhminShirley, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """The full BRDF at local directions (…, 3) (tangent = x) -> (…, 3) float64, 1/sr."""
    wi = np.asarray(wi, np.float64); wo = np.asarray(wo, np.float64)
    h = _half(wi, wo)
    r = m.exponent_v / m.exponent_u
    norm = np.sqrt((m.exponent_u + 1) * (m.exponent_v + 1)) / (8 * np.pi)
    f = norm * quotient(wi, wo, m.exponent_u) * gamma(h, m.exponent_u) ** r
    cd = np.clip((wi * h).sum(-1), 0.0, 1.0)
    f0 = np.asarray(m.specular, np.float64)
    F = f0 + (1 - f0) * ((1 - cd) ** 5)[..., None]
    out = np.asarray(m.albedo) / np.pi + f[..., None] * F
    ok = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    return np.where(ok[..., None], out, 0.0)


def band_coefficients(m: AshikhminShirley, J: int) -> tuple[np.ndarray, np.ndarray]:
    """(c_A, c_B), each (J, 3): the two Fresnel layers' coefficients on J bands uniform in γ:
    norm · F0 · avg(γ^r) and norm · (1 − F0) · avg(γ^r) (eq. 32, 34)."""
    r = m.exponent_v / m.exponent_u
    norm = np.sqrt((m.exponent_u + 1) * (m.exponent_v + 1)) / (8 * np.pi)
    g0 = np.arange(J) / J
    g1 = (np.arange(J) + 1) / J
    avg = (g1 ** (r + 1) - g0 ** (r + 1)) / ((r + 1) * (g1 - g0))
    f0 = np.asarray(m.specular, np.float64)
    return norm * avg[:, None] * f0[None], norm * avg[:, None] * (1 - f0)[None]
