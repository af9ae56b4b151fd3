"""``ashikhmin-shirley``: the anisotropic Phong BRDF of Ashikhmin and Shirley (2000), as the GI
renderer's anisotropy control uses it (polynomial-gi Appendix A, eq. 33-35):

    albedo/π + √((n_u+1)(n_v+1))/(8π) · cos θh^(n_u cos²φh + n_v sin²φh)
               / ((h·ωi) max(cos θi, cos θo)) · F(ωi·h),     F Schlick with F0 = specular,

with φh measured from the local tangent (x). The cut renderer shades it in its C kernel's
scalar path (shade.c, K_AS; this is its reference) in the per-point tangent frame (brdf.onb), so
the brushing direction follows that frame; the GI renderer sets the tangent per object
(gi.anisotropic). Through the NumPy reference alone, a 640×480 frame of the test bunny took
0.9 s and its settled still 143 s.
"""
from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from .base import BRDFModel, Color, Geometry, PackedBRDF, register


@register
class AshikhminShirley(BRDFModel):
    """Anisotropic Phong (Ashikhmin-Shirley 2000); see the module docstring."""
    kernel: ClassVar[str] = "ashikhmin-shirley"
    label: ClassVar[str] = "Ashikhmin-Shirley (anisotropic)"
    controls: ClassVar[tuple[dict, ...]] = (
        {"name": "exponent_u", "kind": "range", "min": 1, "max": 2000, "step": 1},
        {"name": "exponent_v", "kind": "range", "min": 1, "max": 2000, "step": 1},
        {"name": "specular", "kind": "color"}, {"name": "albedo", "kind": "color"})
    studio_default: ClassVar[dict] = {"exponent_u": 100.0, "exponent_v": 100.0, "specular": (0.04, 0.04, 0.04),
                                      "albedo": (0.5, 0.5, 0.5)}
    model: Literal["ashikhmin-shirley"] = "ashikhmin-shirley"
    exponent_u: float = Field(225.0, gt=0.0, le=1e5)
    exponent_v: float = Field(225.0, gt=0.0, le=1e5)
    specular: Color = (0.9, 0.9, 0.9)
    albedo: Color = (0.0, 0.0, 0.0)

    def specular_part(self, g: Geometry) -> np.ndarray:
        h = g.h
        c = np.clip(g.ch, 1e-12, 1.0)
        s2 = h[..., 0] ** 2 + h[..., 1] ** 2
        cos2 = np.where(s2 > 1e-24, h[..., 0] ** 2 / np.maximum(s2, 1e-24), 1.0)
        e = self.exponent_u * cos2 + self.exponent_v * (1.0 - cos2)
        norm = np.sqrt((self.exponent_u + 1) * (self.exponent_v + 1)) / (8 * np.pi)
        hd = np.maximum(g.cd, 1e-12)
        f = norm * np.exp(e * np.log(c)) / (hd * np.maximum(np.maximum(g.ci, g.co), 1e-12))
        f0 = np.asarray(self.specular, np.float64)
        F = f0 + (1 - f0) * (np.clip(1.0 - g.cd, 0.0, 1.0) ** 5)[..., None]
        return f[..., None] * F

    def lobe_width(self) -> float:
        return 2 * 2.0 / np.sqrt(min(self.exponent_u, self.exponent_v) + 2.0)

    def pack(self) -> PackedBRDF:
        return PackedBRDF("ashikhmin-shirley", [*self.albedo, self.exponent_u, self.exponent_v, *self.specular],
                          self.specular_part, lobe_width=min(np.pi, self.lobe_width()))

    @classmethod
    def examples(cls):
        return [cls(exponent_u=100, exponent_v=400, specular=(0.5, 0.4, 0.3), albedo=(0.2, 0.2, 0.2))]
