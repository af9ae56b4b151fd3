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
        for r in rep.get("regions", []):
            how = (f"textures ({r['texture_size']}² through its texture coordinates)" if r["storage"] == "texture"
                   else f"vertex attributes: {r['why']}")
            print(f"{r['object']}: region weights as {how}", file=sys.stderr)
        print(f"wrote {rep['path']} ({rep['bytes']} bytes, {rep['seconds']:.1f} s)", file=sys.stderr)
    return 0
