"""What every export format is given: a loaded scene, its objects' meshes in world space, their
materials and the design variants, with the limits that keep an export bounded."""
from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field

import numpy as np

from ..errors import GlintError
from ..models import BRDFModel, has_regions, parse_material
from ..scene import LoadedScene

FORMATS = ("gltf", "mtlx", "mitsuba")
# bounds of one export: a glb of 2 M faces with normals is ~70 MB; each distinct material costs a
# fit of a few seconds (approx.py)
MAX_FACES = int(os.environ.get("GLINT_MAX_EXPORT_FACES", "2000000"))
MAX_VARIANTS = 16
MAX_LABEL = 200


class ExportError(GlintError):
    """An export that cannot be made (bad variant, too large, unknown format); names the cause."""


@dataclass
class Variant:
    """A named design: materials by object name (objects not named keep the scene's material)."""
    label: str
    materials: dict[str, BRDFModel] = field(default_factory=dict)


@dataclass
class ObjectMesh:
    """One object's triangles in world space: vertices (V, 3) float32, faces (F, 3) uint32,
    normals (V, 3) float32 unit vectors; vertex_ids (V,) int64, each exported vertex's id in the
    object's own mesh (what a regions material's weights index), of n_vertices in all; uvs (V, 2)
    float32 the file's texture coordinates (scene.Mesh: bottom-left origin, NaN where a part has
    none) or None without any."""
    name: str
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    vertex_ids: np.ndarray | None = None
    n_vertices: int = 0
    uvs: np.ndarray | None = None
    source: np.ndarray | None = None        # scene.LoadedScene.vertex_source of the object


def check_format(fmt: str) -> str:
    if fmt not in FORMATS:
        raise ExportError(f"format: unknown export format {fmt!r} (formats: {', '.join(FORMATS)})")
    return fmt


def object_meshes(scene: LoadedScene) -> list[ObjectMesh]:
    """Each object's part of the scene's concatenated mesh, re-indexed; ExportError beyond MAX_FACES."""
    mesh = scene.mesh
    if len(mesh.faces) > MAX_FACES:
        raise ExportError(f"the scene has {len(mesh.faces)} faces, over the export limit of {MAX_FACES} "
                          "(GLINT_MAX_EXPORT_FACES)", 413)
    out = []
    order = np.argsort(scene.object_of_face, kind="stable")
    first = np.searchsorted(scene.object_of_vertex, np.arange(len(scene.spec.objects) + 1))
    bounds = np.searchsorted(scene.object_of_face[order], np.arange(len(scene.spec.objects) + 1))
    for i, o in enumerate(scene.spec.objects):
        faces = mesh.faces[order[bounds[i]:bounds[i + 1]]]
        used = np.unique(faces)
        remap = np.full(len(mesh.vertices), -1, np.int64)
        remap[used] = np.arange(len(used))
        n = mesh.normals[used].astype(np.float64)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        # (an object's vertices are contiguous in the scene's mesh, scene.LoadedScene)
        uvs = None if mesh.uvs is None or np.isnan(mesh.uvs[used]).all() else mesh.uvs[used]
        out.append(ObjectMesh(o.name, mesh.vertices[used], remap[faces].astype(np.uint32), n.astype(np.float32),
                              vertex_ids=used.astype(np.int64) - int(first[i]),
                              n_vertices=int(first[i + 1] - first[i]), uvs=uvs, source=scene.vertex_source(i)))
    return out


def parse_variants(scene: LoadedScene, variants: list[dict] | None) -> list[Variant]:
    """Variants from JSON: [{"label": str, "materials": {object: material JSON}}]; ExportError for
    an unknown object, a bad material, a repeated or empty label or too many variants."""
    names = [o.name for o in scene.spec.objects]
    out: list[Variant] = []
    variants = variants or []
    if len(variants) > MAX_VARIANTS:
        raise ExportError(f"variants: {len(variants)} variants, over the limit of {MAX_VARIANTS}", 413)
    for i, v in enumerate(variants):
        label = str(v.get("label") or "").strip()
        if not label or len(label) > MAX_LABEL:
            raise ExportError(f"variants[{i}].label: a variant needs a name of 1-{MAX_LABEL} characters")
        if any(x.label == label for x in out):
            raise ExportError(f"variants[{i}].label: {label!r} is repeated")
        mats = {}
        for obj, m in (v.get("materials") or {}).items():
            if obj not in names:
                raise ExportError(f"variants[{i}].materials: no object {obj!r} (objects: {', '.join(names)})")
            try:
                mats[obj] = m if isinstance(m, BRDFModel) else parse_material(m)
            except ValueError as e:
                raise ExportError(f"variants[{i}].materials.{obj}: {e}") from None
        if not mats:
            raise ExportError(f"variants[{i}].materials: a variant gives at least one object's material")
        out.append(Variant(label, mats))
    return out


def material_key(m: BRDFModel) -> str:
    """Content key of a material (the same design in two variants is fitted once)."""
    return hashlib.sha256(json.dumps(m.model_dump(mode="json"), sort_keys=True).encode()).hexdigest()[:16]


def layer_materials(m: BRDFModel) -> list[BRDFModel]:
    """The plain materials a material is made of: itself, or a regions material's base and then
    each region's material, bottom first (worker/models/regions.py)."""
    if has_regions(m):
        return [m.base] + [r.material for r in m.regions]
    return [m]


def check_regions(m: BRDFModel, om: ObjectMesh) -> BRDFModel:
    """``m`` with its regions over ``om``'s object's vertices (models.regions.fit_mesh: remapped
    when painted before the object's vertices were split at creases); ExportError when ``m`` has
    regions painted on a mesh of another size."""
    from ..models.regions import RegionsError, fit_mesh

    try:
        return fit_mesh(m, om.n_vertices, om.source)
    except RegionsError:
        raise ExportError(f"object {om.name!r}: its material's regions were painted on a mesh of "
                          f"{m.vertex_count} vertices, but the object has {om.n_vertices}") from None


def region_weights(m: BRDFModel, om: ObjectMesh) -> np.ndarray:
    """A regions material's raw weights on the exported vertices of ``om``: w (K, V) float32, one
    row per region (bottom first), the w_k of L_k = (1 − w_k) L_{k−1} + w_k L_region_k; (0, V) for a
    plain material. ExportError when the regions were painted on a mesh of another size."""
    if not has_regions(m):
        return np.zeros((0, len(om.vertices)), np.float32)
    m = check_regions(m, om)
    return np.stack([r.dense(om.n_vertices)[om.vertex_ids] for r in m.regions]).astype(np.float32)


def region_attribute(m: BRDFModel, k: int) -> str:
    """The name every format gives region k (bottom first) of the regions material ``m``'s weight
    map: a glTF vertex attribute, a MaterialX geomprop, a Mitsuba mesh attribute (with its
    prefix). From the material's content, so the same design is the same name in every file."""
    return f"_GLINT_REGION_{material_key(m)[:8].upper()}_{k}"


def effective_weights(m: BRDFModel, om: ObjectMesh) -> np.ndarray:
    """The layers' effective weights a (L, V) float32 on the exported vertices of ``om``
    (Regions.layers: Σ_l a_l = 1; one row of ones for a plain material)."""
    if not has_regions(m):
        return np.ones((1, len(om.vertices)), np.float32)
    return check_regions(m, om).layers()[1][:, om.vertex_ids]


def distinct_materials(scene: LoadedScene, variants: list[Variant]) -> dict[str, BRDFModel]:
    """Every plain material the export holds (the scene's and the variants', a regions material
    as its layers, layer_materials), by material_key, in order."""
    out: dict[str, BRDFModel] = {}
    for m in scene.materials + [m for v in variants for m in v.materials.values()]:
        for layer in layer_materials(m):
            out.setdefault(material_key(layer), layer)
    return out
