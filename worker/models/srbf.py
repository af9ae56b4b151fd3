"""``srbf``: the distribution-based BRDF of inverse-brdf-modeling eq. 11-12,

    albedo/π + p(h)·s(ωi, ωo),   p(h) = Σ_j c_j exp(λ_j(h·ξ_j − 1))

per RGB channel, h in the local frame (z = normal), s the static function (models/table.py
``distribution_static``): the paper's F(ωi·h)/(cosθi + cosθo − cosθi cosθo) (eq. 11) or the
microfacet form with Smith-GGX shadowing (``static: smith``), F Schlick's approximation with
F0 = ``fresnel_f0``. λ_j is one ``bandwidth`` for every centre, or per centre
(``bandwidths``, a multi-scale basis: worker/fit/basis.py). Packed as a p(h) table
(models/table.py): the kernel never sums the centres.
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import Field, field_validator

from ..keys import content_key
from .base import BRDFModel, Color, Geometry, PackedBRDF, Vec3, register
from .table import STATICS, distribution_static, hemisphere_table_dirs, table_specular

MAX_CENTERS = 4096    # a bound on what a client may send (memory and table time stay small)


def srbf_p(h_local: np.ndarray, centers: np.ndarray, bandwidth, coef: np.ndarray) -> np.ndarray:
    """p(h) = Σ_j c_j exp(λ_j(h·ξ_j − 1)) (inverse-brdf-modeling eq. 12).

    h_local (…, 3), centers (J, 3), bandwidth λ (scalar, or (J,) per centre), coef (J, 3) -> (…, 3)."""
    g = np.exp(np.asarray(bandwidth, np.float64) * (h_local @ centers.T - 1.0))
    return g @ coef


# The basis evaluated at the table's directions, by basis content: a fitted material changes
# its coefficients at every stroke, not its centres, so its table is one mat-mul (25.6K × J ×
# 3, ~5 ms) instead of 25.6K × J exponentials (~55 ms for the fitting basis's J = 206). A few
# bases per process (a fitting basis is shared by every session of a scene).
_TABLE_BASES: OrderedDict = OrderedDict()
_TABLE_BASES_KEPT = 3
_TABLE_LOCK = threading.Lock()
TABLE_CACHE_MIN_J = 16      # below this, the direct sum is as fast as the lookup


def table_basis(centers: np.ndarray, bandwidth) -> np.ndarray:
    """G (TABLE_N², J) float32: exp(λ_j(h·ξ_j − 1)) at hemisphere_table_dirs(), cached by
    content (centres (J, 3) unit, λ scalar or (J,))."""
    lam = np.broadcast_to(np.asarray(bandwidth, np.float64), (len(centers),))
    key = content_key("srbf-table", 1, centers=np.asarray(centers, np.float64), bandwidth=np.ascontiguousarray(lam))
    with _TABLE_LOCK:
        g = _TABLE_BASES.get(key)
        if g is not None:
            _TABLE_BASES.move_to_end(key)
            return g
    h = hemisphere_table_dirs().reshape(-1, 3)
    g = np.exp(lam * (h @ centers.T - 1.0)).astype(np.float32)
    with _TABLE_LOCK:
        _TABLE_BASES[key] = g
        while len(_TABLE_BASES) > _TABLE_BASES_KEPT:
            _TABLE_BASES.popitem(last=False)
    return g


def srbf_table(centers: np.ndarray, bandwidth, coef: np.ndarray) -> np.ndarray:
    """p(h) at the table's directions (TABLE_N, TABLE_N, 3) float64 (eq. 12): through the
    cached basis for large J, else the direct sum (``srbf_p``, the reference)."""
    dirs = hemisphere_table_dirs()
    if len(centers) < TABLE_CACHE_MIN_J:
        return srbf_p(dirs, centers, bandwidth, coef)
    g = table_basis(centers, bandwidth)
    return (g @ np.asarray(coef, np.float32)).astype(np.float64).reshape(*dirs.shape[:2], 3)


def srbf_material_p(m: SRBF, h_local: np.ndarray) -> np.ndarray:
    """p(h) (…, 3) of an srbf material at local unit half vectors (…, 3), every centre with its
    own λ (multi-scale materials; for plots such as the studio's half-angle curve)."""
    c, coef = m._arrays()
    return srbf_p(np.asarray(h_local, np.float64), c, np.asarray(m.lambdas(), np.float64), coef)


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


@register
class SRBF(BRDFModel):
    """Distribution-based BRDF (inverse-brdf-modeling eq. 11-12).

    albedo/π + p(h)·s(ωi, ωo), with p(h) = Σ_j c_j exp(λ_j (h·ξ_j − 1)) per RGB channel, h in
    the local frame (z = normal), and the static function s chosen by ``static``:

    * ``paper`` (the default, and what files without the field mean):
      F(ωi·h)/(cosθi + cosθo − cosθi cosθo), eq. 11 (Ashikhmin's distribution-based BRDF);
    * ``smith``: F(ωi·h)·G1(ωi)G1(ωo)/(4 cosθi cosθo), the microfacet form with separable Smith
      shadowing of a GGX surface of roughness ``static_alpha``; p = D makes it a microfacet BRDF
      (p = specular·D_GGX(α) with α = static_alpha is exactly the ``ggx`` model).

    F is Schlick's approximation with F0 = fresnel_f0. λ_j is ``bandwidths[j]`` when given (a
    multi-scale basis), else ``bandwidth`` for every centre.
    """
    kernel: ClassVar[str] = "table"
    label: ClassVar[str] = "SRBF (from strokes)"
    creatable: ClassVar[bool] = False
    controls: ClassVar[tuple[dict, ...]] = (
        {"name": "albedo", "kind": "color"}, {"name": "fresnel_f0", "kind": "range", "min": 0, "max": 1, "step": 0.01})
    model: Literal["srbf"] = "srbf"
    centers: list[Vec3] = Field(min_length=1, max_length=MAX_CENTERS,
                                description="SRBF centres ξ_j, unit vectors, local frame")
    bandwidth: float = Field(gt=0.0, le=1e6, description="λ (of every centre unless bandwidths is given)")
    coefficients: list[Color] = Field(min_length=1, max_length=MAX_CENTERS,
                                      description="c_j per RGB channel, ≥ 0 when physical")
    fresnel_f0: float = Field(1.0, ge=0.0, le=1.0)
    albedo: Color = (0.0, 0.0, 0.0)
    bandwidths: list[Annotated[float, Field(gt=0.0, le=1e6)]] | None = Field(
        None, max_length=MAX_CENTERS, description="λ_j per centre (multi-scale basis); overrides bandwidth")
    static: Literal["paper", "smith"] = Field("paper", description="static function s(ωi, ωo), see the class doc")
    static_alpha: float = Field(0.1, gt=0.0, le=1.0, description="GGX roughness of the smith static's shadowing")

    @field_validator("coefficients")
    @classmethod
    def _same_length(cls, v, info):
        c = info.data.get("centers")
        if c is not None and len(c) != len(v):
            raise ValueError(f"{len(v)} coefficient rows for {len(c)} centres")
        return v

    @field_validator("bandwidths")
    @classmethod
    def _one_per_centre(cls, v, info):
        c = info.data.get("centers")
        if v is not None and c is not None and len(c) != len(v):
            raise ValueError(f"{len(v)} bandwidths for {len(c)} centres")
        return v

    @field_validator("centers")
    @classmethod
    def _unit(cls, v):
        n = np.linalg.norm(np.asarray(v, np.float64), axis=1)
        if not np.all(np.isfinite(n)) or np.any(n < 1e-9):
            raise ValueError("SRBF centres must be finite, non-zero vectors")
        return v

    def lambdas(self) -> list[float]:
        """λ_j of every centre."""
        return list(self.bandwidths) if self.bandwidths is not None else [self.bandwidth] * len(self.centers)

    def _arrays(self):
        c = np.asarray(self.centers, np.float64)
        return c / np.linalg.norm(c, axis=1, keepdims=True), np.asarray(self.coefficients, np.float64)

    def exact(self, wi, wo) -> np.ndarray:
        """f by the exact sum over centres (no table), for testing the table: (…, 3) 1/sr."""
        g = Geometry.of(wi, wo)
        c, coef = self._arrays()
        p = srbf_p(g.h, c, np.asarray(self.lambdas()), coef)
        s = distribution_static(np.maximum(g.ci, 0.0), np.maximum(g.co, 0.0), g.cd, self.fresnel_f0,
                                self.static, self.static_alpha)
        f = np.asarray(self.albedo) / np.pi + p * s[..., None]
        return np.where(((g.ci > 0) & (g.co > 0))[..., None], f, 0.0)

    def pack(self) -> PackedBRDF:
        c, coef = self._arrays()
        lam = np.asarray(self.lambdas(), np.float64)
        table = srbf_table(c, lam, coef)
        return PackedBRDF("table", [*self.albedo, self.fresnel_f0, STATICS[self.static], self.static_alpha],
                          table_specular(table, self.fresnel_f0, self.static, self.static_alpha), table,
                          **srbf_refinement(c, lam, coef))

    @classmethod
    def examples(cls):
        paper = cls(centers=[(0, 0, 1), (0.3, 0, 0.95)], bandwidth=100.0,
                    coefficients=[(1.0, 0.5, 0.2), (0.3, 0.3, 0.3)], albedo=(0.1, 0.1, 0.1))
        # the fitting basis's kind: per-centre bandwidths (a wide and a narrow level) and the
        # smith static, with a low α so its grazing-angle growth is exercised; specular albedo
        # 0.4-0.6 (tests/models run it through reciprocity, energy, C scalar and AVX2 against
        # NumPy: ~1 s together on 2 loaded cores)
        smith = cls(centers=[(0, 0, 1), (0.3, 0, 0.95), (0, 0.05, 1)], bandwidth=100.0,
                    bandwidths=[100.0, 100.0, 900.0], coefficients=[(8.0, 4.0, 2.0), (2.0, 2.0, 2.0), (40.0, 40.0, 30.0)],
                    albedo=(0.1, 0.1, 0.1), fresnel_f0=0.6, static="smith", static_alpha=0.15)
        return [paper, smith]
