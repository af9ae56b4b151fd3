"""``glint export SCENE.json --format gltf|mtlx|mitsuba --out PATH``: a scene and its materials
(and design variants) in a standard format, with the approximation's report.

Registered with one line in worker/cli.py COMMAND_MODULES. The report (the fitted materials'
BRDF errors, and with ``--render-check`` Glint's render of the exported materials against the
originals) goes to stderr, or as JSON to stdout with ``--json``.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path


def add_commands(sub) -> None:
    e = sub.add_parser("export", help="export a scene and its materials as glTF (.glb), MaterialX (.mtlx) or a Mitsuba 3 folder")
    e.add_argument("scene", help="SCENE.json")
    e.add_argument("--format", required=True, choices=["gltf", "mtlx", "mitsuba"])
    e.add_argument("--out", required=True, help="gltf: FILE.glb; mtlx: FILE.mtlx; mitsuba: a folder (scene.xml, meshes/, envmap.exr)")
    e.add_argument("--variant", action="append", metavar="LABEL=MATERIAL.json",
                   help="a design variant of --object: its name and a material file (e.g. from glint fit); repeatable "
                        "(gltf: KHR_materials_variants; mtlx: one look each)")
    e.add_argument("--object", help="the object the variants dress (default: the first)")
    e.add_argument("--render-check", action="store_true",
                   help="also render the exported materials with Glint against the originals (precomputes the cuts if needed)")
    e.add_argument("--spp", type=int, default=256, help="mitsuba: samples per pixel written in scene.xml")
    e.add_argument("--cuts", help="cut cache folder (for --render-check)")
    e.add_argument("--json", action="store_true", help="print the report as JSON")
    e.set_defaults(fn=cmd_export)

    from ..fit.cli import _bench_subparsers, _floats

    b = _bench_subparsers(sub).add_parser(
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


def read_variants(scene, specs, obj: str | None) -> list[dict]:
    """``LABEL=MATERIAL.json`` specs as variant dicts (common.parse_variants validates them)."""
    from .common import ExportError

    names = [o.name for o in scene.spec.objects]
    obj = obj or names[0]
    if obj not in names:
        raise ExportError(f"--object: no object {obj!r} (objects: {', '.join(names)})")
    out = []
    for spec in specs or []:
        label, sep, path = spec.rpartition("=")
        if not sep or not label:
            raise ExportError(f"--variant {spec!r}: expected LABEL=MATERIAL.json")
        p = Path(path)
        if not p.is_file():
            raise ExportError(f"--variant {spec!r}: {p}: material file not found")
        try:
            m = json.loads(p.read_text())
        except ValueError as e:
            raise ExportError(f"--variant {spec!r}: {p}: not JSON ({e})") from None
        out.append({"label": label, "materials": {obj: m}})
    return out


def cmd_export(a) -> int:
    from ..scene import load_scene
    from .common import parse_variants
    from .run import export

    sc = load_scene(a.scene)
    variants = parse_variants(sc, read_variants(sc, a.variant, a.object))
    renderer = None
    if a.render_check:
        from ..cli import open_renderer
        from ..core.cuts import DEFAULT_TAU

        renderer, _ = open_renderer(sc, a.cuts, a.json, {"tau": DEFAULT_TAU}, kind="cuts")
    rep = export(sc, a.format, Path(a.out), variants, renderer=renderer, mitsuba_spp=a.spp)
    if a.json:
        print(json.dumps(rep))
    else:
        for m in rep["materials"]:
            ext = ", ".join(m.get("extensions") or []) or ("exact" if m.get("exact") else "no extension")
            print(f"{m['label']}: relative BRDF RMSE {100 * m['rel_rmse']:.1f}% "
                  f"(directional albedo {100 * m['albedo_rel_rmse']:.1f}%; {ext})", file=sys.stderr)
        for r in rep.get("render", []):
            print(f"render {r['variant'] or 'as designed'}: relative RMSE {100 * r['rel_rmse']:.1f}% "
                  f"({r['width']}×{r['height']})", file=sys.stderr)
        print(f"wrote {rep['path']} ({rep['bytes']} bytes, {rep['seconds']:.1f} s)", file=sys.stderr)
    return 0


def cmd_bench_export_recovery(a) -> int:
    """For each recovery case (worker/fit/recovery.py): the fitted srbf design, its glTF fit's
    BRDF errors, and the relative RMSE of Glint's render (vertex mode) of the glTF material
    against the fitted design, and against the Mitsuba target the design was fitted to."""
    import os
    import time

    from tqdm import tqdm

    from ..fit.cli import _renderer_for
    from ..fit.recovery import ALPHAS, FINISHES, Case, interior_mask, recover, rel_rmse
    from ..renderers import FrameRequest
    from .approx import GltfPBR
    from .run import a_dict, gltf_approximation

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
