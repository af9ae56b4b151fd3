"""Synthetic fisheye captures from a real HDRI, with known truth (tests and benchmarks).

What a phone with a clip-on fisheye would record, step by step:
1. **Optics**: each photo pixel sees the direction of the documented projection (fisheye.py),
   read from the HDRI with bilinear filtering (2×2 supersampled when the photo is coarser than
   twice the map). Hand-held brackets shift the scene by a few whole pixels (``jitter_px``)
   while the image circle and the lens frame stay put (they are fixed to the sensor).
2. **Lens frame** (``paint_frame``): a black housing intruding from the rim, the same in every
   photo: a band along a random arc of the rim with varying thickness and tapered ends, plus a
   clip arm. Its radiance is a black body's under the room's light: reflectance 3–6% × the
   irradiance E on a surface facing the shot's direction, /π, modulated by a smooth field
   (a soft reflection), so it is dark, smooth and consistent, never a flat constant. Other
   housings (``paint_housing``, the detector's held-out cases): clip arms alone, a decentred
   lens's vignetting crescent with a soft edge, a thin polished rim glinting with the room's
   brightest light (20-60% of the 99th percentile of what the shot sees).
3. **Camera**: sensor exposure X = L·t, shot and read noise, clipped at full well (X = 4), the
   tone curve ``camera_curve`` (Narkowicz's ACES fit, then sRGB; a filmic phone-like curve
   with a toe and a shoulder), quantised to 8 bits, JPEG (quality 95, 4:2:0) with EXIF
   ExposureTime, FNumber (2.0) and ISO (100).
4. **Exposure ladder** (``ladder``): like a careful photographer: the shortest exposure puts
   the brightest pixel at X = 0.5, the longest the 2nd-percentile radiance at X = 0.05;
   brackets evenly spaced in stops between, 1 to 3 EV apart (phones bracket up to ±3 EV). When
   the scene needs more than 3 EV steps, the ladder is a phone's: the middle bracket metered
   (median at X = 0.18), ±3 EV steps, and the brightest lights clip (reported by the capture).

The truth written beside the manifest (``truth.json``, ``frame.png``): the frame mask, the
exposures and the scale the recovered map should have: map = scale × HDRI, with
scale = t_ref · MID_GREY / X₁₂₈ (the response is anchored at mid-grey, hdr.py).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from .fisheye import Lens, yaw_matrix
from .hdr import MID_GREY

FULL_WELL = 4.0
F_NUMBER, ISO = 2.0, 100
LUMA = np.array([0.2126, 0.7152, 0.0722])


def camera_curve(x: np.ndarray) -> np.ndarray:
    """Synthetic camera tone curve: sensor exposure X ≥ 0 → display value in [0, 1]."""
    x = np.minimum(np.maximum(x, 0.0), FULL_WELL)
    a = np.clip((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)
    return np.where(a <= 0.0031308, 12.92 * a, 1.055 * np.power(np.maximum(a, 0.0031308), 1 / 2.4) - 0.055)


def inverse_camera_curve(y: np.ndarray) -> np.ndarray:
    """X for display value y (numerically, on a fine table)."""
    xs = np.concatenate([[0.0], np.geomspace(1e-6, FULL_WELL, 20000)])
    return np.interp(y, camera_curve(xs), xs)


def render_fisheye(envmap: np.ndarray, lens: Lens, yaw_deg: float, shift=(0, 0)) -> np.ndarray:
    """(H, W, 3) float32 radiance the lens sees at yaw_deg (0 outside the image circle).
    shift : the scene content's displacement (dx, dy) in pixels (hand-held shake)."""
    import cv2

    hm, wm, _ = envmap.shape
    ss = 2 if lens.focal < 2.0 * wm / (2 * np.pi) else 1
    h, w = lens.height, lens.width
    offs = (np.arange(ss) + 0.5) / ss
    acc = np.zeros((h, w, 3), np.float32)
    rot = yaw_matrix(yaw_deg).astype(np.float32)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    for oy in offs:
        for ox in offs:
            d = lens.pixel_to_camera(xs + ox - shift[0], ys + oy - shift[1]).astype(np.float32) @ rot.T
            u = np.mod(np.arctan2(d[..., 0], -d[..., 2]) / (2 * np.pi), 1.0)
            v = np.arccos(np.clip(d[..., 1], -1, 1)) / np.pi
            acc += cv2.remap(envmap, (u * wm - 0.5).astype(np.float32), (v * hm - 0.5).astype(np.float32),
                             cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    acc /= ss * ss
    acc[~lens.circle_mask()] = 0.0
    return acc


def forward_irradiance(envmap: np.ndarray, yaw_deg: float) -> float:
    """Luminance irradiance E on a surface facing the shot's view direction (W/m²-like units)."""
    from ..core.lighting import pixel_directions

    h, w, _ = envmap.shape
    dirs, solid = pixel_directions(h, w, 1)
    fwd = yaw_matrix(yaw_deg) @ np.array([0.0, 0.0, -1.0])
    cos = np.clip(dirs @ fwd, 0.0, None)
    return float(((envmap @ LUMA) * cos * solid[:, None]).sum())


HOUSINGS = ("band", "clip", "vignette", "rim")


def paint_housing(lens: Lens, rng: np.random.Generator, kind: str) -> tuple[np.ndarray, np.ndarray, bool]:
    """A random lens housing of one kind, in sensor coordinates (the detector's held-out cases).

    kind : "band" (``paint_frame``: a band along an arc of the rim plus a clip arm), "clip" (one
        or two clip arms alone), "vignette" (a decentred lens: mechanical vignetting, a dark
        crescent from the rim whose coverage ramps over 3-8% of the radius), "rim" (a bright
        polished barrel edge: a thin ring along most of the rim, 2-5% of the radius, glinting
        with the room's brightest light).
    Returns (alpha (H, W) float32 coverage in [0, 1]; shade (H, W) float32 smooth modulation;
    bright: True when the housing reflects the room's highlights rather than its irradiance)."""
    if kind == "band":
        return (*paint_frame(lens, rng), False)
    h, w = lens.height, lens.width
    cx, cy = lens.centre
    rr = lens.radius
    y, x = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    dx, dy = x - cx, cy - y
    r = np.hypot(dx, dy)
    phi = np.arctan2(dy, dx)
    k1, k2 = rng.uniform(1, 3, 2) * 2 * np.pi / (2 * rr)
    ph = rng.uniform(0, 2 * np.pi, 2)
    shade = (1.0 + 0.25 * np.sin(k1 * dx + ph[0]) + 0.15 * np.cos(k2 * dy + ph[1])).astype(np.float32)
    if kind == "clip":
        sd = np.full((h, w), np.inf)
        for _ in range(int(rng.integers(1, 3))):
            a = rng.uniform(-np.pi, np.pi)
            half_w = rng.uniform(0.04, 0.10) * rr
            length = rng.uniform(0.12, 0.3) * rr
            ux, uy = np.cos(a), np.sin(a)
            along = dx * ux + dy * uy
            across = np.abs(-dx * uy + dy * ux)
            sd = np.minimum(sd, np.maximum(across - half_w, (rr - length) - along))
        alpha = np.clip(0.5 - sd, 0.0, 1.0)
    elif kind == "vignette":
        # the lens sits off the sensor's axis: the housing's shadow is thickest on one side
        a0 = rng.uniform(-np.pi, np.pi)
        off = rng.uniform(0.08, 0.16) * rr
        base = rng.uniform(-0.06, 0.02) * rr
        thick = base + off * np.cos(phi - a0)
        ramp = rng.uniform(0.03, 0.08) * rr
        alpha = np.clip(((r - rr) + thick) / ramp + 0.5, 0.0, 1.0)
    elif kind == "rim":
        start = rng.uniform(-np.pi, np.pi)
        span = np.radians(rng.uniform(200, 360))
        s = np.mod(phi - start, 2 * np.pi) / span
        t0 = rng.uniform(0.02, 0.05) * rr
        thick = np.where(s <= 1.0, t0 * np.sqrt(np.clip(np.minimum(s, 1.0 - s) * 20.0, 0.0, 1.0)), 0.0)
        alpha = np.clip(0.5 - ((rr - r) - thick), 0.0, 1.0)
    else:
        raise ValueError(f"unknown housing {kind!r} (known: {', '.join(HOUSINGS)})")
    alpha = alpha.astype(np.float32)
    alpha[r > rr] = 0.0
    return alpha, shade, kind == "rim"


def paint_frame(lens: Lens, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random lens housing in sensor coordinates.

    Returns (alpha (H, W) float32 coverage in [0, 1], anti-aliased over ~1 px; shade (H, W)
    float32 smooth modulation in [0.6, 1.4])."""
    h, w = lens.height, lens.width
    cx, cy = lens.centre
    rr = lens.radius
    y, x = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    dx, dy = x - cx, cy - y
    r = np.hypot(dx, dy)
    phi = np.arctan2(dy, dx)
    # band along an arc of the rim, thickness varying along it, ends tapered
    start = rng.uniform(-np.pi, np.pi)
    span = np.radians(rng.uniform(50, 150))
    t0 = rng.uniform(0.06, 0.12) * rr
    rel = np.mod(phi - start, 2 * np.pi)
    s = rel / span                                           # 0..1 along the arc
    wobble = 1.0 + 0.3 * np.sin(2 * np.pi * s * rng.uniform(1, 3) + rng.uniform(0, 6.28))
    taper = np.clip(np.minimum(s, 1.0 - s) * 6.0, 0.0, 1.0)
    thick = np.where(s <= 1.0, t0 * wobble * np.sqrt(taper), 0.0)
    sd_band = (rr - r) - thick                               # < 0 inside the band
    # the clip's arm: a rectangle from the rim inwards at another azimuth
    a = start + span + rng.uniform(0.6, 2 * np.pi - span - 0.6)
    half_w = rng.uniform(0.04, 0.09) * rr
    length = rng.uniform(0.12, 0.25) * rr
    ux, uy = np.cos(a), np.sin(a)
    along = dx * ux + dy * uy                                # distance from centre along the arm
    across = np.abs(-dx * uy + dy * ux)
    sd_arm = np.maximum(across - half_w, (rr - length) - along)
    sd = np.minimum(sd_band, sd_arm)
    alpha = np.clip(0.5 - sd, 0.0, 1.0).astype(np.float32)  # ~1 px anti-aliased edge
    alpha[r > rr] = 0.0
    k1, k2 = rng.uniform(1, 3, 2) * 2 * np.pi / (2 * rr)
    ph = rng.uniform(0, 2 * np.pi, 2)
    shade = 1.0 + 0.25 * np.sin(k1 * dx + ph[0]) + 0.15 * np.cos(k2 * dy + ph[1])
    return alpha, shade.astype(np.float32)


def ladder(lum_all: np.ndarray, brackets: int) -> np.ndarray:
    """Shutter times (s), increasing, for the radiance seen by the shots (see module doc)."""
    pos = lum_all[lum_all > 0]
    t_short = 0.5 / float(pos.max())                  # brightest pixel at X = 0.5 (z ≈ 200)
    t_long = 0.05 / float(np.percentile(pos, 2))      # 2nd percentile at X = 0.05 (z ≈ 60)
    span = np.log2(max(t_long / t_short, 1.0))
    k = np.arange(brackets) - (brackets - 1) / 2.0
    step = span / max(brackets - 1, 1)
    if step <= 3.0:
        return np.sqrt(t_short * t_long) * 2.0 ** (max(step, 1.0) * k)
    # more range than the bracket can hold: meter like a phone (median at X = 0.18), ±3 EV steps;
    # the brightest lights clip and the capture reports it
    return 0.18 / float(np.median(pos)) * 2.0 ** (3.0 * k)


@dataclass
class SynthCapture:
    manifest: Path
    frame: np.ndarray        # (H, W) bool truth mask (alpha > 0.5), all False without a frame
    shutter_s: np.ndarray    # (K,) shutter times, the same ladder for every shot
    scale: float             # the map the pipeline should recover is scale × the HDRI
    radiance: list           # per shot (H, W, 3) float32 scene radiance at the middle bracket's pose
    with_frame: list         # the same with the lens frame composited (what the sensor saw)


def _write_jpeg(path: Path, img: np.ndarray, t: float, quality: int) -> None:
    from PIL import ExifTags, Image, TiffImagePlugin

    ex = Image.Exif()
    sub = ex.get_ifd(ExifTags.IFD.Exif)
    frac = Fraction(t).limit_denominator(10_000_000)
    sub[ExifTags.Base.ExposureTime] = TiffImagePlugin.IFDRational(frac.numerator, frac.denominator)
    sub[ExifTags.Base.FNumber] = TiffImagePlugin.IFDRational(int(F_NUMBER * 10), 10)
    sub[ExifTags.Base.ISOSpeedRatings] = ISO
    Image.fromarray(img).save(path, "JPEG", quality=quality, subsampling=2, exif=ex)   # 4:2:0 as phones


def synthesize(envmap: np.ndarray, out_dir: str | Path, width: int = 600, height: int = 400,
               projection: str = "equidistant", fov_deg: float = 190.0, yaws=(0.0, 180.0),
               brackets: int = 5, frame: bool | str = True, jitter_px: int = 0, seed: int = 0,
               exposure_in_manifest: bool = False, quality: int = 95, progress=None) -> SynthCapture:
    """Write a synthetic capture of ``envmap`` ((H, W, 3) float32 radiance) to out_dir: JPEGs,
    ``manifest.json``, ``truth.json`` and ``frame.png``. See the module doc.

    frame : True (a "band" housing), False (a clean capture) or a kind of ``paint_housing``."""
    from PIL import Image

    tick = progress or (lambda f, m: None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    lens = Lens(width, height, projection, fov_deg)
    circle = lens.circle_mask()
    bright = False
    if frame:
        alpha, shade, bright = paint_housing(lens, rng, "band" if frame is True else str(frame))
    else:
        alpha, shade = np.zeros((height, width), np.float32), np.ones((height, width), np.float32)
    tick(0.0, "rendering the fisheye views")
    centre = [render_fisheye(envmap, lens, y) for y in yaws]
    if bright:
        # polished metal glinting with the room's brightest light: 20-60% of the 99th percentile
        # of the radiance the shot sees (brighter than most of the scene, never a clipped light)
        frame_l = [rng.uniform(0.2, 0.6) * float(np.percentile((c @ LUMA.astype(np.float32))[circle], 99))
                   for c in centre]
    else:
        frame_l = [rng.uniform(0.03, 0.06) * forward_irradiance(envmap, y) / np.pi for y in yaws]
    seen = np.concatenate([(c @ LUMA.astype(np.float32))[circle] for c in centre])
    times = ladder(seen, brackets)
    x128 = float(inverse_camera_curve(128.0 / 255.0))
    t_ref = float(np.median(times))
    shots, shifts = [], []
    n_total = len(yaws) * brackets
    for i, yaw in enumerate(yaws):
        imgs = []
        for k, t in enumerate(times):
            tick((i * brackets + k) / n_total, f"photo {i * brackets + k + 1}/{n_total}")
            shift = (0, 0)
            if jitter_px and k != brackets // 2:
                shift = tuple(int(v) for v in rng.integers(-jitter_px, jitter_px + 1, 2))
            shifts.append(shift)
            scene = centre[i] if shift == (0, 0) else render_fisheye(envmap, lens, yaw, shift)
            rad = scene * (1.0 - alpha[..., None]) + (alpha * shade * frame_l[i])[..., None]
            x = rad * t
            # read noise (σ 0.0014) and shot noise (σ 1% at X = 1), in units of X
            x = x + rng.normal(0.0, 1.0, x.shape).astype(np.float32) * np.sqrt(2e-6 + 1e-4 * np.maximum(x, 0.0))
            z = np.clip(np.rint(camera_curve(x) * 255.0), 0, 255).astype(np.uint8)
            z[~circle] = 0
            name = f"shot{i}_{k}.jpg"
            _write_jpeg(out / name, z, float(t), quality)
            entry = {"file": name}
            if exposure_in_manifest:
                entry["exposure_s"] = float(t)
            imgs.append(entry)
        shots.append({"yaw_deg": float(yaw), "images": imgs})
    manifest = {"version": 1, "projection": projection, "fov_deg": float(fov_deg), "shots": shots}
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1))
    fmask = alpha > 0.5
    Image.fromarray((fmask * 255).astype(np.uint8)).save(out / "frame.png")
    scale = t_ref * MID_GREY / x128
    (out / "truth.json").write_text(json.dumps({"shutter_s": times.tolist(), "scale": scale, "seed": seed,
                                                "frame_pixels": int(fmask.sum()), "jitter_px": jitter_px,
                                                "scene_shifts_px": shifts}, indent=1))
    tick(1.0, "done")
    framed = [c * (1.0 - alpha[..., None]) + (alpha * shade * fl)[..., None] for c, fl in zip(centre, frame_l)]
    return SynthCapture(out / "manifest.json", fmask, times, scale, centre, framed)
