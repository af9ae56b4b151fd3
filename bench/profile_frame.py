"""Stage-by-stage cost of a full-quality frame of the cut renderer.

    .venv/bin/python bench/profile_frame.py bench/oakChair.json [--reps 15] [--model ggx|srbf|lambert]

Every stage runs ``--reps`` times in one process, interleaved, so that the shares stay
comparable on a loaded machine (the absolute milliseconds do not: see BENCHMARKS.md). Prints one
JSON object: the median wall-clock and CPU milliseconds of each stage (CPU time sums the
kernel's threads and excludes time spent waiting for a core, so it is the steadier figure on a
shared machine), and the counts that explain them (visible vertices, cut entries per frame).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402


def material(model: str):
    from worker.models import GGX, SRBF, Lambert

    if model == "lambert":
        return Lambert(albedo=(0.5, 0.4, 0.3))
    if model == "srbf":
        from worker.fit.basis import default_basis

        b = default_basis()
        rng = np.random.default_rng(0)
        c = (rng.random((b.J, 3)) * 0.02).tolist()
        return SRBF(centers=b.centers.tolist(), bandwidth=float(b.bandwidth), coefficients=c, albedo=(0.3, 0.2, 0.1))
    return GGX(alpha=0.25, specular=(0.9, 0.8, 0.6), albedo=(0.3, 0.2, 0.1))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--reps", type=int, default=15)
    ap.add_argument("--model", default="ggx", choices=["ggx", "srbf", "lambert"])
    a = ap.parse_args()

    from worker.assets import ensure_repo_scene
    from worker.cli import open_renderer
    from worker.core.lighting import light_tables
    from worker.core.render import MaterialTable, background, resolve, shade_points
    from worker.core.tonemap import tonemap
    from worker.renderers import FrameRequest, Lighting
    from worker.scene import load_scene

    ensure_repo_scene(a.scene)   # its assets: tests/.cache/assets, fetched on first use
    scene = load_scene(a.scene)
    r, _ = open_renderer(scene, None, True)
    cam = scene.spec.camera
    mat = material(a.model)
    mats = [mat] * len(scene.spec.objects)
    r.render(FrameRequest(camera=cam, materials=mats))           # warm: hit buffer, matrices
    v = r.view(cam)
    mesh = scene.mesh
    vi, wo = v.visible, v.wo
    n, ov = mesh.normals[vi], scene.object_of_vertex[vi]
    table = MaterialTable([m.pack() for m in mats])
    times: dict[str, list[float]] = {}
    cpu: dict[str, list[float]] = {}
    stages: dict[str, list[float]] = {}

    def t(name, fn):
        t0, c0 = time.perf_counter(), time.process_time()
        res = fn()
        times.setdefault(name, []).append((time.perf_counter() - t0) * 1e3)
        cpu.setdefault(name, []).append((time.process_time() - c0) * 1e3)
        return res

    vert = np.zeros((len(mesh.vertices), 3), np.float32)
    for i in range(a.reps):
        rot = 10.0 * i
        nl, nw, n8 = t("light.tables", lambda: light_tables(r.lighting, rot, 1.0, r.tree, r.k))
        t("materials.pack", lambda: MaterialTable([m.pack() for m in mats]))
        bg = np.zeros((len(v.tri), 3), np.float32)
        t("background", lambda: background(v.bg, v.dirs, v.uv0, r.lighting.map, rot, 1.0, bg, kernels=r.k))
        rad = t("shade.kernel", lambda: shade_points(n, wo, vi, ov, r.cuts, nl, nw, r.tree, table, r.k, node8=n8))
        vert[vi] = rad
        img = np.empty((len(v.tri), 3), np.float32)
        t("resolve", lambda: resolve(v.tri, v.uv, mesh.faces, vert, bg, 1, img, r.k))
        t("tonemap", lambda: tonemap(img.reshape(cam.height, cam.width, 3)))
        # whole frames: light and BRDF change (as glint bench render), then the BRDF alone
        m2 = [mat.model_copy(update={"albedo": (0.3, 0.2, 0.1 + 0.01 * i)})] * len(mats)
        out = t("frame.light+brdf", lambda: r.render(FrameRequest(camera=cam, lighting=Lighting(rot + 5.0),
                                                                  materials=m2)))
        for k, x in out.timings.items():
            stages.setdefault(k, []).append(x)
        m3 = [mat.model_copy(update={"albedo": (0.3, 0.2, 0.2 + 0.01 * i)})] * len(mats)
        t("frame.brdf", lambda: r.render(FrameRequest(camera=cam, lighting=Lighting(rot + 5.0), materials=m3)))
        t("frame.light+brdf+tonemap", lambda: tonemap(r.render(FrameRequest(
            camera=cam, lighting=Lighting(rot + 7.0), materials=m2)).radiance))
    res = {"wall_ms": {k: round(statistics.median(x), 3) for k, x in times.items()},
           "cpu_ms": {k: round(statistics.median(x), 3) for k, x in cpu.items()}}
    cs = r.cuts
    sizes = (cs.offsets[vi + 1] - cs.offsets[vi])
    res.update(scene=a.scene, model=a.model, reps=a.reps, visible_vertices=int(len(vi)),
               vertices=int(len(mesh.vertices)), cut_entries_visible=int(sizes.sum()),
               mean_cut_visible=float(sizes.mean()),
               renderer_stages_wall_ms={k: round(statistics.median(x), 3) for k, x in stages.items()})
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
