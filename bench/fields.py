"""Benchmarks of the visibility cut fields of movable objects (cyber-worlds §V):

    glint field bench MESH [--receivers N] [--frames F] [--hmin H] [--out DIR] [--json]
    glint bench move SCENE --object NAME [--frames N] [--cuts DIR] [--json]

``field bench`` times the per-frame cut product of a field with receivers around its object;
``bench move`` renders a scene while one of its movable objects slides, then turns, at full
quality and at the drag level of detail (cut renderer, vertex shading, camera and light fixed).
Registered by bench/cli.py; the field's own command (``glint field trace``) is
worker/renderers/cuts/fields_cli.py's.
"""
from __future__ import annotations

import json
import os
import time


def cmd_field_bench(a) -> int:
    """Shades nothing: times ``Combiner.combine`` for N floor vertices around the object (a square
    grid at its base, normals up, base cuts = unoccluded cosine), first while the object slides
    2 % of its radius per frame, then while it turns 3° per frame; medians of F frames each, wall
    and process CPU time (on a loaded machine, CPU / threads is the better guess of quiet wall
    time)."""
    import numpy as np

    from worker.core.cuts import build_cuts
    from worker.core.directions import get_tree
    from worker.renderers.cuts.combine import DEFAULT_HMIN, Combiner
    from worker.renderers.cuts.fields_cli import traced_field

    f, st, mesh = traced_field(a)
    tree = get_tree()
    c, r = f.grid.center, f.grid.radius
    side = int(np.ceil(np.sqrt(a.receivers)))
    g = np.linspace(-2.8 * r, 2.8 * r, side)
    X, Z = np.meshgrid(g, g)
    x = np.stack([c[0] + X.ravel(), np.full(X.size, float(mesh.vertices[:, 1].min())), c[2] + Z.ravel()], 1)
    x = x[:a.receivers].astype(np.float32)
    nrm = np.tile(np.float32([0, 1, 0]), (len(x), 1))
    base = build_cuts(np.maximum(nrm[:1] @ tree.leaves.T, 0).astype(np.float32), 1.0)
    ids = np.zeros(len(x), np.int32)
    hmin = DEFAULT_HMIN if a.hmin is None else a.hmin
    cb = Combiner(hmin)

    def frame(k, turning):
        yaw = np.radians(30.0 + (3.0 * k if turning else 0.0))
        m = np.eye(4)
        m[:3, :3] = [[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]]
        m[:3, 3] = [0.02 * r * k, 0.0, 0.0]
        m[:3, 3] += c - m[:3, :3] @ c                       # turn about the object's centre
        t0, c0 = time.perf_counter(), time.process_time()
        cb.combine(base, ids, x, nrm, [(f, m)])
        return {"ms": 1e3 * (time.perf_counter() - t0), "cpu_ms": 1e3 * (time.process_time() - c0), **cb.last_stats}

    frame(0, False)                                          # warm-up: rotates every sample it needs
    out = {"receivers": len(x), "hmin": hmin, "grid": f.grid.spec.tag(), "field": st["path"]}
    for name, turning in (("translate", False), ("rotate", True)):
        rows = [frame(k + 1, turning) for k in range(a.frames)]
        med = {k: float(np.median([r_[k] for r_ in rows])) for k in rows[0] if isinstance(rows[0][k], (int, float))}
        out[name] = {"ms_per_frame": med["ms"], "cpu_ms_per_frame": med["cpu_ms"],
                     "ms_lookup": med["ms_lookup"], "ms_rotate_and_cells": med["ms_rotate_and_cells"],
                     "ms_product": med["ms_product"], "samples_rotated": med["samples_rotated"],
                     "cells_merged": med["cells_merged"], "segments_traced": med["segments_traced"],
                     "receivers_affected": med["receivers_affected"], "mean_cut_in": med["mean_cut_in"],
                     "mean_cut_out": med["mean_cut_out"]}
    out["threads"] = int(os.environ.get("GLINT_THREADS", "0") or 0) or 2
    if a.json:
        print(json.dumps(out))
    else:
        for name in ("translate", "rotate"):
            o = out[name]
            print(f"{name}: {o['ms_per_frame']:.1f} ms/frame (cpu {o['cpu_ms_per_frame']:.1f} ms) for {out['receivers']} "
                  f"receivers, {o['samples_rotated']:.0f} samples rotated, cut {o['mean_cut_in']:.0f} → {o['mean_cut_out']:.0f}")
    return 0


def move_path(transform, radius: float, k: int, turning: bool):
    """The object's transform at frame k of a gesture: it slides back and forth along x by 5% of
    its bounding radius per frame (a drag at about 1 m/s at 30 fps for a chair), and, when
    turning, also turns 3° per frame about +Y."""
    from worker.scene import Transform

    phase = k % 40
    dx = 0.05 * radius * (phase if phase < 20 else 40 - phase)
    t = tuple(float(x) for x in transform.translate)
    r = tuple(float(x) for x in transform.rotate_deg)
    return Transform(scale=transform.scale, translate=(t[0] + dx, t[1], t[2]),
                     rotate_deg=(r[0], r[1] + (3.0 * k if turning else 0.0), r[2]))


def cmd_bench_move(a) -> int:
    """Median frame time (render + tone mapping; wall and the process's CPU) of a movable object's
    gestures, at full quality and at the drag level of detail, after warm-up frames at the object's place (primary hits of
    the static geometry, the static radiance, the first rotated samples: what the frame before
    a drag already paid)."""
    import numpy as np

    from worker import cli, native
    from worker.core.tonemap import tonemap
    from worker.errors import GlintError
    from worker.renderers import FrameRequest, Lighting
    from worker.renderers.cuts.field import bounding_sphere
    from worker.renderers.cuts.fields import object_shape

    scene = cli._load(a.scene)
    names = [o.name for o in scene.spec.objects]
    if a.object not in names:
        raise GlintError(f"--object: no object {a.object!r} (objects: {', '.join(names)})")
    obj = scene.spec.objects[names.index(a.object)]
    if not obj.movable:
        raise GlintError(f"--object: {a.object!r} is not movable (mark it \"movable\": true in the scene file)")
    r, ens = cli.open_renderer(scene, a.cuts, a.json, cli.scene_options(scene, a.tau))
    if a.frames < 1:
        raise GlintError("--frames: give at least 1")
    sh = object_shape(scene, names.index(a.object))
    _, rad = bounding_sphere(sh.vertices)
    rad *= float(np.cbrt(np.linalg.det(sh.world_from_local[:3, :3])))
    spec = scene.spec
    light = Lighting(spec.environment.rotation_deg, spec.environment.intensity)

    cpu: list[float] = []             # the process's CPU time of each frame of the current gesture

    def frame(tr, lod):
        t0, c0 = time.perf_counter(), time.process_time()
        out = r.render(FrameRequest(camera=spec.camera, lighting=light, materials=scene.materials, lod=lod,
                                    transforms={a.object: tr}))
        tonemap(out.radiance, kernels=r.k)
        cpu.append(time.process_time() - c0)
        return time.perf_counter() - t0, out

    res = {"scene": a.scene, "object": a.object, "frames": a.frames, "width": spec.camera.width,
           "height": spec.camera.height, "vertices": len(scene.mesh.vertices), "native": r.k.name == "native",
           "threads": native.max_threads(), "precomputed_parts": ens["computed"]}
    for lod in ("full", "drag"):
        for _ in range(2):
            frame(obj.transform, lod)
        for gesture, turning in (("slide", False), ("turn", True)):
            times, stats, parts = [], [], []
            cpu.clear()
            for k in range(1, a.frames + 1):
                dt, out = frame(move_path(obj.transform, rad, k, turning), lod)
                times.append(dt)
                stats.append(out.info.get("moving", {}))
                parts.append(out.timings)
            ms = float(np.median(times) * 1e3)
            # the process's CPU time (every thread's) beside the wall time: on a shared machine
            # CPU / threads bounds what a quiet machine would take
            row = {"ms_per_frame": ms, "fps": 1e3 / ms, "p95_ms": float(np.percentile(times, 95) * 1e3),
                   "cpu_ms_per_frame": float(np.median(cpu) * 1e3),
                   "width": out.info["width"], "height": out.info["height"], "hmin": out.info.get("hmin"),
                   "stages_ms": {k: float(np.median([p.get(k, 0.0) for p in parts])) for k in parts[0]},
                   **{k: float(np.median([s_.get(k, 0) for s_ in stats])) for k in stats[0]}}
            res[f"{lod}_{gesture}"] = row
        sfx = "" if lod == "full" else "_drag"
        res[f"ms_per_frame{sfx}"] = res[f"{lod}_slide"]["ms_per_frame"]
        res[f"fps{sfx}"] = res[f"{lod}_slide"]["fps"]
        res[f"ms_per_frame_turn{sfx}"] = res[f"{lod}_turn"]["ms_per_frame"]
        res[f"fps_turn{sfx}"] = res[f"{lod}_turn"]["fps"]
    res["width_drag"], res["height_drag"] = res["drag_slide"]["width"], res["drag_slide"]["height"]
    if a.json:
        print(json.dumps(res))
    else:
        for k in ("full_slide", "full_turn", "drag_slide", "drag_turn"):
            o = res[k]
            print(f"{k}: {o['ms_per_frame']:.1f} ms/frame ({o['fps']:.1f} fps; CPU {o['cpu_ms_per_frame']:.1f} ms) "
                  f"at {o['width']}×{o['height']}")
    return 0


def add_field_commands(fsub) -> None:
    """``bench`` into the subparsers of ``glint field``."""
    from worker.renderers.cuts.fields_cli import grid_options

    b = fsub.add_parser("bench", help="per-frame cost of combining floor cuts with the field")
    grid_options(b)
    b.add_argument("--receivers", type=int, default=10000)
    b.add_argument("--frames", type=int, default=10)
    b.add_argument("--hmin", type=int, default=None, help="field cut coarseness: field cut nodes of ≥ 2^HMIN leaves (default 5)")
    b.set_defaults(fn=cmd_field_bench)


def add_bench_commands(bsub) -> None:
    """``move`` into the subparsers of ``glint bench``."""
    from worker.core.cuts import DEFAULT_TAU

    b = bsub.add_parser("move", help="frame time while a movable object slides and turns (visibility cut fields)")
    b.add_argument("scene")
    b.add_argument("--object", required=True, help="a movable object of the scene")
    b.add_argument("--frames", type=int, default=30, help="frames per measured gesture (default 30)")
    b.add_argument("--cuts", help="cut cache folder (default: the data directory)")
    b.add_argument("--tau", type=float, default=DEFAULT_TAU)
    b.add_argument("--json", action="store_true")
    b.set_defaults(fn=cmd_bench_move)
