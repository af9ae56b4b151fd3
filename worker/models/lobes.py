"""``lobes``: cosine lobes with fixed exponents (cacad-cosine-lobes eq. 1-3), reciprocal form:

    albedo/π + Σ_i (gloss_i + dd_i) (E_i+2)/(2π) max(0, r·ωo)^E_i,   r = reflect(ωi, n).

Gloss weights are achromatic (first surface), directional-diffuse weights RGB; ``albedo`` is the
diffuse weight (version-1 files may still call it ``diffuse``).
"""
from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import AliasChoices, ConfigDict, Field, model_validator

from .base import BRDFModel, Color, Geometry, PackedBRDF, register

MAX_LOBES = 32      # the packed layout: 4 + 4·32 ≤ N_PARAMS (base.py)


@register
class Lobes(BRDFModel):
    """Cosine lobes with fixed exponents (cacad-cosine-lobes eq. 1-3), in reciprocal form:
    albedo/π + Σ_i (gloss_i + dd_i) (E_i+2)/(2π) max(0, r·ωo)^E_i, r = reflect(ωi, n).
    gloss weights are achromatic (first-surface), directional-diffuse weights are RGB.
    ``albedo`` is the diffuse weight (named like every model's; files may still say ``diffuse``)."""
    model_config = ConfigDict(extra="forbid", populate_by_name=True)
    kernel: ClassVar[str] = "lobes"
    label: ClassVar[str] = "Cosine lobes (paint)"
    creatable: ClassVar[bool] = False
    model: Literal["lobes"] = "lobes"
    exponents: list[float] = Field(min_length=1, max_length=MAX_LOBES)
    gloss: list[float]
    directional_diffuse: list[Color]
    albedo: Color = Field((0.3, 0.3, 0.3), validation_alias=AliasChoices("albedo", "diffuse"))

    @model_validator(mode="after")
    def _same_lengths(self):
        if not (len(self.exponents) == len(self.gloss) == len(self.directional_diffuse)):
            raise ValueError("lobes: exponents, gloss and directional_diffuse must have equal length")
        return self

    def specular_part(self, g: Geometry) -> np.ndarray:
        rv = np.clip(2.0 * g.ci * g.co - np.einsum("...i,...i->...", g.wi, g.wo), 0.0, 1.0)
        out = np.zeros(np.shape(g.ci) + (3,))
        for e, gl, dd in zip(self.exponents, self.gloss, self.directional_diffuse):
            out += ((e + 2.0) / (2.0 * np.pi) * rv ** e)[..., None] * (gl + np.asarray(dd))
        return out

    def _live(self) -> list[tuple[float, tuple[float, float, float]]]:
        """(exponent, RGB weight gloss + dd) of the lobes that reflect anything. A paint fit on
        the fixed basis leaves most of its 24-32 lobes at zero (a 100 GU paint: one of 24), and
        the kernels evaluate a pow() per lobe per light cluster: a refined 640×480 frame of the
        test bunny cost 31 CPU s with all 24 packed."""
        out = []
        for e, g, dd in zip(self.exponents, self.gloss, self.directional_diffuse):
            w = (g + dd[0], g + dd[1], g + dd[2])
            if max(w) > 0:
                out.append((float(e), w))
        return out

    def lobe_width(self) -> float:
        """Radians: the sharpest lobe that reflects anything (π when none does)."""
        live = [e for e, _ in self._live()]
        return 2.0 / np.sqrt(max(live) + 2.0) if live else np.pi

    def pack(self) -> PackedBRDF:
        live = self._live()
        p = [*self.albedo, float(len(live))]
        for e, w in live:
            p += [e, *w]
        return PackedBRDF("lobes", p, self.specular_part, lobe_width=min(np.pi, self.lobe_width()))

    @classmethod
    def examples(cls):
        return [cls(exponents=[5, 50, 500], gloss=[0.02, 0.05, 0.1], directional_diffuse=[(0.1, 0.05, 0.02)] * 3,
                    albedo=(0.4, 0.1, 0.1)),
                cls(exponents=[10, 300], gloss=[0.1, 0.2], directional_diffuse=[(0.1, 0.0, 0.0), (0.0, 0.1, 0.0)],
                    albedo=(0.3, 0.3, 0.3)),
                # the full packed layout (MAX_LOBES lobes, E over [1, 10⁴] as the paint basis):
                # the kernel must read every lobe of a 4 + 4·MAX_LOBES row
                cls(exponents=[float(e) for e in np.geomspace(1.0, 1e4, MAX_LOBES)], gloss=[0.004] * MAX_LOBES,
                    directional_diffuse=[(0.01, 0.006, 0.002)] * MAX_LOBES, albedo=(0.2, 0.1, 0.05))]
