"""A paint swatch: a sphere shaded with the material's own BRDF (worker/core/brdf.py
``evaluate``, the one the renderers use) under a fixed studio light set, so the paint
designer's palette (cacad-cosine-lobes §1.1: colour swatch palette) compares saved paints side
by side. The browser only shows the image; it evaluates no BRDF.

The light set is a display convention, not a scene: three directional lights (key, fill, rim)
and a dome's diffuse term, in view space (x right, y up, z towards the viewer, orthographic
view along −z). The image goes through the frames' tone curve (worker/core/tonemap.py).
"""
from __future__ import annotations

import base64
import io

import numpy as np

SWATCH_PX = 64
# (direction towards the light in view space, irradiance at normal incidence)
LIGHTS = (((-0.5, 0.6, 0.62), 2.5), ((0.7, 0.2, 0.68), 0.8), ((0.1, -0.3, -0.95), 1.2))
# the dome's diffuse term: irradiance·albedo/π with irradiance π·DOME·(0.6 + 0.4·n_y), brighter
# above (a sky over a darker floor); it lights the diffuse part only
DOME = 0.25


def swatch_radiance(material, n: int = SWATCH_PX) -> tuple[np.ndarray, np.ndarray]:
    """Outgoing radiance of the unit sphere seen head-on, per pixel.

    Returns (radiance (n, n, 3) float64 linear, inside (n, n) bool: the pixels on the sphere).
    Pixel (0, 0) is the top left. Radiance at a pixel with normal N:
    Σ_lights f(ωi, ωo)·max(0, N·ωi)·E  +  albedo·DOME·(0.6 + 0.4·N_y), with ωo = +z (the viewer).
    """
    from ..core.brdf import evaluate, to_local

    c = (np.arange(n) + 0.5) * 2.0 / n - 1.0
    u, v = np.meshgrid(c, -c)                          # v up: row 0 is the top
    r2 = u * u + v * v
    inside = r2 < 1.0
    N = np.stack([u[inside], v[inside], np.sqrt(1.0 - r2[inside])], -1)
    wo = to_local(np.broadcast_to([0.0, 0.0, 1.0], N.shape), N)
    albedo = np.asarray(material.albedo, np.float64)
    col = albedo[None, :] * DOME * (0.6 + 0.4 * N[:, 1:2])
    for d, e in LIGHTS:
        d = np.asarray(d, np.float64) / np.linalg.norm(d)
        cos = N @ d
        lit = cos > 0
        if not lit.any():
            continue
        wi = to_local(np.broadcast_to(d, N[lit].shape), N[lit])
        col[lit] += evaluate(material, wi, wo[lit]) * (cos[lit, None] * e)
    out = np.zeros((n, n, 3))
    out[inside] = col
    return out, inside


def swatch_png(material, n: int = SWATCH_PX) -> str:
    """The swatch as a PNG data URL (RGBA, transparent off the sphere; a few KB at 64 px)."""
    from PIL import Image

    from ..core.tonemap import tonemap

    rad, inside = swatch_radiance(material, n)
    rgba = np.zeros((n, n, 4), np.uint8)
    rgba[..., :3] = tonemap(rad.astype(np.float32), 0.0, "neutral")
    rgba[..., 3] = np.where(inside, 255, 0)
    buf = io.BytesIO()
    Image.fromarray(rgba, "RGBA").save(buf, format="PNG")      # optimize: 6× the time for 3% of the bytes
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")
