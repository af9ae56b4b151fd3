"""Fisheye shots → one equirectangular radiance map (docs/design/conventions.md, Mitsuba's ``envmap``
mapping: u = atan2(x, −z)/2π, v = acos(y)/π).

Each output pixel's direction is projected into every shot (fisheye.py) and read with OpenCV's
bilinear ``remap``. Shots blend with feathered weights: a pixel's weight rises smoothly
(smoothstep) with its distance from anything unusable in its photo (outside the image circle,
the lens frame, pixels shifted in by alignment), over the width of the overlap between
neighbouring shots (fov − yaw gap, at most 20°), so seams fade across the whole overlap and the
frame's edge fades into the other shot. Radiance and weight are resampled premultiplied, so
unusable pixels never bleed in. Pixels clipped in every bracket keep a weight of 10⁻³: another
shot that resolved them wins.

Exposure matching: the shots' gains g_i (in stops) minimise Σ_pairs n_ij (g_i − g_j − d_ij)²
with Σ g_i = 0, where d_ij is the median log₂ luminance ratio of shot j over shot i on their
common, unclipped pixels (robust to parallax and to what the frame hides) and n_ij their
count. Phone auto exposure, vignetting and ISO rounding make equal nominal exposures differ.

Holes (directions no shot sees usefully: frame regions outside the overlap, gaps between shots)
are inpainted in log radiance by OpenCV's Telea method, with the map wrapped around in
longitude. ``seamlessClone``, the paper's tool, takes only 8-bit images; radiance would have to
be quantised, so inpainting of the float log radiance does the automatic fill instead.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.lighting import pixel_directions
from .fisheye import Lens
from .manifest import CaptureError

MAX_UNCOVERED = 0.02     # fraction of the sphere no shot sees before we refuse the capture
LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)


@dataclass
class StitchResult:
    envmap: np.ndarray             # (H, W, 3) float32 linear radiance, W = 2H
    gains_stops: list[float]       # per shot exposure-matching gain
    inpainted_fraction: float      # of the sphere (solid angle) filled by inpainting
    uncovered_fraction: float      # of the sphere outside every shot's field
    clipped_fraction: float        # of the sphere clipped in every bracket of the shot used
    overlap_deg: float
    feather_px: float


def row_solid_angle(h: int, w: int) -> np.ndarray:
    """(h,) float64 solid angle (sr) of one pixel in each row of an h×w equirectangular map."""
    edges = np.linspace(0.0, np.pi, h + 1)
    return (2.0 * np.pi / w) * (np.cos(edges[:-1]) - np.cos(edges[1:]))


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def overlap_deg(yaws: list[float], fov_deg: float) -> float:
    """Smallest horizontal overlap between neighbouring shots (degrees; ≤ 0: gaps)."""
    y = np.sort(np.mod(np.asarray(yaws, np.float64), 360.0))
    if len(y) == 1:
        return fov_deg - 360.0
    gaps = np.diff(np.concatenate([y, y[:1] + 360.0]))
    return float(fov_deg - gaps.max())


def feather_weights(usable: np.ndarray, feather_px: float) -> np.ndarray:
    """(H, W) float32 weight in [0, 1] rising with the distance (pixels) from unusable pixels."""
    import cv2

    d = cv2.distanceTransform(usable.astype(np.uint8), cv2.DIST_L2, 5)
    return _smoothstep(d / max(feather_px, 1.0)).astype(np.float32)


def default_width(lens: Lens, cap: int = 4096) -> int:
    """Output width matching the photos' angular resolution at the centre, a multiple of 16,
    in [256, cap]."""
    w = 2.0 * np.pi * lens.focal
    return int(np.clip(int(round(w / 16.0)) * 16, 256, cap))


def _inpaint_log(img: np.ndarray, hole: np.ndarray, max_width: int = 1024) -> np.ndarray:
    """Fill hole pixels of an equirectangular radiance map by Telea inpainting of log radiance,
    wrapped in longitude; computed at ≤ max_width and upsampled into the holes (a lighting fill is
    smooth anyway). img (H, W, 3) float32; hole (H, W) bool. Returns a filled copy."""
    import cv2

    h, w, _ = img.shape
    out = img.copy()
    if not hole.any():
        return out
    known = ~hole
    if not known.any():
        raise CaptureError("nothing usable in the photos: every pixel is black, clipped or masked")
    s = min(1.0, max_width / w)
    ws, hs = max(4, int(round(w * s))), max(2, int(round(h * s)))
    kf = known.astype(np.float32)
    if s < 1.0:
        num = cv2.resize(img * kf[..., None], (ws, hs), interpolation=cv2.INTER_AREA)
        den = cv2.resize(kf, (ws, hs), interpolation=cv2.INTER_AREA)
        small = num / np.maximum(den, 1e-12)[..., None]
        small_hole = den < 0.999
    else:
        small, small_hole = img, hole
    floor = 1e-6 * max(float(np.median(small[~small_hole])), 1e-12)
    pad = max(8, ws // 8)
    wrap = lambda a: np.concatenate([a[:, -pad:], a, a[:, :pad]], axis=1)   # noqa: E731
    mask = wrap(small_hole.astype(np.uint8))
    fill = np.empty((hs, ws, 3), np.float32)
    for c in range(3):
        lg = wrap(np.log(np.maximum(small[..., c], floor)).astype(np.float32))
        fill[..., c] = cv2.inpaint(lg, mask, 5, cv2.INPAINT_TELEA)[:, pad:pad + ws]
    fill = np.exp(fill)
    if s < 1.0:
        fill = cv2.resize(fill, (w, h), interpolation=cv2.INTER_LINEAR)
    out[hole] = fill[hole]
    return out



def fisheye_map_numpy(h: int, w: int, lens: Lens, yaw_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Reference of glk_fisheye_map: (map_x, map_y) (h, w) float32 cv2.remap coordinates in the
    photo for every pixel of an h×w equirectangular map; −10 where the shot does not see."""
    dirs, _ = pixel_directions(h, w, 1)
    px, py, th = lens.world_to_pixel(dirs.reshape(-1, 3), yaw_deg)
    inside = th <= lens.theta_max
    mx = np.where(inside, px - 0.5, -10.0).astype(np.float32).reshape(h, w)
    my = np.where(inside, py - 0.5, -10.0).astype(np.float32).reshape(h, w)
    return mx, my


def fisheye_map(h: int, w: int, lens: Lens, yaw_deg: float, kernels=None):
    """(map_x, map_y) (h, w) float32 as fisheye_map_numpy (yaw in degrees), by the backend
    ``kernels`` (glk_fisheye_map or the reference; default: the process's)."""
    from ..native.kernels import kernels as _kernels

    return (kernels or _kernels()).capture.fisheye_map(int(h), int(w), lens, float(yaw_deg))


def check_coverage(lens: Lens, yaws: list[float]) -> float:
    """Fraction of the sphere no shot sees (from the geometry alone, on a 64×128 grid); raises
    CaptureError above MAX_UNCOVERED, before any photo is read."""
    h, w = 64, 128
    covered = np.zeros((h, w), bool)
    for yaw in yaws:
        covered |= fisheye_map_numpy(h, w, lens, yaw)[0] > -5.0
    sa = np.broadcast_to(row_solid_angle(h, w)[:, None], (h, w))
    uncovered = float(sa[~covered].sum() / (4 * np.pi))
    if uncovered > MAX_UNCOVERED:
        raise CaptureError(f"the shots cover only {100 * (1 - uncovered):.1f}% of the sphere: with fov_deg "
                           f"{lens.fov_deg:g} the yaw angles {list(yaws)} leave gaps; add shots or check "
                           "fov_deg and yaw_deg")
    return uncovered


def stitch(shots, lens: Lens, frame: np.ndarray | None, width: int, progress=None,
           kernels=None) -> StitchResult:
    """Blend the merged shots into one equirectangular map.

    shots : list of hdr.ShotHDR (radiance (H, W, 3) float32 in the photos' grid, status bits,
        yaw_deg, shifts).
    frame : (H, W) bool lens-frame mask (same for every shot) or None to keep the frame.
    width : output width W (height W/2).
    kernels : the backend (default: the process's).
    """
    import cv2

    tick = progress or (lambda f, m: None)
    h_out, w_out = width // 2, width
    ov = overlap_deg([s.yaw_deg for s in shots], lens.fov_deg)
    feather_rad = np.radians(np.clip(ov, 0.5, 20.0))
    sa = np.broadcast_to(row_solid_angle(h_out, w_out)[:, None], (h_out, w_out))
    circle = lens.circle_mask()
    # resample from a copy at about the output's angular resolution (area-averaged), not alias
    scale = min(1.0, (w_out / (2.0 * np.pi)) / lens.focal * 1.5)
    num_sum = np.zeros((h_out, w_out, 3), np.float32)
    den_sum = np.zeros((h_out, w_out), np.float32)
    covered = np.zeros((h_out, w_out), bool)
    per_shot = []
    feather_px = float(feather_rad * lens.pixels_per_radian(lens.theta_max))
    for i, shot in enumerate(shots):
        tick(0.7 + 0.15 * i / len(shots), f"reprojecting shot {i + 1}/{len(shots)}")
        usable = circle & ((shot.status & 4) == 0)
        if frame is not None:
            usable &= ~frame
        wgt = feather_weights(usable, feather_px)
        clipped = (shot.status & 1) > 0
        wgt = np.where(clipped, wgt * 1e-3, wgt).astype(np.float32)
        rad = shot.radiance
        src_lens = lens
        clip_f = clipped.astype(np.float32)
        if scale < 0.75:
            ws, hs = max(8, int(round(lens.width * scale))), max(8, int(round(lens.height * scale)))
            rad = cv2.resize(rad * wgt[..., None], (ws, hs), interpolation=cv2.INTER_AREA)
            wgt = cv2.resize(wgt, (ws, hs), interpolation=cv2.INTER_AREA)
            rad = rad / np.maximum(wgt, 1e-12)[..., None]
            clip_f = cv2.resize(clip_f, (ws, hs), interpolation=cv2.INTER_AREA)
            src_lens = Lens(ws, hs, lens.projection, lens.fov_deg)
        mx, my = fisheye_map(h_out, w_out, src_lens, shot.yaw_deg, kernels)
        inside = mx > -5.0
        pre = np.ascontiguousarray(rad * wgt[..., None], dtype=np.float32)
        n_i = cv2.remap(pre, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        d_i = cv2.remap(wgt, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        c_i = cv2.remap(clip_f, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        covered |= inside
        per_shot.append((n_i, d_i, c_i))
    uncovered = float(sa[~covered].sum() / (4 * np.pi))
    if uncovered > MAX_UNCOVERED:
        raise CaptureError(f"the shots cover only {100 * (1 - uncovered):.1f}% of the sphere: with fov_deg "
                           f"{lens.fov_deg:g} the yaw angles {[s.yaw_deg for s in shots]} leave gaps; add shots "
                           "or check fov_deg and yaw_deg")
    tick(0.86, "matching exposures between shots")
    gains = _exposure_gains(per_shot)
    for (n_i, d_i, _), g in zip(per_shot, gains):
        num_sum += n_i * np.float32(2.0 ** g)
        den_sum += d_i
    hole = den_sum <= 1e-6
    env = num_sum / np.maximum(den_sum, 1e-12)[..., None]
    env[hole] = 0.0
    clipped_w = sum(c_i * d_i for _, d_i, c_i in per_shot) / np.maximum(den_sum, 1e-12)
    clipped_frac = float(sa[(clipped_w > 0.5) & ~hole].sum() / (4 * np.pi))
    tick(0.9, "filling what no shot sees")
    env = _inpaint_log(env, hole)
    return StitchResult(np.maximum(env, 0.0).astype(np.float32), [float(g) for g in gains],
                        float(sa[hole].sum() / (4 * np.pi)), uncovered, clipped_frac, ov, feather_px)


def _exposure_gains(per_shot) -> np.ndarray:
    """Per shot gains in stops (Σ = 0) from the pairwise median log ratios on common pixels."""
    n = len(per_shot)
    if n < 2:
        return np.zeros(n)
    lum = []
    for n_i, d_i, c_i in per_shot:
        ok = (d_i > 1e-3) & (c_i < 1e-3)
        l = (n_i @ LUMA) / np.maximum(d_i, 1e-12)
        lum.append((l, ok & (l > 0)))
    rows, rhs, wts = [], [], []
    for i in range(n):
        for j in range(i + 1, n):
            both = lum[i][1] & lum[j][1]
            cnt = int(both.sum())
            if cnt < 50:
                continue
            d = float(np.median(np.log2(lum[j][0][both]) - np.log2(lum[i][0][both])))
            r = np.zeros(n); r[i], r[j] = 1.0, -1.0    # g_i − g_j = d: scales j onto i and back
            rows.append(r); rhs.append(d); wts.append(np.sqrt(cnt))
    if not rows:
        return np.zeros(n)
    a = np.array(rows) * np.array(wts)[:, None]
    b = np.array(rhs) * np.array(wts)
    a = np.vstack([a, np.full(n, 1e3)])           # Σ g = 0 (the overall scale stays the photos')
    b = np.append(b, 0.0)
    g, *_ = np.linalg.lstsq(a, b, rcond=None)
    return g
