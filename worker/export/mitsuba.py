"""A Mitsuba 3 scene folder: ``scene.xml`` (scene format 3.0.0), ``meshes/<object>.ply`` (world
space, Glint's vertex normals) and ``envmap.exr`` (the map as Glint loaded it), with the
conventions of worker/mitsuba_ref.py (docs/design/conventions.md): the envmap's to_world is rotate(+Y, angle)
and scaled by the intensity, the camera a perspective sensor with fov_axis y and look_at.

Materials: a lambert or ggx material is written exactly (mitsuba_ref.bsdf_dict: diffuse,
roughconductor, or their blendbsdf); any other model as the Lambert + GGX material closest to it
(approx.approximate_ggx), whose error the report gives. A material with painted regions
(worker/models/regions.py) is its layers' BSDFs nested in ``blendbsdf``s, bottom first, as Glint
blends them: L_k = blend(L_{k−1}, region k, weight = w_k), each w_k a ``mesh_attribute`` texture
of a vertex property of the object's PLY (Mitsuba reads a property ``<name>_0`` as the
attribute ``vertex_<name>``). The folder is built beside its target and renamed into place, so a
reader never sees half of it.
"""
from __future__ import annotations

import shutil
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..envmap import save_exr
from ..mitsuba_ref import bsdf_dict
from ..scene import LoadedScene
from .common import ExportError, ObjectMesh

SCENE_VERSION = "3.0.0"
INTEGRATOR = "direct"      # Glint's cut renderer draws direct light (the GI renderer: "path")


def _vec(v) -> str:
    return ", ".join(f"{float(x):.9g}" for x in v)


def _add(parent: ET.Element, name: str | None, value) -> None:
    """One property of a load_dict-style dictionary as Mitsuba XML (the shapes bsdf_dict gives:
    nested plugins with "type", {"type": "rgb", "value"}, numbers, booleans and strings)."""
    if isinstance(value, dict) and value.get("type") == "rgb":
        ET.SubElement(parent, "rgb", name=name, value=_vec(value["value"]))
    elif isinstance(value, dict) and value.get("type") == "mesh_attribute":
        el = ET.SubElement(parent, "texture", type="mesh_attribute", name=name)
        ET.SubElement(el, "string", name="name", value=value["name"])
    elif isinstance(value, dict):
        tag = "bsdf" if name is None or name.startswith("bsdf") else name
        # nested BSDFs go in order (blendbsdf's bsdf_0, bsdf_1), as Mitsuba's XML reads them
        el = ET.SubElement(parent, tag, type=value["type"])
        for k, v in value.items():
            if k != "type":
                _add(el, k, v)
    elif isinstance(value, bool):
        ET.SubElement(parent, "boolean", name=name, value="true" if value else "false")
    elif isinstance(value, int):
        ET.SubElement(parent, "integer", name=name, value=str(value))
    elif isinstance(value, float):
        ET.SubElement(parent, "float", name=name, value=f"{value:.9g}")
    else:
        ET.SubElement(parent, "string", name=name, value=str(value))


def scene_xml(scene: LoadedScene, meshes: list[ObjectMesh], bsdfs: list[dict], spp: int, mesh_files: list[str],
              env_file: str, two_sided: bool | None = None) -> str:
    """The scene.xml text. two_sided (default: for GI scenes) wraps every BSDF in ``twosided``:
    the GI renderer shades both sides of a surface (a floor or wall quad lights the room from
    either side), as its references do (mitsuba_ref.py)."""
    spec = scene.spec
    cam, env = spec.camera, spec.environment
    gi = spec.renderer == "gi"
    if two_sided is None:
        two_sided = gi
    root = ET.Element("scene", version=SCENE_VERSION)
    integ = ET.SubElement(root, "integrator", type="path" if gi else INTEGRATOR)
    if gi:
        # the bounces the GI renderer draws: its options' (the series' length by default)
        from ..renderers.gi.options import parse_options
        bounces = parse_options(scene).bounces
        ET.SubElement(integ, "integer", name="max_depth", value=str(bounces + 1))
    s = ET.SubElement(root, "sensor", type="perspective")
    ET.SubElement(s, "float", name="fov", value=f"{cam.fov_y_deg:.9g}")
    ET.SubElement(s, "string", name="fov_axis", value="y")
    t = ET.SubElement(s, "transform", name="to_world")
    ET.SubElement(t, "lookat", origin=_vec(cam.eye), target=_vec(cam.target), up=_vec(cam.up))
    smp = ET.SubElement(s, "sampler", type="independent")
    ET.SubElement(smp, "integer", name="sample_count", value=str(int(spp)))
    film = ET.SubElement(s, "film", type="hdrfilm")
    ET.SubElement(film, "integer", name="width", value=str(cam.width))
    ET.SubElement(film, "integer", name="height", value=str(cam.height))
    ET.SubElement(film, "rfilter", type="box")
    ET.SubElement(film, "string", name="pixel_format", value="rgb")
    e = ET.SubElement(root, "emitter", type="envmap")
    ET.SubElement(e, "string", name="filename", value=env_file)
    ET.SubElement(e, "float", name="scale", value=f"{env.intensity:.9g}")
    t = ET.SubElement(e, "transform", name="to_world")
    ET.SubElement(t, "rotate", y="1", angle=f"{env.rotation_deg:.9g}")
    for om, b, f in zip(meshes, bsdfs, mesh_files):
        sh = ET.SubElement(root, "shape", type="ply", id=f"obj-{len(root)}")
        sh.append(ET.Comment(f" object {om.name} "))
        ET.SubElement(sh, "string", name="filename", value=f)
        ET.SubElement(sh, "boolean", name="face_normals", value="false")
        _add(sh, None, {"type": "twosided", "bsdf": b} if two_sided else b)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n"


def ply_property(attribute: str) -> str:
    """The PLY vertex property of a region's weight map (common.region_attribute): Mitsuba takes
    the text before a property's last '_' as the attribute's name, so the name keeps no '_'."""
    return attribute.replace("_", "").lower() + "_0"


def layered_bsdf(layers: list[dict], attributes: list[str]) -> dict:
    """A regions material's BSDF (load_dict form): layers (K + 1,) the base's and each region's
    BSDF, attributes (K,) the regions' weight map names (common.region_attribute)."""
    top = layers[0]
    for b, attr in zip(layers[1:], attributes):
        top = {"type": "blendbsdf",
               "weight": {"type": "mesh_attribute", "name": "vertex_" + ply_property(attr)[:-2]},
               "bsdf_0": top, "bsdf_1": b}
    return top


def _safe(name: str, i: int) -> str:
    keep = "".join(c if c.isalnum() or c in "-_" else "_" for c in name)[:64]
    return f"{i:03d}-{keep or 'object'}.ply"


def write_folder(out: Path, scene: LoadedScene, meshes: list[ObjectMesh], materials: list[list],
                 regions: list[tuple[list[str], np.ndarray]] | None = None, spp: int = 256) -> int:
    """Write the folder ``out`` (replacing an earlier export there); returns its size in bytes.
    materials : per object, its layers' lambert or ggx materials (within Mitsuba's blend bound):
    one for a plain material, the base's then each region's for one with regions; regions : per
    object, its regions' weight map names (K,) (common.region_attribute) and raw weights (K, V)
    float32 on the exported vertices (common.region_weights)."""
    import trimesh

    out = Path(out)
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not (out / "scene.xml").is_file())):
        raise ExportError(f"{out}: exists and is not an earlier Mitsuba export (no scene.xml); choose another --out")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=out.name + ".", suffix=".tmp", dir=out.parent))
    try:
        (tmp / "meshes").mkdir()
        files, bsdfs = [], []
        regions = regions or [([], np.zeros((0, len(om.vertices)), np.float32)) for om in meshes]
        for i, (om, layers, (attrs, w)) in enumerate(zip(meshes, materials, regions)):
            if len(layers) != len(w) + 1:
                raise ValueError(f"object {om.name!r}: {len(layers)} layer materials for {len(w)} regions")
            tm = trimesh.Trimesh(om.vertices, om.faces.astype(np.int64), vertex_normals=om.normals, process=False)
            for a, wk in zip(attrs, w):
                tm.vertex_attributes[ply_property(a)] = wk.astype(np.float32)
            rel = f"meshes/{_safe(om.name, i)}"
            (tmp / rel).write_bytes(trimesh.exchange.ply.export_ply(tm, include_attributes=len(w) > 0,
                                                                    vertex_normal=True))
            files.append(rel)
            bsdfs.append(layered_bsdf([bsdf_dict(m) for m in layers], attrs))
        save_exr(tmp / "envmap.exr", scene.envmap.astype(np.float32))
        (tmp / "scene.xml").write_text(scene_xml(scene, meshes, bsdfs, spp, files, "envmap.exr"))
        size = sum(p.stat().st_size for p in tmp.rglob("*") if p.is_file())
        old = None
        if out.exists():
            old = out.with_name(out.name + ".old-" + tmp.name.rsplit(".", 2)[-2])
            out.rename(old)
        tmp.rename(out)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return size
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
