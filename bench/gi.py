"""``glint gi bench``: freeze time and frame rate of the GI renderer while one object's BRDF
changes every frame. Registered under ``glint gi`` by bench/cli.py; the renderer's own commands
(precompute, render) are worker/renderers/gi/cli.py's."""
from __future__ import annotations

import json
import time


def sweep(r, u: int, i: int):
    """The i-th material of the benchmark's edit of unit u: roughness and colour sweep."""
    from worker.scene import GGX
    m = r.materials[u]
    if getattr(m, "model", None) == "ashikhmin-shirley":
        return m.model_copy(update={"exponent_v": m.exponent_u * (0.1 + 3.0 * ((i * 0.37) % 1.0))})
    return GGX(alpha=0.05 + 0.3 * ((i * 0.37) % 1.0), specular=(0.6, 0.5, 0.4), albedo=(0.3, 0.2 + 0.1 * (i % 3), 0.1))


def cmd_gi_bench(a) -> int:
    """Freeze time and frame rate while one object's (or region's) BRDF changes every frame
    (polynomial-gi §5: freezing the other units, then one dot product per pixel a frame)."""
    import numpy as np

    from worker import native
    from worker.core.tonemap import tonemap
    from worker.renderers.gi.cli import open_renderer

    r = open_renderer(a, a.json)
    u = r.layout.index(a.object)
    other = next((k for k in range(r.U) if k != u), None)
    r.prune = a.prune
    r.draw()                                       # warm-up; a unit is live
    # wall-clock and process CPU times: on a loaded machine the CPU time (all threads) is the
    # better measure of the work; with one thread it is the time on a quiet core
    t_freeze, c_freeze = [], []
    for _ in range(max(1, a.repeat)):
        if other is not None:
            r.freeze(other)
        c0 = time.process_time()
        t_freeze.append(r.freeze(u))
        c_freeze.append(time.process_time() - c0)
    frames, cpu, proj, dots, tm = [], [], [], [], []
    for i in range(a.frames + 2):
        r.set_unit_material(u, sweep(r, u, i))
        t0, c0 = time.perf_counter(), time.process_time()
        img = r.draw()
        t1, c1 = time.perf_counter(), time.process_time()
        tonemap(img, kernels=r.k)
        t2 = time.perf_counter()
        if i >= 2:                                 # warm-up frames
            frames.append(t1 - t0); cpu.append(c1 - c0); tm.append(t2 - t1)
            proj.append(r.last_timings["project"]); dots.append(r.last_timings["frame"])
        assert "freeze" not in r.last_timings, "a frame re-froze"
    ms = float(np.median(frames) * 1000)
    pruned = r.last_pruned
    prune_err = None
    if a.prune > 0:
        # the pruned frame against the unpruned one at another material of the edited object,
        # relative RMSE over its pixels: the cost of the entries folded into V at the freeze-time
        # material
        on = r.prim.pixel[r.frozen.live]
        r.set_unit_material(u, sweep(r, u, a.frames + 7))
        got = r.draw().reshape(-1, 3)[on].astype(np.float64)
        r.prune = 0.0
        r.freeze(u)
        ref = r.draw().reshape(-1, 3)[on].astype(np.float64)
        prune_err = float(np.sqrt(np.mean((got - ref) ** 2)) / max(np.sqrt(np.mean(ref ** 2)), 1e-30))
        r.prune = a.prune
        r.freeze(u)
    cam = r.scene.spec.camera
    fz = r.frozen
    res = {"ms_freeze": float(np.median(t_freeze) * 1000), "ms_per_frame": ms, "fps": 1000.0 / ms,
           "cpu_ms_freeze": float(np.median(c_freeze) * 1000), "cpu_ms_per_frame": float(np.median(cpu) * 1000),
           "p95_ms": float(np.percentile(frames, 95) * 1000), "ms_project": float(np.median(proj)),
           "ms_dot": float(np.median(dots)), "ms_tonemap": float(np.median(tm) * 1000), "frames": a.frames,
           "width": cam.width, "height": cam.height, "object": a.object, "pixels": int(len(r.prim.pixel)),
           "live_pixels": int(len(fz.live)), "live_values": fz.live_values, "live_layout": "dense" if fz.dense is not None else "sparse",
           "live_powers": fz.NPe, "frozen_bytes": int(fz.nbytes),
           "tensor_bytes": r.data.nbytes, "series": list(r.opts.series), "bounces": r.N, "spp": r.opts.spp,
           "native": r.k.name == "native", "threads": native.max_threads(),
           "prune": a.prune, "pruned_fraction": pruned, "prune_rel_rmse": prune_err}
    print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items()))
    return 0


def add_gi_commands(gsub) -> None:
    """``bench`` into the subparsers of ``glint gi``."""
    from worker.renderers.gi.cli import gi_options

    b = gsub.add_parser("bench", help="freeze time and frame rate while one object's BRDF changes every frame")
    gi_options(b)
    b.add_argument("--object", required=True, help="the edited object (or region)")
    b.add_argument("--frames", type=int, default=30)
    b.add_argument("--repeat", type=int, default=3, help="freezes timed (median)")
    b.add_argument("--prune", type=float, default=0.0,
                   help="drop live entries below this fraction of their row's magnitude at freezing, "
                        "folded into the frozen part (e.g. 0.005); 0 keeps every entry")
    b.add_argument("--json", action="store_true")
    b.set_defaults(fn=cmd_gi_bench)
