"""What to tell a designer when the light cannot give the highlight painted.

A BRDF that conserves energy reflects towards ω_o at most the brightest radiance it receives:
B(x, ω_o) = ∫ L(ω_i) f cosθ_i dω_i ≤ max_{ω_i·n > 0} L(ω_i), since ∫ f cosθ_i dω_i ≤ 1
(inverse-brdf-modeling eq. 10). A glossy lobe gets close to that only where the bright light is
near the mirror direction of the pixel; elsewhere a lobe has to be aimed off the mirror direction,
differently at each pixel of a curved stroke, and every lobe draws on the same energy budget (the
energy rows, eq. 19), so one BRDF gives each pixel a share of it.

``highlight_guidance`` measures, for the painted pixels of a brightening stroke, the environment's
radiance around each mirror direction (the map averaged over ~6° texels, unoccluded: an upper
bound), the brightest radiance above each pixel's horizon, and the rotation of the environment
that puts the most light in the mirror directions. The fit's notes then say which case it is: a
highlight no BRDF can make under this light, or one the light near the mirror directions covers
only in part, with what a rotated environment would cover; a stroke that fitted one BRDF for the
whole object is also offered a painted region, which changes only what it covers. The session
sends the same as a guidance event after the stroke's frame (``guidance_event``), for the studio's
buttons.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..core.render import env_lookup_numpy

LUMA = np.array([0.2126, 0.7152, 0.0722])
MAP_W = 64                      # the averaged map's width (texels of 5.6°)
ROTATIONS = 72                  # environment rotations tried (every 5°)
BRIGHTEN = 1.05                 # a stroke asks for a highlight when its target is this much brighter
SHORT = 0.8                     # a fit that achieves less of the change than this gets the guidance


def _small_map(envmap: np.ndarray) -> np.ndarray:
    h = MAP_W // 2
    return cv2.resize(np.ascontiguousarray(envmap[:, :, :3], np.float32), (MAP_W, h), interpolation=cv2.INTER_AREA)


def _texel_dirs(h: int, w: int, rotation_deg: float) -> np.ndarray:
    """(h·w, 3) world directions of the texel centres (render.env_lookup's convention)."""
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(w) + 0.5) / w
    th = np.pi * v[:, None]
    ph = 2.0 * np.pi * (u[None, :] - rotation_deg / 360.0)
    d = np.stack(np.broadcast_arrays(np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)), -1)
    return d.reshape(-1, 3)


def highlight_guidance(envmap: np.ndarray, rotation_deg: float, intensity: float, normals: np.ndarray,
                       wo: np.ndarray, asked: np.ndarray, before: np.ndarray) -> dict | None:
    """Guidance for a highlight at painted pixels (P,): world unit normals and directions to the
    eye (P, 3), the radiance asked for and shown before (P, 3). None when the stroke does not
    brighten. Returns luminances (means over the pixels): ``asked``, ``mirror`` (the map around
    the mirror direction), ``brightest_above`` (the brightest texel above the horizon), the share
    of pixels asking for more than their ``brightest_above`` (``impossible_share``: no BRDF can),
    the share of the ask the mirror light covers now (``covered``) and at the best rotation
    (``rotate_to_deg``, ``covered_at_rotation``)."""
    ya, yb = np.asarray(asked) @ LUMA, np.asarray(before) @ LUMA
    if len(ya) == 0 or ya.mean() <= BRIGHTEN * max(yb.mean(), 1e-12):
        return None
    n = np.asarray(normals, np.float64)
    o = np.asarray(wo, np.float64)
    r = 2.0 * (n * o).sum(1, keepdims=True) * n - o
    small = _small_map(envmap)
    ym_now = env_lookup_numpy(r, small, rotation_deg, intensity) @ LUMA
    lum = small.reshape(-1, 3) @ LUMA * intensity
    top = np.zeros(len(n))
    d = _texel_dirs(small.shape[0], small.shape[1], rotation_deg)
    above = (n @ d.T) > 0                                    # (P, texels)
    top = np.where(above, lum[None, :], 0.0).max(1)
    ask = np.maximum(ya, 1e-12)

    def covered(ym):
        return float(np.mean(np.minimum(ym, ask) / ask))

    best, best_cov = rotation_deg, covered(ym_now)
    for k in range(ROTATIONS):
        rot = 360.0 * k / ROTATIONS
        c = covered(env_lookup_numpy(r, small, rot, intensity) @ LUMA)
        if c > best_cov + 1e-9:
            best, best_cov = rot, c
    return {"asked": float(ya.mean()), "before": float(yb.mean()), "mirror": float(ym_now.mean()),
            "brightest_above": float(top.mean()), "impossible_share": float(np.mean(ya > top)),
            "covered": covered(ym_now), "rotate_to_deg": float(best % 360.0), "covered_at_rotation": best_cov}


def guidance_notes(g: dict | None, achieved: float | None, one_brdf: bool = False, rotate: bool = True) -> list[str]:
    """The fit's notes from highlight_guidance's result, when a highlight fell short (< SHORT).
    one_brdf : the stroke fitted one BRDF for the whole object (a painted region is then offered:
    it changes only what it covers). rotate : the environment can be turned (not under GI, whose
    tensors hold it as it was precomputed)."""
    if g is None or achieved is None or achieved >= SHORT:
        return []
    if g["impossible_share"] > 0.5:
        return [f"no BRDF can make this highlight here: {g['impossible_share'] * 100:.0f}% of the painted pixels ask for "
                f"more light (luminance {g['asked']:.2f}) than the brightest part of the environment above them gives "
                f"({g['brightest_above']:.2f}); paint a weaker highlight, or raise the environment's intensity"]
    # what the light around the mirror directions covers is close to what a fit reaches: on the
    # test bunny under sunset, white strokes of 2× and 4× asked 40% and 21% covered, and one-BRDF
    # and region fits reached 46%, 22% and 21% (a region changed far less of the rest: 1.7% far
    # spill). So the note gives the figure and offers what changes it, not a sharper lobe
    text = (f"the environment has little light near the mirror direction of the painted pixels: it covers "
            f"{g['covered'] * 100:.0f}% of the highlight asked (the fit reached {achieved * 100:.0f}%)")
    offers = []
    if rotate and g["covered_at_rotation"] > g["covered"] + 0.1:
        offers.append(f"rotating the environment to {g['rotate_to_deg']:.0f}° puts light there "
                      f"({g['covered_at_rotation'] * 100:.0f}% of the highlight asked)")
    if one_brdf:
        offers.append("painting the stroke as a region changes only what it covers (one BRDF for the whole object "
                      "brightens all of it)")
    return [text + ("; " + "; ".join(offers) if offers else "")]


def stroke_guidance(fx, views) -> dict | None:
    """highlight_guidance over the painted pixels of the first of a fitter's views with any (None
    when no stroke brightens, or under GI).
    fx : fit.fitter.Fitter; views : per fitter view, (base, target, painted, …) with base and
    target (n, 3) radiance and painted (n,) bool over the view's fit pixels."""
    lighting = getattr(fx.renderer, "lighting", None)
    for v, (base, tgt, painted, *_) in zip(fx.views, views):
        if painted.any():
            s = v.samples
            # GI fit rows carry no surface normals, and under GI the mirror directions of a room
            # see its walls as much as the map: no guidance there yet
            if lighting is None or getattr(s, "normals", None) is None:
                return None
            return highlight_guidance(lighting.map, v.rotation_deg, v.intensity, s.normals[painted], s.wo[painted],
                                      tgt[painted], base[painted])
    return None


def spread_notes(achieved: float | None, spill: float | None) -> list[str]:
    """The note of a one-BRDF stroke fit that fell short where the light is not measured (a
    darkening or a colour change, or any stroke under GI): one BRDF for the whole object changes
    every part of it that sees the same light, so a change asked on part of it comes out weaker
    there and spreads; a painted region changes only what it covers. spill : the RMS change of
    the object's unpainted pixels relative to their radiance (fit.brush.stroke_effect)."""
    if achieved is None or achieved >= SHORT:
        return []
    spread = (f" and changed the rest of the object by {spill * 100:.0f}% of its radiance"
              if spill is not None and spill > 0.1 else "")
    return [f"one BRDF for the whole object reached {achieved * 100:.0f}% of the change painted{spread}: "
            f"painting the stroke as a region changes only what it covers"]


def guidance_event(obj: str, g: dict | None, achieved: float | None, one_brdf: bool, rotate: bool = True,
                   spill: float | None = None) -> dict | None:
    """The session's guidance event (protocol GuidanceEvent) of a stroke fit that fell short, or
    None: it was achieved, or (a region's fit) no highlight was asked. g : highlight_guidance's
    result, None where the light was not measured (not a brightening, or under GI); one_brdf :
    the stroke fitted one BRDF for the whole object (the event then offers a painted region too);
    rotate : as guidance_notes'; spill : the one-BRDF fit's (spread_notes)."""
    from ..protocol import GuidanceEvent

    if g is None:
        notes = spread_notes(achieved, spill) if one_brdf else []
        if not notes:
            return None
        return GuidanceEvent(object=obj, achieved=float(achieved), region=True, message=notes[0],
                             spill=None if spill is None else float(spill)).model_dump()
    notes = guidance_notes(g, achieved, one_brdf, rotate)
    if not notes:
        return None
    # a region is offered where a BRDF could make the highlight at all (guidance_notes' text
    # then suggests one), and only to a stroke that fitted the whole object's BRDF
    region = one_brdf and g["impossible_share"] <= 0.5
    return GuidanceEvent(object=obj, achieved=float(achieved), region=region, message=notes[0],
                         spill=None if spill is None else float(spill),
                         **{k: float(g[k]) for k in ("asked", "mirror", "brightest_above", "covered", "rotate_to_deg",
                                                     "covered_at_rotation", "impossible_share")}).model_dump()
