"""The car-paint benchmarks: ``glint paint bench`` (prefilter and frame times while the paint
and the light change) and ``glint paint bench-fit`` (fit time over the paint database), the
designer (worker/paint) and its renderer (worker/renderers/paint) measured from outside.

bench/cli.py adds them under ``glint paint`` (worker/paint/cli.py makes that command).
"""
from __future__ import annotations

import json
import time

import numpy as np

from worker.paint.cli import _render_args, _setup


def cmd_bench(a) -> int:
    """Median frame time while the paint changes (a fit per frame) and the light rotates, the
    camera fixed (the designer's loop); prefiltering of the scene's map timed cold."""
    from worker.paint.fit import fit_measurements
    from worker.paint.geometry import measure
    from worker.renderers import FrameRequest, Lighting
    from worker.renderers.paint.prefilter import prefilter_all
    scene, rnd, mats, stats = _setup(a, a.json)
    env = scene.spec.environment
    cam = scene.spec.camera
    t0, c0 = time.perf_counter(), time.process_time()
    prefilter_all(scene.envmap, rnd.exponents, rnd.k)
    ms_prefilter = 1e3 * (time.perf_counter() - t0)
    cpu_ms_prefilter = 1e3 * (time.process_time() - c0)
    t0 = time.perf_counter()
    rnd.render(FrameRequest(cam, Lighting(env.rotation_deg, env.intensity), mats))
    ms_first = 1e3 * (time.perf_counter() - t0)
    base = measure(mats[0])
    frames, fits, shades = [], [], []
    cpu0 = time.process_time()
    for k in range(a.frames):
        s = 1.0 + 0.3 * np.sin(k * 0.7)
        m = {"gloss": base["gloss"], "aspecular": {kk: [x * s for x in v] for kk, v in base["aspecular"].items()}}
        t0 = time.perf_counter()
        fr = fit_measurements(m, rnd.exponents)
        t1 = time.perf_counter()
        out = rnd.render(FrameRequest(cam, Lighting(env.rotation_deg + 3.0 * k, env.intensity),
                                      [fr.material] + mats[1:]))
        t2 = time.perf_counter()
        frames.append(t2 - t0); fits.append(t1 - t0); shades.append(out.timings["shade"])
    cpu_ms = 1e3 * (time.process_time() - cpu0) / a.frames
    ms = 1e3 * float(np.median(frames))
    res = {"scene": a.scene, "width": cam.width, "height": cam.height, "frames": a.frames,
           "lobes": len(rnd.exponents), "map": list(scene.envmap.shape[:2]),
           "ms_prefilter": ms_prefilter, "cpu_ms_prefilter": cpu_ms_prefilter, "ms_per_frame": ms, "fps": 1e3 / ms,
           "p95_ms": 1e3 * float(np.percentile(frames, 95)), "ms_fit": 1e3 * float(np.median(fits)),
           "ms_shade": float(np.median(shades)), "ms_first_frame_with_view": ms_first,
           # CPU time of all threads per frame: on a loaded machine, wall time measures the queue;
           # CPU time / cores bounds what 2 free cores would take
           "cpu_ms_per_frame": cpu_ms, "threads": _threads(),
           "visibility": bool(a.visibility), "fresnel": bool(a.fresnel), "cosine": a.cosine,
           "precompute": {"seconds": stats["seconds"], "computed": stats["computed"]}}
    if a.json:
        print(json.dumps(res))
    else:
        print(f"{ms:.2f} ms/frame ({1e3 / ms:.0f} fps) at {cam.width}×{cam.height}; prefilter {ms_prefilter:.0f} ms")
    return 0


def cmd_bench_fit(a) -> int:
    """Fit time over the database's measurements (or the held-out generated paints' readings,
    worker/paint/basis.py): the warm HiGHS instance against linprog."""
    from worker.paint.basis import default_exponents, held_out_cases
    from worker.paint.database import load_paints
    from worker.paint.fit import fit_measurements
    exps = default_exponents()
    meas = [p["measurements"] for p in load_paints()] if a.cases == "database" else list(held_out_cases())
    res = {"cases": a.cases, "paints": len(meas), "lobes": len(exps), "repeats": a.repeats}
    for solver in ("warm", "linprog"):
        fit_measurements(meas[0], exps, solver=solver)      # build once
        ts, errs = [], []
        for _ in range(a.repeats):
            for m in meas:
                t0 = time.perf_counter()
                r = fit_measurements(m, exps, solver=solver)
                ts.append(time.perf_counter() - t0)
                errs.append(r.error_l1)
        res[f"ms_{solver}_median"] = 1e3 * float(np.median(ts))
        res[f"ms_{solver}_p95"] = 1e3 * float(np.percentile(ts, 95))
        res[f"error_l1_{solver}_mean"] = float(np.mean(errs))
    if a.json:
        print(json.dumps(res))
    else:
        print(f"fit: warm {res['ms_warm_median']:.3f} ms median (p95 {res['ms_warm_p95']:.3f}), "
              f"linprog {res['ms_linprog_median']:.3f} ms")
    return 0


def _threads() -> int:
    from worker import native
    return native.max_threads()


def add_paint_commands(ps) -> None:
    """``bench-fit`` and ``bench`` into the subparsers of ``glint paint``."""
    bf = ps.add_parser("bench-fit", help="fit time over the database (warm HiGHS vs linprog)")
    bf.add_argument("--repeats", type=int, default=5); bf.add_argument("--json", action="store_true")
    bf.add_argument("--cases", choices=["database", "held-out"], default="database",
                    help="the database's 30 paints or the held-out generated paints (worker/paint/basis.py)")
    bf.set_defaults(fn=cmd_bench_fit)

    b = ps.add_parser("bench", help="prefilter and frame times (--json)")
    _render_args(b)
    b.add_argument("--frames", type=int, default=60); b.add_argument("--json", action="store_true")
    b.set_defaults(fn=cmd_bench)
