"""Fit a glTF 2.0 metallic-roughness material (and, for Mitsuba, a Lambert + GGX material) to any
Glint material, by weighted least squares on BRDF samples over both hemispheres.

The glTF model (glTF 2.0 spec, appendix B "BRDF implementation", and the extensions' specs), in a
local frame with z the normal, α = roughness²:

* specular_brdf = D(h)·V(ωi, ωo), GGX D and the height-correlated Smith visibility
  V = 0.5 / (cosθi √(cos²θo(1 − α²) + α²) + cosθo √(cos²θi(1 − α²) + α²)) (appendix B.3.2: what
  the Khronos sample viewer, three.js and Filament evaluate);
* dielectric = (1 − s·max(F))·baseColor/π + s·F·specular_brdf, F = f0 + (1 − f0)(1 − ωo·h)⁵,
  f0 = min(0.04·specularColor, 1), s = specular (``KHR_materials_specular``'s fresnel_mix; the
  core spec's mix(diffuse, specular, F) with f0 = 0.04 when both are 1);
* metal = (baseColor + (1 − baseColor)(1 − ωo·h)⁵)·specular_brdf;
* material = mix(dielectric, metal, metallic);
* ``KHR_materials_sheen``: material·min(1 − max(sheenColor)·E(cosθo), 1 − max(sheenColor)·E(cosθi))
  + sheenColor·D_charlie(h)·V_sheen, D_charlie = (2 + 1/α)·sin^(1/α)θh / (2π), α = sheenRoughness²,
  V_sheen = 1/(4(cosθi + cosθo − cosθi cosθo)) (the extension's "Ashikhmin" visibility), E the
  directional albedo of that lobe (tabulated here by quadrature, ``sheen_albedo``);
* ``KHR_materials_clearcoat``: material·(1 − c·Fc) + c·Fc·specular_brdf(α_c),
  Fc = 0.04 + 0.96(1 − ωo·h)⁵.

Samples (``Samples``): ``N_VIEWS`` view directions ωo cosine-distributed (a golden-angle spiral),
and per view ``N_COS`` incident directions cosine-distributed plus ``N_LOBE`` reflected about
GGX-distributed half vectors for each α of ``LOBE_ALPHAS``, so that sharp highlights, which a
cosine-distributed set would miss, are sampled too. Each sample carries the balance-heuristic
weight of the union (1 / Σ_k N_k p_k(ωi)), so Σ w·g estimates ∫ g dωi. Errors:

* ``rel_rmse`` = √(∬ |f_fit − f|² cosθi cosθo dωi dωo / ∬ |f|² cosθi cosθo dωi dωo), summed over
  RGB: the relative RMSE of the BRDF over directions weighted by cosine (the views' cosine is
  their distribution);
* ``albedo_rel_rmse``: the same of the directional albedo ρ(ωo) = ∫ f cosθi dωi over the views.

An extension is kept only if it lowers ``rel_rmse`` by at least ``EXT_MARGIN`` (relative) and
``EXT_MIN_GAIN`` (absolute), tried in turn (specular, clearcoat, sheen), each on top of those
kept: a reader without an extension then loses little.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from functools import lru_cache
from typing import ClassVar, Literal

import numpy as np
from scipy.optimize import least_squares

from ..models.base import BRDFModel, Geometry, PackedBRDF
from ..models.ggx import GGX, ggx_D
from ..models.lambert import Lambert

N_VIEWS = 16
N_COS = 128
N_LOBE = 48
LOBE_ALPHAS = (0.02, 0.08, 0.3)   # half-vector importance samples: sharp, glossy and broad lobes
EXT_MARGIN = 0.05
EXT_MIN_GAIN = 0.002
START_MARGIN = 0.02      # relative cost by which a later start of a fit must beat an earlier one
ALPHA_MIN = 1e-3                   # roughness 0 is a delta no sample set can see
SHEEN_ALPHA_MIN = 0.07 ** 2        # sheen roughness below 0.07 makes sin^(1/α) underflow
MAX_NFEV = 30        # function evaluations per start: a design fits in seconds on a shared core


def _spiral(n: int, seed: float = 0.5) -> np.ndarray:
    """(n, 2) points of a golden-angle spiral on the unit disk (uniform in area)."""
    k = np.arange(n) + seed
    r = np.sqrt(k / n)
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi)], -1)


def _lift(d: np.ndarray) -> np.ndarray:
    """Disk points (…, 2) lifted to the hemisphere (Malley: cosine-distributed)."""
    z = np.sqrt(np.maximum(1.0 - (d ** 2).sum(-1), 0.0))
    return np.concatenate([d, z[..., None]], -1)


def _r2(n: int) -> np.ndarray:
    """(n, 2) points of the R2 low-discrepancy sequence in [0, 1)²."""
    g = 1.32471795724474602596
    k = np.arange(1, n + 1)[:, None]
    return (0.5 + k * np.array([1 / g, 1 / g ** 2])) % 1.0


def _ggx_pdf_wi(wi, wo, alpha):
    """pdf (solid angle) of ωi reflected about a GGX-distributed h: D(h)·cosθh / (4|ωo·h|)."""
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-20)
    return ggx_D(h[..., 2], alpha) * np.maximum(h[..., 2], 0) / np.maximum(4 * np.abs((wo * h).sum(-1)), 1e-12)


@dataclass
class Samples:
    """Direction pairs and quadrature weights: wi, wo (V, N, 3) float64 local unit vectors, w
    (V, N) sr (Σ_N w·g ≈ ∫ g dωi for each view; zero for ωi below the horizon)."""
    wi: np.ndarray
    wo: np.ndarray
    w: np.ndarray

    @classmethod
    def make(cls, n_views: int = N_VIEWS, n_cos: int = N_COS, n_lobe: int = N_LOBE,
             lobe_alphas=LOBE_ALPHAS) -> Samples:
        wo = _lift(_spiral(n_views, 0.5) * 0.985)        # keep the views off the exact horizon
        cos_wi = _lift(_spiral(n_cos, 0.5))
        u = _r2(n_lobe)
        wis, wos = [], []
        for o in wo:
            sets = [cos_wi]
            for a in lobe_alphas:
                # GGX half vectors by inversion of its CDF (tan²θh = α² u / (1 − u))
                th = np.arctan(a * np.sqrt(u[:, 0] / (1 - u[:, 0])))
                ph = 2 * np.pi * u[:, 1]
                h = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
                sets.append(2 * (h @ o)[:, None] * h - o)
            wis.append(np.concatenate(sets))
            wos.append(np.broadcast_to(o, wis[-1].shape))
        wi, wo_ = np.stack(wis), np.stack(wos).copy()
        p = n_cos * np.maximum(wi[..., 2], 0) / np.pi
        for a in lobe_alphas:
            p = p + n_lobe * _ggx_pdf_wi(wi, wo_, a)
        w = np.where((wi[..., 2] > 0) & (p > 0), 1.0 / np.maximum(p, 1e-30), 0.0)
        return cls(wi, wo_, w)

    @property
    def weights(self) -> np.ndarray:
        """(V, N, 1) weights of squared residuals: w·cosθi / V (the views are cosine-distributed)."""
        return (self.w * np.maximum(self.wi[..., 2], 0) / self.wi.shape[0])[..., None]


@lru_cache(maxsize=1)
def default_samples() -> Samples:
    return Samples.make()


# -- the glTF BRDF ------------------------------------------------------------------------------

def _half(wi, wo):
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-20)
    return h, np.clip((wo * h).sum(-1), 0.0, 1.0)


def specular_brdf(ci, co, ch, alpha):
    """glTF specular_brdf D·V (…,) 1/sr, GGX D and height-correlated Smith V (appendix B.3.2)."""
    a = max(alpha, ALPHA_MIN)
    a2 = a * a
    ci, co = np.maximum(ci, 1e-9), np.maximum(co, 1e-9)
    v = 0.5 / (ci * np.sqrt(co * co * (1 - a2) + a2) + co * np.sqrt(ci * ci * (1 - a2) + a2))
    return ggx_D(ch, a) * v


def charlie_D(ch, alpha):
    """KHR_materials_sheen's D_charlie (…,) 1/sr (Estevez & Kulla 2017)."""
    a = max(alpha, SHEEN_ALPHA_MIN)
    s2 = np.maximum(1.0 - ch * ch, 0.0)
    return (2.0 + 1.0 / a) * s2 ** (0.5 / a) / (2 * np.pi)


def sheen_lobe(ci, co, ch, alpha):
    """D_charlie·V_sheen (…,) 1/sr with the Ashikhmin visibility 1/(4(ci + co − ci·co))."""
    return charlie_D(ch, alpha) / np.maximum(4.0 * (ci + co - ci * co), 1e-9)


SHEEN_MU = np.linspace(0.0, 1.0, 33)
SHEEN_R = np.linspace(0.0, 1.0, 33)


@lru_cache(maxsize=1)
def _sheen_table() -> np.ndarray:
    """(len(SHEEN_R), len(SHEEN_MU)) directional albedo ∫ sheen_lobe cosθi dωi of the sheen lobe,
    by midpoint quadrature (128 θ × 128 φ): no closed form exists for D_charlie·V_sheen."""
    nt, nph = 128, 128
    t = (np.arange(nt) + 0.5) * (np.pi / 2) / nt
    ph = (np.arange(nph) + 0.5) * 2 * np.pi / nph
    T, P = np.meshgrid(t, ph, indexing="ij")
    wi = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    dw = np.sin(T) * (np.pi / 2 / nt) * (2 * np.pi / nph)
    out = np.zeros((len(SHEEN_R), len(SHEEN_MU)))
    for j, mu in enumerate(SHEEN_MU):
        mu = max(mu, 1e-3)
        wo = np.array([np.sqrt(1 - mu * mu), 0.0, mu])
        h, _ = _half(wi, wo)
        for i, r in enumerate(SHEEN_R):
            out[i, j] = (sheen_lobe(wi[..., 2], mu, h[..., 2], r * r) * wi[..., 2] * dw).sum()
    return out


def sheen_albedo(mu, roughness: float) -> np.ndarray:
    """E(μ) (…,) of the sheen lobe of the given sheenRoughness, bilinear in the table."""
    tab = _sheen_table()
    r = np.clip(roughness, 0, 1) * (len(SHEEN_R) - 1)
    i0 = min(int(r), len(SHEEN_R) - 2)
    row = tab[i0] * (1 - (r - i0)) + tab[i0 + 1] * (r - i0)
    return np.interp(np.clip(mu, 0, 1), SHEEN_MU, row)


@dataclass
class GltfMaterial:
    """glTF metallic-roughness parameters (linear RGB; all in [0, 1] but specular_color, which
    the extension lets exceed 1 so that 0.04·specular_color can reach 1). None: extension unused."""
    base_color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    metallic: float = 0.0
    roughness: float = 0.5
    specular: float | None = None                     # KHR_materials_specular
    specular_color: tuple[float, float, float] | None = None
    clearcoat: float | None = None                    # KHR_materials_clearcoat
    clearcoat_roughness: float | None = None
    sheen_color: tuple[float, float, float] | None = None   # KHR_materials_sheen
    sheen_roughness: float | None = None

    @property
    def extensions(self) -> list[str]:
        return ([] if self.specular is None else ["KHR_materials_specular"]) + \
               ([] if self.clearcoat is None else ["KHR_materials_clearcoat"]) + \
               ([] if self.sheen_color is None else ["KHR_materials_sheen"])


def gltf_brdf(m: GltfMaterial, wi, wo) -> np.ndarray:
    """f (…, 3) float64 1/sr of the glTF material (module docstring) at local unit directions
    wi, wo (…, 3); zero below either horizon."""
    wi = np.asarray(wi, np.float64)
    wo = np.asarray(wo, np.float64)
    base = np.asarray(m.base_color, np.float64)
    h, cd = _half(wi, wo)
    ci, co, ch = np.maximum(wi[..., 2], 0), np.maximum(wo[..., 2], 0), h[..., 2]
    s = specular_brdf(ci, co, ch, m.roughness ** 2)[..., None]
    w5 = ((1.0 - cd) ** 5)[..., None]
    sw = 1.0 if m.specular is None else m.specular
    sc = np.ones(3) if m.specular_color is None else np.asarray(m.specular_color, np.float64)
    f0 = np.minimum(0.04 * sc, 1.0)
    fd = f0 + (1.0 - f0) * w5
    dielectric = (1.0 - sw * fd.max(-1, keepdims=True)) * base / np.pi + sw * fd * s
    metal = (base + (1.0 - base) * w5) * s
    f = (1.0 - m.metallic) * dielectric + m.metallic * metal
    if m.sheen_color is not None:
        shc = np.asarray(m.sheen_color, np.float64)
        r = m.sheen_roughness or 0.0
        mx = shc.max()
        scale = np.minimum(1 - mx * sheen_albedo(co, r), 1 - mx * sheen_albedo(ci, r))[..., None]
        f = f * scale + shc * sheen_lobe(ci, co, ch, r * r)[..., None]
    if m.clearcoat is not None:
        sc_ = specular_brdf(ci, co, ch, (m.clearcoat_roughness or 0.0) ** 2)[..., None]
        fc = (m.clearcoat * (0.04 + 0.96 * (1.0 - cd) ** 5))[..., None]
        f = f * (1.0 - fc) + fc * sc_
    ok = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    return np.where(ok[..., None], f, 0.0)


class GltfPBR(BRDFModel):
    """The glTF material as a Glint material, so Glint renders it (NumPy reference only; not
    registered: it exists to measure an export, not to design with). Fields as GltfMaterial."""
    model: Literal["gltf-export"] = "gltf-export"
    kernel: ClassVar[str | None] = None
    gltf: dict

    def material(self) -> GltfMaterial:
        return GltfMaterial(**self.gltf)

    def pack(self) -> PackedBRDF:
        m = self.material()
        # the Lambert-like part goes to the albedo (the renderer's diffuse path); the rest, which
        # holds the highlight and the broad Fresnel and sheen corrections, to the specular part
        sw = 1.0 if m.specular is None else m.specular
        f0 = 0.04 * (np.ones(3) if m.specular_color is None else np.asarray(m.specular_color))
        alb = (1 - m.metallic) * np.asarray(m.base_color) * (1 - sw * min(f0.max(), 1.0))

        def spec(g: Geometry):
            return gltf_brdf(m, g.wi, g.wo) - alb / np.pi
        a = max(m.roughness ** 2, 0.02)
        if m.clearcoat:
            a = min(a, max((m.clearcoat_roughness or 0) ** 2, 0.02))
        width = 2 * np.arctan(2 * a)
        # refine to the sharpest lobe's width everywhere: the corrections are not near the mirror
        return PackedBRDF(None, [*alb], spec, refine_radius=0.5 * width, extent=2 * np.pi)


# -- fitting ------------------------------------------------------------------------------------

@dataclass
class Approximation:
    """A fitted material and its errors (module docstring); ``candidates`` gives the rel_rmse of
    each combination of extensions tried, e.g. {"base": 0.08, "base+specular": 0.05}."""
    material: GltfMaterial
    rel_rmse: float
    albedo_rel_rmse: float
    candidates: dict = field(default_factory=dict)

    def public(self) -> dict:
        return {"gltf": {k: v for k, v in asdict(self.material).items() if v is not None},
                "extensions": self.material.extensions, "rel_rmse": self.rel_rmse,
                "albedo_rel_rmse": self.albedo_rel_rmse, "candidates": self.candidates}


def target_values(material: BRDFModel, smp: Samples) -> np.ndarray:
    """f (V, N, 3) float64 of a Glint material at the samples (as the kernels see it)."""
    return np.asarray(material.evaluate(smp.wi, smp.wo), np.float64)


def errors(f_fit, f, smp: Samples) -> tuple[float, float]:
    """(rel_rmse, albedo_rel_rmse) of f_fit against f, both (V, N, 3) (module docstring)."""
    wt = smp.weights
    rel = float(np.sqrt((wt * (f_fit - f) ** 2).sum() / max(float((wt * f ** 2).sum()), 1e-30)))
    c = (smp.w * np.maximum(smp.wi[..., 2], 0))[..., None]
    a_fit, a = (c * f_fit).sum(1), (c * f).sum(1)
    alb = float(np.sqrt(((a_fit - a) ** 2).sum() / max(float((a ** 2).sum()), 1e-30)))
    return rel, alb


def _lsq(evalf, f, smp: Samples, starts, lo, hi):
    """Least squares of ∬ |evalf(x) − f|² cosθi cosθo over x in [lo, hi]: the best x of the starts."""
    sq = np.sqrt(smp.weights)
    norm = max(float(np.sqrt((smp.weights * f ** 2).sum())), 1e-30)

    def res(x):
        return ((evalf(x) - f) * sq / norm).ravel()
    best = None
    for x0 in starts:
        x0 = np.clip(np.asarray(x0, np.float64), lo, hi)
        r = least_squares(res, x0, bounds=(lo, hi), max_nfev=MAX_NFEV, diff_step=1e-4, tr_solver="lsmr")
        # a later start wins only by a margin: two starts that end in near-equal minima (a gold
        # as a metal, or as a dielectric with a tinted specular layer) must not swap with the
        # rounding of the BLAS's thread count
        if best is None or r.cost < best.cost * (1.0 - START_MARGIN):
            best = r
    return best.x


_EXT = {"specular": ([1.0, 1.0, 1.0, 1.0], [0, 0, 0, 0], [1, 25, 25, 25]),
        "clearcoat": ([0.3, 0.1], [0, 0], [1, 1]),
        "sheen": ([0.1, 0.1, 0.1, 0.5], [0, 0, 0, 0], [1, 1, 1, 1])}


def _unpack(x, exts) -> GltfMaterial:
    m = GltfMaterial(tuple(map(float, x[0:3])), float(x[3]), float(x[4]))
    i = 5
    for e in exts:
        if e == "specular":
            m.specular, m.specular_color = float(x[i]), tuple(map(float, x[i + 1:i + 4])); i += 4
        elif e == "clearcoat":
            m.clearcoat, m.clearcoat_roughness = float(x[i]), float(x[i + 1]); i += 2
        elif e == "sheen":
            m.sheen_color, m.sheen_roughness = tuple(map(float, x[i:i + 3])), float(x[i + 3]); i += 4
    return m


def _pack(m: GltfMaterial, exts) -> list[float]:
    x = [*m.base_color, m.metallic, m.roughness]
    for e in exts:
        if e == "specular":
            x += [m.specular, *m.specular_color] if m.specular is not None else _EXT[e][0]
        elif e == "clearcoat":
            x += [m.clearcoat, m.clearcoat_roughness] if m.clearcoat is not None else _EXT[e][0]
        elif e == "sheen":
            x += [*m.sheen_color, m.sheen_roughness] if m.sheen_color is not None else _EXT[e][0]
    return x


def approximate(material: BRDFModel, smp: Samples | None = None) -> Approximation:
    """The glTF material closest to ``material`` (least squares, bounds per the spec), with the
    extensions that earn their keep (module docstring)."""
    smp = smp or default_samples()
    f = target_values(material, smp)

    def fit(exts, starts):
        lo = [0.0] * 5 + [v for e in exts for v in _EXT[e][1]]
        hi = [1.0] * 5 + [v for e in exts for v in _EXT[e][2]]
        x = _lsq(lambda x: gltf_brdf(_unpack(x, exts), smp.wi, smp.wo), f, smp,
                 [_pack(s, exts) for s in starts], lo, hi)
        m = _unpack(x, exts)
        return m, errors(gltf_brdf(m, smp.wi, smp.wo), f, smp)

    # starts: the diffuse colour from the mean albedo; a dielectric and a metal at two roughnesses
    alb = np.clip((smp.w[..., None] * np.maximum(smp.wi[..., 2:3], 0) * f).sum(1).mean(0), 0, 1)
    starts = [GltfMaterial(tuple(alb), mt, 0.4) for mt in (0.0, 1.0)]
    chosen, err = fit([], starts)
    exts: list[str] = []
    cands = {"base": err[0]}
    for e in ("specular", "clearcoat", "sheen"):
        trial = exts + [e]
        # from the fit so far, and from a dielectric of its roughness: an extension can lower
        # the error only from where it acts (KHR_materials_specular does nothing to a metal, so
        # a dark glossy dielectric whose core fit ended as a metal would never leave it)
        seeds = [chosen] + ([replace(chosen, base_color=tuple(alb), metallic=0.0)] if chosen.metallic > 0.5 else [])
        if e == "clearcoat":
            seeds.append(GltfMaterial(chosen.base_color, chosen.metallic, chosen.roughness,
                                      clearcoat=0.5, clearcoat_roughness=0.2))
        m, e_err = fit(trial, seeds)
        cands["+".join(["base", *trial])] = e_err[0]
        if e_err[0] <= err[0] * (1 - EXT_MARGIN) and err[0] - e_err[0] >= EXT_MIN_GAIN:
            chosen, err, exts = m, e_err, trial
    return Approximation(chosen, err[0], err[1], cands)


@dataclass
class GGXApproximation:
    """A Lambert + GGX material (Glint's ``ggx``, which Mitsuba renders exactly) and its errors."""
    material: BRDFModel
    rel_rmse: float
    albedo_rel_rmse: float
    exact: bool


def approximate_ggx(material: BRDFModel, smp: Samples | None = None, blend_max: float = 1.0) -> GGXApproximation:
    """``material`` itself when it is a lambert or ggx within Mitsuba's blend (max specular + max
    albedo ≤ blend_max), else the closest ggx material (albedo, specular, α) within that bound."""
    smp = smp or default_samples()
    if isinstance(material, Lambert) or (isinstance(material, GGX) and
                                         max(material.specular) + max(material.albedo) <= blend_max):
        return GGXApproximation(material, 0.0, 0.0, True)
    f = target_values(material, smp)

    def mk(x):
        alb, sp = np.asarray(x[0:3]), np.asarray(x[3:6])
        tot = sp.max() + alb.max()
        if tot > blend_max:          # scale into the blend's bound (a penalty-free projection)
            alb, sp = alb * blend_max / tot, sp * blend_max / tot
        return GGX(albedo=tuple(map(float, alb)), specular=tuple(map(float, sp)), alpha=float(max(x[6], 0.02)))
    alb = np.clip((smp.w[..., None] * np.maximum(smp.wi[..., 2:3], 0) * f).sum(1).mean(0), 0, 1)
    starts = [[*alb * 0.8, 0.2, 0.2, 0.2, a] for a in (0.08, 0.3)]
    x = _lsq(lambda x: mk(x).evaluate(smp.wi, smp.wo), f, smp, starts, [0] * 6 + [0.02], [1] * 6 + [1.0])
    m = mk(x)
    rel, albe = errors(m.evaluate(smp.wi, smp.wo), f, smp)
    return GGXApproximation(m, rel, albe, False)
