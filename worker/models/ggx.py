"""``ggx``: albedo/π + specular·D(h)·G1(ωi)G1(ωo)/(4 cosθi cosθo).

D and the separable Smith G exactly as Mitsuba 3's ``roughconductor`` (GGX, ``material: none``,
i.e. Fresnel = 1 scaled by ``specular_reflectance``); tests/models compares value for value.
"""
from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from .base import BRDFModel, Color, Geometry, PackedBRDF, register


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


@register
class GGX(BRDFModel):
    """albedo/π + specular·D·G/(4 cosθi cosθo); Mitsuba roughconductor, material none."""
    kernel: ClassVar[str] = "ggx"
    label: ClassVar[str] = "GGX microfacet"
    controls: ClassVar[tuple[dict, ...]] = (
        {"name": "alpha", "kind": "range", "min": 0.02, "max": 1.0, "step": 0.01},
        {"name": "specular", "kind": "color"}, {"name": "albedo", "kind": "color"})
    # a grey plastic: a dielectric's 4 % specular over a mid-grey diffuse
    studio_default: ClassVar[dict] = {"alpha": 0.3, "specular": (0.04, 0.04, 0.04), "albedo": (0.5, 0.5, 0.5)}
    model: Literal["ggx"] = "ggx"
    alpha: float = Field(0.25, gt=0.0, le=2.0)
    specular: Color = (1.0, 1.0, 1.0)
    albedo: Color = (0.0, 0.0, 0.0)

    def specular_part(self, g: Geometry) -> np.ndarray:
        a = self.alpha
        s = ggx_D(g.ch, a) * ggx_G1(g.ci, g.cd, a) * ggx_G1(g.co, g.cd, a)
        return (s / np.maximum(4.0 * g.ci * g.co, 1e-20))[..., None] * np.asarray(self.specular)

    def lobe_width(self) -> float:
        # most of D's mass lies within θh ≲ 2α; ωi moves twice as fast as h
        return 2 * np.arctan(2 * self.alpha)

    def pack(self) -> PackedBRDF:
        return PackedBRDF("ggx", [*self.albedo, *self.specular, self.alpha], self.specular_part,
                          lobe_width=min(np.pi, self.lobe_width()))

    @classmethod
    def examples(cls):
        return [cls(alpha=0.08, specular=(0.9, 0.8, 0.6), albedo=(0.1, 0.1, 0.1)),
                cls(alpha=0.6, specular=(0.3, 0.3, 0.3), albedo=(0.5, 0.5, 0.5)), cls(alpha=0.25)]
