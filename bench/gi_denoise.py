"""Accuracy, noise and cost of the denoised GI tensors (worker/renderers/gi/denoise.py) against
Mitsuba 3 ``path`` (max_depth = bounces + 1), with the noise of both sides stated.

    PYTHONPATH=. python bench/gi_denoise.py --case sofa --width 320 --height 240 --spp 64 --mitsuba-spp 512

Ours: two independent precomputations (seeds 0 and 1), raw and denoised (the denoising is the
one ``"denoise": true`` runs at precomputation, applied here to the cached raw tensors so that
the trace is paid once). Mitsuba: seeds 1 and 2. Error: relative RMSE of the means over 2×2
pixel blocks whose pixels all lie inside tests/gi/gi_harness.inner_mask, raw and with both
noises subtracted (gi_harness.compare); noise of one render = that of the mean × √2. Images
(ours raw | ours denoised | Mitsuba) go to --out.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "gi"), str(ROOT / "tests")]

from gi_harness import CACHE, compare, inner_mask, mitsuba, scene_with  # noqa: E402

from worker.scene import GGX  # noqa: E402

GLOSSY_FLOOR = GGX(alpha=0.1, specular=(0.5, 0.5, 0.5), albedo=(0.4, 0.12, 0.05))
GLOSSY_SOFA = GGX(alpha=0.2, specular=(0.5, 0.5, 0.5), albedo=(0.4, 0.4, 0.38))
GLOSSY_WALL = GGX(alpha=0.15, specular=(0.6, 0.6, 0.6), albedo=(0.1, 0.1, 0.1))
CASES = {  # name: (scene, materials, options)
    "sofa": ("sofa", {}, {}),
    "sofa-glossy-floor-and-sofa": ("sofa", {"floor": GLOSSY_FLOOR, "sofa": GLOSSY_SOFA},
                                   {"quotient": {"floor": "microfacet", "sofa": "microfacet"}}),
    "cornell": ("cornell", {}, {"quotient": {"back_wall": "microfacet"}}),
    "cornell-glossy-wall": ("cornell", {"back_wall": GLOSSY_WALL}, {"quotient": {"back_wall": "microfacet"}}),
}


def blocks(img: np.ndarray, b: int = 2) -> np.ndarray:
    h, w = img.shape[0] // b * b, img.shape[1] // b * b
    return img[:h, :w].reshape(h // b, b, w // b, b, -1).mean((1, 3))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", default="sofa", choices=sorted(CASES))
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--mitsuba-spp", type=int, default=512)
    ap.add_argument("--out", default=str(ROOT / "test-artifacts"))
    ap.add_argument("--quality", choices=["fast", "balanced", "high"], help="OIDN quality (default denoise.QUALITY)")
    ap.add_argument("--separate-tails", action="store_true",
                    help="one OIDN image per (hat component, tail) of the indirect bounces, as before 2026-12-06")
    a = ap.parse_args(argv)
    from PIL import Image

    from worker.artifacts import DirStore
    from worker.core.tonemap import tonemap
    from worker.native.kernels import kernels
    from worker.renderers import ensure, load
    from worker.renderers.gi import GIData, GIPrecomputation, GIRenderer
    from worker.renderers.gi.options import parse_options, unit_layout
    from worker.renderers.gi.renderer import denoise_tensors, region_images
    from worker.renderers.gi.trace import make_setup

    name, mats, extra = CASES[a.case]
    sc = scene_with(name, a.width, a.height, mats)
    pre = GIPrecomputation(kernels())
    store = DirStore(CACHE, "gi")
    raw, den, info = [], [], []
    for seed in (0, 1):
        opts = {"spp": a.spp, "series": [64, 1, 1, 1], "seed": seed, **extra}
        st = ensure(pre, sc, store, opts)
        (part,) = st["parts"].values()
        data = load(pre, sc, store, opts)
        raw.append(GIRenderer(sc, data))
        o = parse_options(sc, opts)
        S = make_setup(sc, o, unit_layout(sc, o), region_images(sc, o))
        t0, c1 = time.perf_counter(), time.process_time()
        bounces, dmeta = denoise_tensors(sc, S, data.bounces, quality=a.quality, together=not a.separate_tails)
        dt, dc = time.perf_counter() - t0, time.process_time() - c1
        meta = {**data.meta, "denoise": dmeta}
        den.append(GIRenderer(sc, GIData(meta, data.pixel, data.obj, bounces, data.opts)))
        info.append({"trace_seconds": part.get("seconds"), "trace_cached": part.get("cached"),
                     "denoise_seconds": dt, "denoise_cpu_seconds": dc, "images": dmeta["images"],
                     "quality": dmeta["quality"], "tails_together": dmeta["tails_together"],
                     "raw_bytes": data.nbytes, "denoised_bytes": int(sum(b.nbytes for b in bounces)),
                     "raw_entries": [b.entries for b in data.bounces], "denoised_entries": [b.entries for b in bounces]})
        print(json.dumps({"seed": seed, **info[-1]}), flush=True)
    N = raw[0].N
    ref = [mitsuba(sc, a.mitsuba_spp, s, N + 1) for s in (1, 2)]
    m = blocks(inner_mask(raw[0])[..., None].astype(float))[..., 0] == 1
    res = {"case": a.case, "width": a.width, "height": a.height, "spp": a.spp, "mitsuba_spp": a.mitsuba_spp,
           "blocks": int(m.sum()), "precompute": info}
    imgs = {}
    for label, rs in (("raw", raw), ("denoised", den)):
        for k, key in ((1, "direct"), (N, "gi")):
            out = []
            for r in rs:
                r.max_bounces = k
                out.append(r.draw().copy())
            imgs[(label, key)] = out
        c = compare([blocks(x) for x in imgs[(label, "gi")]], [blocks(x) for x in ref], m)
        c["noise_ours_one_render"] = c["noise_ours"] * np.sqrt(2)
        c["noise_ref_one_render"] = c["noise_ref"] * np.sqrt(2)
        res[label] = c
    # frames on the denoised tensors (this resolution): freeze and a BRDF sweep of the first unit
    from bench.gi import sweep as _sweep
    r = den[0]
    r.max_bounces = N
    r.draw()
    tf = [r.freeze(0) for _ in range(3)]
    ft = []
    for i in range(22):
        r.set_unit_material(0, _sweep(r, 0, i))
        t0 = time.perf_counter(); r.draw(); ft.append(time.perf_counter() - t0)
    res["frames"] = {"ms_freeze": 1000 * float(np.median(tf)), "ms_per_frame": 1000 * float(np.median(ft[2:])),
                     "unit": r.layout.names[0], "K1": r.K1, "live_layout": "dense" if r.frozen.dense is not None else "sparse"}
    out = Path(a.out); out.mkdir(parents=True, exist_ok=True)
    mean = lambda x: 0.5 * (x[0] + x[1])
    tile = np.concatenate([tonemap(imgs[("raw", "gi")][0]), tonemap(imgs[("denoised", "gi")][0]), tonemap(mean(ref))], 1)
    tag = f"{a.case}-{a.width}-{dmeta['quality']}{'-separate' if a.separate_tails else ''}"
    Image.fromarray(tile).save(out / f"gi-denoise-{tag}.png")
    (out / f"gi-denoise-{tag}.json").write_text(json.dumps(res, indent=1))
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
