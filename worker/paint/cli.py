"""``glint paint …``: the car-paint designer's commands (cacad-cosine-lobes).

  glint paint measure MATERIAL.json [--json]            industry measurements of any material
  glint paint fit --gloss G --aspecular 15=r,g,b:… --out MATERIAL.json [--json]
  glint paint exponents --lobes M [--json] [--recompute [--out FILE]]
  glint paint basis [--json] [--recompute [--out FILE]]
  glint paint export MATERIAL.json --format json|csv
  glint paint render SCENE.json --out PNG [--raw NPY] [--material OBJ=M.json] [--fresnel] [--cosine vector|albedo|paper] [--visibility]

``glint paint bench`` and ``bench-fit`` are the benchmark package's (bench/paint.py).
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
        if r.warning:
            print(f"warning: {r.warning}")
    return 0


def cmd_basis(a) -> int:
    from .basis import BASIS_PATH, main_recompute, stored
    doc = main_recompute(Path(a.out) if a.out else None) if a.recompute else stored()
    if a.json:
        print(json.dumps({"source": "recomputed" if a.recompute else str(BASIS_PATH), **doc}))
    else:
        pct = lambda d: (f"{d['cases']} cases: worst {100 * d['max']:.1f}%, p90 {100 * d['p90']:.2f}%, "
                         f"{100 * d['within']:.0f}% within 3%")
        print(f"basis ({len(doc['basis'])} lobes): {', '.join(f'{e:g}' for e in doc['basis'])}; "
              f"max-residual weight {doc['max_weight']:g}")
        print(f"  tuning   (seed {doc['tuning']['seed']}): {pct(doc['tuning'])}")
        print(f"  held out (seed {doc['held_out']['seed']}): {pct(doc['held_out'])}")
        print(f"  held out, old basis: {pct(doc['held_out_old_basis'])}")
        inh = doc["inherent_microfacet"]
        print(f"  microfacet paints, raw readings on any lobes material: {pct(inh['raw_round_trip'])}; "
              f"misses by reading {inh['misses_by_reading']}")
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
    from ..cli import data_dir, load_material_overrides
    from ..renderers import ensure, get, load
    from ..scene import load_scene
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
    return scene, rnd, load_material_overrides(scene, a.material), stats


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

    bs = ps.add_parser("basis", help="the fit's basis exponents: tuning and held-out round-trip figures")
    bs.add_argument("--json", action="store_true")
    bs.add_argument("--recompute", action="store_true", help="choose the basis again on the tuning paints (minutes)")
    bs.add_argument("--out", help="with --recompute: write the choice here (data/basis.json is the stored one)")
    bs.set_defaults(fn=cmd_basis)

    x = ps.add_parser("export", help="a material's measurements as JSON or CSV (for paint formulation)")
    x.add_argument("material"); x.add_argument("--format", choices=["json", "csv"], default="json")
    x.add_argument("--out")
    x.set_defaults(fn=cmd_export)

    r = ps.add_parser("render", help="render a scene with prefiltered lobe maps")
    _render_args(r)
    r.add_argument("--out", required=True); r.add_argument("--raw")
    r.add_argument("--exposure", type=float, default=0.0); r.add_argument("--tone", default="neutral")
    r.set_defaults(fn=cmd_render)
