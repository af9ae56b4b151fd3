"""``srbf``: the distribution-based BRDF of inverse-brdf-modeling eq. 11-12,

    albedo/π + p(h)·F(ωi·h)/(cosθi + cosθo − cosθi cosθo),   p(h) = Σ_j c_j exp(λ(h·ξ_j − 1))

per RGB channel, h in the local frame (z = normal), F Schlick's approximation with F0 =
``fresnel_f0``. Packed as a p(h) table (models/table.py): the kernel never sums the centres.
"""
from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, field_validator

from .base import BRDFModel, Color, Geometry, PackedBRDF, Vec3, register
from .table import distribution_static, hemisphere_table_dirs, table_specular

MAX_CENTERS = 4096    # a bound on what a client may send (memory and table time stay small)


def srbf_p(h_local: np.ndarray, centers: np.ndarray, bandwidth: float, coef: np.ndarray) -> np.ndarray:
    """p(h) = Σ_j c_j exp(λ(h·ξ_j − 1)) (inverse-brdf-modeling eq. 12).

    h_local (…, 3), centers (J, 3), coef (J, 3) -> (…, 3)."""
    g = np.exp(bandwidth * (h_local @ centers.T - 1.0))
    return g @ coef


def srbf_refinement(centers: np.ndarray, bandwidth: float, coef: np.ndarray | None = None) -> dict:
    """Refinement of an SRBF p(h) (centres (J, 3) local unit vectors, λ, coefficients (J, 3)).

    A Gaussian SRBF exp(λ(h·ξ − 1)) has angular standard deviation ≈ 1/√λ in h, twice that in
    ωi, so clusters are split to radius 2/√λ. Off-normal centres put highlights away from the
    mirror direction: a half vector at angle θ from the normal moves ωi up to 2θ from the mirror
    direction, so the extent is twice the largest centre angle (over centres that matter) plus
    three deviations."""
    sd = 1.0 / np.sqrt(bandwidth)
    use = np.ones(len(centers), bool)
    if coef is not None and np.max(coef) > 0:
        use = np.max(coef, axis=1) > 1e-3 * np.max(coef)
    th = np.arccos(np.clip(centers[use, 2], -1.0, 1.0))
    th_max = (th.max() if len(th) else 0.0) + 3.0 * sd
    return {"refine_radius": min(np.pi, 2.0 * sd), "extent": min(2.0 * np.pi, 2.0 * th_max)}


@register
class SRBF(BRDFModel):
    """Distribution-based BRDF (inverse-brdf-modeling eq. 11-12).

    albedo/π + p(h)·F(ωi·h)/(cosθi + cosθo − cosθi cosθo), with
    p(h) = Σ_j c_j exp(λ (h·ξ_j − 1)) per RGB channel, h in the local frame (z = normal),
    F Schlick's approximation with F0 = fresnel_f0.
    """
    kernel: ClassVar[str] = "table"
    label: ClassVar[str] = "SRBF (from strokes)"
    creatable: ClassVar[bool] = False
    controls: ClassVar[tuple[dict, ...]] = (
        {"name": "albedo", "kind": "color"}, {"name": "fresnel_f0", "kind": "range", "min": 0, "max": 1, "step": 0.01})
    model: Literal["srbf"] = "srbf"
    centers: list[Vec3] = Field(min_length=1, max_length=MAX_CENTERS,
                                description="SRBF centres ξ_j, unit vectors, local frame")
    bandwidth: float = Field(gt=0.0, le=1e6, description="λ")
    coefficients: list[Color] = Field(min_length=1, max_length=MAX_CENTERS,
                                      description="c_j per RGB channel, ≥ 0 when physical")
    fresnel_f0: float = Field(1.0, ge=0.0, le=1.0)
    albedo: Color = (0.0, 0.0, 0.0)

    @field_validator("coefficients")
    @classmethod
    def _same_length(cls, v, info):
        c = info.data.get("centers")
        if c is not None and len(c) != len(v):
            raise ValueError(f"{len(v)} coefficient rows for {len(c)} centres")
        return v

    @field_validator("centers")
    @classmethod
    def _unit(cls, v):
        n = np.linalg.norm(np.asarray(v, np.float64), axis=1)
        if not np.all(np.isfinite(n)) or np.any(n < 1e-9):
            raise ValueError("SRBF centres must be finite, non-zero vectors")
        return v

    def _arrays(self):
        c = np.asarray(self.centers, np.float64)
        return c / np.linalg.norm(c, axis=1, keepdims=True), np.asarray(self.coefficients, np.float64)

    def exact(self, wi, wo) -> np.ndarray:
        """f by the exact sum over centres (no table), for testing the table: (…, 3) 1/sr."""
        g = Geometry.of(wi, wo)
        c, coef = self._arrays()
        p = srbf_p(g.h, c, self.bandwidth, coef)
        f = np.asarray(self.albedo) / np.pi + p * distribution_static(g.ci, g.co, g.cd, self.fresnel_f0)[..., None]
        return np.where(((g.ci > 0) & (g.co > 0))[..., None], f, 0.0)

    def pack(self) -> PackedBRDF:
        c, coef = self._arrays()
        table = srbf_p(hemisphere_table_dirs(), c, self.bandwidth, coef)
        return PackedBRDF("table", [*self.albedo, self.fresnel_f0], table_specular(table, self.fresnel_f0), table,
                          **srbf_refinement(c, self.bandwidth, coef))

    @classmethod
    def examples(cls):
        return [cls(centers=[(0, 0, 1), (0.3, 0, 0.95)], bandwidth=100.0,
                    coefficients=[(1.0, 0.5, 0.2), (0.3, 0.3, 0.3)], albedo=(0.1, 0.1, 0.1))]
