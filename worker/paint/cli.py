"""``glint paint …``: the car-paint designer's commands (cacad-cosine-lobes).

  glint paint measure MATERIAL.json [--json]            industry measurements of any material
  glint paint fit --gloss G --aspecular 15=r,g,b:… --out MATERIAL.json [--json]
  glint paint exponents --lobes M [--json] [--recompute [--out FILE]]
  glint paint export MATERIAL.json --format json|csv
  glint paint render SCENE.json --out PNG [--raw NPY] [--material OBJ=M.json] [--fresnel] [--cosine vector|albedo|paper] [--visibility]
  glint paint bench SCENE.json [--frames N] [--json]
  glint paint bench-fit [--repeats N] [--json]
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np


def _material(path: str):
    from pydantic import TypeAdapter, ValidationError

    from ..scene import Material, SceneError
    p = Path(path)
    if not p.is_file():
        raise SceneError(f"{p}: material file not found")
    try:
        return TypeAdapter(Material).validate_python(json.loads(p.read_text()))
    except (ValueError, ValidationError) as e:
        raise SceneError(f"{p}: not a valid material ({str(e).splitlines()[0]})") from None


def parse_aspecular(text: str) -> dict:
    """'15=r,g,b:25=r,g,b:…' -> {"15": [r, g, b], …}."""
    from .geometry import MeasurementError
    out = {}
    for item in filter(None, text.split(":")):
        k, sep, v = item.partition("=")
        try:
            vals = [float(x) for x in v.split(",")]
            float(k)
        except ValueError:
            vals = []
        if not sep or len(vals) != 3:
            raise MeasurementError(f"--aspecular item {item!r}: expected ANGLE=r,g,b")
        out[k.strip()] = vals
    if not out:
        raise MeasurementError("--aspecular needs at least one ANGLE=r,g,b")
    return out


def cmd_measure(a) -> int:
    from .geometry import flop_index, measure
    m = measure(_material(a.material))
    m["gloss"] = float(m["gloss"])
    if a.json:
        print(json.dumps(m))
    else:
        print(f"gloss (D523 20°): {m['gloss']:.2f} GU   flop index: {flop_index(m):.2f}")
        for k, v in m["aspecular"].items():
            print(f"  {k:>5}°  R = {v[0]:.4f} {v[1]:.4f} {v[2]:.4f}")
    return 0


def cmd_fit(a) -> int:
    from ..atomic import atomic_write
    from .fit import fit_measurements
    exps = [float(x) for x in a.exponents.split(",")] if a.exponents else None
    r = fit_measurements({"gloss": a.gloss, "aspecular": parse_aspecular(a.aspecular)}, exps)
    if a.out:
        atomic_write(Path(a.out), (json.dumps(r.material.model_dump(), indent=1) + "\n").encode())
    if a.json:
        print(json.dumps(r.to_json()))
    else:
        print(f"fit in {r.seconds * 1e3:.2f} ms, mean relative error {r.error_l1:.2e} (max {r.error_max:.2e})"
              + (f"; wrote {a.out}" if a.out else ""))
    return 0


def cmd_exponents(a) -> int:
    from .exponents import EXPONENTS_PATH, exponents_for, main_recompute, stored_table
    if a.recompute:
        doc = main_recompute(Path(a.out) if a.out else None, a.lobes if a.lobes else 11)
        rows = doc["table"]
    else:
        rows = stored_table()["table"]
    if a.lobes:
        rows = [r for r in rows if r["lobes"] <= a.lobes]
        row = exponents_for(a.lobes) if not a.recompute else rows[-1]
    else:
        row = None
    if a.json:
        print(json.dumps({"source": str(EXPONENTS_PATH) if not a.recompute else "recomputed",
                          "lobes": a.lobes, "selected": row, "table": rows}))
    else:
        for r in rows:
            print(f"M={r['lobes']:2d}  mean {r['error_mean']:.4f}  max {r['error_max']:.4f}  f {r['objective']:.4f}  "
                  f"E = {', '.join(f'{e:g}' for e in r['exponents'])}")
    return 0


def cmd_export(a) -> int:
    from .geometry import export_measurements
    text = export_measurements(_material(a.material), a.format)
    if a.out:
        from ..atomic import atomic_write
        atomic_write(Path(a.out), text.encode())
    else:
        sys.stdout.write(text)
    return 0


def _setup(a, quiet: bool):
    """(scene, renderer, materials) with the paint precomputation ensured in the folder store."""
    from tqdm import tqdm

    from ..artifacts import DirStore
    from ..cli import data_dir
    from ..renderers import ensure, get, load
    from ..scene import SceneError, load_scene
    scene = load_scene(a.scene)
    cls, pre = get("paint")
    store = DirStore(Path(a.store) if a.store else data_dir(), "paint")
    opts = {"visibility": bool(a.visibility)}
    parts = pre.parts(scene, opts)
    bar = tqdm(total=sum(p.work for p in parts), desc="paint precompute", file=sys.stderr, disable=quiet)
    try:
        stats = ensure(pre, scene, store, opts, progress=bar.update)
    finally:
        bar.close()
    rnd = cls(scene, load(pre, scene, store, opts))
    rnd.cosine = a.cosine
    rnd.fresnel = a.fresnel
    mats = list(scene.materials)
    names = [o.name for o in scene.spec.objects]
    for spec in a.material or []:
        name, sep, path = spec.partition("=")
        if not sep or name not in names:
            raise SceneError(f"--material {spec!r}: expected OBJECT=FILE with OBJECT one of {', '.join(names)}")
        mats[names.index(name)] = _material(path)
    return scene, rnd, mats, stats


def cmd_render(a) -> int:
    from PIL import Image

    from ..core.tonemap import tonemap
    from ..renderers import FrameRequest, Lighting
    scene, rnd, mats, _ = _setup(a, False)
    env = scene.spec.environment
    t0 = time.perf_counter()
    out = rnd.render(FrameRequest(scene.spec.camera, Lighting(env.rotation_deg, env.intensity), mats))
    dt = time.perf_counter() - t0
    p = Path(a.out)
    p.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(tonemap(out.radiance, a.exposure, a.tone)).save(p)
    if a.raw:
        np.save(a.raw, out.radiance.astype(np.float32))
    print(f"wrote {p} ({out.radiance.shape[1]}×{out.radiance.shape[0]}, {dt * 1000:.0f} ms)", file=sys.stderr)
    return 0


def cmd_bench(a) -> int:
    """Median frame time while the paint changes (a fit per frame) and the light rotates, the
    camera fixed (the designer's loop); prefiltering of the scene's map timed cold."""
    from ..renderers import FrameRequest, Lighting
    from ..renderers.paint.prefilter import prefilter_all
    from .fit import fit_measurements
    from .geometry import measure
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
    """Fit time over the database's measurements: the warm HiGHS instance against linprog."""
    from .database import load_paints
    from .exponents import default_exponents
    from .fit import fit_measurements
    exps = default_exponents()
    paints = load_paints()
    res = {"paints": len(paints), "lobes": len(exps), "repeats": a.repeats}
    for solver in ("warm", "linprog"):
        fit_measurements(paints[0]["measurements"], exps, solver=solver)      # build once
        ts, errs = [], []
        for _ in range(a.repeats):
            for p in paints:
                t0 = time.perf_counter()
                r = fit_measurements(p["measurements"], exps, solver=solver)
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
    from .. import native
    return native.max_threads()


def _render_args(p):
    p.add_argument("scene")
    p.add_argument("--material", action="append", metavar="OBJECT=FILE", help="replace an object's material; repeatable")
    p.add_argument("--fresnel", action="store_true", help="Fresnel on the gloss weights (cacad §5.3)")
    p.add_argument("--cosine", choices=["vector", "albedo", "paper"], default="vector",
                   help="the cosine inside a lobe: vector maps for wide lobes (default), the lobe's directional "
                        "albedo, or the paper's R·N (eq. 7); see README")
    p.add_argument("--visibility", action="store_true", help="self-shadowing from the cut renderer's visibility")
    p.add_argument("--store", help="folder for precomputed parts (default $GLINT_DATA_DIR/parts)")


def add_commands(sub) -> None:
    p = sub.add_parser("paint", help="car-paint design: measurements, lobe fits, prefiltered rendering")
    ps = p.add_subparsers(dest="paint_cmd", required=True)

    m = ps.add_parser("measure", help="industry measurements (D523 20° gloss, E2194 aspecular) of a material")
    m.add_argument("material"); m.add_argument("--json", action="store_true")
    m.set_defaults(fn=cmd_measure)

    f = ps.add_parser("fit", help="fit lobe weights to gloss and aspecular readings")
    f.add_argument("--gloss", type=float, required=True, help="20° gloss, GU")
    f.add_argument("--aspecular", required=True, help="ANGLE=r,g,b:ANGLE=r,g,b:… reflectance factors (linear RGB); write --aspecular=-15=… when the first angle is negative")
    f.add_argument("--exponents", help="comma-separated basis (default: the stored LM optimum)")
    f.add_argument("--out"); f.add_argument("--json", action="store_true")
    f.set_defaults(fn=cmd_fit)

    e = ps.add_parser("exponents", help="the LM basis exponents and database fit errors for M lobes")
    e.add_argument("--lobes", type=int); e.add_argument("--json", action="store_true")
    e.add_argument("--recompute", action="store_true", help="rerun the LM search (minutes)")
    e.add_argument("--out", help="with --recompute: write the table here")
    e.set_defaults(fn=cmd_exponents)

    x = ps.add_parser("export", help="a material's measurements as JSON or CSV (for paint formulation)")
    x.add_argument("material"); x.add_argument("--format", choices=["json", "csv"], default="json")
    x.add_argument("--out")
    x.set_defaults(fn=cmd_export)

    r = ps.add_parser("render", help="render a scene with prefiltered lobe maps")
    _render_args(r)
    r.add_argument("--out", required=True); r.add_argument("--raw")
    r.add_argument("--exposure", type=float, default=0.0); r.add_argument("--tone", default="neutral")
    r.set_defaults(fn=cmd_render)

    bf = ps.add_parser("bench-fit", help="fit time over the database (warm HiGHS vs linprog)")
    bf.add_argument("--repeats", type=int, default=5); bf.add_argument("--json", action="store_true")
    bf.set_defaults(fn=cmd_bench_fit)

    b = ps.add_parser("bench", help="prefilter and frame times (--json)")
    _render_args(b)
    b.add_argument("--frames", type=int, default=60); b.add_argument("--json", action="store_true")
    b.set_defaults(fn=cmd_bench)
