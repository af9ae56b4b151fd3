"""One export of a loaded scene to a format, with its report: the approximation of every
distinct material (approx.py) and, given a renderer of the scene, the relative RMSE of Glint's
render of the exported materials against the original ones."""
from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from ..models import BRDFModel, has_regions
from ..scene import LoadedScene
from .approx import Approximation, GltfPBR, approximate, approximate_ggx
from .common import (
    ExportError,
    Variant,
    check_format,
    check_regions,
    distinct_materials,
    layer_materials,
    material_key,
    object_meshes,
    region_attribute,
    region_weights,
)

RENDER_WIDTH = 160         # the render check's width (height by the camera's aspect)
_CACHE: dict[str, Approximation] = {}     # material_key -> glTF fit (a fit costs seconds)
_CACHE_MAX = 256


def gltf_approximation(m: BRDFModel) -> Approximation:
    """approximate(m), cached by the material's content."""
    k = material_key(m)
    if k not in _CACHE:
        if len(_CACHE) >= _CACHE_MAX:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[k] = approximate(m)
    return _CACHE[k]


def labels_of(scene: LoadedScene, variants: list[Variant]) -> dict[str, str]:
    """material_key -> a name: the object's for the scene's materials, the variant's for others;
    a regions material's layers by their region ("chair (seat, ggx)")."""
    out: dict[str, str] = {}

    def name(m: BRDFModel, owner: str, where: str = "") -> None:
        if has_regions(m):
            out.setdefault(material_key(m.base), f"{owner} ({where}base, {m.base.model})")
            for r in m.regions:
                out.setdefault(material_key(r.material), f"{owner} ({where}{r.name}, {r.material.model})")
        else:
            out.setdefault(material_key(m), f"{owner} ({where}{m.model})")

    for o in scene.spec.objects:
        name(o.material, o.name)
    for v in variants:
        for obj, m in v.materials.items():
            name(m, v.label, f"{obj}, ")
    return out


def exported_material(m: BRDFModel, layer: Callable[[BRDFModel], BRDFModel]) -> BRDFModel:
    """``m`` with each of its plain materials replaced by ``layer(material)`` (a regions material
    keeps its weights, so the render check compares what the formats carry)."""
    if not has_regions(m):
        return layer(m)
    return m.model_copy(update={"base": layer(m.base), "regions": [
        r.model_copy(update={"material": layer(r.material)}) for r in m.regions]})


def render_errors(renderer, variants: list[Variant], exported: Callable[[BRDFModel], BRDFModel],
                  width: int = RENDER_WIDTH, own: list[BRDFModel] | None = None) -> list[dict]:
    """Relative RMSE (over the objects' pixels, away from silhouettes) of Glint's render of the
    exported materials against the original materials, for the scene's own materials and each
    variant; vertex (Gouraud) shading, both sides in the same mode (the exported glTF material
    has no C kernel and its NumPy reference shades every pixel ~10× slower than a vertex frame,
    so the refined mode's per-pixel rows would cost more than the frame), at the scene's
    camera scaled to ``width``. own : the objects' own materials (the exported scene's; default
    the renderer's scene's)."""
    from scipy.ndimage import binary_erosion

    from ..fit.recovery import rel_rmse
    from ..renderers import FrameRequest

    sc = renderer.scene
    cam = sc.spec.camera
    w = min(width, cam.width)
    cam = cam.model_copy(update={"width": w, "height": max(1, round(cam.height * w / cam.width))})
    mask = binary_erosion(renderer.object_mask(cam) >= 0, iterations=1)
    names = [o.name for o in sc.spec.objects]
    own = own or [o.material for o in sc.spec.objects]
    out = []
    for label, over in [(None, {})] + [(v.label, v.materials) for v in variants]:
        mats = [over.get(n, m) for n, m in zip(names, own)]
        ref = renderer.render(FrameRequest(camera=cam, materials=mats, shading="vertex")).radiance
        exp = renderer.render(FrameRequest(camera=cam, materials=[exported_material(m, exported) for m in mats],
                                           shading="vertex")).radiance
        out.append({"variant": label, "rel_rmse": rel_rmse(exp, ref, mask), "pixels": int(mask.sum()),
                    "width": cam.width, "height": cam.height})
    return out


def export(scene: LoadedScene, fmt: str, out: Path, variants: list[Variant] | None = None, renderer=None,
           mitsuba_spp: int = 256, progress: Callable[[float, str], None] | None = None) -> dict:
    """Write ``scene`` (with ``variants``) as ``fmt`` to ``out`` and return the report:
    {"format", "path", "bytes", "objects", "faces", "variants", "materials": [{key, label, model,
    rel_rmse, albedo_rel_rmse, …}], "render": [{variant, rel_rmse, …}] (with a renderer), "seconds",
    and for a glb with painted regions "regions": [{object, storage: "texture" | "vertex attribute",
    why (for vertex attributes), texture_size, texture_error}]}.
    ExportError for bad input or sizes."""
    check_format(fmt)
    variants = variants or []
    progress = progress or (lambda f, msg: None)
    t0 = time.perf_counter()
    meshes = object_meshes(scene)
    mats = distinct_materials(scene, variants)
    labels = labels_of(scene, variants)
    default = [o.material for o in scene.spec.objects]
    for om, m in zip(meshes, default):       # regions painted on another mesh: refused before any fit
        check_regions(m, om)
    for v in variants:
        for om in meshes:
            if om.name in v.materials:
                check_regions(v.materials[om.name], om)
    report = {"format": fmt, "objects": len(meshes), "faces": int(sum(len(m.faces) for m in meshes)),
              "variants": [v.label for v in variants], "materials": []}
    if fmt == "mitsuba":
        if variants:
            raise ExportError("variants: a Mitsuba scene has one material per object; export each variant "
                              "as its own scene (or use gltf or mtlx)")
        fits = {}
        for i, (k, m) in enumerate(mats.items()):
            progress(i / max(1, len(mats)), f"material {i + 1}/{len(mats)}")
            g = fits[k] = approximate_ggx(m)
            report["materials"].append({"key": k, "label": labels[k], "model": m.model, "exact": g.exact,
                                        "as": g.material.model_dump(mode="json"), "rel_rmse": g.rel_rmse,
                                        "albedo_rel_rmse": g.albedo_rel_rmse})
        if renderer is not None:
            report["render"] = render_errors(renderer, [], lambda m: fits[material_key(m)].material, own=default)
        from .mitsuba import write_folder

        layers = [[fits[material_key(x)].material for x in layer_materials(o.material)] for o in scene.spec.objects]
        weights = [region_weights(m, om) for m, om in zip(default, meshes)]
        regions = [([region_attribute(m, k) for k in range(len(w))], w) for m, w in zip(default, weights)]
        report["bytes"] = write_folder(out, scene, meshes, layers, regions, spp=mitsuba_spp)
    else:
        approx = {}
        for i, (k, m) in enumerate(mats.items()):
            progress(0.9 * i / max(1, len(mats)), f"fitting material {i + 1}/{len(mats)}")
            a = approx[k] = gltf_approximation(m)
            report["materials"].append({"key": k, "label": labels[k], "model": m.model, **a.public()})
        if renderer is not None:
            progress(0.9, "render check")
            report["render"] = render_errors(renderer, variants,
                                             lambda m: GltfPBR(gltf=a_dict(approx[material_key(m)])), own=default)
        report["summary"] = summary(report)
        if fmt == "gltf":
            from .gltf import write_glb

            small = _small(report)
            report["bytes"] = write_glb(out, meshes, default, variants, approx, labels, small)
            if "regions" in small:            # how each painted object's weights were written
                report["regions"] = small["regions"]
        else:
            from .mtlx import document, validate, write_mtlx

            doc = document(meshes, default, variants, approx, labels, report)
            ok, msg = validate(doc)
            if not ok:       # a bug of ours, not the user's: say what MaterialX found
                raise RuntimeError(f"MaterialX rejects the exported document: {msg}")
            report["bytes"] = write_mtlx(out, doc)
    report["path"] = str(out)
    report["seconds"] = time.perf_counter() - t0
    progress(1.0, "done")
    return report


def a_dict(a: Approximation) -> dict:
    return {k: v for k, v in a.public()["gltf"].items()}


def summary(report: dict) -> str:
    """One line: the worst BRDF and render errors."""
    worst = max((m["rel_rmse"] for m in report["materials"]), default=0.0)
    s = f"worst relative BRDF RMSE {100 * worst:.1f}%"
    if report.get("render"):
        s += f", worst relative render RMSE {100 * max(r['rel_rmse'] for r in report['render']):.1f}%"
    return s


def _small(report: dict) -> dict:
    """The report as the glb's asset extras (without paths and times)."""
    return {k: v for k, v in report.items() if k in ("materials", "render", "summary", "variants")}
