"""Automatic removal of the fisheye lens's frame (cyber-worlds §IV and VII: the paper removes
the reflection of the black frame by hand and asks for an automatic method).

What the frame is: the housing of a clip-on fisheye (its barrel, the clip's arm, the phone's
edge beyond 180°) seen at the edge of the image circle. These properties hold for every such
lens, whatever the scene, and together they separate it from the scene:

1. **Fixed to the sensor.** It sits at the same pixels in every bracket and in every shot (the
   lens turns with the camera), while the scene behind it changes from shot to shot. So a
   pixel is a candidate only if it is frame-like in *all* shots at once (and it is detected on
   the merged HDR, the consensus of the brackets).
2. **Attached to the rim.** It intrudes from outside the field: every region must come within a
   few pixels of the image circle's rim and lie in the circle's outer half.
3. **Dark.** Black plastic or metal facing the room: a reflectance of a few % of the
   irradiance E on a surface facing forward, which the shot itself measures (Σ L cosθ dω). A
   candidate reads below ``DARK_ALBEDO`` · E/π (margin for clipped lights, which make E low)
   *and* ``DARK_STOPS`` below the shot's median (so ordinary dark scenery is not taken).
4. **Low texture.** Its log radiance is smooth: the 5×5 median of the gradient magnitude of
   log₂ luminance is below ``FLAT_STOPS_PER_PX`` in every shot. The median ignores an edge
   crossing the window, so a thin band still has flat pixels.
5. **Occluding.** Where shots overlap, the frame in one shot hides a direction another shot
   sees: pixels ``OCCLUDED_STOPS`` darker than the other shot's view of the same direction (and
   flat) are candidates even when not dark by the scene's standards (a dim studio lit by lamps,
   where the housing is brighter than the median but hides a lamp).
6. **Not seen through.** A region whose overlap pixels read what the other shot sees of the
   same directions (within ``AGREE_STOPS``, for ``SEEN_FRACTION`` of them) is scene both shots
   see alike (a dark ceiling at the top of both), not a housing hiding it; and a housing that
   read like the scene it hides would not change the light. Exception: a region along
   ``ENCIRCLE`` of the rim (a centred housing is at the same place in both shots, so their
   agreement proves nothing).

7. **Bright when polished** (a second pass). A polished barrel edge glints with the room's
   light, so darkness cannot find it; fixed to the sensor, it reads ``GLINT_STOPS`` brighter
   than another shot's view of the same direction in some shot and not that much darker in
   any, within ``RIM_BAND`` of the radius from the rim. The other shot's view must be neither
   dark nor inside a housing the first pass found: a black housing makes the scene facing it,
   in the other shot, read brighter than it (in both shots, when the housing is at the same
   pixels of both).
8. **Occluding in every shot.** A pixel ``OCCLUDED_STOPS`` darker than another shot's view at
   the same sensor pixel of *every* shot is fixed to the sensor, which the texture test stands
   for elsewhere: it seeds even where the housing's soft edge (a vignetting ramp, a gradient of
   several stops over a few pixels) is not flat; the hysteresis also grows through pixels
   ``DIMMED_STOPS`` darker than the other view in every shot (the ramp's lighter part).

9. **One factor between the shots** (a third pass). Fixed to the sensor and lit differently in
   each shot, a housing reads the same in every shot up to one factor: over a rim-attached region
   flat in every shot, the difference of two shots' log₂ luminance at the same pixels is itself
   flat and spreads at most ``RATIO_SPREAD`` stops (10th-90th percentile), whatever the
   housing's brightness against the scene (a dim studio's black clip arms read brighter than its
   median and hide no lamp). The scene behind the rim differs from shot to shot; where it does
   not (the same directions at the rim's top and bottom in both shots), the overlap test vetoes
   the region as seen alike.

10. **The same factor along the rim** (last). A found region attached to the rim extends through
   the pixels of its band along the rim (as deep as its own pixels that read its factor) where
   every two shots differ by the region's own factor within ``RATIO_EXTEND`` stops, connected to
   it: the stretches of a thin polished rim whose glint matched the scene beside it, the faint
   part of a vignette. A region whose factor is near 1 does not extend (the scene both shots see
   alike reads 1 too).

Detection runs at about 512 px across the circle. Rim-attached components of the candidates
are seeds; they grow (hysteresis, at most ``GROW_PX`` working pixels) through pixels that are
dark in every shot or occluding, texture or not and not seen alike by another shot, which
recovers the frame's thin parts and edges. The mask then grows by ``EDGE_PX`` working pixels
(the anti-aliased or soft edge), by the largest alignment shift (aligned brackets see the frame displaced
by it) and by one photo pixel.

Where another shot sees the same directions, stitching fills the frame from it (the frame's
pixels get zero weight and a feathered edge); what no shot sees is inpainted (stitch.py).
How the constants were chosen and what they achieve: bench/frame_detector.py chooses them on
its TUNING HDRIs only and reports on its HELD_OUT HDRIs, which no choice saw (the figures:
docs/benchmarks/history/2026-12-01-frame-detector.md, 2026-12-02-frame-detector-rims.md,
2026-12-06-frame-detector-sweep.md, which chose DARK_STOPS, OCCLUDED_STOPS and GROW_PX again
and RATIO_SPREAD, and 2026-12-07-frame-detector-ratio.md, which chose RATIO_EXTEND).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fisheye import Lens

DARK_STOPS = 1.25      # below the shot's median log₂ luminance
DARK_ALBEDO = 0.25     # × E/π facing forward: black housings reflect < 10%; margin for clipped lights
OCCLUDED_STOPS = 1.25  # darker than another shot's view of the same direction
FLAT_STOPS_PER_PX = 0.1   # 5×5 median of |∇ log₂ luminance| at the working resolution
AGREE_STOPS = 0.75     # a region's pixel agrees with another shot's view of its direction
SEEN_FRACTION = 0.8    # a region whose overlap pixels agree this often is scene, seen by both shots
ENCIRCLE = 0.9         # ... unless it runs along this fraction of the rim (a centred housing,
                       # which both shots see at the same place: their agreement proves nothing)
GLINT_STOPS = 1.0      # a polished rim reads this much brighter than another shot's view of its direction
RIM_BAND = 0.05        # ... within this fraction of the radius from the rim (a barrel edge is thin)
DIMMED_STOPS = 1.0     # hysteresis: a housing's soft edge reads this much darker than another shot's view
GROW_PX = 8            # hysteresis: how far (working pixels) a region grows from its seeds
RATIO_SPREAD = 0.1     # a fixed-ratio region's shots differ by one factor within this many stops (0: off)
RATIO_EXTEND = 0.15    # a rim-attached region extends along the rim through pixels whose shots differ
                       # by the region's own factor within this many stops (0: off)
BAND_PCT = 95          # ... no deeper from the rim than this percentile of its own pixels that read its factor
EDGE_PX = 2            # the found regions grow by this many working pixels (the housing's soft edge)
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


def _cross_views(small: Lens, ells, oks, yaws, extra=None) -> list[tuple]:
    """Per shot a, what another shot sees of the same directions (the overlap of the shots):
    a list of (lb (h, w) float32 the other shot's log₂ luminance of the direction a's pixel sees,
    valid (h, w) bool where some other shot sees it inside its circle, away from its own rim,
    outer (h, w) bool where a's pixel is nearer a's rim than the other shot's view is to its
    own, xb (h, w) float32 the per-shot image ``extra[b]`` read at that view, or None without
    ``extra``). With more than two shots the view nearest its own centre is kept."""
    import cv2

    from .fisheye import yaw_matrix

    hs, ws = ells[0].shape
    ys, xs = np.mgrid[0:hs, 0:ws].astype(np.float64) + 0.5
    cam = small.pixel_to_camera(xs, ys)
    th_a = small.theta_of_radius(small.pixel_radius())
    edge = small.theta_max - 3.0 / small.focal          # stay off the other shot's own rim
    out = []
    for a in range(len(ells)):
        world = cam @ yaw_matrix(yaws[a]).T
        lb_best = np.full((hs, ws), -1e9, np.float32)
        xb_best = None if extra is None else np.zeros((hs, ws), np.float32)
        th_best = np.full((hs, ws), np.inf)
        for b in range(len(ells)):
            if b == a:
                continue
            px, py, th = small.world_to_pixel(world, yaws[b])
            mx, my = (px - 0.5).astype(np.float32), (py - 0.5).astype(np.float32)
            lb = cv2.remap(ells[b], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1e9)
            okb = cv2.remap(oks[b].astype(np.float32), mx, my, cv2.INTER_LINEAR, borderValue=0) > 0.99
            better = (th <= edge) & okb & (th < th_best)
            lb_best = np.where(better, lb, lb_best)
            if extra is not None:
                xb = cv2.remap(extra[b], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
                xb_best = np.where(better, xb, xb_best)
            th_best = np.where(better, th, th_best)
        valid = np.isfinite(th_best) & oks[a]
        out.append((lb_best, valid, valid & (th_a >= th_best), xb_best))
    return out


def _regions(cand, allowed, seen, agree, rim, small: Lens, min_area: int):
    """The frame's regions at the working resolution: rim-attached components of ``cand``
    ((h, w) bool candidates) of at least ``min_area`` pixels seed a hysteresis through
    ``allowed`` (at most GROW_PX pixels), and regions another shot sees alike (``agree`` on
    ``SEEN_FRACTION`` of their ``seen`` overlap pixels) are dropped unless they run along
    ``ENCIRCLE`` of the rim. Returns (keep (n,) bool per label, labels (h, w) int32)."""
    import cv2

    hs, ws = cand.shape
    cand = cv2.morphologyEx(cand.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(cand, connectivity=8)
    # "touches the rim": within 7 working pixels of it (the circle's edge is itself textured:
    # JPEG rings against the black surround, so the last pixels are rarely candidates)
    keep = np.zeros(n, bool)
    keep[np.unique(lab[rim & (lab > 0)])] = True
    keep &= stats[:, cv2.CC_STAT_AREA] >= min_area
    keep[0] = False
    seeds = keep[lab]
    # hysteresis: grow the seeds through pixels dark in every shot (texture not required), which
    # recovers the frame's thin parts, where the texture window also sees the scene
    # at most GROW_PX working pixels from a seed, and not into pixels another shot sees alike
    allowed = allowed | seeds
    m = seeds.astype(np.uint8)
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    for _ in range(GROW_PX):
        m = cv2.dilate(m, cross) & allowed
    n2, lab2 = cv2.connectedComponents(m, connectivity=8)
    grown = np.ones(n2, bool)
    grown[0] = False
    # seen through: a region whose overlap pixels read what the other shot sees in the same
    # directions is scene (a dark ceiling at the top of both shots), not a housing hiding it; a
    # housing that reads the same as the scene it hides would not change the light either
    n_seen = np.bincount(lab2[seen], minlength=n2)
    n_agree = np.bincount(lab2[agree], minlength=n2)
    yy, xx = np.mgrid[0:hs, 0:ws].astype(np.float64) + 0.5
    phi = np.arctan2(small.centre[1] - yy, xx - small.centre[0])
    bins = ((phi + np.pi) / (2 * np.pi) * 72).astype(int) % 72
    along = np.zeros((n2, 72), bool)
    along[lab2[rim], bins[rim]] = True
    encircles = along.mean(axis=1) >= ENCIRCLE
    through = (n_seen >= min_area) & (n_agree >= SEEN_FRACTION * np.maximum(n_seen, 1)) & ~encircles
    grown &= ~through
    return grown, lab2


def _fixed_ratio(ells, oks, flats, where, rim, min_area: int) -> np.ndarray:
    """(h, w) bool: rim-attached regions, flat in every shot, where every two shots differ at the
    same sensor pixels by one factor (the spread of the difference of their log₂ luminance over
    the region within RATIO_SPREAD stops): a housing fixed to the sensor, lit differently in
    each shot, whatever its brightness against the scene."""
    import cv2

    m = where.copy()
    for f, ok in zip(flats, oks):
        m &= f & ok
    diffs = []
    for a in range(len(ells)):
        for b in range(a + 1, len(ells)):
            d = ells[a] - ells[b]
            m &= flatness(d.astype(np.float32), oks[a] & oks[b]) < FLAT_STOPS_PER_PX
            diffs.append(d)
    m = cv2.morphologyEx(m.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    out = np.zeros(m.shape, bool)
    touch = np.zeros(n, bool)
    touch[np.unique(lab[rim & (lab > 0)])] = True
    for k in np.nonzero(touch & (stats[:, cv2.CC_STAT_AREA] >= min_area))[0]:
        if k == 0:
            continue
        sel = lab == k
        if all(np.percentile(d[sel], 90) - np.percentile(d[sel], 10) <= RATIO_SPREAD for d in diffs):
            out |= sel
    return out


def _ratio_extend(ells, oks, found: np.ndarray, r: np.ndarray, rim: np.ndarray) -> np.ndarray:
    """(h, w) bool: ``found`` with each of its rim-attached regions extended along the rim. A
    housing is fixed to the sensor and each shot lights it with one factor, so every two shots
    differ over it by one factor c (the region's median difference of log₂ luminance); the
    pixels of the band the region occupies (from the rim to the BAND_PCT percentile depth of its
    own pixels that read c, plus two pixels) where every pair of shots differs by c within
    RATIO_EXTEND stops, and connected to the region there, are the same housing where the other
    cues missed it (a thin polished rim whose glint matches the scene beside it, the faint part of
    a vignette). Skipped for a region whose c is within 2·RATIO_EXTEND stops of 0 (a factor near
    1): there the scene both shots see alike (the rim's top and bottom, the same directions in
    both) reads the same. ells, oks : per shot (h, w) log₂ luminance and validity; found, rim
    (h, w) bool; r (h, w) radius over the circle's radius."""
    import cv2

    pairs = [(a, b) for a in range(len(ells)) for b in range(a + 1, len(ells))]
    diffs = [ells[a] - ells[b] for a, b in pairs]
    both = [oks[a] & oks[b] for a, b in pairs]
    _, lab = cv2.connectedComponents(found.astype(np.uint8), connectivity=8)
    out = found.copy()
    depth = 1.0 - r
    px = float(np.max(depth[rim])) / 7.0          # one working pixel, as a fraction of the radius
    for k in np.unique(lab[rim & found]):
        if k == 0:
            continue
        sel = lab == k
        match = (r <= 1.0).copy()
        for d, ok in zip(diffs, both):
            c = float(np.median(d[sel & ok])) if (sel & ok).any() else 0.0
            if abs(c) < 2.0 * RATIO_EXTEND:
                match[:] = False
                break
            match &= ok & (np.abs(d - c) <= RATIO_EXTEND)
        # the band: as deep as the region's own pixels that read its factor (the hysteresis may
        # have grown it into the scene beside the housing, which does not)
        own = sel & match
        if not own.any():
            continue
        cand = match & (depth <= np.percentile(depth[own], BAND_PCT) + 2.0 * px)
        _, lab_c = cv2.connectedComponents((cand | sel).astype(np.uint8), connectivity=8)
        out |= np.isin(lab_c, np.unique(lab_c[sel])) & (lab_c > 0)
    return out


def detect_frame(radiance: list[np.ndarray], lens: Lens, max_shift: int = 0,
                 yaws: list[float] | None = None) -> FrameMask:
    """Find the lens frame in a capture's merged shots.

    radiance : per shot (H, W, 3) float32 linear radiance in the photos' pixel grid (0 outside
        the image circle).
    max_shift : the largest bracket alignment shift, pixels.
    yaws : the shots' yaw angles (degrees), for the overlap test; None skips it.
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
    ells, oks, flats, thrs = [], [], [], []
    for rad in radiance:
        lum = cv2.resize(rad, (ws, hs), interpolation=cv2.INTER_AREA) @ LUMA
        ok = circle & (lum > 0)
        if not ok.any():
            return FrameMask(np.zeros((h, w), bool), 0, 0.0, 0.0, 0)
        floor = 1e-6 * float(np.median(lum[ok]))
        ell = np.log2(np.maximum(lum, floor)).astype(np.float32)
        med = float(np.median(ell[ok & (r < 0.9)]))
        e_pi = float((lum * sa * cos_axis)[ok].sum() / np.pi)      # E/π on a surface facing forward
        thr = min(med - DARK_STOPS, np.log2(DARK_ALBEDO * e_pi))
        dark = ell < thr
        thrs.append(thr)
        flat = flatness(ell, ok) < FLAT_STOPS_PER_PX
        cand &= dark & flat & ok
        dark_all &= dark & ok
        ells.append(ell); oks.append(ok); flats.append(flat)
    occl = np.zeros_like(cand)
    agree = np.ones_like(cand)
    seen = np.zeros_like(cand)
    dimmed = np.ones_like(cand)
    hidden_all = np.ones_like(cand)
    multi = yaws is not None and len(radiance) > 1
    views = _cross_views(small, ells, oks, yaws) if multi else []
    for ell, flat, (lb, valid, outer, _) in zip(ells, flats, views):
        occl |= flat & valid & (ell < lb - OCCLUDED_STOPS)
        agree &= ~outer | (np.abs(ell - lb) < AGREE_STOPS)
        seen |= outer
        dimmed &= ~valid | (ell < lb - DIMMED_STOPS)
        hidden_all &= ~valid | (ell < lb - OCCLUDED_STOPS)
    # the soft edge of a housing (a vignetting ramp, anti-aliasing) dims the scene without
    # hiding it: in every shot darker than another shot's view, a grow-only criterion
    any_valid = np.stack([v[1] for v in views]).any(axis=0) if views else np.zeros_like(cand)
    dimmed &= any_valid
    # occluding at the same pixels of every shot is being fixed to the sensor, which the
    # texture test stands for elsewhere: a seed even where the housing's soft edge is textured
    occl |= hidden_all & any_valid
    agree &= seen
    rim = circle & (r >= 1.0 - 7.0 / small.radius)
    min_area = max(16, int(1e-4 * circle.sum()))
    grown, lab2 = _regions(cand | occl, (dark_all | occl | dimmed) & ~agree, seen, agree, rim, small, min_area)
    if multi:
        # second pass, the bright polished rim: fixed to the sensor, it reads brighter than
        # another shot's view of its direction in some shot and darker in none. The other
        # shot's view must be neither dark nor a housing found by the first pass: a black
        # housing makes the scene facing it, in the other shot, read brighter than it (and a
        # housing at the same pixels of both shots does so in both)
        dark_mask = cv2.dilate(grown[lab2].astype(np.uint8), np.ones((5, 5), np.uint8)).astype(np.float32)
        glint = circle & (r >= 1.0 - RIM_BAND)
        glint_any = np.zeros_like(cand)
        for a, (ell, (lb, valid, _, hidden)) in enumerate(
                zip(ells, _cross_views(small, ells, oks, yaws, [dark_mask] * len(ells)))):
            lit = max(t for b, t in enumerate(thrs) if b != a)
            glint_any |= valid & (ell > lb + GLINT_STOPS) & (lb > lit) & (hidden < 0.01)
            glint &= ~valid | (ell > lb - GLINT_STOPS)
        glint &= glint_any
        if glint.any():
            grown, lab2 = _regions(cand | occl | glint, ((dark_all | occl | dimmed | glint) & ~agree), seen, agree, rim,
                                   small, min_area)
        if RATIO_SPREAD > 0:
            fixed = _fixed_ratio(ells, oks, flats, circle & (r >= 0.5) & ~grown[lab2], rim, min_area)
            if fixed.any():
                glint_part = glint if glint.any() else np.zeros_like(cand)
                grown, lab2 = _regions(cand | occl | glint_part | fixed,
                                       ((dark_all | occl | dimmed | glint_part | fixed) & ~agree), seen, agree, rim,
                                       small, min_area)
    keep_regions = int(grown.sum())
    m = grown[lab2]
    if multi and RATIO_EXTEND > 0 and m.any():
        m = _ratio_extend(ells, oks, m, r, rim)
    m = m.astype(np.uint8)
    grow = EDGE_PX + int(np.ceil(max_shift * scale))
    m = cv2.dilate(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1)))
    full = cv2.resize(m * 255, (w, h), interpolation=cv2.INTER_LINEAR) > 0
    # one more full-resolution pixel for the upsampling's edge
    full = cv2.dilate(full.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    full &= lens.circle_mask()
    px = int(full.sum())
    circle_px = int(lens.circle_mask().sum())
    return FrameMask(full, px, px / max(circle_px, 1), float(lens.pixel_solid_angle()[full].sum()), keep_regions)
