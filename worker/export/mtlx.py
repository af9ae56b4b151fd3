"""MaterialX document of a scene's materials: an ``open_pbr_surface`` (OpenPBR Surface 1.1) and a
``surfacematerial`` per distinct Glint material, from its fitted glTF parameters (approx.py), and
a look per design variant binding materials to the objects by name (``/object``).

glTF → OpenPBR (both are a GGX dielectric-metal mix with a coat and a fuzz layer):

* base_color, base_metalness, specular_roughness, specular_weight ← baseColor, metallic,
  roughness, specular;
* specular_color and specular_ior ← KHR_materials_specular's specularColor c: OpenPBR's
  F0 = ((ior − 1)/(ior + 1))²·specular_color with specular_color ≤ 1, so the ior takes the
  brightness, F0 = min(0.04·max c, 1), and specular_color the tint c / max c;
* coat_weight, coat_roughness ← clearcoat, clearcoatRoughness, coat_ior 1.5 (glTF's coat F0 0.04);
* fuzz_weight, fuzz_color, fuzz_roughness ← max sheenColor, sheenColor / max, sheenRoughness.

A material with painted regions (worker/models/regions.py) is its layers' shaders mixed per vertex,
bottom first, as Glint blends them: L_k = mix(bg = L_{k−1}, fg = region k's shader, mix = w_k),
with w_k a ``geompropvalue`` of the region's weight map (the name common.region_attribute gives,
which the glTF export writes as the mesh's vertex attribute).
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import MaterialX as mx
import numpy as np

from ..atomic import atomic_write
from ..models import BRDFModel, has_regions
from .approx import Approximation, GltfMaterial
from .common import ObjectMesh, Variant, layer_materials, material_key, region_attribute

SHADER = "open_pbr_surface"


@lru_cache(maxsize=1)
def libraries() -> mx.Document:
    """MaterialX's standard data libraries (node definitions), loaded once."""
    lib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
    return lib


def _ior(f0: float) -> float:
    r = np.sqrt(np.clip(f0, 1e-6, 0.999))
    return float((1 + r) / (1 - r))


def openpbr_inputs(m: GltfMaterial) -> dict[str, tuple[str, object]]:
    """OpenPBR inputs (name -> (type, value)) of a fitted glTF material (module docstring)."""
    inp: dict[str, tuple[str, object]] = {
        "base_weight": ("float", 1.0), "base_color": ("color3", m.base_color),
        "base_metalness": ("float", m.metallic), "specular_roughness": ("float", m.roughness),
        "specular_weight": ("float", 1.0 if m.specular is None else m.specular), "specular_ior": ("float", 1.5)}
    if m.specular_color is not None and (m.specular or 0.0) >= 1e-3:
        # (a vanishing specular weight leaves the colour undetermined: OpenPBR's defaults then)
        c = np.asarray(m.specular_color, np.float64)
        mx_ = float(c.max())
        if mx_ > 0:
            inp["specular_color"] = ("color3", tuple(float(x) for x in c / mx_))
            inp["specular_ior"] = ("float", _ior(min(0.04 * mx_, 1.0)))
        else:
            inp["specular_weight"] = ("float", 0.0)
    if m.clearcoat is not None:
        inp.update({"coat_weight": ("float", m.clearcoat), "coat_roughness": ("float", m.clearcoat_roughness),
                    "coat_ior": ("float", 1.5)})
    if m.sheen_color is not None:
        c = np.asarray(m.sheen_color, np.float64)
        w = float(c.max())
        inp.update({"fuzz_weight": ("float", w),
                    "fuzz_color": ("color3", tuple(float(x) for x in (c / w if w > 0 else np.ones(3)))),
                    "fuzz_roughness": ("float", m.sheen_roughness)})
    return inp


def _name(text: str) -> str:
    return mx.createValidName(text)


def _unique(doc: mx.Document, base: str) -> str:
    n, i = base or "material", 1
    while doc.getChild(f"{n}_shader") is not None or doc.getChild(n) is not None:
        i += 1
        n = f"{base}_{i}"
    return n


def document(meshes: list[ObjectMesh], default: list[BRDFModel], variants: list[Variant],
             approx: dict[str, Approximation], labels: dict[str, str], report: dict) -> mx.Document:
    """The MaterialX document (no libraries imported into it). default : each object's own
    material; approx : material_key of every plain material -> its fitted glTF material."""
    doc = mx.createDocument()
    doc.setDocString(f"Glint export: OpenPBR fits of Glint materials; relative BRDF RMSE per material "
                     f"in each shader's doc. {report.get('summary', '')}".strip())
    every = default + [m for v in variants for m in v.materials.values()]
    shaders: dict[str, mx.Node] = {}
    for k in dict.fromkeys(material_key(x) for m in every for x in layer_materials(m)):
        n = _unique(doc, _name(labels[k]))
        sh = shaders[k] = doc.addNode(SHADER, f"{n}_shader", "surfaceshader")
        sh.setDocString(f"fitted to Glint material {k}: rel_rmse {approx[k].rel_rmse:.4f}, "
                        f"albedo_rel_rmse {approx[k].albedo_rel_rmse:.4f}")
        for inp, (t, v) in openpbr_inputs(approx[k].material).items():
            val = mx.Color3(*map(float, v)) if t == "color3" else float(v)
            sh.setInputValue(inp, val, t)
    names = {}
    for m in dict((material_key(m), m) for m in every).values():
        k = material_key(m)
        if has_regions(m):
            n = _unique(doc, _name(f"regions_{k}"))
            top = shaders[material_key(m.base)]
            for i, r in enumerate(m.regions):
                gp = doc.addNode("geompropvalue", f"{n}_w{i}", "float")
                gp.setInputValue("geomprop", region_attribute(m, i), "string")
                gp.setDocString(f"weight map of region {r.name!r}")
                mix = doc.addNode("mix", f"{n}_mix{i}", "surfaceshader")
                mix.setConnectedNode("bg", top)
                mix.setConnectedNode("fg", shaders[material_key(r.material)])
                mix.setConnectedNode("mix", gp)
                top = mix
            mat = doc.addMaterialNode(n, top)
            mat.setAttribute("uiname", "regions: " + ", ".join(r.name for r in m.regions))
        else:
            n = shaders[k].getName()[:-len("_shader")]
            mat = doc.addMaterialNode(n, shaders[k])
            mat.setAttribute("uiname", labels[k])
        names[k] = mat.getName()
    looks = [("default", {om.name: material_key(default[i]) for i, om in enumerate(meshes)})]
    for v in variants:
        looks.append((v.label, {om.name: material_key(v.materials.get(om.name, default[i]))
                                for i, om in enumerate(meshes)}))
    for j, (label, assign) in enumerate(looks):
        lk = doc.addLook(_name(f"look_{label}") if j else "look_default")
        lk.setAttribute("uiname", label)
        for obj, k in assign.items():
            ma = lk.addMaterialAssign(_name(f"assign_{obj}"), names[k])
            ma.setGeom(f"/{obj}")
    return doc


def validate(doc: mx.Document) -> tuple[bool, str]:
    """MaterialX's own validation of ``doc`` against the standard libraries: (ok, message)."""
    check = mx.createDocument()
    check.copyContentFrom(doc)
    check.importLibrary(libraries())
    return check.validate()


def write_mtlx(path: Path, doc: mx.Document) -> int:
    """Write the document atomically; returns its size in bytes."""
    data = mx.writeToXmlString(doc).encode()
    atomic_write(Path(path), data)
    return len(data)
