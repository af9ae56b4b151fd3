"""Rendering and encoding a batch of turntable frames in a worker (the ``bundle_frames`` job).

Each view is rendered once, at twice the published resolution (the 2× set, for high-DPI screens
and zoom); the 1× frame is its 2 × 2 box average in linear radiance before tone mapping, so it
carries four samples per pixel: anti-aliased at no extra render (a pixel's value is the mean
radiance over its footprint). Views of one camera are rendered together, camera-major, so the
primary hits (the largest cost) are traced once for all variants and environments of a camera.

Files, each stored in the blob store under its key (keys.py ``file_key``):

* ``avif2``: the 2× frame, AVIF (Pillow/libavif), ``avif_quality_2x``;
* ``avif1``: the 1× frame, AVIF, ``avif_quality``;
* ``jpeg1``: the 1× frame, baseline JPEG ``jpeg_quality``: the fallback for browsers without
  AVIF, which get no 2× set (they zoom the 1× frame instead).

AVIF rather than WebP: at the same look a frame is about a third smaller (bunny 640×480: 1× 10 KB
at quality 60 against WebP's 12.5 KB at 80, 2× 12.7 KB at quality 40 against 30.6 KB), and the 2×
set is viewed at twice the pixel density, where a lower quality does not show. ``avif_speed`` 10
(libavif's fastest) keeps the encode at ~40 ms of CPU a view; Pillow's default (6) costs
several times that for a few percent less.
* ``meta``: JSON {"swatch": [r, g, b] 0..255, "coverage": fraction of the frame the object covers},
  written last, so its presence means the frame's files are all stored.
"""
from __future__ import annotations

import io
import json
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .keys import FILES, file_key

DEFAULT_ENCODE = {"avif_quality": 60, "avif_quality_2x": 40, "avif_speed": 10, "jpeg_quality": 85}


def downsample2(radiance: np.ndarray) -> np.ndarray:
    """(2H, 2W, 3) float32 linear radiance -> (H, W, 3) float32, the mean of each 2 × 2 block
    (the 1× frame's radiance; the job tone-maps both in one pass, core.tonemap.tonemap_pair)."""
    from worker.core.tonemap import half_mean

    return half_mean(radiance)


def encode(rgb1: np.ndarray, rgb2: np.ndarray, enc: dict) -> dict[str, bytes]:
    """The encoded files of one frame from its (H, W, 3) and (2H, 2W, 3) uint8 sRGB images."""
    from PIL import Image

    out = {}
    for name, rgb, q in (("avif2", rgb2, enc["avif_quality_2x"]), ("avif1", rgb1, enc["avif_quality"]),
                         ("jpeg1", rgb1, None)):
        buf = io.BytesIO()
        if q is not None:
            Image.fromarray(rgb).save(buf, format="AVIF", quality=q, speed=enc["avif_speed"])
        else:
            Image.fromarray(rgb).save(buf, format="JPEG", quality=enc["jpeg_quality"])
        out[name] = buf.getvalue()
    return out


def swatch(rgb1: np.ndarray, obj_mask: np.ndarray) -> tuple[list[int], float]:
    """([r, g, b] sRGB colour of the object, the fraction of pixels it covers): the colour a
    shopper sees on the object, for the variant's swatch: the per-channel median over the
    object's pixels away from its outline (an anti-aliased outline pixel mixes in the
    background, and a highlight is the light's colour, not the material's), over all its pixels
    when too few are inside."""
    from scipy.ndimage import binary_erosion

    n = int(obj_mask.sum())
    if n == 0:
        return [128, 128, 128], 0.0
    inner = binary_erosion(obj_mask, iterations=1)
    px = rgb1[inner] if inner.sum() >= max(16, n // 4) else rgb1[obj_mask]
    return [int(round(float(c))) for c in np.median(px, axis=0)], n / obj_mask.size


def render_frames(cache, p: dict, progress) -> dict:
    """The ``bundle_frames`` job: render, encode and store the views of ``p``.

    p : {"scene": scene payload, "object": name, "variants": [scene material dicts],
    "environments": [{"sha256", "filename", "rotation_deg", "intensity"}], "views": [{"key",
    "variant", "environment", "camera" (the 2× camera)}] (grouped by camera), "render":
    {"samples", "antialias" (when samples > 1), "shading", "tone", "exposure", "ground_shadow"},
    "encode": encoder settings}.
    Returns {"files": {key: {name: sha256}}, "meta": {key: meta}, "rendered", "skipped",
    "seconds", "ms": {stage: total ms}}. A view whose files are already stored is skipped."""
    from worker.core.tonemap import tonemap_pair
    from worker.models import parse_material
    from worker.renderers import FrameRequest, Lighting
    from worker.scene import Camera

    from ..jobs.ipc import JobError

    t0 = time.perf_counter()
    scene = p["scene"]
    r = cache.renderer(scene)
    if "camera" not in r.controls:          # a fixed-view renderer (GI): the turntable's is the cut renderer
        r = cache.renderer(scene, kind="cuts")
    names = [o.name for o in r.scene.spec.objects]
    if p["object"] not in names:
        raise JobError(f"object: no object {p['object']!r} (objects: {', '.join(names)})", 422)
    oi = names.index(p["object"])
    base = list(r.scene.materials)
    mats = []
    for m in p["variants"]:
        ms = list(base)
        ms[oi] = parse_material(m)
        mats.append(ms)
    rend, enc = p["render"], {**DEFAULT_ENCODE, **(p.get("encode") or {})}
    views = p["views"]
    ms = {"render": 0.0, "tone": 0.0, "encode": 0.0, "store": 0.0}
    out_files, out_meta, rendered, skipped = {}, {}, 0, 0
    env_now = None
    storer, stores = ThreadPoolExecutor(1, thread_name_prefix="glint-store"), []
    try:
        for n, v in enumerate(views):
            key = v["key"]
            mk = file_key(key, "meta")
            if cache.frames.sha(mk) is not None:         # stored meanwhile (another batch, an earlier build)
                out_files[key] = {k: cache.frames.sha(file_key(key, k)) for k in FILES}
                out_meta[key] = json.loads(cache.frames.get(mk))
                skipped += 1
                progress((n + 1) / len(views), f"{n + 1}/{len(views)} frames")
                continue
            e = p["environments"][v["environment"]]
            if env_now != e["sha256"]:
                r.set_environment(cache.envmap(e))
                env_now = e["sha256"]
            a = time.perf_counter()
            res = r.render(FrameRequest(camera=Camera.model_validate(v["camera"]),
                                        lighting=Lighting(e["rotation_deg"], e["intensity"]),
                                        materials=mats[v["variant"]], samples=rend["samples"],
                                        antialias=rend.get("antialias", "full"), shading=rend["shading"],
                                        ground_shadow=rend["ground_shadow"]))
            b = time.perf_counter()
            rgb2, rgb1 = tonemap_pair(res.radiance, rend["exposure"], rend["tone"])
            c = time.perf_counter()
            files = encode(rgb1, rgb2, enc)
            d = time.perf_counter()
            colour, cover = swatch(rgb1, res.object_id[::2, ::2][:rgb1.shape[0], :rgb1.shape[1]] == oi)
            meta = {"swatch": colour, "coverage": round(cover, 4),
                    "bytes": {k: len(b_) for k, b_ in files.items()}}
            # stored on the store thread (each file is fsynced: the waits overlap the next render)
            stores.append(storer.submit(_store, cache.frames, key, files, meta))
            ms["render"] += (b - a) * 1e3
            ms["tone"] += (c - b) * 1e3
            ms["encode"] += (d - c) * 1e3
            out_files[key], out_meta[key] = None, meta
            rendered += 1
            progress((n + 1) / len(views), f"{n + 1}/{len(views)} frames")
        for f in stores:
            key, shas, dt = f.result()
            out_files[key] = shas
            ms["store"] += dt
    finally:
        storer.shutdown(wait=True)          # a failed frame's batch still finishes what it stored
    return {"files": out_files, "meta": out_meta, "rendered": rendered, "skipped": skipped,
            "seconds": time.perf_counter() - t0, "ms": {k: round(x, 1) for k, x in ms.items()}}


def _store(parts, key: str, files: dict[str, bytes], meta: dict) -> tuple[str, dict, float]:
    """Store one frame's files, then its meta (last: its presence means the frame is complete).
    Returns (key, {name: sha256}, milliseconds)."""
    t = time.perf_counter()
    shas = {name: parts.put(file_key(key, name), data) for name, data in files.items()}
    parts.put(file_key(key, "meta"), json.dumps(meta).encode())
    return key, shas, (time.perf_counter() - t) * 1e3
