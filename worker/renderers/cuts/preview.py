"""A first look at a scene while its precomputation runs.

The full precomputation traces 2^15 directions per vertex (cyber-worlds §V.A.1): minutes for a
piece of furniture on two cores, during which a new designer saw a black canvas. The preview is
the same cut renderer's frame from cuts over a coarse direction tree of PREVIEW_HEIGHT levels
(2^8 directions per vertex, 1/128 of the rays): the object, its material, the environment and
its self-shadowing, at the blur of 256 directions (a wide highlight, soft shadows), in a few
seconds. It is an image for the studio while it waits, not a part: nothing renders from it again.
"""
from __future__ import annotations

import io
import time

import numpy as np

from ...core.directions import get_tree
from .precompute import BATCH, CutData, precompute_cuts

PREVIEW_HEIGHT = 8          # 256 directions per vertex
PREVIEW_SAMPLES = 2         # per pixel: smooth edges at 2× the primary rays of one sample
PREVIEW_MAX_WIDTH = 960     # the studio draws it in the canvas; a bigger camera is scaled down
PREVIEW_JPEG_QUALITY = 85


def preview_cuts(scene, threads: int = 2, kernels=None):
    """(CutSet over the PREVIEW_HEIGHT tree of every vertex of the scene's static mesh, rays
    traced). Batches hold as many rays as the full precomputation's (BATCH × 2^15): with 256
    rays per vertex, 4-vertex batches spent their time in per-call overhead (4.2 s against 1.5 s
    for the demo chair's 21K vertices)."""
    tree = get_tree(PREVIEW_HEIGHT)
    m = scene.mesh
    batch = BATCH << max(0, 15 - PREVIEW_HEIGHT)
    cs, rays, _ = precompute_cuts(m.vertices, m.faces, m.normals, tree=tree, threads=threads, batch=batch,
                                  kernels=kernels)
    return cs, rays


def preview_jpeg(scene, threads: int = 2, kernels=None) -> tuple[bytes, dict]:
    """(JPEG of the scene camera's view, stats {"seconds", "rays", "width", "height",
    "exposure"}). scene : a LoadedScene. Its own materials, lighting rotation and intensity; the
    exposure is the scene file's, or for "auto" (and none) the one that shows the object's median
    pixel as middle grey (core/tonemap.py auto_exposure, as a session's first frame)."""
    from PIL import Image

    from ...core.tonemap import auto_exposure, tonemap
    from .. import FrameRequest, Lighting
    from .renderer import CutRenderer

    t0 = time.perf_counter()
    cs, rays = preview_cuts(scene, threads, kernels)
    r = CutRenderer(scene, CutData(cuts=cs), kernels)
    spec = scene.spec
    cam = spec.camera
    if cam.width > PREVIEW_MAX_WIDTH:
        k = PREVIEW_MAX_WIDTH / cam.width
        cam = cam.model_copy(update={"width": PREVIEW_MAX_WIDTH, "height": max(1, round(cam.height * k))})
    env = spec.environment
    out = r.render(FrameRequest(camera=cam, lighting=Lighting(env.rotation_deg, env.intensity), materials=[],
                                samples=PREVIEW_SAMPLES))
    ev = getattr(spec, "exposure", None)
    if not isinstance(ev, (int, float)):
        ev = auto_exposure(out.radiance, out.object_id >= 0) if ev == "auto" else 0.0
    ev = float(ev or 0.0)
    buf = io.BytesIO()
    Image.fromarray(tonemap(np.asarray(out.radiance), ev, "neutral")).save(buf, format="JPEG",
                                                                          quality=PREVIEW_JPEG_QUALITY)
    return buf.getvalue(), {"seconds": round(time.perf_counter() - t0, 3), "rays": int(rays),
                            "width": int(cam.width), "height": int(cam.height), "exposure": round(ev, 2)}
