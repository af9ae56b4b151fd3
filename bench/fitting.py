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
    s.add_argument("--regions", action="store_true",
                   help="also fit a region per stroke (worker/fit/regions.py) and measure both in rendered frames "
                        "(achieved on painted pixels, spill beyond one brush diameter) and the frame cost")
    s.add_argument("--env", action="append", help="light the scenes with this map instead (repeatable; --regions)")
    s.add_argument("--parts", default="auto", type=lambda x: x if x == "auto" else int(x),
                   help="parts of a region (worker/fit/regions.py fit_region; default auto)")
    s.add_argument("--frames", type=int, default=15, help="rounds of frames timed per material (--regions)")
    s.add_argument("--images", help="write before | target | one BRDF | region JPEGs per case to this folder (--regions)")
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
               "worst_rel_rmse_refined_alpha_ge_0.1": max((r["rel_rmse_refined"] for r in ok), default=None),
               "worst_rel_rmse_still_alpha_ge_0.1": max((r["rel_rmse_still"] for r in ok), default=None),
               "energy_ok": all(r["energy_ok"] for r in results), "static": a.static, "spp": a.spp,
               "fit_scale": a.fit_scale}
    out = {"summary": summary, "results": results}
    if a.json:
        print(json.dumps(out))
    else:
        for r in results:
            print(f"{r['scene']} {r['env']} α={r['alpha']:g} s={r['specular']:g}: {100 * r['rel_rmse']:.1f}% "
                  f"per pixel, {100 * r['rel_rmse_refined']:.1f}% refined, {100 * r['rel_rmse_still']:.1f}% settled "
                  f"(Glint's GGX {100 * r['ggx_floor']:.1f}% / {100 * r['ggx_floor_refined']:.1f}% / "
                  f"{100 * r['ggx_floor_still']:.1f}%, noise {100 * r['noise']:.1f}%), "
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


def _view_radiance(fx, material, view: int = 0):
    """(n, 3) float64 radiance at the fit view's pixels with the fitter's object in ``material``
    (a rendered frame of the view, read at its fit pixels)."""
    import numpy as np

    from worker.renderers import FrameRequest

    v = fx.views[view]
    r = fx.renderer
    mats = list(r.scene.materials)
    mats[fx.obj] = material
    img = r.render(FrameRequest(camera=v.camera, lighting=v.lighting, materials=mats)).radiance
    px = np.floor(v.xy).astype(np.int64)
    return img[px[:, 1], px[:, 0]].astype(np.float64)


def _ask_along(v, stroke, rad):
    """What a stroke asks when it asks for the radiance ``rad`` (n, 3) of a view's fit pixels:
    (its mean over the stroke's core (brush weight ≥ 0.5) (3,), that mean's luminance over the
    base's there, the core's pixel count)."""
    from worker.core.tonemap import LUMA
    from worker.fit.brush import stroke_weights

    core = stroke_weights(stroke, v.xy, v.footprint) >= 0.5
    if not core.any():
        return None, 0.0, 0
    ask = rad[core].mean(0)
    return ask, float(ask @ LUMA / max(float(v.base[core].mean(0) @ LUMA), 1e-12)), int(core.sum())


# a stroke the material that made its ask answers: the material itself delivers at least this
# share of the ask on the painted pixels (the regions target's own bar)
ANSWERED = 0.8
# a highlight: the ask at least this much brighter than the base along the stroke (luminance)
HIGHLIGHT_GAIN = 1.1
# stroke lengths tried for the glossy highlight, as fractions of the standard stroke's (the middle
# half of the row): the standard one first, shorter ones (slid along the row) only where no row's
# standard stroke is answered
HIGHLIGHT_LENGTHS = (1.0, 0.5, 0.25)


def own_share(stroke, xy, base, made) -> float | None:
    """The share of a stroke's ask (eq. 23 on ``base``) that the material whose radiance is
    ``made`` delivers itself, as ``brush.stroke_effect`` measures a fit (xy (P, 2) pixel
    centres, base and made (P, 3)). A colour-mode stroke asks one colour along its length: where
    the base is brighter than that colour it asks to darken, elsewhere to brighten, while a real
    material's change varies along it with the light. Its own share can be far below 1, or
    negative (a lacquer adds light where the ask darkens), even when the ask is its mean."""
    from worker.fit.brush import apply_stroke, stroke_effect, stroke_weights

    w = stroke_weights(stroke, xy)
    t = apply_stroke(base.copy(), stroke, w)
    return stroke_effect([base], [t], [w > 0], [made])[0]


def glossy_highlight(fx, view: int = 0, alpha: float = 0.1):
    """A highlight a real material gives and answers: ("glossy highlight", Stroke or None, its
    luminance over the base's along the stroke, the lacquer's own share of the ask) for the
    fitter's object.

    The object is rendered with its base's diffuse albedo under a white GGX lobe of roughness
    ``alpha`` holding the energy the albedo leaves (specular 1 − max albedo: a lacquer as bright
    as energy conservation allows on that colour). A candidate stroke is the studio's default
    brush along a row of the object (rows half a brush diameter apart): the standard stroke (the
    middle half of the row), else shorter ones slid along it (HIGHLIGHT_LENGTHS); it asks for the
    lacquer's mean radiance over its core (brush weight ≥ 0.5). A colour stroke asks one colour
    along its length, while the base and the lacquer vary along it (the reflection moves, the
    base's shading too), so the ask is a highlight a real material gives only where the lacquer
    itself delivers ANSWERED of it (``own_share``, on the view's vertex-shaded frames, as
    ``rendered_effect`` measures a fit): the brightest such candidate of the longest length
    that has one, at least HIGHLIGHT_GAIN over the base. None for the stroke and the gain (with
    the best own share of any candidate bright enough) when no stroke in the view is one: there
    one colour along any stroke asks the lacquer for what it does not do."""
    import numpy as np

    from worker.core.tonemap import LUMA
    from worker.fit.brush import stroke_weights
    from worker.fit.regions import object_frames
    from worker.scene import GGX

    v = fx.views[view]
    hl = standard_strokes(fx, view)[0][1]
    albedo = np.asarray(fx.base_material.albedo, np.float64)
    h = 1.0 - float(albedo.max())
    lacquer = GGX(alpha=alpha, specular=(h, h, h), albedo=tuple(albedo.tolist()))
    xy, (b, p), _ = object_frames(fx.renderer, fx.obj, v.camera, v.lighting, [fx.base_material, lacquer])
    ys, d = v.xy[:, 1], hl.diameter
    best_own = None
    for frac in HIGHLIGHT_LENGTHS:
        best = None
        for y0 in np.arange(ys.min() + d / 2, ys.max() - d / 2, d / 2):
            row = v.xy[np.abs(ys - y0) <= v.footprint * 2, 0]
            if len(row) < 8:
                continue
            x0, x1 = float(np.quantile(row, 0.25)), float(np.quantile(row, 0.75))
            length = (x1 - x0) * frac
            if length < 2 * d:
                continue
            starts = [x0] if frac == 1.0 else np.arange(float(row.min()), float(row.max()) - length + 1e-9, d / 2)
            # every pixel a stroke on this row reaches (its middle point is 2 px off the row)
            band = np.abs(xy[:, 1] - y0) <= 0.5 * d + 3.0
            xb, bb, pb = xy[band], b[band], p[band]
            for s0 in starts:
                pts = [(float(s0), float(y0)), (float(s0) + length / 2, float(y0) + 2.0), (float(s0) + length, float(y0))]
                st = hl.model_copy(update={"points": pts})
                core = stroke_weights(st, xb) >= 0.5
                if core.sum() < 8:
                    continue
                ask = pb[core].mean(0)
                gain = float(ask @ LUMA / max(float(bb[core].mean(0) @ LUMA), 1e-12))
                if gain < HIGHLIGHT_GAIN:
                    continue
                st = st.model_copy(update={"color": tuple(float(x) for x in ask)})
                own = own_share(st, xb, bb, pb)
                if own is None:
                    continue
                best_own = own if best_own is None else max(best_own, own)
                if own >= ANSWERED and (best is None or gain > best[0]):
                    best = (gain, st, own)
        if best is not None:
            return "glossy highlight", best[1], best[0], best[2]
    return "glossy highlight", None, None, best_own


def paint_colour(fx, view: int = 0, tint=(1.6, 0.8, 0.5)):
    """A colour change a real material gives: ("paint colour", Stroke, its luminance over the
    base's along the stroke, the paint's own share of the ask: ``own_share``) for the fitter's
    object.

    The base material with its diffuse albedo tinted by ``tint`` (the standard colour change's
    factors), scaled down where needed so that albedo plus specular stays within 1 in every
    channel (a paint of that hue as bright as energy allows), rendered; the standard stroke asks
    for its mean radiance over the stroke's core (brush weight ≥ 0.5). The standard colour change
    asks for the base's mean radiance tinted, one colour along a stroke whose light varies, which
    needs an albedo above 1 where the light is dimmer; this one is within energy by construction."""
    import numpy as np

    from worker.fit.regions import object_frames

    v = fx.views[view]
    st = standard_strokes(fx, view)[2][1]
    base = fx.base_material
    albedo = np.asarray(base.albedo, np.float64) * np.asarray(tint, np.float64)
    spec = float(np.max(getattr(base, "specular", (0.0, 0.0, 0.0))))
    albedo *= min(1.0, (1.0 - spec) / max(float(albedo.max()), 1e-12))
    paint = base.model_copy(update={"albedo": tuple(float(x) for x in albedo)})
    rad = _view_radiance(fx, paint, view)
    color, gain, _ = _ask_along(v, st, rad)
    st = st.model_copy(update={"color": tuple(float(x) for x in color)})
    xy, (b, p), _ = object_frames(fx.renderer, fx.obj, v.camera, v.lighting, [base, paint])
    return "paint colour", st, gain, own_share(st, xy, b, p)


def _gi_renderer(path, store, quiet, env=None):
    """The GI renderer of a scene file (precomputing into ``store`` when needed), under another
    environment map when ``env`` is given (GI tensors hold the lighting: one precomputation
    per map)."""
    from worker.cli import open_renderer, scene_options
    from worker.envmap import load_envmap
    from worker.scene import LoadedScene, load_scene

    sc = load_scene(path)
    if env is not None:
        spec = sc.spec.model_copy(deep=True)
        spec.environment.map = str(Path(env).resolve())
        sc = LoadedScene(spec, sc.root, envmap=load_envmap(env))
    r, _ = open_renderer(sc, store, quiet, scene_options(sc, 1.0))
    return r


def _gi_frame_times(r, cam, lighting, materials: dict, frames: int) -> dict:
    """``_frame_times`` for the GI renderer, one material list at a time: a list that changes
    the painted regions' weights freezes again (once per stroke in a session), so each list is
    drawn until frozen with the unit a session would edit live (the region's, after a frame of
    the same weights with the base's material in it: key "regions_base_material" first), then
    timed."""
    import numpy as np

    from worker.renderers import FrameRequest

    wall, cpu = {}, {}
    for k, m in materials.items():
        q = FrameRequest(camera=cam, lighting=lighting, materials=m)
        r.render(q)
        r.render(q)
        w, c = [], []
        for _ in range(frames):
            t0, c0 = time.perf_counter(), time.process_time()
            r.render(q)
            w.append((time.perf_counter() - t0) * 1e3)
            c.append((time.process_time() - c0) * 1e3)
        wall[k], cpu[k] = float(np.median(w)), float(np.median(c))
    return {"wall": wall, "cpu": cpu}


def session_stroke(rnd, name: str, stroke, region: str | None = None, more: int = 0) -> dict:
    """One live stroke through a fresh session on the renderer (worker/jobs/runtime.py), as the
    studio sends it: milliseconds from the stroke message to its frame (the fit view built on
    the way), split into the stroke (its view), the fit and the frame. ``region``: the stroke
    paints that region (the studio's Paint a region, turned on before it). ``more``: that many
    strokes follow, each the same one moved down by a third of its diameter (a region grown
    stroke by stroke), their stroke → frame in ``ms_more``."""
    from worker.jobs.runtime import SessionRuntime
    from worker.protocol import new_state

    rt = SessionRuntime(rnd.scene, rnd, {"state": new_state(rnd.scene.spec, name).model_dump(mode="json"),
                                         "strokes": []})
    rt.frame(-1)
    if region is not None:
        rt.handle({"seq": 0, "type": "region", "action": "paint", "name": region})
        rt.fit_if_needed()
        rt.frame(0)
    c0 = time.process_time()
    t0 = time.perf_counter()
    ev = rt.handle({"seq": 1, "type": "stroke", "stroke": stroke.model_dump(mode="json", exclude={"view"})})
    t1 = time.perf_counter()
    fit = rt.fit_if_needed()
    t2 = time.perf_counter()
    rt.frame(1)
    t3 = time.perf_counter()
    cpu = time.process_time() - c0
    ms_more = []
    for k in range(1, more + 1):
        d = stroke.model_dump(mode="json", exclude={"view"})
        d["points"] = [[x, y + k * stroke.diameter / 3] for x, y in d["points"]]
        t4 = time.perf_counter()
        rt.handle({"seq": 1 + k, "type": "stroke", "stroke": d})
        rt.fit_if_needed()
        rt.frame(1 + k)
        ms_more.append((time.perf_counter() - t4) * 1e3)
    rt.close()
    if ev[0].get("rejected"):
        raise RuntimeError(f"stroke rejected: {ev[0]['notes']}")
    return {"ms_stroke_to_frame": (t3 - t0) * 1e3, "cpu_ms_stroke_to_frame": cpu * 1e3, "ms_view": (t1 - t0) * 1e3, "ms_fit": (t2 - t1) * 1e3,
            "ms_frame": (t3 - t2) * 1e3, "steps": fit[0]["stats"].get("steps"), "ms_more": ms_more}


def cmd_bench_strokes(a) -> int:
    import os

    from worker.fit.fitter import Fitter
    from worker.renderers.base import FrameRequest, Lighting
    from worker.scene import load_scene

    if a.regions:
        return cmd_bench_regions(a)
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


def _frame_times(r, cam, lighting, materials: dict, frames: int) -> dict:
    """Per material list (name -> materials), the median wall and CPU time (ms) of a
    full-quality vertex-mode frame, in interleaved rounds (each round renders every list once,
    so a load change hits all alike); the view and light tables are cached by a first frame, so
    each timed frame is the shading and resolve a material change costs. CPU time is the
    process's (all threads): on a shared machine it is the cost, where wall time also counts
    waiting for a core."""
    import numpy as np

    from worker.renderers import FrameRequest

    # vertex mode named: the studio's frame after a stroke (FrameRequest's default is refined,
    # the settled still's)
    reqs = {k: FrameRequest(camera=cam, lighting=lighting, materials=m, shading="vertex") for k, m in materials.items()}
    for q in reqs.values():
        r.render(q)
    wall = {k: [] for k in reqs}
    cpu = {k: [] for k in reqs}
    for _ in range(frames):
        for k, q in reqs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            r.render(q)
            wall[k].append((time.perf_counter() - t0) * 1e3)
            cpu[k].append((time.process_time() - c0) * 1e3)
    return {"wall": {k: float(np.median(v)) for k, v in wall.items()},
            "cpu": {k: float(np.median(v)) for k, v in cpu.items()}}


def cmd_bench_regions(a) -> int:
    """``glint bench strokes --regions``: per scene × map × stroke (the standard strokes, the
    glossy highlight and the paint colour: ``glossy_highlight``, ``paint_colour``, what a real
    material gives there), a region fit and a one-BRDF fit (unpainted weight 0.25, albedo fitted),
    each measured in rendered frames at the view's resolution (worker/fit/regions.py ``rendered_effect``), and the frame cost of the
    object with its region against the same object with one material."""
    import os

    from worker.fit.fitter import Fitter
    from worker.fit.regions import fit_region, fit_region_gi, rendered_effect
    from worker.scene import load_scene

    res = []
    envs = a.env or [None]
    for s in a.scenes:
        gi = load_scene(s).spec.renderer == "gi"
        for env in envs:
            rnd = _gi_renderer(s, a.store, a.json, env) if gi else _renderer_for(s, env, a.cuts, a.tau, a.json)
            sc = rnd.scene
            name = sc.spec.objects[0].name
            fx = Fitter(rnd, name, fit_scale=a.fit_scale or rnd.stroke_fit_scale)
            fx.add_view()
            v = fx.views[0]
            real = [glossy_highlight(fx), paint_colour(fx)]
            gains = {label: gain for label, _, gain, _ in real}
            owns = {label: own for label, _, _, own in real}
            for label, st, _, own in real:
                if st is None:                # reported: no stroke in the view the material answers
                    res.append({"scene": Path(s).stem, "renderer": sc.spec.renderer,
                                "env": Path(env).name if env else Path(sc.spec.environment.map).name,
                                "object": name, "stroke": label, "answered_by_material": None,
                                "best_material_own_share": own})
                    if not a.json:
                        print(f"{Path(s).stem} {res[-1]['env']} {label}: no stroke the material answers in this "
                              f"view (its best own share {own if own is None else round(own, 2)})", file=sys.stderr)
            for label, st in standard_strokes(fx) + [(label, st) for label, st, _, _ in real if st is not None]:
                fx.history.clear()
                fx.add_stroke(st)
                fx._last = None
                t0 = time.perf_counter()
                reg = fit_region_gi(fx, name=label, parts=a.parts) if gi else fit_region(fx, name=label, parts=a.parts)
                t_reg = time.perf_counter() - t0
                one = fx.fit(unpainted_weight=0.25, fit_albedo=True)
                got = rendered_effect(rnd, 0, v.camera, v.lighting, fx.base_material, reg.material, [st])
                ref = rendered_effect(rnd, 0, v.camera, v.lighting, fx.base_material, one.material, [st])
                if a.images:
                    _write_case_image(Path(a.images) / f"{Path(s).stem}-{Path(env).stem if env else 'scene'}-"
                                      f"{label.replace(' ', '-')}.jpg", rnd, v, fx.base_material, one.material,
                                      reg.material, st)
                # the blend's own cost: the same regions with the base's material in every region
                # (what the layers cost beyond the materials' own shading)
                same = reg.material.model_copy(update={"regions": [g.model_copy(update={"material": fx.base_material})
                                                                   for g in reg.material.regions]})
                lists = {}
                for key, m in (("base", fx.base_material), ("one_brdf", one.material),
                               ("regions_base_material", same), ("regions", reg.material)):
                    mats = list(sc.materials)
                    mats[0] = m
                    lists[key] = mats
                tm = (_gi_frame_times if gi else _frame_times)(rnd, v.camera, v.lighting, lists, a.frames)
                ms, cpu = tm["wall"], tm["cpu"]
                res.append({"scene": Path(s).stem, "renderer": sc.spec.renderer,
                            "env": Path(env).name if env else Path(sc.spec.environment.map).name,
                            "object": name, "vertices": int((sc.object_of_vertex == 0).sum()), "stroke": label,
                            "ask_over_base": gains.get(label),
                            "material_own_share": owns.get(label),
                            "region_vertices": sum(len(g.vertices) for g in reg.regions), "parts": reg.parts,
                            "tried": reg.tried,
                            "rendered": {k: got[k] for k in ("achieved", "spill", "spill_far")},
                            "predicted": {"achieved": reg.achieved, "spill": reg.spill, "spill_far": reg.spill_far},
                            "one_brdf_rendered": {k: ref[k] for k in ("achieved", "spill", "spill_far")},
                            "painted_pixels": got["painted_pixels"], "far_pixels": got["far_pixels"],
                            "object_pixels": got["object_pixels"], "region_albedo": reg.region_albedo,
                            "notes": reg.notes, "seconds_region_fit": t_reg, "ms_transfer": reg.seconds_transfer * 1e3,
                            "ms_solve": reg.solve.seconds * 1e3, "ms_frame": ms, "cpu_ms_frame": cpu,
                            "cost_vs_base": cpu["regions"] / cpu["base"], "cost_vs_one_brdf": cpu["regions"] / cpu["one_brdf"],
                            "blend_cost": cpu["regions_base_material"] / cpu["base"],
                            "wall_cost_vs_base": ms["regions"] / ms["base"]})
                # stroke → frame in one session, the region's and the one BRDF's (the studio's paths)
                res[-1]["session"] = {"region": session_stroke(rnd, name, st, region=label, more=2),
                                      "one_brdf": session_stroke(rnd, name, st, more=2)}
                if not a.json:
                    r = res[-1]
                    print(f"{r['scene']} {r['env']} {label}: region achieved {100 * got['achieved']:.0f}%, spill beyond D "
                          f"{100 * got['spill_far']:.1f}% (one BRDF {100 * ref['achieved']:.0f}%, {100 * ref['spill_far']:.1f}%); "
                          f"frame CPU {cpu['regions']:.1f} ms vs {cpu['base']:.1f} ms base ({r['cost_vs_base']:.2f}×, blend "
                          f"{r['blend_cost']:.2f}×)", file=sys.stderr)
    summary = {}
    fitted = [r for r in res if "rendered" in r]
    if fitted:
        summary = {"cases": len(fitted), "min_achieved": min(r["rendered"]["achieved"] for r in fitted),
                   "min_achieved_by_stroke": {k: min(r["rendered"]["achieved"] for r in fitted if r["stroke"] == k)
                                              for k in dict.fromkeys(r["stroke"] for r in fitted)},
                   "max_spill_far": max(r["rendered"]["spill_far"] for r in fitted),
                   "max_cost_vs_base": max(r["cost_vs_base"] for r in fitted),
                   "max_blend_cost": max(r["blend_cost"] for r in fitted),
                   "max_cost_vs_one_brdf": max(r["cost_vs_one_brdf"] for r in fitted),
                   "load_average": list(os.getloadavg())}
    # strokes no real material answers in the view (glossy_highlight found none): not fitted
    summary["unanswered"] = [{k: r[k] for k in ("scene", "env", "stroke", "best_material_own_share")}
                             for r in res if "rendered" not in r]
    if a.json:
        print(json.dumps({"summary": summary, "results": res}))
    return 0


def _write_case_image(path: Path, rnd, v, before, one, region, stroke) -> None:
    """before | target (the stroke over before's frame) | one BRDF | region, tone-mapped alike."""
    import numpy as np
    from PIL import Image

    from worker.core.tonemap import tonemap
    from worker.fit.brush import apply_stroke, stroke_weights
    from worker.renderers import FrameRequest

    frames = []
    for m in (before, one, region):
        mats = list(rnd.scene.materials)
        mats[0] = m
        frames.append(rnd.render(FrameRequest(camera=v.camera, lighting=v.lighting, materials=mats)))
    h, w = v.camera.height, v.camera.width
    on = frames[0].object_id.reshape(-1) == 0
    yy, xx = np.divmod(np.nonzero(on)[0], w)
    tgt = frames[0].radiance.reshape(-1, 3).astype(np.float64).copy()
    sub = tgt[on]
    apply_stroke(sub, stroke, stroke_weights(stroke, np.stack([xx + 0.5, yy + 0.5], 1)))
    tgt[on] = sub
    imgs = [frames[0].radiance, tgt.reshape(h, w, 3).astype(np.float32), frames[1].radiance, frames[2].radiance]
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate([tonemap(x) for x in imgs], 1)).save(path, quality=88)
