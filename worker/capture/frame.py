"""Automatic removal of the fisheye lens's frame (cyber-worlds §IV and VII: the paper removes
the reflection of the black frame by hand and asks for an automatic method).

What the frame is: the housing of a clip-on fisheye (its barrel, the clip's arm, the phone's
edge beyond 180°) seen at the edge of the image circle. Four properties hold for every such
lens, whatever the scene, and together they separate it from the scene:

1. **Fixed to the sensor.** It sits at the same pixels in every bracket and in every shot (the
   lens turns with the camera), while the scene behind it changes from shot to shot. So a
   pixel is a candidate only if it is frame-like in *all* shots at once.
2. **Attached to the rim.** It intrudes from outside the field: every region must touch the
   image circle's rim and lie in its outer half.
3. **Dark.** It is black plastic or metal lit by the room: at most ~10% reflectance, so
   several times darker than the scene it hides. A candidate is darker than both
   ``DARK_STOPS`` below the shot's median radiance and ``DARK_OF_MEAN`` × the shot's mean
   radiance (the mean ≈ irradiance/π: a 10% grey card facing the room would read 0.1 × it).
   The first test keeps ordinary scene shadows, the second keeps dim scenes with a few bright
   lights, where a black housing is not the problem (it hides little light).
4. **Low texture.** Its log radiance is smooth: the local standard deviation of log₂ luminance
   (window ~2% of the circle) is below ``FLAT_STOPS`` in every shot.

Detection runs on the merged HDR (the consensus of the brackets) at a working resolution of
about 512 px across the circle. Rim-attached components of the candidates are seeds; they grow
(hysteresis) through pixels that are dark in every shot, texture or not, which recovers the
frame's thin parts and edges, where the texture window also sees the scene. The mask then grows
by a quarter of the texture window (the frame's anti-aliased edge), by the largest alignment
shift (aligned brackets see the frame displaced by it) and by one photo pixel.

Where another shot sees the same directions, stitching fills the frame from it (the frame's
pixels get zero weight and a feathered edge); what no shot sees is inpainted (stitch.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fisheye import Lens

DARK_STOPS = 1.5       # below the shot's median log₂ luminance
DARK_ALBEDO = 0.25     # × E/π facing forward: black housings reflect < 10%; margin for clipped lights
FLAT_STOPS_PER_PX = 0.1   # 5×5 median of |∇ log₂ luminance| at the working resolution
WORK_DIAMETER = 512    # working resolution across the image circle
LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)


@dataclass
class FrameMask:
    mask: np.ndarray         # (H, W) bool at the photos' resolution: the frame (same for all shots)
    pixels: int              # pixels of one photo flagged as frame
    fraction_of_circle: float
    solid_angle_sr: float    # of one shot's frame pixels
    regions: int


def flatness(ell: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(H, W) float32 local texture of log₂ luminance: the 5×5 median of the gradient magnitude
    (stops per pixel). The median ignores an edge crossing the window, so a thin frame still
    has flat pixels right up to near its border; invalid pixels count as flat (they are masked
    elsewhere)."""
    import cv2

    x = np.where(valid, ell, 0.0).astype(np.float32)
    # the edge of the valid area is not texture: replicate inwards values outwards first
    if not valid.all():
        x = cv2.inpaint(x, (~valid).astype(np.uint8), 2, cv2.INPAINT_NS) if valid.any() else x
    gx = cv2.Sobel(x, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(x, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return cv2.medianBlur(np.sqrt(gx * gx + gy * gy), 5)


def detect_frame(radiance: list[np.ndarray], lens: Lens, max_shift: int = 0) -> FrameMask:
    """Find the lens frame in a capture's merged shots.

    radiance : per shot (H, W, 3) float32 linear radiance in the photos' pixel grid (0 outside
        the image circle).
    max_shift : the largest bracket alignment shift, pixels.
    Returns the FrameMask (one mask for all shots: the frame is fixed to the sensor)."""
    import cv2

    h, w = radiance[0].shape[:2]
    scale = min(1.0, WORK_DIAMETER / (2.0 * lens.radius))
    ws, hs = max(8, int(round(w * scale))), max(8, int(round(h * scale)))
    small = Lens(ws, hs, lens.projection, lens.fov_deg)
    r = small.pixel_radius() / small.radius
    circle = r <= 1.0
    sa = small.pixel_solid_angle()
    cos_axis = np.clip(np.cos(small.theta_of_radius(small.pixel_radius())), 0.0, None)
    cand = (r >= 0.5) & circle
    dark_all = cand.copy()
    for rad in radiance:
        lum = cv2.resize(rad, (ws, hs), interpolation=cv2.INTER_AREA) @ LUMA
        ok = circle & (lum > 0)
        if not ok.any():
            return FrameMask(np.zeros((h, w), bool), 0, 0.0, 0.0, 0)
        floor = 1e-6 * float(np.median(lum[ok]))
        ell = np.log2(np.maximum(lum, floor)).astype(np.float32)
        med = float(np.median(ell[ok & (r < 0.9)]))
        e_pi = float((lum * sa * cos_axis)[ok].sum() / np.pi)      # E/π on a surface facing forward
        dark = ell < min(med - DARK_STOPS, np.log2(DARK_ALBEDO * e_pi))
        flat = flatness(ell, ok) < FLAT_STOPS_PER_PX
        cand &= dark & flat & ok
        dark_all &= dark & ok
    cand = cv2.morphologyEx(cand.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(cand, connectivity=8)
    # "touches the rim": within 7 working pixels of it (the circle's edge is itself textured:
    # JPEG rings against the black surround, so the last pixels are rarely candidates)
    rim = circle & (r >= 1.0 - 7.0 / small.radius)
    min_area = max(16, int(1e-4 * circle.sum()))
    keep = np.zeros(n, bool)
    touching = np.unique(lab[rim & (lab > 0)])
    keep[touching] = True
    keep &= stats[:, cv2.CC_STAT_AREA] >= min_area
    keep[0] = False
    seeds = keep[lab]
    # hysteresis: grow the seeds through pixels dark in every shot (texture not required), which
    # recovers the frame's thin parts, where the texture window also sees the scene
    n2, lab2 = cv2.connectedComponents((dark_all | seeds).astype(np.uint8), connectivity=8)
    grown = np.zeros(n2, bool)
    grown[np.unique(lab2[seeds])] = True
    grown[0] = False
    m = grown[lab2].astype(np.uint8)
    grow = 2 + int(np.ceil(max_shift * scale))
    m = cv2.dilate(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1)))
    full = cv2.resize(m * 255, (w, h), interpolation=cv2.INTER_LINEAR) > 0
    # one more full-resolution pixel for the upsampling's edge
    full = cv2.dilate(full.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    full &= lens.circle_mask()
    px = int(full.sum())
    circle_px = int(lens.circle_mask().sum())
    return FrameMask(full, px, px / max(circle_px, 1), float(lens.pixel_solid_angle()[full].sum()), int(keep.sum()))
