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


SIGNIFICANT = 0.05   # of the curve's largest value: bins below it count as no lobe for the refinement


def curve_widths(values: np.ndarray) -> tuple[float, float]:
    """(peak, outer) radians about the mirror direction (twice the half-angle) of a curve's
    values (K, 3): ``peak`` the width of the run of significant bins (above SIGNIFICANT of the
    largest value) that holds the largest value, measured from θh = 0 when the run starts
    there, else the run's own width (a ring); ``outer`` the width out to the last significant
    bin. The refinement works at the peak's scale and within the outer extent: a fitted curve
    often has a sharp peak and small bumps far out (at grazing half angles), and the outermost
    bin alone made the refinement treat a sharp highlight as a wide one (faceted stills).
    π, π for a curve without any value."""
    peak_bin = values.max(axis=1)
    top = float(peak_bin.max()) if len(peak_bin) else 0.0
    if top <= 0:
        return np.pi, np.pi
    sig = peak_bin > SIGNIFICANT * top
    binw = (np.pi / 2) / len(values)
    k = int(np.argmax(peak_bin))
    a = k
    while a > 0 and sig[a - 1]:
        a -= 1
    b = k
    while b + 1 < len(sig) and sig[b + 1]:
        b += 1
    peak = 2 * (b + 1) * binw if a == 0 else 2 * (b - a + 1) * binw
    outer = 2 * (int(np.nonzero(sig)[0].max()) + 1) * binw
    return min(np.pi, peak), min(np.pi, outer)


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
        peak, outer = curve_widths(v)
        return PackedBRDF("table", [*self.albedo, self.fresnel_f0], table_specular(table, self.fresnel_f0), table,
                          refine_radius=0.5 * peak, extent=2.0 * outer)

    @classmethod
    def examples(cls):
        return [cls(values=[(2.0, 1.5, 1.0), (0.8, 0.6, 0.4), (0.2, 0.2, 0.2), (0.05, 0.05, 0.05)] + [(0.0, 0.0, 0.0)] * 12,
                    fresnel_f0=0.8, albedo=(0.3, 0.3, 0.3))]
