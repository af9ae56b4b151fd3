"""``lambert``: f = albedo/π."""
from __future__ import annotations

from typing import ClassVar, Literal

from .base import BRDFModel, Color, PackedBRDF, register


@register
class Lambert(BRDFModel):
    """albedo/π."""
    kernel: ClassVar[str] = "lambert"
    label: ClassVar[str] = "Lambert (diffuse)"
    model: Literal["lambert"] = "lambert"
    albedo: Color = (0.5, 0.5, 0.5)

    def pack(self) -> PackedBRDF:
        return PackedBRDF("lambert", [*self.albedo], self.specular_part)

    @classmethod
    def examples(cls):
        return [cls(albedo=(0.7, 0.5, 0.3)), cls(albedo=(1.0, 1.0, 1.0))]
