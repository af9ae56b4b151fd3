"""Paint-to-BRDF benchmarks on the command line: ``glint bench recovery`` and ``glint bench strokes``
(worker/fit measured from outside).

Registered by bench/cli.py ``add_bench_commands``; both print one JSON object with ``--json``
(progress on stderr).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def _floats(text: str) -> list[float]:
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def add_bench_commands(bsub) -> None:
    """``glint bench recovery | strokes`` into the subparsers of ``glint bench``."""
    r = bsub.add_parser("recovery", help="fit srbf to Mitsuba renders of GGX materials and re-render")
    r.add_argument("scenes", nargs="+", help="scene files: mesh, camera and object (material and map are replaced)")
    r.add_argument("--env", action="append", required=True, help="environment map (repeatable)")
    r.add_argument("--alpha", type=_floats, default=None, help="GGX α values (default 0.05,0.1,0.15,0.25,0.4)")
    r.add_argument("--finish", choices=["bare", "coated", "both"], default="both",
                   help="bare: specular 0.95, no diffuse; coated: specular 0.5 over diffuse (0.45, 0.3, 0.2)")
    r.add_argument("--spp", type=int, default=128, help="Mitsuba samples per pixel per seed (two seeds)")
    r.add_argument("--fit-scale", type=float, default=1.0,
                   help="fit resolution / view resolution (default 1: every pixel of the target)")
    r.add_argument("--static", choices=["smith", "paper"], default="smith",
                   help="smith: the default model; paper: inverse-brdf-modeling's basis and static function")
    r.add_argument("--no-auto-static", action="store_true", help="keep the smith static's roughness fixed")
    r.add_argument("--cache", help="folder for Mitsuba targets (default $GLINT_DATA_DIR/mitsuba)")
    r.add_argument("--cuts", help="cut cache folder"); r.add_argument("--tau", type=float, default=1.0)
    r.add_argument("--images", help="write target | fit | Glint GGX PNGs per case to this folder")
    r.add_argument("--json", action="store_true")
    r.set_defaults(fn=cmd_bench_recovery)

    s = bsub.add_parser("strokes", help="share of the requested change achieved and spill, per stroke and weight")
    s.add_argument("scenes", nargs="+", help="scene files (first editable object is painted; its material is the "
                                             "base); a GI scene (\"renderer\": \"gi\") is painted through its tensors")
    s.add_argument("--weights", type=_floats, default=[0.25, 1.0, 4.0], help="unpainted weights")
    s.add_argument("--fit-scale", type=float, default=None,
                   help="fit resolution / view resolution (default: the renderer's, 0.25 cuts, 1 GI)")
    s.add_argument("--store", help="precomputation store folder for GI scenes (default $GLINT_DATA_DIR)")
    s.add_argument("--fit-albedo", choices=["no", "yes", "both"], default="both",
                   help="also fit the diffuse albedo (solve.solve fit_albedo)")
    s.add_argument("--cuts"); s.add_argument("--tau", type=float, default=1.0)
    s.add_argument("--json", action="store_true")
    s.set_defaults(fn=cmd_bench_strokes)


def _renderer_for(path, env, cuts_dir, tau, quiet):
    """The cut renderer of a scene file, under another environment map when ``env`` is given
    (the cuts are geometry only: one precomputation serves every map)."""
    from worker.cli import open_renderer
    from worker.envmap import load_envmap
    from worker.scene import LoadedScene, load_scene

    sc = load_scene(path)
    if env is not None:
        spec = sc.spec.model_copy(deep=True)
        spec.environment.map = str(Path(env).resolve())
        sc = LoadedScene(spec, sc.root, envmap=load_envmap(env))
    r, _ = open_renderer(sc, cuts_dir, quiet, {"tau": tau}, kind="cuts")
    return r


def cmd_bench_recovery(a) -> int:
    import os

    import numpy as np
    from PIL import Image
    from tqdm import tqdm

    from worker.core.tonemap import tonemap
    from worker.fit.basis import default_basis, paper_basis
    from worker.fit.recovery import ALPHAS, FINISHES, Case, public, recover

    cache = Path(a.cache) if a.cache else Path(os.environ.get("GLINT_DATA_DIR", Path.home() / ".cache" / "glint")) / "mitsuba"
    finishes = {"bare": FINISHES[:1], "coated": FINISHES[1:], "both": FINISHES}[a.finish]
    alphas = a.alpha or list(ALPHAS)
    cases = [(s, e, al, sp, alb) for s in a.scenes for e in a.env for al in alphas for sp, alb in finishes]
    results = []
    bar = tqdm(total=len(cases), desc="recovery", file=sys.stderr, disable=False)
    t0 = time.perf_counter()
    loaded = {}
    for s, e, al, sp, alb in cases:
        if (s, e) not in loaded:
            loaded.clear()
            loaded[(s, e)] = _renderer_for(s, e, a.cuts, a.tau, True)
        rnd = loaded[(s, e)]
        basis = paper_basis() if a.static == "paper" else default_basis()
        case = Case(Path(s).stem, Path(e).name, al, sp, tuple(alb))
        r = recover(rnd, case, basis=basis, fit_scale=a.fit_scale, spp=a.spp, cache_dir=cache,
                    auto_static=a.static == "smith" and not a.no_auto_static)
        if a.images:
            out = Path(a.images)
            out.mkdir(parents=True, exist_ok=True)
            im = r["_images"]
            Image.fromarray(np.concatenate([tonemap(im["target"]), tonemap(im["fit"]), tonemap(im["ggx"])], 1)).save(
                out / f"{case.scene}-{Path(e).stem}-a{al:g}-s{sp:g}.png")
        results.append(public(r))
        bar.update(1)
        bar.set_postfix_str(f"{case.scene}/{Path(e).stem} α={al:g}: {100 * r['rel_rmse']:.1f}%")
    bar.close()
    ok = [r for r in results if r["alpha"] >= 0.1]
    summary = {"cases": len(results), "seconds": time.perf_counter() - t0,
               "worst_rel_rmse_alpha_ge_0.1": max((r["rel_rmse"] for r in ok), default=None),
               "worst_excess_over_floor_alpha_ge_0.1": max((r["rel_rmse"] - r["ggx_floor"] for r in ok), default=None),
               "energy_ok": all(r["energy_ok"] for r in results), "static": a.static, "spp": a.spp,
               "fit_scale": a.fit_scale}
    out = {"summary": summary, "results": results}
    if a.json:
        print(json.dumps(out))
    else:
        for r in results:
            print(f"{r['scene']} {r['env']} α={r['alpha']:g} s={r['specular']:g}: {100 * r['rel_rmse']:.1f}% "
                  f"(Glint's GGX {100 * r['ggx_floor']:.1f}%, noise {100 * r['noise']:.1f}%), "
                  f"energy {r['energy_fraction']:.3f} of its bound")
    return 0


def standard_strokes(fx, view: int = 0):
    """The benchmark's strokes for the fitter's object, in its view's pixels: (name, Stroke).

    All run across the object's middle row from a quarter to three quarters of its width,
    with the studio's default brush (diameter 24 view pixels at 640 wide, κ 0.05):
    a white highlight (colour twice the brightest base radiance), a darkening (scale 0.3) and
    a colour change (colour mode, the base's mean radiance there tinted (1.6, 0.8, 0.5))."""
    import numpy as np

    from worker.fit.brush import Stroke

    v = fx.views[view]
    ys = v.xy[:, 1]
    y0 = float(np.median(ys))
    row = v.xy[np.abs(ys - y0) <= v.footprint * 2, 0]
    x0, x1 = float(np.quantile(row, 0.25)), float(np.quantile(row, 0.75))
    pts = [(x0, y0), (0.5 * (x0 + x1), y0 + 2.0), (x1, y0)]
    d = 24.0 * v.camera.width / 640.0
    near = np.abs(ys - y0) <= d / 2
    mean = v.base[near].mean(0)
    white = 2.0 * float(v.base.max())
    tint = (mean * np.array([1.6, 0.8, 0.5])).tolist()
    return [("white highlight", Stroke(points=pts, color=(white, white, white), diameter=d, kappa=0.05, view=view)),
            ("darkening", Stroke(points=pts, mode="scale", scale=0.3, diameter=d, kappa=0.05, view=view)),
            ("colour change", Stroke(points=pts, color=tuple(tint), diameter=d, kappa=0.05, view=view))]


def _gi_renderer(path, store, quiet):
    from worker.cli import open_renderer, scene_options
    from worker.scene import load_scene

    sc = load_scene(path)
    r, _ = open_renderer(sc, store, quiet, scene_options(sc, 1.0))
    return r


def session_stroke(rnd, name: str, stroke) -> dict:
    """One live stroke through a fresh session on the renderer (worker/jobs/runtime.py), as the
    studio sends it: milliseconds from the stroke message to its frame (the fit view built on
    the way), split into the stroke (its view), the fit and the frame."""
    from worker.jobs.runtime import SessionRuntime
    from worker.protocol import new_state

    rt = SessionRuntime(rnd.scene, rnd, {"state": new_state(rnd.scene.spec, name).model_dump(mode="json"),
                                         "strokes": []})
    rt.frame(-1)
    c0 = time.process_time()
    t0 = time.perf_counter()
    ev = rt.handle({"seq": 1, "type": "stroke", "stroke": stroke.model_dump(mode="json", exclude={"view"})})
    t1 = time.perf_counter()
    fit = rt.fit_if_needed()
    t2 = time.perf_counter()
    rt.frame(1)
    t3 = time.perf_counter()
    cpu = time.process_time() - c0
    rt.close()
    if ev[0].get("rejected"):
        raise RuntimeError(f"stroke rejected: {ev[0]['notes']}")
    return {"ms_stroke_to_frame": (t3 - t0) * 1e3, "cpu_ms_stroke_to_frame": cpu * 1e3, "ms_view": (t1 - t0) * 1e3, "ms_fit": (t2 - t1) * 1e3,
            "ms_frame": (t3 - t2) * 1e3, "steps": fit[0]["stats"].get("steps")}


def cmd_bench_strokes(a) -> int:
    import os

    import numpy as np

    from worker.fit.fitter import Fitter
    from worker.renderers.base import FrameRequest, Lighting
    from worker.scene import load_scene

    res = []
    for s in a.scenes:
        gi = load_scene(s).spec.renderer == "gi"
        rnd = _gi_renderer(s, a.store, a.json) if gi else _renderer_for(s, None, a.cuts, a.tau, a.json)
        sc = rnd.scene
        oi = next(i for i, o in enumerate(sc.spec.objects) if o.editable or not gi)
        name = sc.spec.objects[oi].name
        scale = a.fit_scale or rnd.stroke_fit_scale
        fx = Fitter(rnd, name, fit_scale=scale)
        t0 = time.perf_counter()
        fx.add_view()
        ms_view = (time.perf_counter() - t0) * 1e3
        env = sc.spec.environment
        for label, st in standard_strokes(fx):
            fx.history.clear()
            fx.add_stroke(st)
            albedo_modes = {"no": (False,), "yes": (True,), "both": (False, True)}[a.fit_albedo]
            for w, fa in ((w, fa) for w in a.weights for fa in albedo_modes):
                fx._last = None
                c0, t0 = time.process_time(), time.perf_counter()
                out = fx.fit(unpainted_weight=w, fit_albedo=fa)
                ms_fit, cpu_fit = (time.perf_counter() - t0) * 1e3, (time.process_time() - c0) * 1e3
                mats = list(sc.materials)
                mats[oi] = out.material
                t0 = time.perf_counter()
                rnd.render(FrameRequest(sc.spec.camera, Lighting(env.rotation_deg, env.intensity), mats))
                ms_frame = (time.perf_counter() - t0) * 1e3
                res.append({"scene": Path(s).stem, "renderer": sc.spec.renderer, "object": name,
                            "base": sc.spec.objects[oi].material.model, "width": sc.spec.camera.width,
                            "height": sc.spec.camera.height, "fit_scale": scale,
                            "stroke": label, "unpainted_weight": w, "fit_albedo": fa,
                            "albedo": [float(x) for x in out.material.albedo],
                            "achieved": out.achieved, "spill": out.spill,
                            "painted": out.painted, "pixels": out.pixels, "energy": out.energy,
                            "energy_bound": out.energy_bound, "ms_solve": out.solve.seconds * 1e3,
                            "ms_fit": ms_fit, "cpu_ms_fit": cpu_fit, "ms_frame": ms_frame, "ms_view": ms_view, "steps": out.steps,
                            "gap": out.gap, "notes": out.notes})
            if gi:
                res[-1]["session"] = session_stroke(rnd, name, st)
    load = os.getloadavg()
    if a.json:
        print(json.dumps({"results": res, "load": load}))
    else:
        print(f"load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}")
        for r in res:
            print(f"{r['scene']} {r['stroke']} w={r['unpainted_weight']:g} fit albedo {r['fit_albedo']}: "
                  f"achieved {100 * r['achieved']:.0f}%, spill {100 * r['spill']:.1f}%, albedo {r['albedo']}, "
                  f"fit {r['ms_fit']:.0f} ms ({r['steps']} steps), frame {r['ms_frame']:.0f} ms"
                  + (f"; session stroke → frame {r['session']['ms_stroke_to_frame']:.0f} ms" if "session" in r else ""))
    return 0
