"""Stage-by-stage cost of orbit frames of the cut renderer: every frame a new camera, so the
primary hits (``CutRenderer.view``) are rebuilt before shading.

    .venv/bin/python bench/profile_orbit.py bench/oakChair.json [--frames 12] [--samples 1]
        [--model ggx|srbf|lambert] [--primary embree|project]

Prints one JSON object: the median wall-clock and CPU milliseconds (CPU time sums the threads
and excludes waiting for a core, the steadier figure on a shared machine) of the view build
(primary hits, visible vertices, background coordinates), of the primary-hit step alone, and of
the whole frame (view + shading), for a camera orbiting the scene's own by 3° per frame.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from bench.profile_frame import material  # noqa: E402


def orbit(cam, k: int, step_deg: float = 3.0):
    """The scene camera turned by k·step_deg about the vertical through its target."""
    eye, tgt = np.asarray(cam.eye, float), np.asarray(cam.target, float)
    a = math.radians(step_deg * k)
    q = eye - tgt
    x, z = q[0] * math.cos(a) - q[2] * math.sin(a), q[0] * math.sin(a) + q[2] * math.cos(a)
    return cam.model_copy(update={"eye": (float(tgt[0] + x), float(eye[1]), float(tgt[2] + z))})


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--samples", type=int, default=1)
    ap.add_argument("--lod", default="full", choices=["full", "quick", "drag"], help="quick: a session's orbit frames")
    ap.add_argument("--model", default="ggx", choices=["ggx", "srbf", "lambert"])
    ap.add_argument("--primary", default=None, choices=["embree", "project"])
    a = ap.parse_args()

    from worker.assets import ensure_repo_scene
    from worker.cli import open_renderer
    from worker.renderers import FrameRequest
    from worker.scene import load_scene

    ensure_repo_scene(a.scene)
    scene = load_scene(a.scene)
    r, _ = open_renderer(scene, None, True)
    if a.primary:
        r.primary = a.primary
    cam = scene.spec.camera
    mats = [material(a.model)] * len(scene.spec.objects)
    r.render(FrameRequest(camera=cam, materials=mats, samples=a.samples, lod=a.lod))    # warm
    wall: dict[str, list[float]] = {}
    cpu: dict[str, list[float]] = {}

    def t(name, fn):
        t0, c0 = time.perf_counter(), time.process_time()
        res = fn()
        wall.setdefault(name, []).append((time.perf_counter() - t0) * 1e3)
        cpu.setdefault(name, []).append((time.process_time() - c0) * 1e3)
        return res

    hits = getattr(r, "_primary_hits", None)
    for k in range(1, a.frames + 1):
        c = orbit(cam, k)
        if hits is not None:
            from worker.core.render import camera_dirs

            d = camera_dirs(c.eye, c.target, c.up, c.fov_y_deg, c.width, c.height, a.samples, kernels=r.k)
            t("primary_hits", lambda: hits(c, a.samples, d))
        t("view", lambda: r.view(c, a.samples))
        r._views.clear()
        t("frame", lambda: r.render(FrameRequest(camera=c, materials=mats, samples=a.samples, lod=a.lod)))
    res = {"wall_ms": {k: round(statistics.median(x), 2) for k, x in wall.items()},
           "cpu_ms": {k: round(statistics.median(x), 2) for k, x in cpu.items()},
           "scene": a.scene, "model": a.model, "samples": a.samples, "frames": a.frames,
           "primary": getattr(r, "primary", None), "load": os.getloadavg()[0],
           "faces": int(len(scene.mesh.faces)), "pixels": int(cam.width * cam.height)}
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
