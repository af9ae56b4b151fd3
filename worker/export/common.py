"""What every export format is given: a loaded scene, its objects' meshes in world space, their
materials and the design variants, with the limits that keep an export bounded."""
from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field

import numpy as np

from ..errors import GlintError
from ..models import BRDFModel, parse_material
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
    normals (V, 3) float32 unit vectors."""
    name: str
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray


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
    bounds = np.searchsorted(scene.object_of_face[order], np.arange(len(scene.spec.objects) + 1))
    for i, o in enumerate(scene.spec.objects):
        faces = mesh.faces[order[bounds[i]:bounds[i + 1]]]
        used = np.unique(faces)
        remap = np.full(len(mesh.vertices), -1, np.int64)
        remap[used] = np.arange(len(used))
        n = mesh.normals[used].astype(np.float64)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        out.append(ObjectMesh(o.name, mesh.vertices[used], remap[faces].astype(np.uint32), n.astype(np.float32)))
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


def distinct_materials(scene: LoadedScene, variants: list[Variant]) -> dict[str, BRDFModel]:
    """Every material the export holds (the scene's and the variants'), by material_key, in order."""
    out: dict[str, BRDFModel] = {}
    for m in scene.materials:
        out.setdefault(material_key(m), m)
    for v in variants:
        for m in v.materials.values():
            out.setdefault(material_key(m), m)
    return out
