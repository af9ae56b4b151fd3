"""``glint bench export-recovery``: the glTF approximation error of the recovery benchmark's
fitted designs (bench/fitting.py ``recovery``; docs/benchmarks/history/exports.md)."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from .fitting import _floats, _renderer_for


def add_bench_commands(bsub) -> None:
    """``glint bench export-recovery`` into the subparsers of ``glint bench``."""
    b = bsub.add_parser(
        "export-recovery", help="glTF approximation error of the recovery benchmark's fitted designs (srbf fits of GGX renders)")
    b.add_argument("scenes", nargs="+", help="scene files, as for glint bench recovery")
    b.add_argument("--env", action="append", required=True, help="environment map (repeatable)")
    b.add_argument("--alpha", type=_floats, default=None, help="GGX α values (default 0.05,0.1,0.15,0.25,0.4)")
    b.add_argument("--spp", type=int, default=128, help="Mitsuba samples per pixel per seed of the targets")
    b.add_argument("--cache", help="folder for Mitsuba targets (default $GLINT_DATA_DIR/mitsuba)")
    b.add_argument("--cuts", help="cut cache folder")
    b.add_argument("--json", action="store_true",
                   help="one JSON object a line: each case as it is done, then {\"summary\": …}")
    b.set_defaults(fn=cmd_bench_export_recovery)


def cmd_bench_export_recovery(a) -> int:
    """For each recovery case (worker/fit/recovery.py): the fitted srbf design, its glTF fit's
    BRDF errors, and the relative RMSE of Glint's render (vertex mode) of the glTF material
    against the fitted design, and against the Mitsuba target the design was fitted to."""
    import os
    import time

    from tqdm import tqdm

    from worker.fit.recovery import ALPHAS, FINISHES, Case, interior_mask, recover, rel_rmse
    from worker.renderers import FrameRequest
    from worker.export.approx import GltfPBR
    from worker.export.run import a_dict, gltf_approximation

    cache = Path(a.cache) if a.cache else Path(os.environ.get("GLINT_DATA_DIR", Path.home() / ".cache" / "glint")) / "mitsuba"
    cases = [(s, e, al, sp, alb) for s in a.scenes for e in a.env for al in (a.alpha or ALPHAS) for sp, alb in FINISHES]
    out, t0 = [], time.perf_counter()
    bar = tqdm(total=len(cases), desc="export-recovery", file=sys.stderr)
    loaded = {}
    for s, e, al, sp, alb in cases:
        if (s, e) not in loaded:
            loaded.clear()
            loaded[(s, e)] = _renderer_for(s, e, a.cuts, 1.0, True)
        r = loaded[(s, e)]
        case = Case(Path(s).stem, Path(e).name, al, sp, tuple(alb))
        res = recover(r, case, spp=a.spp, cache_dir=cache)
        design = res["_material"]
        ap = gltf_approximation(design)
        cam = r.scene.spec.camera
        mask = interior_mask(r)
        fit_vx = r.render(FrameRequest(camera=cam, materials=[design], shading="vertex")).radiance
        gl_vx = r.render(FrameRequest(camera=cam, materials=[GltfPBR(gltf=a_dict(ap))], shading="vertex")).radiance
        row = {"scene": case.scene, "env": case.env, "alpha": al, "specular": sp, "albedo": list(alb),
               "extensions": ap.material.extensions, "gltf": a_dict(ap), "brdf_rel_rmse": ap.rel_rmse,
               "albedo_rel_rmse": ap.albedo_rel_rmse, "render_rel_rmse": rel_rmse(gl_vx, fit_vx, mask),
               "design_vs_target": res["rel_rmse_vertex"],
               "gltf_vs_target": rel_rmse(gl_vx, res["_images"]["target"], mask)}
        out.append(row)
        if a.json:            # as each case is done: a long run interrupted keeps its results
            print(json.dumps(row), flush=True)
        bar.update(1)
        bar.set_postfix_str(f"α={al:g}: BRDF {100 * ap.rel_rmse:.1f}%, render {100 * row['render_rel_rmse']:.1f}%")
    bar.close()
    summary = {"cases": len(out), "seconds": time.perf_counter() - t0, "spp": a.spp,
               "worst_render_rel_rmse": max(x["render_rel_rmse"] for x in out),
               "median_render_rel_rmse": sorted(x["render_rel_rmse"] for x in out)[len(out) // 2],
               "worst_brdf_rel_rmse": max(x["brdf_rel_rmse"] for x in out)}
    if a.json:
        print(json.dumps({"summary": summary}))
    else:
        for x in out:
            print(f"{x['scene']} {x['env']} α={x['alpha']:g} s={x['specular']:g}: BRDF {100 * x['brdf_rel_rmse']:.1f}%, "
                  f"render {100 * x['render_rel_rmse']:.1f}% ({', '.join(x['extensions']) or 'core'})")
    return 0
