"""The paint designer's pictures come from the worker: the swatch (worker/paint/swatch.py) and
the lobe plot's RGB values (worker/jobs/curves.py brdf_lobe), checked against closed forms."""
import base64
import io

import numpy as np
from PIL import Image

from worker.core.tonemap import tonemap
from worker.jobs.curves import LOBE_INCIDENT_DEG, brdf_lobe
from worker.paint.session import apply_paint
from worker.paint.swatch import DOME, LIGHTS, SWATCH_PX, swatch_png, swatch_radiance
from worker.protocol.events import PaintEvent
from worker.scene import Lobes


def _normals(n):
    c = (np.arange(n) + 0.5) * 2.0 / n - 1.0
    u, v = np.meshgrid(c, -c)
    z = np.sqrt(np.maximum(1.0 - u * u - v * v, 0.0))
    return np.stack([u, v, z], -1), u * u + v * v < 1.0


def test_a_diffuse_swatch_is_lambert_under_the_lights():
    """No lobes: every pixel is albedo/π·Σ max(0, n·l)·E plus the dome term (the packed BRDF
    evaluates in float32: 1e-6)."""
    a = np.array([0.6, 0.3, 0.1])
    mat = Lobes(exponents=[10.0], gloss=[0.0], directional_diffuse=[(0.0, 0.0, 0.0)], albedo=tuple(a))
    rad, inside = swatch_radiance(mat, 48)
    N, disc = _normals(48)
    assert (inside == disc).all()
    want = a * DOME * (0.6 + 0.4 * N[..., 1:2])
    for d, e in LIGHTS:
        d = np.asarray(d) / np.linalg.norm(d)
        want = want + a / np.pi * np.maximum(N @ d, 0.0)[..., None] * e
    err = np.abs(rad[inside] - want[inside]).max()
    assert err < 1e-6, f"swatch differs from Lambert's closed form by {err:.3g}"
    assert (rad[~inside] == 0).all()


def test_a_sharp_lobe_highlights_where_the_mirror_sends_the_key_light_to_the_viewer():
    """One narrow lobe and no diffuse: the brightest pixel's normal is the half vector of the key
    light and the view (+z), within a pixel's normal spacing."""
    n = 128
    mat = Lobes(exponents=[2000.0], gloss=[0.5], directional_diffuse=[(0.0, 0.0, 0.0)], albedo=(0.0, 0.0, 0.0))
    rad, inside = swatch_radiance(mat, n)
    lum = rad @ [0.2126, 0.7152, 0.0722]
    j, i = np.unravel_index(np.argmax(lum), lum.shape)
    N, _ = _normals(n)
    key = np.asarray(LIGHTS[0][0], float)
    h = key / np.linalg.norm(key) + [0.0, 0.0, 1.0]
    h /= np.linalg.norm(h)
    ang = np.degrees(np.arccos(np.clip(N[j, i] @ h, -1, 1)))
    # normal spacing near the half vector: a pixel is 2/n of the disc, ~1.1° at n = 128 there
    assert ang < 1.5, f"highlight at {ang:.2f}° from the half vector"


def test_the_swatch_png_is_the_tone_mapped_radiance_and_small():
    mat, _ = apply_paint({"gloss": 85, "aspecular": {"15": [0.3, 0.1, 0.1], "45": [0.1, 0.05, 0.05],
                                                     "110": [0.02, 0.02, 0.02]}})
    url = swatch_png(mat)
    assert url.startswith("data:image/png;base64,")
    raw = base64.b64decode(url.split(",", 1)[1])
    assert len(raw) < 16_384, f"swatch {len(raw)} bytes"
    img = np.asarray(Image.open(io.BytesIO(raw)).convert("RGBA"))
    assert img.shape == (SWATCH_PX, SWATCH_PX, 4)
    rad, inside = swatch_radiance(mat)
    assert (img[..., 3] == np.where(inside, 255, 0)).all()
    assert (img[inside, :3] == tonemap(rad.astype(np.float32))[inside]).all()


def test_the_paint_event_carries_its_swatch():
    mat, ev = apply_paint({"object": "car", "seq": 3, "gloss": 60,
                           "aspecular": {"15": [0.2, 0.2, 0.3], "45": [0.05, 0.05, 0.08]}})
    e = PaintEvent(**ev)
    assert e.swatch == swatch_png(mat)


def test_the_lobe_rgb_is_f_cos_and_its_luminance_the_plotted_values():
    """Lobe RGB at θi = 45°: a diffuse material's is albedo/π·cosθo; a lobes material's
    luminance is the luminance curve the curve panel draws (to its rounding)."""
    a = (0.5, 0.25, 0.125)
    diffuse = Lobes(exponents=[10.0], gloss=[0.0], directional_diffuse=[(0.0, 0.0, 0.0)], albedo=a)
    lobe = brdf_lobe(diffuse)
    assert lobe["rgb_theta_i_deg"] == [15, 30, 45, 60, 75]
    k = lobe["rgb_theta_i_deg"].index(45)
    to = np.radians(lobe["theta_o_deg"])
    want = np.asarray(a)[None, :] / np.pi * np.maximum(np.cos(to), 0.0)[:, None]
    assert np.allclose(lobe["rgb"][k], want, rtol=1e-3, atol=1e-7)
    glossy = Lobes(exponents=[1.0, 12.0, 900.0], gloss=[0.0, 0.01, 0.04],
                   directional_diffuse=[(0.2, 0.1, 0.05), (0.3, 0.3, 0.2), (0.0, 0.0, 0.0)], albedo=(0.05, 0.04, 0.03))
    lobe = brdf_lobe(glossy)
    rgb = np.asarray(lobe["rgb"])
    assert rgb.shape == (len(lobe["rgb_theta_i_deg"]), len(lobe["theta_o_deg"]), 3)
    lum = rgb @ [0.2126, 0.7152, 0.0722]
    rows = [LOBE_INCIDENT_DEG.index(t) for t in lobe["rgb_theta_i_deg"]]
    assert np.allclose(lum, np.asarray(lobe["values"])[rows], rtol=2e-3, atol=2e-6)
    # the mirror lobe peaks at θo = θi on the +x side (θo is sampled every 2°)
    peak = lobe["theta_o_deg"][int(np.argmax(lum[k]))]
    # and four decades below the peak the values keep their digits (a log plot shows them)
    far = np.asarray(lobe["rgb"])[k]
    exact = np.asarray(lobe["values"])[LOBE_INCIDENT_DEG.index(45)]
    low = (exact > 1e-4 * exact.max()) & (exact < 1e-3 * exact.max())
    if low.any():
        assert np.allclose((far @ [0.2126, 0.7152, 0.0722])[low], exact[low], rtol=2e-2)
    assert abs(peak - 45.0) <= 1.0 + 1e-9, peak
