"""``glint bench antialias``: how close each sampling of the cut renderer comes to a supersampled
reference, and what it costs. The frames are the turntable views a publication renders (its 2×
frames), the reference is the same renderer with 16 samples at every pixel (a 4 × 4 grid), so
the figure is the aliasing alone, not the renderer's distance from a path tracer
(``glint bench accuracy``)."""
from __future__ import annotations

import json
import time
import types
from pathlib import Path

import numpy as np

SAMPLINGS = ((1, "full"), (4, "full"), (4, "edges"))


def bench_antialias(scene: str, views: int = 3, width: int = 1280, height: int = 960, alpha: float = 0.1,
                    reference: int = 16, cuts: str | None = None) -> dict:
    """Relative RMSE against ``reference`` samples everywhere over the pixels some sample of
    which sees the mesh, per sampling (samples, antialias) of SAMPLINGS, and CPU seconds per
    frame (the second frame of each view: its primary hits cached, as a publication's other
    variants and environments of a camera find them), the mean over ``views`` turntable views
    (the first object in a GGX α ``alpha`` red material, the scene's map unturned)."""
    from worker.cli import _renderer
    from worker.core.cuts import DEFAULT_TAU
    from worker.models import parse_material
    from worker.publish.turntable import azimuths, default_elevations, turntable_camera
    from worker.renderers import FrameRequest, Lighting
    from worker.scene import Camera

    path = Path(scene)
    r, _ = _renderer(types.SimpleNamespace(scene=str(path), cuts=cuts, tau=DEFAULT_TAU), quiet=True)
    cam0 = json.loads(path.read_text())["camera"]
    mat = parse_material({"model": "ggx", "alpha": alpha, "specular": [0.3, 0.3, 0.3], "albedo": [0.6, 0.04, 0.04]})
    mats = [mat] + list(r.scene.materials)[1:]
    azs = azimuths(cam0, views)
    el = default_elevations(cam0)[0]
    out = {f"{s}-{aa}": {"rel_rmse": [], "cpu_s": [], "edge_pixels": [], "steep_pixels": []} for s, aa in SAMPLINGS}
    for az in azs:
        cam = Camera.model_validate(turntable_camera(cam0, az, el, width, height))

        def frame(s, aa):
            req = FrameRequest(camera=cam, lighting=Lighting(0.0, 1.0), materials=mats, samples=s, antialias=aa,
                               shading="refined", ground_shadow=False)
            r.render(req)
            c = time.process_time()
            res = r.render(req)
            return res, time.process_time() - c

        ref, _ = frame(reference, "full")
        seen = ~(r.view(cam, reference).tri.reshape(-1, reference) < 0).all(1)
        want = ref.radiance.reshape(-1, 3)[seen].astype(np.float64)
        for s, aa in SAMPLINGS:
            res, cpu = frame(s, aa)
            got = res.radiance.reshape(-1, 3)[seen]
            o = out[f"{s}-{aa}"]
            o["rel_rmse"].append(float(np.sqrt(((got - want) ** 2).mean() / (want ** 2).mean())))
            o["cpu_s"].append(cpu)
            o["edge_pixels"].append(int(res.info.get("edge_pixels", 0)))
            o["steep_pixels"].append(int(res.info.get("steep_pixels", 0)))
    return {"scene": str(scene), "views": views, "width": width, "height": height, "alpha": alpha,
            "reference_samples": reference,
            "samplings": {k: {"rel_rmse_pct": round(100 * float(np.mean(v["rel_rmse"])), 2),
                              "cpu_s_per_frame": round(float(np.mean(v["cpu_s"])), 3),
                              "edge_pixels": int(np.mean(v["edge_pixels"])),
                              "steep_pixels": int(np.mean(v["steep_pixels"]))} for k, v in out.items()}}
