"""Moved-object frames against exact field cuts and against the static renderer.

    python -m bench.move_accuracy SCENE STATIC_SCENE OBJECT [--hmin 0 3 5] [--json]

SCENE has OBJECT movable; STATIC_SCENE is the same scene with nothing movable (its cuts traced
through the object where it stands). For each h_min (the field cuts' coarsest node, 2^h_min
leaves; 0 is exact), prints the relative RMS (over the pixels the static frame lights) of

* the moved-object frame at the object's own place against the static renderer's vertex frame
  (what the visibility cut fields approximate: their interpolation and the coarser nodes), and
* five frames of a slide (``bench.fields.move_path``) against the same frames with exact field
  cuts (h_min 0): what the coarser nodes alone change.

Cut renderer, vertex shading, 2 threads; the scenes' precomputed parts are made on first use.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np


def _rel(a, b, m):
    return float(np.sqrt(((a - b)[m] ** 2).mean() / max((b[m] ** 2).mean(), 1e-300)))


def main(argv=None) -> int:
    sys.path.insert(0, os.getcwd())
    from bench.fields import move_path
    from worker import cli
    from worker.renderers import FrameRequest, Lighting
    from worker.renderers.cuts.combine import Combiner
    from worker.renderers.cuts.field import bounding_sphere
    from worker.renderers.cuts.fields import object_shape

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene"); ap.add_argument("static_scene"); ap.add_argument("object")
    ap.add_argument("--hmin", type=int, nargs="+", default=[0, 3, 5])
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)

    st = cli._load(a.static_scene)
    rs, _ = cli.open_renderer(st, None, True, cli.scene_options(st, 1.0))
    spec = st.spec
    light = Lighting(spec.environment.rotation_deg, spec.environment.intensity)
    ref = np.asarray(rs.render(FrameRequest(camera=spec.camera, lighting=light, materials=st.materials,
                                            shading="vertex")).radiance, np.float64)
    lit = ref.sum(-1) > 0
    sc = cli._load(a.scene)
    rm, _ = cli.open_renderer(sc, None, True, cli.scene_options(sc, 1.0))
    names = [o.name for o in sc.spec.objects]
    i = names.index(a.object)
    obj = sc.spec.objects[i]
    _, rad = bounding_sphere(object_shape(sc, i).vertices)
    steps = [0, 3, 6, 9, 12]

    def frames(h):
        lv = rm._moving.levels["full"]
        lv.combiner, lv.static_combiner = Combiner(h, kernels=rm.k), Combiner(h, kernels=rm.k)
        out = []
        for tr in [obj.transform] + [move_path(obj.transform, rad, k, False) for k in steps]:
            out.append(np.asarray(rm.render(FrameRequest(camera=spec.camera, lighting=light, materials=sc.materials,
                                                         shading="vertex", transforms={a.object: tr})).radiance,
                              np.float64))
        return out

    exact = frames(0)
    rows = []
    for h in a.hmin:
        f = exact if h == 0 else frames(h)
        vs_exact = [_rel(x, e, np.ones(lit.shape, bool)) for x, e in zip(f[1:], exact[1:])]
        rows.append({"hmin": h, "vs_static": _rel(f[0], ref, lit), "vs_exact_min": min(vs_exact),
                     "vs_exact_max": max(vs_exact)})
    if a.json:
        print(json.dumps({"scene": a.scene, "static_scene": a.static_scene, "object": a.object, "rows": rows}))
    else:
        for r in rows:
            print(f"h_min {r['hmin']}: {100 * r['vs_static']:.3f}% from the static renderer, "
                  f"{100 * r['vs_exact_min']:.3f}-{100 * r['vs_exact_max']:.3f}% from exact field cuts")
    return 0


if __name__ == "__main__":
    sys.exit(main())
