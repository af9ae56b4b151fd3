"""Where the demo session's orbit frames go, in process: the session of ``glint bench stream``
(the demo scene, its 21 white strokes fitted in a session runtime, so the chair wears the
fitted srbf), then orbit frames as a session draws them while the camera moves (one sample,
vertex shading, 640×480, a new camera every frame, swinging ±0.5 rad about the target).

    .venv/bin/python bench/profile_session_orbit.py [--frames 60] [--store DIR]

Prints one JSON object: median milliseconds of the whole render and of its stages (the
renderer's timings: view, light, background, shade, refine, resolve), and the load average.
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

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--store", help="cut cache folder (default: the data directory's)")
    a = ap.parse_args()

    from bench.stream import stroke_fields
    from worker.assets import demo_scene
    from worker.cli import open_renderer
    from worker.jobs.runtime import SessionRuntime
    from worker.protocol import new_state
    from worker.renderers import FrameRequest, Lighting
    from worker.scene import load_scene

    sc = load_scene(demo_scene())
    r, _ = open_renderer(sc, a.store, True)
    name = sc.spec.objects[0].name
    rt = SessionRuntime(sc, r, {"state": new_state(sc.spec, name).model_dump(mode="json"), "strokes": []})
    rt.frame(-1)
    cam = sc.spec.camera
    for i in range(21):
        rt.handle({"seq": i + 1, "type": "stroke", **stroke_fields(i, cam.width, cam.height)})
        rt.fit_if_needed()
        rt.frame(i + 1)
    mats = list(rt.state.materials)
    rt.close()
    eye, tgt = cam.eye, cam.target
    rad = math.hypot(eye[0] - tgt[0], eye[2] - tgt[2])
    a0 = math.atan2(eye[0] - tgt[0], eye[2] - tgt[2])
    light = Lighting(sc.spec.environment.rotation_deg, sc.spec.environment.intensity)

    def req(k):
        ang = a0 + 0.5 * math.sin(0.1 * k)
        c = cam.model_copy(update={"eye": (tgt[0] + rad * math.sin(ang), eye[1], tgt[2] + rad * math.cos(ang))})
        return FrameRequest(camera=c, lighting=light, materials=mats, shading="vertex")

    for k in range(3):
        r.render(req(k))
    total, stages = [], {}
    for k in range(3, 3 + a.frames):
        t0 = time.perf_counter()
        out = r.render(req(k))
        total.append((time.perf_counter() - t0) * 1e3)
        for s, v in out.timings.items():
            stages.setdefault(s, []).append(v)
    print(json.dumps({"render_ms": round(statistics.median(total), 2),
                      **{f"{s}_ms": round(statistics.median(v), 2) for s, v in stages.items()},
                      "material": mats[0].model, "frames": a.frames, "load": os.getloadavg()[0]}))


if __name__ == "__main__":
    main()
