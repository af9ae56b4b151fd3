"""Accuracy of moving an object, against Mitsuba 3 (BENCHMARKS.md "Moving objects"):

    python scripts/move_accuracy.py SCENE.json --object NAME [--spp 128] [--width 320]
        [--transform '{"rotate_deg": [0, 40, 0], "translate": [-60, 0, 80]}'] [--cuts DIR] [--json]

renders the scene with the cut renderer (vertex shading, full quality) with the movable object
where the scene file puts it and where --transform puts it, and Mitsuba 3 (``direct``, two seeds)
of both configurations; prints the relative RMSE over the objects' pixels, over the moved
object's pixels, and over the floor around its base (contact shadows: pixels of other objects
within --contact (default 0.6) bounding radii of the point under its centre), each for the
unmoved and the moved configuration, with Mitsuba's own noise (the two seeds against each other,
/√2) beside them. Glint is rendered at --ss × the resolution and box-filtered like Mitsuba's
pixels (edges of thin chair parts otherwise dominate both errors). The moved configuration needs
no precomputation (the cut fields)."""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None) -> int:
    from worker import cli
    from worker.core.render import camera_rays
    from worker.mitsuba_ref import render_mitsuba
    from worker.renderers import FrameRequest, Lighting
    from worker.renderers.cuts.field import bounding_sphere
    from worker.renderers.cuts.fields import object_shape
    from worker.scene import LoadedScene, Transform
    from worker.trace.embree import Tracer

    p = argparse.ArgumentParser()
    p.add_argument("scene")
    p.add_argument("--object", required=True)
    p.add_argument("--transform", default='{"rotate_deg": [0, 40, 0], "translate": [-60, 0, 80]}')
    p.add_argument("--spp", type=int, default=128)
    p.add_argument("--width", type=int, default=320)
    p.add_argument("--contact", type=float, default=0.6)
    p.add_argument("--ss", type=int, default=3, help="Glint rendered at ss× the resolution and box-filtered, as "
                                                        "Mitsuba's box pixel filter (default 3)")
    p.add_argument("--cuts")
    p.add_argument("--out", help="folder for the images (npy)")
    p.add_argument("--json", action="store_true")
    a = p.parse_args(argv)

    scene = cli._load(a.scene)
    names = [o.name for o in scene.spec.objects]
    k = names.index(a.object)
    r, _ = cli.open_renderer(scene, a.cuts, True, cli.scene_options(scene, 1.0))
    cam = scene.spec.camera
    cam = cam.model_copy(update={"width": a.width, "height": round(a.width * cam.height / cam.width)})
    light = Lighting(scene.spec.environment.rotation_deg, scene.spec.environment.intensity)
    moved = Transform.model_validate(json.loads(a.transform))
    out = {"scene": a.scene, "object": a.object, "width": cam.width, "height": cam.height, "spp": a.spp, "ss": a.ss,
           "transform": json.loads(moved.model_dump_json())}
    for name, tr in (("unmoved", scene.spec.objects[k].transform), ("moved", moved)):
        spec = scene.spec.model_copy(deep=True)
        spec.objects[k].transform = tr
        spec.camera = cam
        placed = LoadedScene(spec, scene.root, envmap=scene.envmap)
        t0 = time.perf_counter()
        big = cam.model_copy(update={"width": cam.width * a.ss, "height": cam.height * a.ss})
        g = r.render(FrameRequest(camera=big, lighting=light, materials=scene.materials,
                                  transforms={a.object: tr})).radiance
        g = g.reshape(cam.height, a.ss, cam.width, a.ss, 3).mean((1, 3))
        t_glint = time.perf_counter() - t0
        t0 = time.perf_counter()
        m1 = render_mitsuba(placed, spp=a.spp, seed=1)
        m2 = render_mitsuba(placed, spp=a.spp, seed=2)
        t_mitsuba = time.perf_counter() - t0
        m = 0.5 * (m1 + m2)
        o, d = camera_rays(cam.eye, cam.target, cam.up, cam.fov_y_deg, cam.width, cam.height)
        tri, _, t = Tracer(placed.mesh.vertices, placed.mesh.faces).first_hit(o, d)
        ids = np.where(tri >= 0, placed.object_of_face[np.maximum(tri, 0)], -1).reshape(cam.height, cam.width)
        hit = (o + d * t[:, None]).reshape(cam.height, cam.width, 3)
        sh = object_shape(scene, k, tr)
        c, rad = bounding_sphere(sh.vertices)
        s = float(np.cbrt(np.linalg.det(sh.world_from_local[:3, :3])))
        cw = sh.world_from_local[:3, :3] @ c + sh.world_from_local[:3, 3]
        base = np.array([cw[0], placed.mesh.vertices[placed.object_of_vertex == k, 1].min(), cw[2]])
        near = (ids >= 0) & (ids != k) & (np.linalg.norm(hit - base, axis=-1) < a.contact * rad * s)
        masks = {"objects": ids >= 0, "object": ids == k, "contact": near}

        def rmse(x, y, mk):
            dd = (x - y).mean(-1)[mk]
            return float(np.sqrt((dd ** 2).mean()) / y.mean(-1)[mk].mean()) if mk.any() else None

        out[name] = {"ms_glint": 1e3 * t_glint, "s_mitsuba": t_mitsuba,
                     **{f"rmse_{kk}": rmse(g, m, mk) for kk, mk in masks.items()},
                     **{f"mitsuba_noise_{kk}": (rmse(m1, m2, mk) or 0.0) / np.sqrt(2) / np.sqrt(2) for kk, mk in masks.items()},
                     "pixels": {kk: int(mk.sum()) for kk, mk in masks.items()}}
        if a.out:
            Path(a.out).mkdir(parents=True, exist_ok=True)
            np.save(Path(a.out) / f"{name}_glint.npy", g)
            np.save(Path(a.out) / f"{name}_mitsuba.npy", m)
            np.save(Path(a.out) / f"{name}_ids.npy", ids)
    print(json.dumps(out) if a.json else json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
