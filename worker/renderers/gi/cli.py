"""``glint gi …``: precompute the GI tensors of a scene and render it with edited materials
(polynomial-gi). Registered in worker/cli.py COMMAND_MODULES; ``glint gi bench`` (freezing and
frames) is the benchmark package's (bench/gi.py).

Tensors are stored as content-keyed parts in ``--store`` (default ``$GLINT_DATA_DIR/gi``, else
``~/.cache/glint/gi``); ``render`` (and the benchmark) precompute first when they are missing.
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path


def _store(a):
    from ...artifacts import DirStore
    root = Path(a.store) if a.store else Path(os.environ.get("GLINT_DATA_DIR", Path.home() / ".cache" / "glint"))
    return DirStore(root, "gi")


def _overrides(a) -> dict:
    from .options import parse_series
    return {"series": parse_series(a.series) if a.series else None, "bounces": a.bounces, "spp": a.spp,
            "fresnel": True if a.fresnel else None, "seed": a.seed, "denoise": True if a.denoise else None,
            "painted": _painted(getattr(a, "trace_regions", None))}


def _painted(specs) -> list | None:
    """``--trace-regions OBJECT=FILE`` values as options ``painted`` entries (None: none given)."""
    from ...scene import SceneError
    if not specs:
        return None
    out = []
    for spec in specs:
        name, sep, path = spec.partition("=")
        p = Path(path)
        if not sep or not p.is_file():
            raise SceneError(f"--trace-regions {spec!r}: expected OBJECT=FILE with an existing material file")
        try:
            out.append({"object": name, "material": json.loads(p.read_text())})
        except json.JSONDecodeError as e:
            raise SceneError(f"{p}: not valid JSON ({e.msg})") from None
    return out


def _ensure(a, quiet: bool):
    """(scene, GIPrecomputation, store, options, stats) with the tensors computed if missing."""
    from tqdm import tqdm

    from ...scene import load_scene
    from .. import ensure
    from . import GIPrecomputation

    scene = load_scene(a.scene)
    pre = GIPrecomputation()
    store = _store(a)
    options = _overrides(a)
    parts = pre.parts(scene, options)
    missing = [p for p in parts if store.get(p.key) is None]
    bar = tqdm(total=sum(p.work for p in parts), desc="gi precompute", unit="px", file=sys.stderr,
               disable=quiet or not missing, smoothing=0.1)
    try:
        stats = ensure(pre, scene, store, options, progress=bar.update)
    finally:
        bar.close()
    return scene, pre, store, options, stats


def cmd_precompute(a) -> int:
    from . import tensors
    t0 = time.perf_counter()
    scene, pre, store, options, stats = _ensure(a, a.json)
    (key, info), = stats["parts"].items()
    meta, arrays = tensors.unpack(store.get(key))
    N = meta["bounces"]
    per = [int(sum(arrays[f"b{k}.{n}"].nbytes for n in ("offsets", "slot", "tail", "val", "scale")))
           for k in range(1, N + 1)]
    res = {"seconds": info.get("seconds", 0.0), "seconds_total": time.perf_counter() - t0, "cached": info["cached"],
           "pixels": meta["pixels"], "width": meta["width"], "height": meta["height"], "bounces": N,
           "series": meta["series"], "spp": meta["spp"], "fresnel": meta["fresnel"], "units": meta["units"],
           "bytes": len(store.get(key)), "bytes_per_bounce": per, "denoise": meta.get("denoise"),
           "entries_per_bounce": [int(len(arrays[f"b{k}.slot"])) for k in range(1, N + 1)],
           "rays": meta["rays"], "key": key, "store": str(store.root)}
    if not info["cached"]:
        res["rays_per_second"] = meta["rays"] / max(info["seconds"], 1e-9)
        res.update(embree_speed(scene))
    if a.json:
        print(json.dumps(res))
    else:
        took = "cached" if res["cached"] else f"{res['seconds']:.1f} s"
        mb = ", ".join(f"{b / 1e6:.1f}" for b in per)
        print(f"GI tensors {','.join(map(str, res['series']))}: {res['pixels']} pixels × {res['spp']} spp, "
              f"{res['bytes'] / 1e6:.1f} MB ({mb} MB per bounce), {took}\n  {store.path(key)}")
    return 0


def embree_speed(scene, n: int = 400_000, seed: int = 0) -> dict:
    """Raw Embree throughput on this scene, for comparison with the precomputation's rays/s:
    n occlusion and n first-hit rays from random surface points in uniform random directions,
    in the precomputation's two threads (trace.Geometry.trace)."""
    import numpy as np

    from .trace import Geometry
    geo = Geometry(scene)
    rng = np.random.default_rng(seed)
    area = np.linalg.norm(np.cross(geo.V[geo.F[:, 1]] - geo.V[geo.F[:, 0]], geo.V[geo.F[:, 2]] - geo.V[geo.F[:, 0]]), axis=1)
    f = rng.choice(len(geo.F), n, p=area / area.sum())
    u = rng.random((n, 2)); fl = u.sum(1) > 1; u[fl] = 1 - u[fl]
    o = (1 - u.sum(1))[:, None] * geo.V[geo.F[f, 0]] + u[:, :1] * geo.V[geo.F[f, 1]] + u[:, 1:] * geo.V[geo.F[f, 2]]
    d = rng.normal(size=(n, 3)); d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = o + geo.face_n[f] * np.sign((geo.face_n[f] * d).sum(1))[:, None] * geo.eps
    out = {}
    for name, occl in (("occluded", True), ("first_hit", False)):
        geo.trace(o[:1000], d[:1000], occluded=occl)                 # warm-up
        t0 = time.perf_counter()
        geo.trace(o, d, occluded=occl)
        out[f"embree_{name}_rays_per_second"] = n / (time.perf_counter() - t0)
    return out


def open_renderer(a, quiet):
    from .. import load
    from . import GIRenderer
    scene, pre, store, options, _ = _ensure(a, quiet)
    data = load(pre, scene, store, options)
    return GIRenderer(scene, data)


def _apply_materials(r, specs) -> None:
    from ...scene import SceneError
    from .options import parse_material
    objs = [o.name for o in r.scene.spec.objects]
    mats = list(r.scene.materials)
    for spec in specs or []:
        name, sep, path = spec.partition("=")
        if not sep:
            raise SceneError(f"--material {spec!r}: expected OBJECT=FILE")
        p = Path(path)
        if not p.is_file():
            raise SceneError(f"{p}: material file not found")
        try:
            data = json.loads(p.read_text())
        except json.JSONDecodeError as e:
            raise SceneError(f"{p}: not valid JSON ({e.msg})") from None
        if name in objs and r.layout.fixed[objs.index(name)]:
            raise SceneError(f"--material {name}=…: {name!r} is fixed (\"editable\": false) in this precomputation")
        m = parse_material(data, str(p))
        if name in objs:
            mats[objs.index(name)] = m          # objects' materials go in together (painted regions)
        else:
            r.set_unit_material(r.layout.index(name), m)
    r.apply_materials(mats)


def cmd_render(a) -> int:
    import numpy as np
    from PIL import Image

    from ...core.tonemap import tonemap
    r = open_renderer(a, False)
    _apply_materials(r, a.material)
    if a.bounces_drawn:
        r.max_bounces = max(1, min(a.bounces_drawn, r.N))
    t0 = time.perf_counter()
    img = r.draw()
    dt = time.perf_counter() - t0
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(tonemap(img, a.exposure, a.tone)).save(out)
    if a.raw:
        np.save(a.raw, img.astype(np.float32))
    print(f"wrote {out} ({img.shape[1]}×{img.shape[0]}, {r.max_bounces} bounces, {dt * 1000:.0f} ms)"
          + (f" and {a.raw}" if a.raw else ""), file=sys.stderr)
    return 0


def gi_options(p) -> None:
    """The options every ``glint gi`` command takes (also ``glint gi bench``, bench/gi.py)."""
    p.add_argument("scene")
    p.add_argument("--series", help="BRDF series from the eye, e.g. 64,1,1,1 (default: the scene's gi.series)")
    p.add_argument("--bounces", type=int, help="bounces N (pads the series with 1 or truncates it)")
    p.add_argument("--spp", type=int, help="paths per pixel (default: the scene's gi.spp, else 64)")
    p.add_argument("--fresnel", action="store_true", help="precompute the Fresnel layer (Appendix A)")
    p.add_argument("--seed", type=int, help="random seed of the path tracer")
    p.add_argument("--denoise", action="store_true",
                   help="denoise every basis image of the tensors once with Open Image Denoise (denoise.py)")
    p.add_argument("--store", help="tensor store folder (default $GLINT_DATA_DIR or ~/.cache/glint)")
    p.add_argument("--trace-regions", action="append", metavar="OBJECT=FILE",
                   help="trace this material's painted regions into the tensors as units of their own (the "
                        "light they send on to other surfaces); repeatable")


def add_commands(sub) -> None:
    g = sub.add_parser("gi", help="global illumination with BRDF editing (polynomial-gi tensors)")
    gs = g.add_subparsers(dest="gi_cmd", required=True)

    p = gs.add_parser("precompute", help="path-trace and store the multibounce tensors")
    gi_options(p)
    p.add_argument("--json", action="store_true")
    p.set_defaults(fn=cmd_precompute)

    r = gs.add_parser("render", help="render with edited materials (precomputing first if needed)")
    gi_options(r)
    r.add_argument("--out", required=True)
    r.add_argument("--raw", help="linear float32 H×W×3 radiance .npy")
    r.add_argument("--material", action="append", metavar="OBJECT=FILE",
                   help="an object's (or region's) material as JSON; repeatable")
    r.add_argument("--bounces-drawn", type=int, help="draw only the first N bounces (1: direct light)")
    r.add_argument("--exposure", type=float, default=0.0)
    r.add_argument("--tone", default="neutral", choices=["linear", "aces", "neutral"])
    r.set_defaults(fn=cmd_render)

