"""The whole capture path: manifest → HDR shots → lens-frame removal → equirectangular map.

``capture(manifest_path)`` returns the map (linear float32 radiance, docs/design/conventions.md) and the
statistics the CLI prints and the service stores; ``exr_bytes`` / ``preview_png`` encode them.
"""
from __future__ import annotations

import io
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .fisheye import Lens
from .frame import detect_frame
from .hdr import merge_capture, reference_exposure
from .manifest import CaptureError, load_capture
from .stitch import check_coverage, default_width, row_solid_angle, stitch

LUMA = np.array([0.2126, 0.7152, 0.0722])


@dataclass
class CaptureResult:
    envmap: np.ndarray      # (H, W, 3) float32 linear radiance
    frame: np.ndarray       # (h, w) bool lens-frame mask in the photos' grid (all False if kept)
    stats: dict


def dynamic_range_stops(env: np.ndarray) -> float:
    """log₂ of the ratio of the 99.9th to the 0.1th percentile of luminance over the sphere
    (solid-angle weighted): the map's usable range, robust to single pixels. Percentiles from a
    histogram of log₂ luminance in 1/64-stop bins."""
    h, w, _ = env.shape
    lum = (env @ LUMA.astype(np.float32)).ravel()
    wts = np.broadcast_to(row_solid_angle(h, w)[:, None], (h, w)).ravel()
    pos = lum > 0
    if pos.sum() < 2:
        return 0.0
    lg = np.log2(lum[pos])
    lo, hi = float(lg.min()), float(lg.max())
    if hi - lo < 1e-6:
        return 0.0
    bins = max(2, int(np.ceil((hi - lo) * 64)))
    hist, edges = np.histogram(lg, bins=bins, range=(lo, hi), weights=wts[pos])
    cdf = np.cumsum(hist) / hist.sum()
    return float(edges[np.searchsorted(cdf, 0.999) + 1] - edges[np.searchsorted(cdf, 0.001)])


def capture(manifest_path: str | Path, width: int | None = None, remove_frame: bool = True,
            root: str | Path | None = None, progress=None, kernels=None) -> CaptureResult:
    """Turn a capture manifest and its photos into an environment map.

    width : output width (height = width/2); default matches the photos' angular resolution
        (at most 4096).
    remove_frame : detect and remove the lens frame (default); False keeps it, for comparison.
    root : confine the photos to this folder (the service passes the upload's folder).
    progress : optional callable(fraction 0..1, message).
    kernels : the backend for the merge and the reprojection (default: the process's).
    """
    t0 = time.perf_counter()
    tick = progress or (lambda f, m: None)
    tick(0.0, "reading the manifest")
    cap = load_capture(manifest_path, root)
    m = cap.manifest
    lens = Lens(cap.width, cap.height, m.projection, m.fov_deg)
    width = int(width) if width else default_width(lens)
    if width < 16 or width % 2:
        raise CaptureError(f"output width {width}: use an even number of at least 16")
    check_coverage(lens, [s.yaw_deg for s in m.shots])
    shots, resp = merge_capture(cap, lens, tick, kernels)
    max_shift = max((abs(dx) + abs(dy) for s in shots for dx, dy in s.shifts), default=0)
    if remove_frame:
        tick(0.62, "finding the lens frame")
        fm = detect_frame([s.radiance for s in shots], lens, max_shift, [s.yaw_deg for s in shots])
        frame = fm.mask
    else:
        fm, frame = None, np.zeros((cap.height, cap.width), bool)
    st = stitch(shots, lens, frame if remove_frame else None, width, tick, kernels)
    tick(0.97, "statistics")
    env = st.envmap
    stats = {
        "seconds": round(time.perf_counter() - t0, 3),
        "width": int(env.shape[1]), "height": int(env.shape[0]),
        "photos": sum(len(s) for s in cap.shots), "shots": len(cap.shots),
        "photo_width": cap.width, "photo_height": cap.height,
        "projection": m.projection, "fov_deg": m.fov_deg,
        "dynamic_range_stops": round(dynamic_range_stops(env), 2),
        "frame_removed": bool(remove_frame),
        "frame_pixels_removed": int(fm.pixels) if fm else 0,
        "frame_fraction_of_circle": round(fm.fraction_of_circle, 5) if fm else 0.0,
        "frame_solid_angle_sr": round(fm.solid_angle_sr, 5) if fm else 0.0,
        "frame_regions": fm.regions if fm else 0,
        "inpainted_fraction_of_sphere": round(st.inpainted_fraction, 5),
        "uncovered_fraction_of_sphere": round(st.uncovered_fraction, 5),
        "clipped_fraction_of_sphere": float(f"{st.clipped_fraction:.3g}"),
        "clipped_pixels": int(sum(((s.status & 1) > 0).sum() for s in shots)),
        "overlap_deg": round(st.overlap_deg, 3),
        "exposure_gains_stops": [round(g, 4) for g in st.gains_stops],
        "alignment_shifts_px": [[list(s) for s in shot.shifts] for shot in shots],
        "reference_exposure": reference_exposure(cap),
        "exposure_sources": sorted({p.shutter_source for s in cap.shots for p in s}),
        "exposure_notes": cap.exposure_notes + resp.notes,
        "response": resp.summary(),
    }
    tick(1.0, "done")
    return CaptureResult(env, frame, stats)


def exr_bytes(env: np.ndarray) -> bytes:
    """The map as a float EXR file's bytes (worker.envmap.save_exr)."""
    from ..envmap import save_exr

    fd, tmp = tempfile.mkstemp(suffix=".exr")
    os.close(fd)
    try:
        save_exr(tmp, env)
        return Path(tmp).read_bytes()
    finally:
        Path(tmp).unlink(missing_ok=True)


def preview_png(env: np.ndarray, max_width: int = 1024) -> bytes:
    """A tone-mapped PNG of the map (display only): area-downsampled to ≤ max_width, exposed so
    the median luminance reads 0.18, neutral curve, sRGB."""
    import cv2
    from PIL import Image

    from ..core.tonemap import tonemap

    h, w, _ = env.shape
    if w > max_width:
        env = cv2.resize(env, (max_width, max_width // 2), interpolation=cv2.INTER_AREA)
    med = float(np.median(env @ LUMA.astype(np.float32)))
    ev = float(np.log2(0.18 / med)) if med > 0 else 0.0
    img = tonemap(np.ascontiguousarray(env, np.float32), ev, "neutral")
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, "PNG")
    return buf.getvalue()
