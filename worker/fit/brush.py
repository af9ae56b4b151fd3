"""Brush strokes to target radiance (inverse-brdf-modeling §4.3, eq. 23), with a stroke history.

A stroke is a polyline in the pixel coordinates of the view image the designer sees (x right,
y down, pixel (0, 0)'s centre at (0.5, 0.5)). Each fit pixel at distance d from the polyline gets
weight w = exp(−κ d) when d ≤ D/2 (D is the brush diameter; the paper writes d ≤ D), else 0, and

    colour mode:  B = w C + (1 − w) B'           C linear RGB radiance, negative removes light
    scale mode:   B = w S B' + (1 − w) B'        S ≥ 0 brightens (> 1) or dims (< 1)

with B' the radiance before the stroke. Strokes apply in order over the view's base rendering.
"""
from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

Point = tuple[float, float]
# painted pixels weigh 1, unpainted ones this much (BENCHMARKS.md "Strokes"): the standard
# strokes get 1.6-2.5× as much of their requested change as with 1 (the paper's uniform
# weighting, under which strokes looked ineffective), and darkenings and colour changes spill
# at most 6% onto the unpainted pixels; a highlight spills more (one BRDF per object)
DEFAULT_UNPAINTED_WEIGHT = 0.25


class Stroke(BaseModel):
    """One brush stroke (JSON form used by the CLI's STROKES.json and the session protocol)."""
    model_config = ConfigDict(extra="forbid")

    points: list[Point] = Field(min_length=1, max_length=10_000, description="polyline, view-image pixels")
    color: tuple[float, float, float] = Field((1.0, 1.0, 1.0), description="C, linear radiance; < 0 removes light")
    diameter: float = Field(24.0, gt=0.0, le=10_000.0, description="D, view-image pixels")
    kappa: float = Field(0.05, ge=0.0, le=100.0, description="κ of exp(−κ d), 1/pixel")
    mode: Literal["color", "scale"] = "color"
    scale: float = Field(1.0, ge=0.0, le=1000.0, description="S in scale mode")
    view: int = Field(0, ge=0, description="index of the saved view the stroke was painted in")

    @field_validator("points")
    @classmethod
    def _finite(cls, v):
        if not np.all(np.isfinite(np.asarray(v, np.float64))):
            raise ValueError("stroke points must be finite numbers")
        return v

    @field_validator("color")
    @classmethod
    def _finite_color(cls, v):
        if not np.all(np.isfinite(v)) or max(abs(x) for x in v) > 1e6:
            raise ValueError("stroke colour must be finite linear radiance (|C| ≤ 1e6)")
        return v


def rescale_stroke(stroke: Stroke, frame: tuple[int, int], camera) -> Stroke:
    """The stroke painted on a frame of ``frame`` = (w, h) pixels, in the pixels of ``camera``'s
    (W, H): the camera's vertical field of view spans both heights, so a point keeps its ray when
    scaled by s = H / h about the image centre (x' = W/2 + (x − w/2) s, y' = y s), also where the
    aspect differs; the diameter scales by s and κ (1/pixel) by 1/s."""
    w, h = (int(v) for v in frame)
    W, H = int(camera.width), int(camera.height)
    if (w, h) == (W, H):
        return stroke
    sc = H / h
    pts = [(W / 2 + (x - w / 2) * sc, y * sc) for x, y in stroke.points]
    return stroke.model_copy(update={"points": pts, "diameter": min(stroke.diameter * sc, 10_000.0),
                                     "kappa": min(stroke.kappa / sc, 100.0)})


def polyline_distance(xy: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance (N,) from points xy (N, 2) to the polyline through points (K, 2)."""
    pts = np.asarray(points, np.float64).reshape(-1, 2)
    if len(pts) == 1:
        return np.linalg.norm(xy - pts[0], axis=1)
    best = np.full(len(xy), np.inf)
    for a, b in zip(pts[:-1], pts[1:]):
        ab = b - a
        t = np.clip(((xy - a) @ ab) / max(ab @ ab, 1e-12), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(xy - (a + t[:, None] * ab), axis=1))
    return best


def stroke_weights(stroke: Stroke, xy: np.ndarray, footprint: float = 0.0) -> np.ndarray:
    """Brush weights w (N,) of eq. 23 at fit pixels whose centres are xy (N, 2) in view-image
    pixels. ``footprint`` (view pixels) is half a fit pixel: a fit pixel counts as touched when
    any part of it is within the brush, so a thin stroke still reaches a coarse fit grid."""
    d = np.maximum(polyline_distance(xy, np.asarray(stroke.points)) - footprint, 0.0)
    return np.where(d <= 0.5 * stroke.diameter, np.exp(-stroke.kappa * d), 0.0)


def apply_stroke(target: np.ndarray, stroke: Stroke, w: np.ndarray) -> np.ndarray:
    """Eq. 23 in place on target (N, 3) float64 with weights w (N,)."""
    w = w[:, None]
    if stroke.mode == "color":
        target[:] = w * np.asarray(stroke.color) + (1.0 - w) * target
    else:
        target[:] = w * stroke.scale * target + (1.0 - w) * target
    return target


class StrokeHistory:
    """Ordered strokes with undo and redo (a new stroke clears the redo stack)."""

    def __init__(self, strokes: list[Stroke] | None = None):
        self._done: list[Stroke] = list(strokes or [])
        self._undone: list[Stroke] = []

    @property
    def strokes(self) -> list[Stroke]:
        return list(self._done)

    @property
    def can_undo(self) -> bool:
        return bool(self._done)

    @property
    def can_redo(self) -> bool:
        return bool(self._undone)

    def push(self, stroke: Stroke) -> None:
        self._done.append(stroke)
        self._undone.clear()

    def undo(self) -> Stroke | None:
        if not self._done:
            return None
        s = self._done.pop()
        self._undone.append(s)
        return s

    def redo(self) -> Stroke | None:
        if not self._undone:
            return None
        s = self._undone.pop()
        self._done.append(s)
        return s

    def clear(self) -> None:
        self._done.clear()
        self._undone.clear()

    def __len__(self) -> int:
        return len(self._done)


def stroke_effect(base, target, painted, pred) -> tuple[float | None, float | None]:
    """How far a fit follows its strokes, over all views (lists of per-view arrays):
    base, target, pred (N, 3) radiance before the strokes, asked for, and predicted by the fit;
    painted (N,) bool.

    achieved : ⟨pred − base, target − base⟩ / ‖target − base‖² over the painted pixels and
        channels: the share of the requested change delivered (1 all of it, 0 none; a change in
        another colour or direction does not count, and overshoot counts above 1).
    spill : RMS(pred − base) / RMS(base) over the unpainted pixels: how much the rest of the
        object changed, relative to its radiance.
    Either is None when there is no painted (unpainted) pixel or nothing was requested."""
    b, t, p = (np.concatenate(x).astype(np.float64) for x in (base, target, pred))
    m = np.concatenate(painted).astype(bool)
    ask = t[m] - b[m]
    den = float((ask * ask).sum())
    achieved = float(((p[m] - b[m]) * ask).sum() / den) if m.any() and den > 0 else None
    u = ~m
    ref = float(np.sqrt((b[u] ** 2).mean())) if u.any() else 0.0
    spill = float(np.sqrt(((p[u] - b[u]) ** 2).mean()) / ref) if ref > 0 else None
    return achieved, spill


def achromatic(strokes) -> bool:
    """Whether strokes ask for no colour: each scales the radiance (scale mode) or paints equal
    channels (white, grey, or removing light evenly). A fit to such strokes keeps the specular
    part white (solve.solve ``neutral``)."""
    strokes = list(strokes)
    return bool(strokes) and all(
        s.mode == "scale" or max(s.color) - min(s.color) <= 1e-6 * max(abs(c) for c in s.color) for s in strokes)


def stroke_notes(achieved: float | None, solve, albedo) -> list[str]:
    """What a designer should know about a stroke fit that falls short: which channels hit
    energy conservation (ρ_d + specular albedo ≤ 1 per channel)."""
    notes = []
    if achieved is not None and achieved < 0.8 and solve.constrained:
        hit = [ch for ch, a in zip("RGB", solve.at_bound) if a]
        if hit:
            bounds = ", ".join(f"{ch} {1 - r:.2f}" for ch, r in zip("RGB", albedo))
            notes.append(f"{achieved * 100:.0f}% of the requested change: energy conservation caps the specular "
                         f"albedo in {'/'.join(hit)} (1 − diffuse albedo: {bounds}); a lower diffuse albedo "
                         "leaves room for a brighter highlight")
        else:
            notes.append(f"{achieved * 100:.0f}% of the requested change: one BRDF serves the whole object, so "
                         "pixels that see the same light directions keep it from changing further "
                         "(lower 'keep unpainted' to follow the stroke more)")
    return notes
