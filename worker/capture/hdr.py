"""Bracketed 8-bit photos → linear HDR radiance per shot (cyber-worlds §IV: "HDR images from
the two photographs ... auto exposure bracketing").

1. **Alignment** (hand-held brackets): median threshold bitmaps (Ward 2003), with two changes
   that OpenCV's AlignMTB cannot take: bitmaps are compared inside the image circle only (the
   black surround is fixed to the sensor and pins the shift to zero), and each pair of brackets
   is thresholded at a common quantile of its common radiance range (``_common_range``,
   ``mtb_shift``): with the 2-3 EV steps that high-range scenes need, the short bracket is
   mostly black, its median splits noise, and OpenCV's MTB returned shifts at its search limit
   (measured on synthetic captures). Brackets are chained outwards from the middle exposure
   (neighbouring exposures look most alike); a pair with no common range keeps its neighbour's
   shift.
2. **Response** (Debevec & Malik 1997): the system of OpenCV's ``CalibrateDebevec`` (same
   weights, smoothness and anchor), solved by sparse normal equations (``debevec_solve``; 100×
   faster than OpenCV's dense SVD, checked against it), and fed with samples we choose instead
   of OpenCV's grid over the whole frame: pixels inside the
   image circle, valid in every aligned bracket, in smooth areas (so residual misalignment
   does not corrupt them), stratified over the brightness range of the whole bracket (so every
   pixel value of every exposure is constrained). OpenCV's grid would put many samples on the
   black surround outside the circle. The smoothness weight λ = 100 (OpenCV's default is 10):
   brackets evenly spaced by a ratio R determine the response only up to a factor periodic in
   log exposure with period log R (Grossberg & Nayar 2003, "What can be known about the
   radiometric response from images?"); with steps of 2-3 EV that ripple spans a hundred pixel
   levels, costs the smoothness term little, and only a stronger prior removes it. On synthetic
   captures of five HDRIs (tests/capture) the curve's error fell from 0.03-0.24 stops (λ = 10)
   to 0.01-0.08 (λ = 100), with ~250-350 samples × 5 brackets.
   The curve is made monotone and normalised per channel to
   the sRGB decoding at mid-grey (f⁻¹(128) = 0.2158), so a merged map at exposure 0 looks like
   the middle bracket, and grey stays grey.
3. **Merge** (``merge``; C kernel glk_hdr_merge, NumPy reference ``merge_numpy``). Not
   OpenCV's ``MergeDebevec``: it has no notion of invalid pixels (alignment borders, the
   outside of the circle), and its weights never reach zero (at least 1/128), so a pixel
   clipped in every bracket becomes the average of all of them. Ours takes, in the linear
   domain, the inverse-variance weighted mean of the estimates v_k = f⁻¹(z_k)/e_k: with z
   quantised (±½ level) an estimate's standard deviation is (df⁻¹/dz)/e_k, so
   w_k(z) = hat(z) · (e_k / f⁻¹'(z))², the hat zeroing z ≤ 3 (JPEG black) and z ≥ 250 (clipping
   and JPEG ringing at saturation). Pixels clipped in every bracket take the shortest
   exposure's value (a lower bound, counted as clipped). On the same photos its log error
   matches MergeDebevec's and its energy is closer (tests/capture/test_hdr.py).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .fisheye import Lens
from .manifest import Capture, CaptureError, Photo

Z_LO, Z_HI = 3, 250          # hat support: below is JPEG black, above clipping
CLIP_Z = 245                 # the shortest exposure at or above this (any channel): clipped light
MID_GREY = 0.21586050011389926   # sRGB decode of 128/255: the response's anchor

# --- reading ----------------------------------------------------------------------------------


def read_bracket(photos: list[Photo], width: int, height: int) -> np.ndarray:
    """(K, H, W, 3) uint8 RGB of one shot's photos, upright (EXIF orientation applied)."""
    from PIL import Image, ImageOps

    out = np.empty((len(photos), height, width, 3), np.uint8)
    for k, p in enumerate(photos):
        try:
            with Image.open(p.path) as im:
                if im.getexif().get(0x0112, 1) != 1:           # EXIF Orientation: read upright
                    im = ImageOps.exif_transpose(im)
                a = np.asarray(im.convert("RGB") if im.mode != "RGB" else im)
        except OSError as e:
            raise CaptureError(f"{p.field}: {p.path.name} cannot be decoded ({e})") from None
        if a.shape[:2] != (height, width):
            raise CaptureError(f"{p.field}: {p.path.name} decodes to {a.shape[1]}×{a.shape[0]}, expected {width}×{height}")
        out[k] = a
    return out


# --- alignment --------------------------------------------------------------------------------


def _grey(img: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)


def _srgb_decode(z: np.ndarray) -> np.ndarray:
    c = z / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _common_range(za: np.ndarray, ea: float, zb: np.ndarray, eb: float):
    """Two brackets' grey images re-expressed on their common radiance range, for MTB.

    Median threshold bitmaps assume the median splits the same scene pixels in both images;
    with 2-3 EV steps the short bracket is mostly black (ties at 0-2) and the long one partly
    clipped, and OpenCV's MTB then returned shifts at its search limit (measured on synthetic
    captures). So both images are mapped to rough radiance (sRGB decoding / exposure; only
    monotonicity matters), clipped to the range both resolve — above the shorter one's black,
    below the longer one's clipping — and requantised on a log scale, through a 256-entry table
    each. Pixels outside the range tie at its ends in *both* images, so thresholds at a common
    quantile mark the same scene pixels. None when the ranges overlap by less than one stop."""
    import cv2

    lo = max(_srgb_decode(Z_LO + 5.0) / min(ea, eb), 1e-30)
    hi = _srgb_decode(Z_HI - 5.0) / max(ea, eb)
    if hi < 2.0 * lo:
        return None
    z = np.arange(256, dtype=np.float64)
    out = []
    for img, e in ((za, ea), (zb, eb)):
        lg = np.log(np.clip(_srgb_decode(z) / e, lo, hi))
        lut = np.rint((lg - np.log(lo)) * (255.0 / np.log(hi / lo))).astype(np.uint8)
        out.append(cv2.LUT(img, lut))
    return out


def _quantile_u8(img: np.ndarray, mask: np.ndarray, q: float) -> int:
    """The q-quantile of a uint8 image's values under mask (histogram, O(N))."""
    import cv2

    hist = cv2.calcHist([img], [0], mask.astype(np.uint8), [256], [0, 256]).ravel()
    c = np.cumsum(hist)
    return int(np.searchsorted(c, q * c[-1]))


def mtb_shift(a: np.ndarray, b: np.ndarray, bits: int, exclude: int = 4, mask: np.ndarray | None = None) -> tuple[int, int]:
    """Ward's median threshold bitmap alignment (J. graphics tools 2003), thresholding both images
    at one common quantile instead of the median: the quantile halfway through the pixels that
    neither image ties at its range ends (see _common_range). Returns the integer (dx, dy) that
    moves ``b`` onto ``a``, searched coarse to fine over ``bits`` pyramid levels (|shift| <
    2^bits). OpenCV's AlignMTB has the median and the whole frame fixed inside; the rest is Ward's.

    a, b : (H, W) uint8; mask : (H, W) bool pixels to compare (e.g. the image circle), or None.
    """
    import cv2

    m = np.ones(a.shape, bool) if mask is None else mask
    n = max(int(m.sum()), 1)
    lo = max(np.count_nonzero((a == 0) & m), np.count_nonzero((b == 0) & m)) / n
    hi = max(np.count_nonzero((a == 255) & m), np.count_nonzero((b == 255) & m)) / n
    if lo + hi > 1.0 - max(1e-3, 64.0 / n):
        return 0, 0
    q = 0.5 * (lo + 1.0 - hi)
    pyr = [(a, b, m)]
    for _ in range(bits - 1):
        pa, pb, pm = pyr[-1]
        if min(pa.shape) < 16:
            break
        half = (pa.shape[1] // 2, pa.shape[0] // 2)
        pyr.append((cv2.resize(pa, half, interpolation=cv2.INTER_AREA), cv2.resize(pb, half, interpolation=cv2.INTER_AREA),
                    cv2.resize(pm.astype(np.uint8), half, interpolation=cv2.INTER_NEAREST) > 0))
    dx = dy = 0
    for pa, pb, pm in reversed(pyr):
        dx, dy = 2 * dx, 2 * dy
        ta_t, tb_t = _quantile_u8(pa, pm, q), _quantile_u8(pb, pm, q)
        ta, tb = pa > ta_t, pb > tb_t
        ea = (np.abs(pa.astype(np.int16) - ta_t) > exclude) & pm      # Ward's exclusion bitmaps
        eb = (np.abs(pb.astype(np.int16) - tb_t) > exclude) & pm
        h, w = pa.shape
        best = None
        for sy in (-1, 0, 1):
            for sx in (-1, 0, 1):
                x, y = dx + sx, dy + sy
                # b shifted by (x, y): b'[i, j] = b[i - y, j - x], compared on the overlap
                ya, yb = slice(max(0, y), h + min(0, y)), slice(max(0, -y), h - max(0, y))
                xa, xb = slice(max(0, x), w + min(0, x)), slice(max(0, -x), w - max(0, x))
                err = np.count_nonzero((ta[ya, xa] ^ tb[yb, xb]) & ea[ya, xa] & eb[yb, xb])
                if best is None or err < best[0]:
                    best = (err, x, y)
        dx, dy = best[1], best[2]
    return dx, dy


def align_bracket(stack: np.ndarray, lens: Lens, exposures) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Align a shot's brackets to its middle exposure by median threshold bitmaps, in place.

    stack : (K, H, W, 3) uint8, brackets in order of increasing exposure; exposures (K,).
    Returns (valid (K, H, W) bool: pixels not shifted in from outside the frame, shifts (dx, dy)
    applied to each bracket, pixels)."""
    import cv2

    k_n, h, w, _ = stack.shape
    ref = k_n // 2
    side = 2 * int(lens.radius)                                # the image circle's bounding square
    cx, cy = int(lens.centre[0]), int(lens.centre[1])
    crop = (slice(cy - side // 2, cy + side // 2), slice(cx - side // 2, cx + side // 2))
    bits = int(np.clip(np.floor(np.log2(max(side, 64) / 48.0)), 1, 6))   # finds shifts up to ~2^bits px
    greys = [_grey(stack[k][crop]) for k in range(k_n)]
    # compare inside the circle only: the black surround is fixed to the sensor and would pin the
    # shift to zero; margin for the largest shift searched
    inside = (lens.pixel_radius()[crop] <= lens.radius - 2 ** bits)
    shifts = [(0, 0)] * k_n
    for order in (range(ref - 1, -1, -1), range(ref + 1, k_n)):
        for k in order:
            nb = k + 1 if k < ref else k - 1                     # neighbour towards the reference
            pair = _common_range(greys[nb], exposures[nb], greys[k], exposures[k])
            dx, dy = mtb_shift(*pair, bits, mask=inside) if pair is not None else (0, 0)
            shifts[k] = (int(dx) + shifts[nb][0], int(dy) + shifts[nb][1])   # moves k onto nb
    valid = np.ones((k_n, h, w), bool)
    for k, (dx, dy) in enumerate(shifts):
        if dx or dy:
            m = np.float32([[1, 0, dx], [0, 1, dy]])
            stack[k] = cv2.warpAffine(stack[k], m, (w, h), flags=cv2.INTER_NEAREST, borderValue=(0, 0, 0))
            valid[k] = cv2.warpAffine(np.ones((h, w), np.uint8), m, (w, h), flags=cv2.INTER_NEAREST) > 0
    return valid, shifts


# --- response ---------------------------------------------------------------------------------


@dataclass
class Response:
    """The camera's inverse response f⁻¹: pixel value → linear exposure (relative), per channel.

    lin : (256, 3) float64, monotone, lin[128] = MID_GREY in every channel.
    samples : pixels used; lam : Debevec's smoothness weight; monotone_fixes : values raised to
    keep the curve monotone (a sign of too few samples at that level)."""
    lin: np.ndarray
    samples: int
    lam: float
    monotone_fixes: int = 0
    notes: list[str] = field(default_factory=list)

    def slope(self) -> np.ndarray:
        """(256, 3) df⁻¹/dz, smoothed over ±2 levels and floored above zero."""
        g = np.gradient(self.lin, axis=0)
        k = np.ones(5) / 5.0
        g = np.stack([np.convolve(np.pad(g[:, c], 2, mode="edge"), k, "valid") for c in range(3)], axis=1)
        return np.maximum(g, 1e-4 * g.max(axis=0))

    def summary(self) -> dict:
        """JSON-able: method, samples, gamma per channel (least-squares exponent of
        f⁻¹(z) ∝ (z/255)^γ over z in [16, 240]) and the curve at a few levels."""
        z = np.arange(16, 241)
        x = np.log(z / 255.0)
        gam = [float(np.polyfit(x, np.log(np.maximum(self.lin[z, c], 1e-12)), 1)[0]) for c in range(3)]
        at = [8, 32, 64, 128, 192, 224, 248]
        return {"method": "Debevec-Malik (OpenCV's system, sparse solve) on selected samples", "samples": self.samples,
                "lambda": self.lam, "gamma_rgb": [round(g, 3) for g in gam],
                "curve": {"z": at, "linear_rgb": [[round(float(self.lin[v, c]), 5) for c in range(3)] for v in at]},
                "monotone_fixes": self.monotone_fixes}


def select_samples(stack: np.ndarray, valid: np.ndarray, inner: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Pick up to n sample pixels of one shot for response recovery.

    stack : (K, H, W, 3) uint8 aligned brackets; valid : (K, H, W) bool; inner : (H, W) bool
    allowed area (inside the image circle, away from its rim).
    Returns (n', K, 3) uint8 pixel values. Pixels are taken on a grid of at most ~512² (no
    averaging: averaging mixes levels through a non-linear curve), kept where every bracket is
    valid, the local gradient of the middle bracket is in the smoothest half, and the values
    never fall by more than JPEG noise as the exposure grows (a pixel that does was misaligned
    or moved), then stratified by Σ_k z_k (a monotone proxy of radiance)."""
    import cv2

    k_n, h, w, _ = stack.shape
    step = max(1, int(np.ceil(max(h, w) / 512)))
    sub = stack[:, ::step, ::step]
    ok = inner[::step, ::step] & valid[:, ::step, ::step].all(axis=0)
    g = _grey(np.ascontiguousarray(sub[k_n // 2])).astype(np.float32)
    grad = np.hypot(cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3))
    grad = cv2.dilate(grad, np.ones((3, 3), np.uint8))       # a sample's neighbours must be smooth too
    if ok.sum() < 16:
        return np.empty((0, k_n, 3), np.uint8)
    ok &= grad <= np.median(grad[ok])
    zs = sub.astype(np.int16)
    ok &= ((zs[1:] >= zs[:-1] - 3) | (zs[:-1] >= Z_HI)).all(axis=(0, 3))   # monotone in exposure
    if ok.sum() < 16:
        return np.empty((0, k_n, 3), np.uint8)
    ys, xs = np.nonzero(ok)
    key = sub[:, ys, xs].astype(np.int32).sum(axis=(0, 2))   # Σ over brackets and channels
    # half the budget evenly over the key's range (rare highlights and shadows get samples), the
    # rest over its quantiles (where most pixels are)
    edges = np.linspace(key.min(), key.max() + 1, n // 2 + 1)
    which = np.digitize(key, edges)
    pick = [rng.choice(np.nonzero(which == b)[0]) for b in np.unique(which)]
    order = np.argsort(key, kind="stable")
    rest = max(0, n - len(pick))
    if rest:
        pick += [b[rng.integers(len(b))] for b in np.array_split(order, min(rest, len(order))) if len(b)]
    pick = np.unique(np.array(pick))
    return np.ascontiguousarray(sub[:, ys[pick], xs[pick]].transpose(1, 0, 2))


def _triangle() -> np.ndarray:
    """OpenCV's Debevec weights (photo/src/hdr_common.cpp triangleWeights): z+1 below 128, 256−z
    from 128 — never zero."""
    z = np.arange(256, dtype=np.float64)
    return np.where(z < 128, z + 1.0, 256.0 - z)


def debevec_solve(z: np.ndarray, log_t: np.ndarray, lam: float) -> np.ndarray:
    """Debevec & Malik 1997 (eq. 3 with their weighting), the system OpenCV's CalibrateDebevec
    builds, solved through its sparse normal equations instead of OpenCV's dense SVD (~100×
    faster at 250 samples × 5 brackets; tests/capture/test_hdr.py compares the two).

    z : (N, P) int pixel values of N samples in P brackets; log_t : (P,) log exposures.
    Returns g (256,) float64, log inverse response with g(128) = 0."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spl

    n, p = z.shape
    w = _triangle()
    wz = w[z].ravel()
    rows_d = np.arange(n * p)
    r = np.concatenate([rows_d, rows_d])
    c = np.concatenate([z.ravel(), 256 + np.repeat(np.arange(n), p)])
    v = np.concatenate([wz, -wz])
    b = np.concatenate([wz * np.tile(log_t, n), [0.0], np.zeros(254)])
    k = np.arange(1, 255)
    base = n * p + 1
    r = np.concatenate([r, [n * p], np.repeat(base + k - 1, 3)])
    c = np.concatenate([c, [128], np.stack([k - 1, k, k + 1], axis=1).ravel()])
    v = np.concatenate([v, [1.0], (lam * w[k])[:, None].repeat(3, 1).ravel() * np.tile([1.0, -2.0, 1.0], 254)])
    a = sp.csr_matrix((v, (r, c)), shape=(base + 254, 256 + n))
    x = spl.spsolve((a.T @ a).tocsc(), a.T @ b)
    return x[:256] - x[128]


def calibrate(samples: list[tuple[np.ndarray, np.ndarray]], lam: float = 100.0, use_opencv: bool = False) -> Response:
    """Recover the inverse response from sample pixels of one or more shots.

    samples : list of (values (N_i, K_i, 3) uint8, exposures (K_i,) float) per shot. Shots with the
        same exposure ladder are solved together; curves of different ladders are averaged in the
        log domain, weighted by their sample counts.
    use_opencv : solve with OpenCV's CalibrateDebevec (the reference) instead of debevec_solve.
    """
    groups: dict[tuple, list[np.ndarray]] = {}
    for vals, ex in samples:
        if len(vals):
            groups.setdefault(tuple(np.round(np.log2(ex), 3)), []).append(vals)
    if not groups:
        raise CaptureError("no usable pixels for response recovery: are the photos black or fully clipped?")
    logs, weights, total = [], [], 0
    for key, vs in groups.items():
        v = np.concatenate(vs, axis=0)
        ex = np.exp2(np.array(key, np.float64))
        log_t = np.log(ex / ex[len(ex) // 2])
        if use_opencv:
            g = _calibrate_opencv(v, log_t, lam)
        else:
            g = np.stack([debevec_solve(v[:, :, ch].astype(np.int64), log_t, lam) for ch in range(3)], axis=1)
        logs.append(g)
        weights.append(len(v))
        total += len(v)
    g = np.average(np.stack(logs), axis=0, weights=weights)
    lin = np.exp(g)
    mono = np.maximum.accumulate(lin, axis=0)
    fixes = int((mono > lin * (1 + 1e-9)).sum())
    lin = mono * MID_GREY                                                  # lin[128] = MID_GREY
    return Response(lin, total, lam, fixes)


def _calibrate_opencv(v: np.ndarray, log_t: np.ndarray, lam: float) -> np.ndarray:
    """OpenCV's CalibrateDebevec on exactly these samples: (256, 3) log response, g(128) = 0."""
    import cv2

    side = int(np.ceil(np.sqrt(len(v))))
    pad = side * side - len(v)
    v = np.concatenate([v, v[:pad]], axis=0) if pad else v          # repeat to fill the square
    # OpenCV samples a grid; a side×side image with side² samples makes it take every pixel
    imgs = [np.ascontiguousarray(v[:, k].reshape(side, side, 3)) for k in range(v.shape[1])]
    crf = cv2.createCalibrateDebevec(side * side, lam, False).process(imgs, np.exp(log_t).astype(np.float32))
    crf = crf.reshape(256, 3).astype(np.float64)
    return np.log(np.maximum(crf, 1e-30)) - np.log(np.maximum(crf[128], 1e-30))


# --- merge ------------------------------------------------------------------------------------


def hat() -> np.ndarray:
    z = np.arange(256, dtype=np.float64)
    half = 0.5 * (Z_HI - Z_LO)
    return np.clip(np.minimum(z - Z_LO, Z_HI - z) / half, 0.0, None)


def merge_tables(resp: Response, exposures: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-bracket lookup tables (val, wt), each (K, 256, 3) float32: val_k(z) = f⁻¹(z)/e_k and
    w_k(z) = hat(z)·(e_k/f⁻¹'(z))², scaled so the largest weight is 1."""
    e = np.asarray(exposures, np.float64)[:, None, None]
    val = resp.lin[None] / e
    wt = hat()[None, :, None] * (e / resp.slope()[None]) ** 2
    wt /= wt.max()
    return val.astype(np.float32), wt.astype(np.float32)


def merge_numpy(z: np.ndarray, valid: np.ndarray | None, val: np.ndarray, wt: np.ndarray):
    """Reference of glk_hdr_merge.

    z : (K, N, 3) uint8 brackets (increasing exposure); valid : (K, N) bool or None;
    val, wt : (K, 256, 3) float32 tables (merge_tables).
    Returns (radiance (N, 3) float32 linear, relative units; status (N,) uint8)."""
    k_n, n, _ = z.shape
    ch = np.arange(3)[None, :]
    v = np.ones((k_n, n), bool) if valid is None else valid.astype(bool)
    w = np.stack([wt[k][z[k], ch] for k in range(k_n)]) * v[..., None]          # (K, N, 3)
    e = np.stack([val[k][z[k], ch] for k in range(k_n)])
    sw = w.astype(np.float64).sum(0)
    sv = (w.astype(np.float64) * e).sum(0)
    out = np.where(sw > 0, sv / np.where(sw > 0, sw, 1.0), 0.0)
    # fallback: the valid bracket nearest mid-range; ties → shortest when bright, longest when dark
    d = np.abs(z.astype(np.float64) - 127.5)
    bright = z.astype(np.float64) > 127.5
    rank = np.arange(k_n, dtype=np.float64)[:, None, None] / (2.0 * k_n)   # < ½ level: breaks ties only
    cost = np.where(v[..., None], d + np.where(bright, rank, -rank), np.inf)
    best = np.argmin(cost, axis=0)                                           # (N, 3)
    has = np.isfinite(cost.min(axis=0))
    zb = np.take_along_axis(z, best[None], 0)[0]
    fb = np.take_along_axis(e, best[None], 0)[0]
    fall = (sw <= 0) & has
    out = np.where(fall, fb, out)
    status = ((fall & (zb > 127.5)).any(1) * 1 | (fall & (zb <= 127.5)).any(1) * 2 | (~has).any(1) * 4).astype(np.uint8)
    return out.astype(np.float32), status


def merge(z: np.ndarray, valid: np.ndarray | None, val: np.ndarray, wt: np.ndarray, kernels=None):
    """HDR merge (see merge_numpy for arrays; z may be (K, H, W, 3), valid (K, H, W)) by the
    backend ``kernels`` (glk_hdr_merge or merge_numpy; default: the process's)."""
    from ..native.kernels import kernels as _kernels

    k_n = z.shape[0]
    z = np.ascontiguousarray(z.reshape(k_n, -1, 3), dtype=np.uint8)
    n = z.shape[1]
    v = None if valid is None else np.ascontiguousarray(valid.reshape(k_n, n), dtype=np.uint8)
    return (kernels or _kernels()).capture.merge(z, v, np.ascontiguousarray(val, np.float32),
                                                 np.ascontiguousarray(wt, np.float32))


def merge_opencv(stack: np.ndarray, exposures: np.ndarray, resp: Response) -> np.ndarray:
    """OpenCV's MergeDebevec with the same response, for comparison: (H, W, 3) float32."""
    import cv2

    crf = (resp.lin / MID_GREY).astype(np.float32).reshape(256, 1, 3)
    ex = np.asarray(exposures, np.float32)
    out = cv2.createMergeDebevec().process([np.ascontiguousarray(s) for s in stack], ex, crf)
    return out * np.float32(MID_GREY)


# --- one capture -----------------------------------------------------------------------------


@dataclass
class ShotHDR:
    radiance: np.ndarray     # (H, W, 3) float32 linear (relative units), 0 outside the circle
    status: np.ndarray       # (H, W) uint8 merge status bits (glk_hdr_merge)
    shifts: list             # per bracket (dx, dy) pixels applied by alignment
    yaw_deg: float
    exposures: np.ndarray    # (K,) relative exposures, increasing


def exposure_disagreements(cap: Capture, stacks, valids, resp: Response, stops: float = 0.5) -> list[str]:
    """Notes for neighbouring brackets whose pixels disagree with their stated exposures: the
    median log₂ ratio of f⁻¹(z)/e between the two, over pixels well exposed in both (green,
    20 ≤ z ≤ 235, on a grid of ≤ 512² pixels), beyond ``stops``. A mistyped exposure_s or a
    wrong EXIF shows up in the pairs on both sides of the photo."""
    notes = []
    for i, (st, valid) in enumerate(zip(stacks, valids)):
        step = max(1, int(np.ceil(max(st.shape[1:3]) / 512)))
        z = st[:, ::step, ::step, 1].astype(np.int64)
        v = valid[:, ::step, ::step]
        photos = cap.shots[i]
        for k in range(len(photos) - 1):
            ok = v[k] & v[k + 1] & (z[k] >= 20) & (z[k] <= 235) & (z[k + 1] >= 20) & (z[k + 1] <= 235)
            if ok.sum() < 100:
                continue
            d = float(np.median(np.log2(resp.lin[z[k + 1][ok], 1] / photos[k + 1].exposure)
                                - np.log2(resp.lin[z[k][ok], 1] / photos[k].exposure)))
            if abs(d) > stops:
                notes.append(f"{photos[k].field} and {photos[k + 1].field} ({photos[k].path.name}, "
                             f"{photos[k + 1].path.name}) disagree with their exposures by {d:+.1f} stops: "
                             "check exposure_s or the photos' EXIF")
    return notes


def reference_exposure(cap: Capture) -> float:
    """The median relative exposure of all photos: the merged radiance is in units where this
    exposure maps mid-grey (pixel 128) to MID_GREY, so the map at exposure 0 looks like the
    metered (middle) bracket. Radiance per unit exposure = map / reference_exposure."""
    return float(np.median([p.exposure for s in cap.shots for p in s]))


def merge_capture(cap: Capture, lens: Lens, progress=None, kernels=None,
                  lam: float = 100.0) -> tuple[list[ShotHDR], Response]:
    """Read, align, calibrate and merge every shot of a capture.

    progress : optional callable(fraction 0..1, message); kernels : the backend (default: the
    process's)."""
    tick = progress or (lambda f, m: None)
    circle = lens.circle_mask()
    inner = lens.pixel_radius() <= 0.9 * lens.radius
    rng = np.random.default_rng(0)
    stacks, valids, shifts, samples = [], [], [], []
    n_shots = len(cap.shots)
    for i, photos in enumerate(cap.shots):
        tick(0.05 + 0.35 * i / n_shots, f"reading and aligning shot {i + 1}/{n_shots}")
        st = read_bracket(photos, cap.width, cap.height)
        ex = np.array([p.exposure for p in photos])
        valid, sh = align_bracket(st, lens, ex)
        valid &= circle[None]
        # Debevec & Malik need N(P−1) ≫ 256 samples; ~3× that over the whole capture (the SVD
        # solve grows as N³)
        n_samples = int(np.ceil(min(400, 3 * 256 / (len(photos) - 1) + 50) / n_shots))
        samples.append((select_samples(st, valid, inner, n_samples, rng), ex))
        stacks.append(st); valids.append(valid); shifts.append(sh)
    tick(0.4, "recovering the camera response")
    resp = calibrate(samples, lam)
    resp.notes.extend(exposure_disagreements(cap, stacks, valids, resp))
    out = []
    e_ref = reference_exposure(cap)
    for i, photos in enumerate(cap.shots):
        tick(0.45 + 0.15 * i / n_shots, f"merging shot {i + 1}/{n_shots}")
        ex = np.array([p.exposure for p in photos]) / e_ref
        val, wt = merge_tables(resp, ex)
        rad, status = merge(stacks[i], valids[i], val, wt, kernels)
        # clipped even in the shortest exposure (JPEG ringing keeps a clipped sun a few levels
        # under 255, so the merge may still call it measured): flag it, it is a lower bound
        short = (stacks[i][0].max(axis=-1) >= CLIP_Z) & valids[i][0]
        status |= short.reshape(-1).astype(np.uint8)
        out.append(ShotHDR(rad.reshape(cap.height, cap.width, 3), status.reshape(cap.height, cap.width),
                           shifts[i], cap.manifest.shots[i].yaw_deg, ex))
        stacks[i] = None   # free the brackets as we go
    return out, resp
