"""The benchmarks of the ``glint`` command line: ``glint bench render | accuracy | fit | stream |
load | publish | viewer | move | recovery | strokes | export-recovery``, ``glint field bench``,
``glint gi bench``, ``glint paint bench | bench-fit`` and ``glint bench-ray``. They live outside the runtime packages (worker/, server/): a benchmark
measures the library or the running service from outside, as a user would, and ships with
neither. ``glint bench stream`` and ``load`` start ``glint serve`` as a child process (or use a
server already running), so this package imports no server module either.

glint/cli.py registers them: ``add_bench_commands`` under ``glint bench`` (before the
capabilities' commands), ``add_commands`` for the top-level ones and those under a
capability's command.
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path


def cmd_bench_render(a) -> int:
    """Frame time while the light and the BRDF change every frame, at full quality (the
    precomputed τ, full resolution, one sample), as the studio draws while something changes
    (``_quick``: one sample, interpolated, clusters no finer than the drag level's), at the drag
    level of detail, and as the studio's settled frames (jobs/lod.py STILL_SAMPLES at edges and
    curved highlights: ``_aa16``), after two warm-up frames (hit buffer, lighting matrices) that a
    user's first frame pays once."""
    import numpy as np

    from worker import native
    from worker.cli import _frame, _renderer
    from worker.core.tonemap import tonemap
    from worker.scene import GGX

    r, _ = _renderer(a, quiet=a.json)
    cam = r.scene.spec.camera
    mode = "pixel" if a.per_pixel else a.shading
    n = len(r.scene.materials)
    res = {"frames": a.frames, "width": cam.width, "height": cam.height, "mode": mode,
           "vertices": int(len(r.scene.mesh.vertices)), "native": native.available(), "threads": native.max_threads(),
           "simd": bool(r.k.simd()) if hasattr(r.k, "simd") else False,
           "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY")}
    from worker.jobs.lod import STILL_ANTIALIAS, STILL_SAMPLES

    for lod, samples in (("full", 1), ("quick", 1), ("drag", 1), ("full", STILL_SAMPLES)):
        aa = STILL_ANTIALIAS if samples > 1 else "full"
        for _ in range(2):  # warm-up: hit buffer, lighting matrices, caches
            tonemap(_frame(r, shading=mode, lod=lod, samples=samples, antialias=aa).radiance)
        times = []
        for i in range(a.frames):
            rot = (i * 360.0 / max(a.frames, 1)) % 360.0
            # the BRDF changes every frame: a GGX whose roughness and colour sweep
            mats = [GGX(alpha=0.1 + 0.3 * ((i * 0.37) % 1.0), specular=(0.9, 0.8, 0.6),
                        albedo=(0.3, 0.2 + 0.1 * (i % 3), 0.1)) for _ in range(n)]
            t0 = time.perf_counter()
            out = _frame(r, mats, mode, rot, lod=lod, samples=samples, antialias=aa)
            tonemap(out.radiance)
            times.append(time.perf_counter() - t0)
        ms = float(np.median(times) * 1000)
        sfx = f"_aa{samples}" if samples > 1 else ("" if lod == "full" else f"_{lod}")
        res.update({f"ms_per_frame{sfx}": ms, f"fps{sfx}": 1000.0 / ms, f"p95_ms{sfx}": float(np.percentile(times, 95) * 1000)})
        if lod == "drag":
            res.update(width_drag=out.info["width"], height_drag=out.info["height"], tau_drag=out.info["tau"])
        elif samples == 1 and lod == "full":
            res.update(visible_vertices=out.info.get("visible_vertices"), tau=out.info["tau"],
                       refined_samples=out.info.get("refined_samples", 0))
        if mode == "pixel":
            break
    res["mean_cut_size"] = float(r.cuts.sizes().mean())
    print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items()))
    return 0


def cmd_bench_antialias(a) -> int:
    from .antialias import bench_antialias

    res = bench_antialias(a.scene, views=a.views, width=a.width, height=a.height, alpha=a.alpha, cuts=a.cuts)
    print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items()))
    return 0


def cmd_bench_accuracy(a) -> int:
    """Relative RMSE against Mitsuba 3 (scalar_rgb, direct, box pixel filter; the mean of two
    renders) over the object's pixels at least 2 pixels from silhouettes, per shading mode and
    GGX α (albedo 0.1, specular 0.8), with the reference's own noise and each mode's frame time
    (after a warm-up frame; light and BRDF fixed, so the view's refinement candidates are
    cached). Glint renders with ``samples`` per pixel where ``antialias`` puts them (default the
    studio's settled frame: STILL_SAMPLES at edges and curved highlights), since a reference
    pixel is the mean over its area: one sample against it counts the aliasing of fine detail as
    error."""
    import numpy as np
    from scipy.ndimage import binary_erosion

    from worker.cli import _renderer
    from worker.fit.recovery import mitsuba_target
    from worker.renderers import FrameRequest
    from worker.scene import GGX, LoadedScene

    r, _ = _renderer(a, quiet=a.json)
    rows = []
    for alpha in [float(x) for x in a.alphas.split(",")]:
        mat = GGX(alpha=alpha, albedo=(0.1, 0.1, 0.1), specular=(0.8, 0.8, 0.8))
        spec = r.scene.spec.model_copy(deep=True)
        for o in spec.objects:
            o.material = mat
        sc = LoadedScene(spec, r.scene.root, envmap=r.scene.envmap)
        ref, imgs = mitsuba_target(sc, a.spp, (1, 2), a.cache)
        row = {"alpha": alpha}
        for mode in ("vertex", "refined", "pixel"):
            req = FrameRequest(camera=spec.camera, materials=[mat] * len(spec.objects), shading=mode,
                               samples=a.samples, antialias=a.antialias)
            r.render(req)
            t0 = time.perf_counter()
            out = r.render(req)
            ms = (time.perf_counter() - t0) * 1000
            inner = binary_erosion(out.object_id >= 0, iterations=2)
            norm = float(np.sqrt((ref[inner].astype(np.float64) ** 2).mean()))
            row[f"rel_{mode}"] = float(np.sqrt(((out.radiance[inner] - ref[inner]) ** 2).mean()) / norm)
            row[f"ms_{mode}"] = ms
            if mode == "refined":
                row["refined_fraction"] = out.info["refined_samples"] / max(int((out.object_id >= 0).sum()), 1)
        row["noise"] = float(0.5 * np.sqrt(((imgs[0] - imgs[1])[inner] ** 2).mean()) / norm)
        row["refined_over_pixel"] = row["rel_refined"] / row["rel_pixel"]
        rows.append(row)
        if not a.json:
            print(" ".join(f"{k}={v:.4g}" for k, v in row.items()), flush=True)
    res = {"scene": a.scene, "width": r.scene.spec.camera.width, "height": r.scene.spec.camera.height,
           "vertices": int(len(r.scene.mesh.vertices)), "spp": a.spp, "samples": a.samples,
           "antialias": a.antialias, "rows": rows}
    if a.json:
        print(json.dumps(res))
    return 0


def cmd_bench_fit(a) -> int:
    import numpy as np

    from worker.cli import _fitter, _renderer
    from worker.fit.brush import Stroke

    r, _ = _renderer(a, quiet=a.json)
    if a.object is None:
        a.object = r.scene.spec.objects[0].name
    fx = _fitter(r, a)
    t_tr = []
    for _ in range(a.repeat):
        fx.views.clear()
        t0 = time.perf_counter()
        fx.add_view()
        t_tr.append(time.perf_counter() - t0)
    v = fx.views[0]
    # a white stroke across the middle of the object, twice as bright as its brightest pixel
    ys = v.xy[:, 1]
    mid = np.abs(ys - np.median(ys)) < v.footprint * 2
    xs = np.sort(v.xy[mid, 0])
    y0 = float(np.median(ys))
    c = float(v.base.max()) * 2.0
    fx.add_stroke(Stroke(points=[(float(xs[len(xs) // 4]), y0), (float(xs[len(xs) // 2]), y0)],
                         color=(c, c, c), diameter=6 * v.footprint, kappa=0.05))
    cold, warm = [], []
    for _ in range(a.repeat):
        fx._last = None
        cold.append(fx.fit().solve.seconds)
        warm.append(fx.fit().solve.seconds)
    res = {"ms_transfer": float(np.median(t_tr) * 1000), "ms_solve": float(np.median(cold) * 1000),
           "ms_solve_warm": float(np.median(warm) * 1000), "pixels": v.n, "basis": fx.basis.J,
           "energy_rows": len(fx.basis.energy_rows()), "fit_width": v.size[0], "fit_height": v.size[1],
           "repeat": a.repeat, "object": a.object}
    print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items()))
    return 0


def cmd_bench_stream(a) -> int:
    from .stream import bench_stream

    res = bench_stream(port=a.port, data_dir=a.data_dir, strokes=a.strokes, orbit_seconds=a.orbit_seconds,
                       quiet=a.json)
    print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items()))
    return 0


def cmd_bench_load(a) -> int:
    from .stream import bench_load

    res = bench_load(sessions=a.sessions, seconds=a.seconds, runs=a.runs, port=a.port, data_dir=a.data_dir,
                     quiet=a.json, workers=a.workers)
    print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items() if k != "runs"))
    return 0


def cmd_bench_publish(a) -> int:
    from .publish import bench_publish, frame_cost

    if a.in_process:
        res = frame_cost(a.scene, cameras=a.cameras, width=a.width, height=a.height, samples=a.samples,
                         shading=a.shading, antialias=a.antialias, **({"env2": Path(a.env2)} if a.env2 else {}))
        print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items()))
        return 0
    res = bench_publish(azimuths=a.azimuths, elevations=a.elevations, width=a.width, height=a.height, port=a.port,
                        data_dir=a.data_dir, workers=a.workers, scene=a.scene, quiet=a.json, env2=a.env2,
                        samples=a.samples, antialias=a.antialias)
    print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items()))
    return 0


def cmd_bench_viewer(a) -> int:
    from .publish import bench_viewer, bench_viewer_static

    if a.static:
        if not (a.publication and a.data_dir):
            raise SystemExit("--static needs --publication and --data-dir (a bundle built by glint bench publish --data-dir D, which prints its publication)")
        res = bench_viewer_static(a.publication, a.data_dir, clients=a.clients,
                                  rates=[int(x) for x in a.rates.split(",")], nice=a.client_nice, quiet=a.json,
                                  visit_s=a.visit)
        print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items() if k != "runs"))
        return 0

    res = bench_viewer(clients=a.clients, frames=a.frames, interval=a.interval, ramp=a.ramp, runs=a.runs,
                       port=a.port, publication=a.publication, data_dir=a.data_dir, browser=not a.no_browser,
                       quiet=a.json, azimuths=a.azimuths)
    print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items() if k != "runs"))
    return 0


def cmd_bench_first_start(a) -> int:
    from .first_start import bench_first_start

    res = bench_first_start(data_dir=a.data_dir, timeout=a.timeout, quiet=a.json)
    print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items()))
    return 0


def add_bench_commands(bsub) -> None:
    """``glint bench render | fit | stream | load | publish | viewer | first-start`` into the subparsers of
    ``glint bench``."""
    from worker.cli import fit_options
    from worker.core.cuts import DEFAULT_TAU
    from worker.jobs.lod import STILL_SAMPLES

    br = bsub.add_parser("render", help="frame time while light and BRDF change")
    br.add_argument("scene"); br.add_argument("--frames", type=int, default=60); br.add_argument("--json", action="store_true")
    br.add_argument("--per-pixel", action="store_true", help="the same as --shading pixel")
    br.add_argument("--shading", choices=("vertex", "refined", "pixel"), default="refined",
                    help="refined (default: vertex shading, per pixel where its interpolation is wrong), "
                         "vertex (the interpolation alone), pixel")
    br.add_argument("--cuts"); br.add_argument("--tau", type=float, default=DEFAULT_TAU)
    br.set_defaults(fn=cmd_bench_render)
    ba = bsub.add_parser("accuracy", help="relative RMSE of each shading mode against Mitsuba 3 (GGX α list)")
    ba.add_argument("scene"); ba.add_argument("--alphas", default="0.05,0.1,0.15,0.25,0.4")
    ba.add_argument("--spp", type=int, default=256, help="Mitsuba samples per pixel of each of its two renders")
    ba.add_argument("--cache", default="tests/.cache/mitsuba", help="where Mitsuba's renders are kept by content")
    ba.add_argument("--cuts"); ba.add_argument("--tau", type=float, default=DEFAULT_TAU)
    ba.add_argument("--samples", type=int, default=STILL_SAMPLES,
                    help=f"Glint's samples per pixel (default {STILL_SAMPLES}, the studio's settled frame: Mitsuba's "
                         "pixels are box-filtered means too)")
    ba.add_argument("--antialias", choices=["edges", "full"], default="edges")
    ba.add_argument("--json", action="store_true")
    ba.set_defaults(fn=cmd_bench_accuracy)
    bq = bsub.add_parser("antialias", help="each sampling (1, 4 everywhere, 4 at edges) against 16 samples, and its CPU")
    bq.add_argument("scene"); bq.add_argument("--views", type=int, default=3)
    bq.add_argument("--width", type=int, default=1280); bq.add_argument("--height", type=int, default=960)
    bq.add_argument("--alpha", type=float, default=0.1); bq.add_argument("--json", action="store_true")
    bq.add_argument("--cuts", help="cut cache folder (default: the scene's)")
    bq.set_defaults(fn=cmd_bench_antialias)
    bf = bsub.add_parser("fit", help="transfer-matrix and solve times at the default sizes")
    bf.add_argument("scene"); bf.add_argument("--object", help="default: the first object")
    bf.add_argument("--repeat", type=int, default=7); bf.add_argument("--json", action="store_true")
    fit_options(bf)
    bf.set_defaults(fn=cmd_bench_fit)

    bs = bsub.add_parser("stream", help="stroke-to-frame latency and orbit fps over a real WebSocket")
    bs.add_argument("--port", type=int, help="use the server already on this loopback port (default: start one)")
    bs.add_argument("--data-dir", help="data directory of the server this starts (default: a temporary copy of nothing; the demo scene is fetched)")
    bs.add_argument("--strokes", type=int, default=20); bs.add_argument("--orbit-seconds", type=float, default=5.0)
    bs.add_argument("--json", action="store_true")
    bs.set_defaults(fn=cmd_bench_stream)
    bl = bsub.add_parser("load", help="N concurrent editing sessions (orbit at 30 Hz, a stroke every 3 s)")
    bl.add_argument("--sessions", type=int, default=8); bl.add_argument("--seconds", type=float, default=20.0)
    bl.add_argument("--runs", type=int, default=2, help="identical runs in a row (memory must stay flat)")
    bl.add_argument("--port", type=int); bl.add_argument("--data-dir"); bl.add_argument("--workers", type=int)
    bl.add_argument("--json", action="store_true")
    bl.set_defaults(fn=cmd_bench_load)
    bp = bsub.add_parser("publish", help="build a static bundle (2 variants × 2 environments), then rebuild after one change")
    bp.add_argument("--azimuths", type=int, default=72); bp.add_argument("--elevations", type=int, default=2)
    bp.add_argument("--width", type=int, default=640); bp.add_argument("--height", type=int, default=480)
    bp.add_argument("--scene", help="scene file (default: tests/scenes/bunny-ground.json)")
    bp.add_argument("--env2", help="the second environment map (default: tests/.cache/assets/env/sunset.exr)")
    bp.add_argument("--port", type=int); bp.add_argument("--data-dir"); bp.add_argument("--workers", type=int)
    bp.add_argument("--in-process", action="store_true",
                    help="only the CPU cost per view of the frames job, in this process (no service)")
    bp.add_argument("--cameras", type=int, default=4, help="with --in-process: cameras (4 views each) measured")
    bp.add_argument("--samples", type=int, help="samples per pixel of the 2× frames (default: the service's)")
    bp.add_argument("--shading", choices=["vertex", "refined"], help="with --in-process (default: the service's)")
    bp.add_argument("--antialias", choices=["edges", "full"], help="where the 2× frames' samples go (default: the service's)")
    bp.add_argument("--json", action="store_true")
    bp.set_defaults(fn=cmd_bench_publish)
    bv = bsub.add_parser("viewer", help="N concurrent shoppers opening and turning a published object (loopback)")
    bv.add_argument("--clients", type=int, default=1000); bv.add_argument("--frames", type=int, default=24)
    bv.add_argument("--interval", type=float, default=1.0, help="mean seconds between a shopper's frame requests")
    bv.add_argument("--ramp", type=float, default=2.0, help="seconds over which the shoppers arrive")
    bv.add_argument("--runs", type=int, default=2, help="identical runs in a row (memory must stay flat)")
    bv.add_argument("--port", type=int); bv.add_argument("--publication", help="a publication on --port (default: build one)")
    bv.add_argument("--azimuths", type=int, default=72, help="of the bundle built here")
    bv.add_argument("--data-dir"); bv.add_argument("--no-browser", action="store_true", help="skip the first-image measurement")
    bv.add_argument("--static", action="store_true",
                    help="through nginx in front of the service, real shoppers' requests (recorded from Chromium) "
                         "replayed by h2load (bench/static.py)")
    bv.add_argument("--rates", default="25,50,100,200", help="with --static: shoppers arriving per second, one run each")
    bv.add_argument("--client-nice", type=int, default=5, help="with --static: the load generator's nice level")
    bv.add_argument("--visit", type=float, default=0.0,
                    help="with --static: seconds each shopper stays on the page (connected; the variant switch at the "
                         "end), so rate × visit shoppers are connected at once; 0: back to back")
    bv.add_argument("--json", action="store_true")
    bv.set_defaults(fn=cmd_bench_viewer)
    bfs = bsub.add_parser("first-start", help="a fresh `glint serve` and the studio in Chromium: seconds to the "
                                               "first look, the first frame and the settled one")
    bfs.add_argument("--data-dir", help="the server's data folder (default: a new empty one, removed after)")
    bfs.add_argument("--timeout", type=float, default=900.0); bfs.add_argument("--json", action="store_true")
    bfs.set_defaults(fn=cmd_bench_first_start)


def add_commands(sub) -> None:
    """Into the subparsers of ``glint`` (after worker's commands): the top-level benchmark
    commands (``glint bench-ray``), the fitter's benchmarks under ``glint bench`` (``recovery``,
    ``strokes``: bench/fitting.py), the moving objects' (``glint bench move``, ``glint field
    bench``: bench/fields.py), the GI renderer's (``glint gi bench``: bench/gi.py) and the
    car-paint ones under ``glint paint`` (``bench-fit``, ``bench``: bench/paint.py)."""
    from .exporting import add_bench_commands as add_exporting
    from .fields import add_bench_commands as add_move
    from .fields import add_field_commands
    from .fitting import add_bench_commands as add_fitting
    from .gi import add_gi_commands
    from .paint import add_paint_commands
    from .ray_precompute import add_commands as add_ray

    add_ray(sub)
    add_move(_subparsers(sub.choices["bench"]))
    add_fitting(_subparsers(sub.choices["bench"]))
    add_exporting(_subparsers(sub.choices["bench"]))
    add_field_commands(_subparsers(sub.choices["field"]))
    add_gi_commands(_subparsers(sub.choices["gi"]))
    add_paint_commands(_subparsers(sub.choices["paint"]))


def _subparsers(parser):
    """The subparsers of a command made by worker/cli.py (e.g. ``glint bench``)."""
    import argparse

    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
