"""``curve``: the quotient model over a 1D half-angle curve (a box basis over θh ∈ [0, π/2]):

    albedo/π + p(θh)·F(ωi·h)/(cosθi + cosθo − cosθi cosθo),   p piecewise constant.

Packed as a p(h) table like ``srbf`` (models/table.py)."""
from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from .base import BRDFModel, Color, PackedBRDF, register
from .table import hemisphere_table_dirs, table_specular


def curve_p(cos_h: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Box basis over θh ∈ [0, π/2]: values (K, 3) -> p (…, 3)."""
    k = len(values)
    th = np.arccos(np.clip(cos_h, 0.0, 1.0))
    idx = np.clip((th * (2.0 * k / np.pi)).astype(np.int64), 0, k - 1)
    return values[idx]


@register
class Curve(BRDFModel):
    """Quotient model over a 1D half-angle curve (box basis over θh ∈ [0, π/2]):
    albedo/π + p(θh)·F(ωi·h)/(cosθi + cosθo − cosθi cosθo), p piecewise constant."""
    kernel: ClassVar[str] = "table"
    label: ClassVar[str] = "Half-angle curve"
    creatable: ClassVar[bool] = False     # the studio starts a curve from the current BRDF
    controls: ClassVar[tuple[dict, ...]] = (
        {"name": "albedo", "kind": "color"}, {"name": "fresnel_f0", "kind": "range", "min": 0, "max": 1, "step": 0.01})
    model: Literal["curve"] = "curve"
    values: list[Color] = Field(min_length=1, max_length=1024)
    fresnel_f0: float = Field(1.0, ge=0.0, le=1.0)
    albedo: Color = (0.0, 0.0, 0.0)

    def pack(self) -> PackedBRDF:
        d = hemisphere_table_dirs()
        v = np.asarray(self.values, np.float64)
        table = curve_p(d[..., 2], v)
        nz = np.nonzero(v.max(axis=1) > 0.05 * v.max())[0]
        width = np.pi if len(nz) == 0 else min(np.pi, 2 * (nz.max() + 1) * (np.pi / 2) / len(v))
        return PackedBRDF("table", [*self.albedo, self.fresnel_f0], table_specular(table, self.fresnel_f0), table,
                          lobe_width=width)

    @classmethod
    def examples(cls):
        return [cls(values=[(2.0, 1.5, 1.0), (0.8, 0.6, 0.4), (0.2, 0.2, 0.2), (0.05, 0.05, 0.05)] + [(0.0, 0.0, 0.0)] * 12,
                    fresnel_f0=0.8, albedo=(0.3, 0.3, 0.3))]
