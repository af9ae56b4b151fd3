"""``blinn-phong``: albedo/π + specular·(e+8)/(8π)·cos^e θh (normalised Blinn-Phong)."""
from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from .base import BRDFModel, Color, Geometry, PackedBRDF, register


@register
class BlinnPhong(BRDFModel):
    """albedo/π + specular·(e+8)/(8π)·cos^e θh (normalised Blinn-Phong)."""
    kernel: ClassVar[str] = "blinn-phong"
    label: ClassVar[str] = "Blinn-Phong"
    controls: ClassVar[tuple[dict, ...]] = (
        {"name": "exponent", "kind": "range", "min": 1, "max": 2000, "step": 1},
        {"name": "specular", "kind": "color"}, {"name": "albedo", "kind": "color"})
    model: Literal["blinn-phong"] = "blinn-phong"
    exponent: float = Field(50.0, ge=0.0, le=1e5)
    specular: Color = (0.04, 0.04, 0.04)
    albedo: Color = (0.5, 0.5, 0.5)

    def specular_part(self, g: Geometry) -> np.ndarray:
        e = self.exponent
        return ((e + 8.0) / (8.0 * np.pi) * np.clip(g.ch, 0, 1) ** e)[..., None] * np.asarray(self.specular)

    def lobe_width(self) -> float:
        return 2 * 2.0 / np.sqrt(self.exponent + 2.0)

    def pack(self) -> PackedBRDF:
        return PackedBRDF("blinn-phong", [*self.albedo, *self.specular, self.exponent], self.specular_part,
                          lobe_width=min(np.pi, self.lobe_width()))

    @classmethod
    def examples(cls):
        return [cls(exponent=200, specular=(0.5, 0.5, 0.5), albedo=(0.2, 0.2, 0.2)), cls(exponent=8)]
