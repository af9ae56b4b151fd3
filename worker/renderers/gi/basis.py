"""The BRDF basis of the GI tensors and the projection of any material onto it
(polynomial-gi §3.1 eq. 4-6, §4.1 eq. 17, Appendix A eq. 30-32, Appendix B eq. 36-37).

First bounce from the eye (slots of the tensor's first index):

* slot 0: the diffuse basis 1/π, coefficient = the material's ``albedo``;
* slots 1..J: box functions over the half angle θh ∈ [0, π/2] (J uniform bands, as Glint's
  ``curve`` model) times the quotient s(ωi, ωo) = 1/(cos θi + cos θo − cos θi cos θo)
  (inverse-brdf-modeling eq. 11, Appendix A's ρ_q);
* slots J+1..2J (``fresnel``): the same bands times s · (1 − cos θd)^5, Appendix A's Fresnel
  layer (eq. 31-32), so Schlick's F0 is edited exactly.

Anisotropic units use bands over γ and the quotient of anisotropy.py instead (always with both
layers). A material is projected *per view angle*: the coefficient of band j is tabulated at
``THETA_NODES`` view angles θo and interpolated per pixel. The basis is then the box/hat
functions over (θh, θo), still one coefficient per (band, node) per object; since θo is fixed
per pixel by the fixed view, the tensor keeps one entry per band. The coefficients are the
ratio of ∫ρ cos θi to ∫q cos θi over the band's ring of incident directions, so a uniformly lit
surface (white furnace) is reproduced exactly for any model; with the Fresnel layer a weighted
least-squares split into the two layers keeps that energy.

Further bounces use the diffuse equivalent d = (1/π)∬ρ cos θi cos θo (Appendix B, eq. 36), or,
for the second bounce of a (J, J2) series, J2 half-angle bands plus a diffuse slot whose
coefficients are averaged over view angles with weight cos θo (hemispherical projection).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from ...core.brdf import evaluate
from .anisotropy import AshikhminShirley, band_coefficients, evaluate_as

THETA_NODES = 16          # view-angle nodes of the per-object coefficient tables
J2_NODES = 4              # view-angle nodes of the second-vertex bands ((J, J2) series)
INV_PI = 1.0 / np.pi


# --- the basis as the precomputation uses it (NumPy reference of gi.c) --------------------------


QUOTIENTS = ("distribution", "microfacet")


def quotient_s(ci, co, kind=0):
    """The quotient ρ_q of the half-angle bands (Appendix A), 1/sr: kind 0 ("distribution"),
    s = 1/(cos θi + cos θo − cos θi cos θo) (inverse-brdf-modeling eq. 11, the form of Glint's
    curve and srbf models); kind 1 ("microfacet"), 1/(4 cos θi cos θo), the Jacobian of
    microfacet models such as GGX, whose ratio to it is D·G (nearly constant over a ring)."""
    x = np.where(np.asarray(kind) == 1, 4.0 * ci * co, ci + co - ci * co)
    return 1.0 / np.maximum(x, 1e-12)


def half_band(h_z, J: int):
    """Band index of half vectors by θh: (…,) int64 in [0, J)."""
    th = np.arccos(np.clip(h_z, -1.0, 1.0))
    return np.clip((th * (2.0 * J / np.pi)).astype(np.int64), 0, J - 1)


def theta_nodes() -> np.ndarray:
    """View-angle nodes θ_k (cell centres over [0, π/2]) and cell edges."""
    e = np.linspace(0.0, np.pi / 2, THETA_NODES + 1)
    return 0.5 * (e[1:] + e[:-1]), e


def node_interp(cos_o: np.ndarray, K: int) -> tuple[np.ndarray, np.ndarray]:
    """Hat-function interpolation over K view-angle nodes at the centres of K equal cells of
    θo ∈ [0, π/2]: (k0 int64, t float64), value = (1 − t)·C[k0] + t·C[k0 + 1], clamped at the
    ends."""
    th = np.arccos(np.clip(cos_o, 0.0, 1.0))
    x = np.clip(th * (2.0 * K / np.pi) - 0.5, 0.0, K - 1.0)
    k0 = np.minimum(x.astype(np.int64), K - 2)
    return k0, x - k0


def theta_interp(cos_o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel interpolation over the THETA_NODES view-angle nodes: (k0 (P,) int32, t (P,)
    float32), coefficient = (1 − t)·C[k0] + t·C[k0 + 1]."""
    k0, t = node_interp(cos_o, THETA_NODES)
    return k0.astype(np.int32), t.astype(np.float32)


# --- quadrature over (ωi, ωo) pairs, stratified in the half vector ------------------------------


@lru_cache(maxsize=8)
def pair_quadrature(J: int, n_t: int = 4, n_phi: int = 8, phi_o: tuple = (0.0,), full_azimuth: bool = False):
    """Incident directions stratified per half-angle band for each view-angle node.

    Returns (wi (K, A, Q, 3), wo (K, A, 3), weight (K, A, Q), band (Q,)) in the local frame
    (normal +z): K view-angle nodes, A view azimuths ``phi_o``, Q = J·n_t·n_phi samples, and
    weight = dωi · cos θi (0 below the horizon), so Σ weight·f ≈ ∫_band f cos θi dωi.
    h is sampled at θh midpoints of n_t sub-bands and n_phi azimuths (over [0, π] with weight 2
    for isotropic materials, [0, 2π) when ``full_azimuth``); dωi = 4 (ωo·h) dωh.
    """
    nodes, _ = theta_nodes()
    span = 2 * np.pi if full_azimuth else np.pi
    sub = (np.arange(J * n_t) + 0.5) * (np.pi / 2) / (J * n_t)          # θh midpoints
    dth = (np.pi / 2) / (J * n_t)
    ph = (np.arange(n_phi) + 0.5) * span / n_phi
    TH, PH = np.meshgrid(sub, ph, indexing="ij")                           # (J n_t, n_phi)
    h = np.stack([np.sin(TH) * np.cos(PH), np.sin(TH) * np.sin(PH), np.cos(TH)], -1).reshape(-1, 3)
    dwh = (np.sin(TH) * dth * (span / n_phi) * (2.0 if not full_azimuth else 1.0)).reshape(-1)
    band = np.repeat(np.arange(J), n_t * n_phi)
    K, A = len(nodes), len(phi_o)
    wi = np.zeros((K, A, len(h), 3)); wo = np.zeros((K, A, 3)); w = np.zeros((K, A, len(h)))
    for k, th in enumerate(nodes):
        for a, po in enumerate(phi_o):
            o = np.array([np.sin(th) * np.cos(po), np.sin(th) * np.sin(po), np.cos(th)])
            oh = h @ o
            d = 2.0 * oh[:, None] * h - o
            ok = (oh > 0) & (d[:, 2] > 0)
            wi[k, a] = d
            wo[k, a] = o
            w[k, a] = np.where(ok, 4.0 * oh * dwh * np.clip(d[:, 2], 0, None), 0.0)
    for arr in (wi, wo, w, band):
        arr.setflags(write=False)
    return wi, wo, w, band


# --- projection ---------------------------------------------------------------------------------


def _eval(material, wi, wo):
    if isinstance(material, AshikhminShirley):
        return evaluate_as(material, wi, wo)
    return evaluate(material, wi, wo)


def _spec_part(material, wi, wo):
    """ρ − albedo/π (…, 3): the part the bands carry; the diffuse slot carries albedo/π."""
    f = _eval(material, wi, wo)
    alb = np.asarray(getattr(material, "albedo", (0.0, 0.0, 0.0)), np.float64)
    valid = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    return f - np.where(valid[..., None], alb * INV_PI, 0.0)


class Projection:
    """One material's coefficients on the GI basis.

    first : (THETA_NODES, K1, 3) float32, first-bounce slots per view-angle node
        (K1 = 1 + J·(2 if layers == 2 else 1)).
    second : (1 + J2·J2_NODES, 3) float32, second-bounce functions (diffuse, then J2 bands ×
        J2_NODES view-angle nodes), J2 > 1 series only.
    d : (3,) float64, diffuse equivalent (Appendix B).
    ok : see project_measure (isotropic, two layers), else None.
    """

    def __init__(self, first, second, d, ok=None):
        self.first = first
        self.second = second
        self.d = d
        # (THETA_NODES, J, 3) bool with the Fresnel layer: where the two-layer split is used
        # (project_measure); None otherwise
        self.ok = ok


@lru_cache(maxsize=16)
def _iso_basis(J: int, qkind: int):
    """The material-independent parts of an isotropic projection: quadrature pairs (K, Q, 3),
    weights (K, Q), quotient measure Es = w·q (K, Q), μ(1) per band (K, J), m5 (K, Q) and the
    Fresnel-layer normal-equation terms a12, a22 (K, J)."""
    wi, wo, w, band = pair_quadrature(J)
    wi1, wo1, w1 = wi[:, 0], np.broadcast_to(wo[:, 0][:, None, :], wi[:, 0].shape), w[:, 0]
    Es = w1 * quotient_s(wi1[..., 2], wo1[..., 2], qkind)
    per = Es.shape[1] // J                                                   # samples are band-major
    hv = wi1 + wo1
    h = hv / np.linalg.norm(hv, axis=-1, keepdims=True)
    m5 = np.clip(1.0 - (wi1 * h).sum(-1), 0.0, 1.0) ** 5
    mu = Es.reshape(THETA_NODES, J, per).sum(-1)
    a12 = (Es * m5).reshape(THETA_NODES, J, per).sum(-1)
    a22 = (Es * m5 * m5).reshape(THETA_NODES, J, per).sum(-1)
    return wi1, wo1, w1, Es, per, m5, mu, a12, a22


@lru_cache(maxsize=16)
def _iso_valid(J: int, qkind: int):
    """The pairs of ``_iso_basis`` that carry weight (both directions above the horizon; about
    half of them: at θo = 0 every band beyond θh = 45° sends ωi below it), for the projection of
    a material each frame: (Geometry of the n pairs, weight (n,) = dωi cos θi, starts (K·J,)
    int64 first pair of each (node, band) group in node-major order, has (K·J,) bool groups
    with pairs). Pairs keep their order, so the groups are contiguous."""
    from ...models.base import Geometry
    wi1, wo1, w1, Es, per, *_ = _iso_basis(J, qkind)
    keep = (w1 > 0).reshape(-1)
    g = Geometry.of(wi1.reshape(-1, 3)[keep], wo1.reshape(-1, 3)[keep])
    group = np.repeat(np.arange(THETA_NODES * J), per)[keep]
    counts = np.bincount(group, minlength=THETA_NODES * J)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    return g, w1.reshape(-1)[keep], starts, counts > 0


def _project_single(material, albedo: np.ndarray, J: int, qkind: int):
    """``project_measure`` for one layer and a (J, 1, …) series from the weighted pairs alone
    (``_iso_valid``): (first (THETA_NODES, 1 + J, 3), d (3,)) float64, the same sums in another
    order. Pairs of zero weight add nothing to any band, so they are not evaluated."""
    g, wv, starts, has = _iso_valid(J, qkind)
    *_, mu, _a12, _a22 = _iso_basis(J, qkind)
    if isinstance(material, AshikhminShirley):
        spec = evaluate_as(material, g.wi, g.wo) - albedo * INV_PI
    else:
        spec = material.pack().specular(g)            # ρ − albedo/π: both cosines are positive
    Ew = wv[:, None] * spec
    g_mu = np.zeros((THETA_NODES * J, 3))
    g_mu[has] = np.add.reduceat(Ew, starts[has], axis=0)
    g_mu = g_mu.reshape(THETA_NODES, J, 3)
    first = np.zeros((THETA_NODES, 1 + J, 3))
    first[:, 0] = albedo
    first[:, 1:] = np.where(mu[..., None] > 0, g_mu / np.maximum(mu[..., None], 1e-300), 0.0)
    _, edges = theta_nodes()
    wk = np.sin(edges[1:]) ** 2 - np.sin(edges[:-1]) ** 2
    d = albedo + (wk[:, None] * g_mu.sum(1)).sum(0)    # eq. 36, as _tails
    return first, d


@lru_cache(maxsize=16)
def _aniso_basis(J: int, qkind: int):
    """Quadrature with view azimuths for the anisotropic units' diffuse equivalent and
    second-vertex bands: (wi, wo, w, Es (K, Q) averaged over azimuths)."""
    wi, wo, w, band = pair_quadrature(J, 2, 16, (0.0, np.pi / 8, np.pi / 4, 3 * np.pi / 8), True)
    ci = wi[..., 2]; co = wo[..., 2][:, :, None]
    Es = np.einsum("kaq->kq", w * quotient_s(ci, co, qkind)) / wi.shape[1]
    return wi, wo, w, Es


def project(material, J: int, layers: int, J2: int = 1, anisotropic_nu: float | None = None,
            qkind: int = 0) -> Projection:
    """Project a material (any Glint model, or AshikhminShirley for anisotropic units) onto the
    basis of module docstring. ``layers`` is 1 (no Fresnel layer) or 2; ``qkind`` the quotient
    of the half-angle bands (quotient_s). Costs one BRDF evaluation per quadrature pair
    (THETA_NODES × 32 J)."""
    albedo = np.asarray(getattr(material, "albedo", (0.0, 0.0, 0.0)), np.float64)
    if anisotropic_nu is not None:
        if not isinstance(material, AshikhminShirley):
            raise TypeError("anisotropic units take an ashikhmin-shirley material")
        K1 = 1 + J * layers
        first = np.zeros((THETA_NODES, K1, 3))
        first[:, 0] = albedo
        cA, cB = band_coefficients(material, J)
        first[:, 1:1 + J] = cA
        first[:, 1 + J:1 + 2 * J] = cB
        # diffuse equivalent and second-bounce bands over θh: a quadrature with view azimuths
        wi, wo, w, Es = _aniso_basis(J, qkind)
        spec = _spec_part(material, wi, np.broadcast_to(wo[:, :, None, :], wi.shape))   # (K, A, Q, 3)
        Erho = np.einsum("kaq,kaqc->kqc", w, spec) / wi.shape[1]           # averaged over azimuths
        d, second = _tails(Erho, albedo, Es, J2)
        return Projection(first.astype(np.float32), None if second is None else second.astype(np.float32), d)
    if layers == 1 and J2 <= 1:
        first, d = _project_single(material, albedo, J, qkind)
        return Projection(first.astype(np.float32), None, d)
    wi1, wo1, w1, *_ = _iso_basis(J, qkind)
    Erho = w1[..., None] * _spec_part(material, wi1, wo1)                   # (K, Q, 3)
    first, d, second, ok = project_measure(Erho, albedo, J, layers, J2, qkind)
    p = Projection(first.astype(np.float32), None if second is None else second.astype(np.float32), d)
    p.ok = ok
    return p


def project_measure(Erho: np.ndarray, albedo: np.ndarray, J: int, layers: int, J2: int = 1, qkind: int = 0,
                    ok: np.ndarray | None = None):
    """The isotropic projection from the measure of a BRDF's specular part on the quadrature
    pairs of ``_iso_basis``: Erho (THETA_NODES, Q, M) = w·(ρ − albedo/π) for M channels (or M
    basis BRDFs), albedo (M,). Returns (first (THETA_NODES, K1, M), d (M,), second
    (1 + J2·J2_NODES, M) or None, ok (THETA_NODES, J, M) bool or None) float64.

    Everything is linear in (Erho, albedo) except, with the Fresnel layer, the choice per band
    between the two-layer split and the single-layer ratio (``ok``, True where the split is
    used): given ``ok`` (e.g. a material's, to linearise around it) that choice is not made
    here and the map is linear."""
    wi1, wo1, w1, Es, per, m5, mu, a12, a22 = _iso_basis(J, qkind)
    M = Erho.shape[-1]
    K1 = 1 + J * layers
    first = np.zeros((THETA_NODES, K1, M))
    first[:, 0] = albedo
    g_mu = Erho.reshape(THETA_NODES, J, per, M).sum(2)                       # μ(ρ/q) per band
    one = np.where(mu[..., None] > 0, g_mu / np.maximum(mu[..., None], 1e-300), 0.0)
    if layers == 1:
        first[:, 1:1 + J] = one
        okm = None
    else:
        # weighted LSQ of g = ρ/q by a + b·m5 under μ = q cos θi dωi; its first normal
        # equation is the energy constraint a μ(1) + b μ(m5) = μ(g). Where the ring is too
        # thin for m5 to vary, or the fit goes negative, the single-layer ratio is used.
        a11 = mu
        b2 = (Erho * m5[..., None]).reshape(THETA_NODES, J, per, M).sum(2)
        det = (a11 * a22 - a12 * a12)[..., None]
        good = det > 1e-6 * (a11 * a22)[..., None] + 1e-300
        dd = np.where(good, det, 1.0)
        a = (g_mu * a22[..., None] - a12[..., None] * b2) / dd
        b = (a11[..., None] * b2 - a12[..., None] * g_mu) / dd
        okm = np.broadcast_to(good & (a >= 0) & (b >= 0), a.shape) if ok is None else np.broadcast_to(ok, a.shape)
        first[:, 1:1 + J] = np.where(okm, a, one)
        first[:, 1 + J:1 + 2 * J] = np.where(okm, b, 0.0)
    d, second = _tails(Erho, albedo, Es, J2)
    return first, d, second, okm


def _tails(Erho, albedo, Es, J2):
    """Diffuse equivalent d (M,) and, for J2 > 1, the second-vertex functions (1 + J2·J2_NODES,
    M) from Erho (THETA_NODES, Q, M) and the quotient measure Es (THETA_NODES, Q)."""
    _, edges = theta_nodes()
    wk = np.sin(edges[1:]) ** 2 - np.sin(edges[:-1]) ** 2                 # ∫ 2 sin cos dθ per cell
    M = Erho.shape[-1]
    # diffuse equivalent: d = (1/π)∬ρ cos cos = Σ_k wk · (albedo + ∫ρ_spec cos θi dωi)(θ_k)
    a_spec = Erho.sum(axis=1)                                               # (K, M)
    d = albedo + (wk[:, None] * a_spec).sum(0)
    if J2 <= 1:
        return d, None
    # J2 bands × J2_NODES view cells, each the cos θo-weighted ratio over its fine cells
    second = np.zeros((1 + J2 * J2_NODES, M))
    second[0] = albedo
    per2 = Es.shape[1] // J2
    fine = THETA_NODES // J2_NODES
    den = (wk[:, None] * Es.reshape(THETA_NODES, J2, per2).sum(-1)).reshape(J2_NODES, fine, J2).sum(1)
    num = (wk[:, None, None] * Erho.reshape(THETA_NODES, J2, per2, M).sum(2)).reshape(J2_NODES, fine, J2, M).sum(1)
    c2 = np.where(den[..., None] > 0, num / np.maximum(den[..., None], 1e-300), 0.0)   # (nodes, J2, M)
    second[1:] = c2.transpose(1, 0, 2).reshape(J2 * J2_NODES, M)
    return d, second


def fixed_projection(J: int, layers: int, J2: int = 1) -> Projection:
    """The constant table of fixed (baked) objects: slot 0 = 1 (the baked BRDF)."""
    first = np.zeros((THETA_NODES, 1 + J * layers, 3), np.float32)
    first[:, 0] = 1.0
    return Projection(first, None, np.zeros(3))
