"""Generated paints: what no registry has, for choosing the basis on one set and reporting on another.

The database (database.py) holds 30 one-lobe Lafortune fits; a basis chosen on them alone
fits them and little else (its exponents cluster where those fits' lobes are). The basis is
therefore chosen on paints drawn at random within physical bounds, and reported on paints drawn
the same way from seeds the choice never saw (``TUNING_SEED`` / ``HELD_OUT_SEED``).

Two families:

* ``random_lobes_paint`` — a ``lobes`` material (scene.Lobes) with 1-5 lobes at exponents drawn
  log-uniformly in [1, 10⁴] (a lobe of E ≈ 2/σ² is σ wide: from the widest directional diffuse
  down to a clearcoat 0.6° wide), each carrying achromatic gloss and/or RGB directional diffuse,
  over an RGB albedo. Physical bound: a normalised cosine lobe (E+2)/(2π) cos^E reflects at
  most its weight (its directional albedo is the weight at normal incidence and less elsewhere),
  so albedo_c + Σ_i (g_i + dd_ic) ≤ 1 in every channel c keeps the paint energy-conserving.
* ``random_microfacet_paint`` — a clearcoated microfacet paint (``ClearcoatPaint``): a base of
  GGX (Walter et al. 2007, scene.GGX) or anisotropic Ashikhmin-Shirley (2000) of roughness
  α ∈ [0.05, 0.6] (A-S exponents by n = 2/α² − 2, the Beckmann-Phong correspondence, Walter
  et al. eq. 30), under a dielectric clearcoat of index 1.5 (the specular lobe a smooth GGX of
  α_c ∈ [0.01, 0.04] times the unpolarised Fresnel reflectance) that transmits (1 − F(θi))(1 − F(θo))
  to the base (the usual no-interreflection layering, as Weidlich-Wilkie 2007 eq. 2 without the
  absorption term). Physical bound: specular colour and albedo of the base sum to ≤ 1.

Every paint is drawn from a ``numpy.random.Generator``, so a seed gives the same set on every
machine (NumPy's PCG64 stream is stable across versions for these calls).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models import GGX, Lobes
from ..models.ashikhmin_shirley import AshikhminShirley
from ..models.base import Geometry
from ..models.ggx import ggx_D, ggx_G1

E_RANGE = (1.0, 1e4)
ROUGHNESS = (0.05, 0.6)
CLEARCOAT_ALPHA = (0.01, 0.04)
CLEARCOAT_N = 1.5
TUNING_SEED = 20261202
HELD_OUT_SEED = 90210


def random_lobes_paint(rng: np.random.Generator, max_lobes: int = 5) -> Lobes:
    """A random energy-conserving lobes material (see the module docstring)."""
    n = int(rng.integers(1, max_lobes + 1))
    ex = np.sort(np.exp(rng.uniform(np.log(E_RANGE[0]), np.log(E_RANGE[1]), n)))
    albedo = np.exp(rng.uniform(np.log(0.005), np.log(0.9), 3))
    kind = rng.integers(0, 3, n)                        # 0: gloss, 1: directional diffuse, 2: both
    g = np.where(kind != 1, rng.uniform(0.0, 1.0, n), 0.0)
    dd = np.where((kind != 0)[:, None], rng.uniform(0.0, 1.0, (n, 3)), 0.0)
    total = albedo + g.sum() + dd.sum(axis=0)           # (3,) per-channel energy before scaling
    s = rng.uniform(0.15, 1.0) / total.max()
    return Lobes(exponents=[float(e) for e in ex], gloss=[float(v) for v in g * s],
                 directional_diffuse=[tuple(float(v) for v in r) for r in dd * s],
                 albedo=tuple(float(v) for v in albedo * s))


def _fresnel(cos_i: np.ndarray, n: float) -> np.ndarray:
    """Unpolarised Fresnel reflectance of a dielectric of index n from air, (…,) for cosines (…,)."""
    c = np.clip(cos_i, 0.0, 1.0)
    st2 = (1.0 - c * c) / (n * n)
    ct = np.sqrt(np.maximum(1.0 - st2, 0.0))
    rs = (c - n * ct) / (c + n * ct)
    rp = (n * c - ct) / (n * c + ct)
    return 0.5 * (rs * rs + rp * rp)


@dataclass(frozen=True)
class ClearcoatPaint:
    """A microfacet base under a dielectric clearcoat (module docstring).

    base : scene.GGX or AshikhminShirley (its albedo is the base's diffuse); coat_alpha : GGX α
    of the clearcoat; coat_n : its index. ``evaluate`` gives f (…, 3) in 1/sr."""
    base: GGX | AshikhminShirley
    coat_alpha: float
    coat_n: float = CLEARCOAT_N

    def evaluate(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        from ..core.brdf import evaluate
        wi = np.asarray(wi, np.float64)
        wo = np.asarray(wo, np.float64)
        g = Geometry.of(wi, wo)
        a = self.coat_alpha
        coat = ggx_D(g.ch, a) * ggx_G1(g.ci, g.cd, a) * ggx_G1(g.co, g.cd, a) * _fresnel(g.cd, self.coat_n)
        coat = coat / np.maximum(4.0 * g.ci * g.co, 1e-20)
        t = (1.0 - _fresnel(g.ci, self.coat_n)) * (1.0 - _fresnel(g.co, self.coat_n))
        f = evaluate(self.base, wi, wo) * t[..., None] + coat[..., None]
        ok = (g.ci > 0) & (g.co > 0)
        return np.where(ok[..., None], f, 0.0)


def random_microfacet_paint(rng: np.random.Generator) -> ClearcoatPaint:
    """A random clearcoated GGX or Ashikhmin-Shirley paint (module docstring)."""
    alpha = float(np.exp(rng.uniform(np.log(ROUGHNESS[0]), np.log(ROUGHNESS[1]))))
    spec = rng.uniform(0.0, 1.0, 3) * rng.uniform(0.05, 1.0)
    albedo = rng.uniform(0.0, 1.0, 3) * rng.uniform(0.005, 1.0)
    s = max(1.0, float((spec + albedo).max()))
    spec, albedo = tuple(float(v) for v in spec / s), tuple(float(v) for v in albedo / s)
    if rng.random() < 0.5:
        base = GGX(alpha=alpha, specular=spec, albedo=albedo)
    else:
        # anisotropy: the second exponent from a roughness up to 2× the first (brushed flakes)
        alpha_v = float(np.clip(alpha * rng.uniform(0.5, 2.0), *ROUGHNESS))
        nu, nv = 2.0 / alpha ** 2 - 2.0, 2.0 / alpha_v ** 2 - 2.0
        base = AshikhminShirley(exponent_u=nu, exponent_v=nv, specular=spec, albedo=albedo)
    coat = float(np.exp(rng.uniform(np.log(CLEARCOAT_ALPHA[0]), np.log(CLEARCOAT_ALPHA[1]))))
    return ClearcoatPaint(base, coat)


def paint_set(seed: int, lobes: int, microfacet: int) -> tuple[list[Lobes], list[ClearcoatPaint]]:
    """``lobes`` random lobes paints and ``microfacet`` clearcoated microfacet paints from one seed
    (the two families from independent streams, so growing one set does not change the other)."""
    r1, r2 = (np.random.default_rng([seed, k]) for k in (1, 2))
    return [random_lobes_paint(r1) for _ in range(lobes)], [random_microfacet_paint(r2) for _ in range(microfacet)]
