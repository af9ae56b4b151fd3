"""The worker's job handlers (precompute, missing_parts, render, fit, capture, export, bundle_frames), in one registry: ``JOBS``,
job type -> handler(cache, payload, progress) -> result dict. progress : (fraction 0..1,
message[, extra dict sent along: a precomputation's preview]) -> None; a handler raises JobError
(or GlintError, ValueError) for bad input."""
from __future__ import annotations

import logging
import os
from pathlib import Path

from .data_cache import DataCache
from .ipc import JobError

log = logging.getLogger("glint.worker")


def _render(cache: DataCache, p: dict) -> dict:
    import io

    import numpy as np
    from PIL import Image

    from worker.core.tonemap import tonemap
    from worker.overrides import InvalidMaterial, UnknownObject, apply_material_overrides
    from worker.renderers import FrameRequest, Lighting
    from worker.scene import Camera, Transform

    r = cache.renderer(p["scene"])
    sc = r.scene
    names = [o.name for o in sc.spec.objects]
    try:
        mats = apply_material_overrides(sc, (p.get("materials") or {}).items())
    except UnknownObject as e:
        raise JobError(f"materials: {e}") from None
    except InvalidMaterial as e:
        raise JobError(f"materials: {e}") from e
    env = sc.spec.environment
    cam = Camera.model_validate(p["camera"]) if p.get("camera") else sc.spec.camera
    rot = env.rotation_deg if p.get("rotation_deg") is None else p["rotation_deg"]
    inten = env.intensity if p.get("intensity") is None else p["intensity"]
    transforms = {}
    for name, t in (p.get("transforms") or {}).items():
        if name not in names:
            raise JobError(f"transforms: no object {name!r} in the scene (objects: {', '.join(names)})")
        transforms[name] = Transform.model_validate(t)
    out = r.render(FrameRequest(camera=cam, lighting=Lighting(rot, inten), materials=mats,
                                shading=p.get("mode", "refined"), transforms=transforms or None))
    img = out.radiance
    if p.get("format") == "exr":
        import tempfile

        from worker.envmap import save_exr

        with tempfile.TemporaryDirectory(dir=cache.tmp) as d:
            path = Path(d) / "r.exr"
            save_exr(path, img.astype(np.float32))
            return {"bytes": path.read_bytes(), "media_type": "image/x-exr"}
    buf = io.BytesIO()
    Image.fromarray(tonemap(img, p.get("exposure", 0.0), p.get("tone", "neutral"))).save(buf, format="PNG")
    return {"bytes": buf.getvalue(), "media_type": "image/png"}


def _fit(cache: DataCache, p: dict) -> dict:
    import json

    import numpy as np

    from worker.fit.basis import default_basis
    from worker.fit.files import ViewSpec, load_mask, load_target
    from worker.fit.fitter import DEFAULT_UNPAINTED_WEIGHT, Fitter

    r = cache.renderer(p["scene"])
    req = p["request"]
    f0 = req.get("fresnel_f0")
    basis = default_basis(fresnel_f0=1.0 if f0 is None else f0)     # 0 means 0, not the default
    fx = Fitter(r, req["object"], basis=basis, fit_scale=req.get("fit_scale") or 0.25, albedo=req.get("albedo"))
    notes = []
    if req.get("strokes"):
        for v in req.get("views") or [{}]:
            v = ViewSpec.model_validate(v)
            fx.add_view(v.camera, v.rotation_deg, v.intensity)
        for s in req["strokes"]:
            notes += fx.add_stroke(s)
        out = fx.fit(constrained=req.get("constrained", True),
                     unpainted_weight=req.get("unpainted_weight", DEFAULT_UNPAINTED_WEIGHT))
    else:
        fx.add_view()
        target = load_target(cache.linked(p["target"]))
        mask = load_mask(cache.linked(p["mask"])) if p.get("mask") else None
        out = fx.fit_targets([target], [mask], constrained=req.get("constrained", True))
    s = out.solve
    return {"material": json.loads(out.material.model_dump_json()),
            "stats": {"seconds_transfer": out.seconds_transfer, "seconds_solve": s.seconds, "pixels": out.pixels,
                      "painted": out.painted, "basis": fx.basis.J, "residual_rms": s.residual_rms,
                      "residual_rel": s.residual_rel, "energy_max": s.energy_max,
                      "energy_bound": float(np.min(s.energy_bound)), "constrained": s.constrained,
                      "notes": list(dict.fromkeys(notes + out.notes))}}


def _precompute(cache: DataCache, p: dict, progress) -> dict:
    """Ensure a scene's precomputation in the blob store (parts already there are reused)."""
    from worker.renderers import get

    kind = p["scene"].get("renderer") or "cuts"
    sc = cache.scene(p["scene"])
    options = p["scene"].get("options") or {}
    # the scene's renderer, and the cut renderer for every scene (a GI scene's way back to direct
    # light and a free camera; the paint renderer's self-shadowing)
    kinds = [kind] + (["cuts"] if kind != "cuts" else [])
    pres = [get(k)[1] for k in kinds]
    total = max(1, sum(x.work for pre in pres for x in pre.parts(sc, options if pre.kind == kind else {})))
    done = [0.0, -1.0]
    stage = [""]

    def tick(k):
        done[0] += k
        f = min(1.0, done[0] / total)
        if f - done[1] >= 0.01 or done[0] >= total:
            done[1] = f
            progress(f, f"{stage[0]}: {round(done[0])}/{total}" if stage[0] else f"{round(done[0])}/{total}")

    def say(text):
        stage[0] = text
        progress(max(0.0, done[1]), f"{text}: {round(done[0])}/{total}")

    from worker.renderers import ensure

    preview = {}
    if len(sc.mesh.vertices) >= cache.settings.preview_min_vertices and any(
           cache.parts.sha(part.key) is None for pre in pres
           for part in pre.parts(sc, options if pre.kind == kind else {})):
        say("a first look at the scene")
        preview = first_look(cache, sc)
        if preview:
            progress(0.0, "a first look at the scene: ready", {"preview": preview})
    manifest, flat, seconds, computed = {}, {}, 0.0, 0
    for pre in pres:
        stats = ensure(pre, sc, cache.parts, options if pre.kind == kind else {}, tick,
                       threads=cache.settings.threads or os.cpu_count() or 2, stage=say)
        manifest.update({k: cache.parts.sha(k) for k in stats["parts"]})
        for info in stats["parts"].values():
            if pre.kind == kind:          # the scene renderer's figures are the job's headline
                flat.update({k: v for k, v in info.items() if k not in ("label",)})
        seconds += stats["seconds"]
        computed += stats["computed"]
    return {"kind": kind, "parts": manifest, "stats": {**flat, "seconds": seconds, "computed": computed,
                                                       "renderers": kinds, **({"preview": preview} if preview else {})}}


def _missing_parts(cache: DataCache, p: dict, progress) -> dict:
    """The parts a precompute job of this scene would have to compute (their labels): none when
    its stored precomputation is current. Loads the scene and computes the parts' content keys,
    nothing more."""
    from worker.renderers import get

    kind = p["scene"].get("renderer") or "cuts"
    sc = cache.scene(p["scene"])
    options = p["scene"].get("options") or {}
    kinds = [kind] + (["cuts"] if kind != "cuts" else [])
    missing = [part.label for k in kinds
               for part in get(k)[1].parts(sc, options if k == kind else {}) if cache.parts.sha(part.key) is None]
    return {"missing": missing}


def first_look(cache: DataCache, sc) -> dict:
    """The preview frame of a scene whose precomputation is about to run (renderers/cuts/
    preview.py), stored as a blob: {"sha256", "seconds", "rays", "width", "height", "exposure"};
    {} when it cannot be drawn (a material the cut renderer does not shade): the precomputation
    goes on without it."""
    from worker.renderers.cuts.preview import preview_jpeg

    try:
        jpeg, stats = preview_jpeg(sc, threads=cache.settings.threads or os.cpu_count() or 2)
    except Exception:   # noqa: BLE001 -- a first look is optional; the precomputation is not
        log.exception("no preview of the scene")
        return {}
    return {"sha256": cache.blobs.put(jpeg), **stats}


def _capture(cache: DataCache, p: dict, progress) -> dict:
    """A lighting capture (worker/capture): the uploaded zip extracted in this worker's scratch
    folder (paths checked, sizes capped), processed, and the map and its preview stored as blobs."""
    import shutil
    import tempfile

    from worker.capture.job import extract_capture_zip, run_capture

    work = Path(tempfile.mkdtemp(prefix="capture-", dir=cache.tmp))
    try:
        manifest = extract_capture_zip(cache.blobs.verified_path(p["zip_sha256"]), work, p.get("max_files", 64),
                                       p.get("max_total_bytes", 2 * 1024 ** 3))
        exr, png, stats = run_capture(manifest, progress, root=work)
        return {"exr_sha256": cache.blobs.put(exr), "exr_bytes": len(exr), "preview_sha256": cache.blobs.put(png),
                "stats": stats}
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _export(cache: DataCache, p: dict, progress) -> dict:
    """A scene exported (worker/export) in this worker's scratch folder: the file's bytes (the
    Mitsuba folder zipped, with its report.json), a file name and the report."""
    import json
    import re
    import shutil
    import tempfile
    import zipfile

    from worker.export.common import ExportError, parse_variants
    from worker.export.run import export

    sc = cache.scene(p["scene"])
    renderer = cache.renderer(p["scene"], "cuts") if p.get("render_check") else None
    variants = parse_variants(sc, p.get("variants"))
    name = re.sub(r"[^A-Za-z0-9_-]+", "-", sc.spec.objects[0].name).strip("-") or "scene"
    work = Path(tempfile.mkdtemp(prefix="export-", dir=cache.tmp))
    try:
        fmt = p["format"]
        out = work / {"gltf": "scene.glb", "mtlx": "scene.mtlx", "mitsuba": "scene"}[fmt]
        rep = export(sc, fmt, out, variants, renderer=renderer, progress=progress)
        if fmt != "mitsuba":
            return {"bytes": out.read_bytes(), "name": name, "report": rep}
        zpath = work / "scene.zip"
        with zipfile.ZipFile(zpath, "w", zipfile.ZIP_DEFLATED) as z:
            for f in sorted(out.rglob("*")):
                if f.is_file():
                    z.write(f, f"{name}/{f.relative_to(out)}")
            z.writestr(f"{name}/report.json", json.dumps({k: v for k, v in rep.items() if k != "path"}, indent=1))
        return {"bytes": zpath.read_bytes(), "name": name, "report": rep}
    except ExportError as e:
        raise JobError(str(e), e.status) from None
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _bundle_frames(cache: DataCache, p: dict, progress) -> dict:
    from worker.publish.frames import render_frames

    return render_frames(cache, p, progress)


JOBS = {"render": lambda cache, p, progress: _render(cache, p),
        "fit": lambda cache, p, progress: _fit(cache, p),
        "precompute": _precompute, "missing_parts": _missing_parts, "capture": _capture, "export": _export,
        "bundle_frames": _bundle_frames}


def run_job(cache: DataCache, p: dict, progress) -> dict:
    """The result of job payload ``p`` (its "type" picks the handler)."""
    handler = JOBS.get(p["type"])
    if handler is None:
        raise JobError(f"unknown job type {p['type']!r}", 400)
    return handler(cache, p, progress)
