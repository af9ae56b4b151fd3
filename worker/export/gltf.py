"""glTF 2.0 binary (.glb) of a scene: one mesh a object (positions, normals, indices, world
space: Glint's +Y up and metres are glTF's), one fitted metallic-roughness material per distinct
Glint material (approx.py), and the design variants through ``KHR_materials_variants``.

Written with pygltflib (the document model and the GLB container); the buffer layout (one
buffer, a view per accessor, 4-byte aligned) is the plain one the spec describes.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib as gl

from ..atomic import atomic_write
from .approx import Approximation, GltfMaterial
from .common import ObjectMesh, Variant, material_key

GENERATOR = "Glint (worker/export/gltf.py)"


def material_json(name: str, m: GltfMaterial, extras: dict) -> gl.Material:
    """A glTF material of the fitted parameters, with the extensions it uses."""
    ext = {}
    if m.specular is not None:
        ext["KHR_materials_specular"] = {"specularFactor": m.specular, "specularColorFactor": list(m.specular_color)}
    if m.clearcoat is not None:
        ext["KHR_materials_clearcoat"] = {"clearcoatFactor": m.clearcoat,
                                          "clearcoatRoughnessFactor": m.clearcoat_roughness}
    if m.sheen_color is not None:
        ext["KHR_materials_sheen"] = {"sheenColorFactor": list(m.sheen_color), "sheenRoughnessFactor": m.sheen_roughness}
    return gl.Material(name=name, pbrMetallicRoughness=gl.PbrMetallicRoughness(
        baseColorFactor=[*m.base_color, 1.0], metallicFactor=m.metallic, roughnessFactor=m.roughness),
        extensions=ext, extras={"glint": extras})


class _Blob:
    """The binary chunk: appended arrays, each a 4-byte aligned buffer view."""

    def __init__(self, doc: gl.GLTF2):
        self.doc = doc
        self.parts: list[bytes] = []
        self.size = 0

    def add(self, a: np.ndarray, target: int) -> int:
        data = a.tobytes()
        self.doc.bufferViews.append(gl.BufferView(buffer=0, byteOffset=self.size, byteLength=len(data), target=target))
        pad = (-len(data)) % 4
        self.parts.append(data + b"\0" * pad)
        self.size += len(data) + pad
        return len(self.doc.bufferViews) - 1

    def accessor(self, a: np.ndarray, ctype: int, kind: str, target: int, bounds: bool = False) -> int:
        view = self.add(np.ascontiguousarray(a), target)
        acc = gl.Accessor(bufferView=view, componentType=ctype, count=len(a), type=kind)
        if bounds:
            acc.min = a.min(0).astype(float).tolist()
            acc.max = a.max(0).astype(float).tolist()
        self.doc.accessors.append(acc)
        return len(self.doc.accessors) - 1


def write_glb(path: Path, meshes: list[ObjectMesh], default: list[str], variants: list[Variant],
              approx: dict[str, Approximation], labels: dict[str, str], report: dict) -> int:
    """Write the .glb atomically; returns its size in bytes.

    meshes : the objects' meshes; default : material_key of each object's own material;
    variants : the design variants; approx : material_key -> its fitted glTF material;
    labels : material_key -> a human name; report : the export's figures (asset extras)."""
    doc = gl.GLTF2(asset=gl.Asset(version="2.0", generator=GENERATOR, extras={"glint": report}))
    keys = list(dict.fromkeys(default + [material_key(m) for v in variants for m in v.materials.values()]))
    index = {k: i for i, k in enumerate(keys)}
    for k in keys:
        doc.materials.append(material_json(labels[k], approx[k].material, {"material_key": k, **approx[k].public()}))
    blob = _Blob(doc)
    used = set()
    for m in approx.values():
        used.update(m.material.extensions)
    for i, om in enumerate(meshes):
        small = len(om.vertices) < 65535
        idx = om.faces.reshape(-1).astype(np.uint16 if small else np.uint32)
        a_pos = blob.accessor(om.vertices.astype(np.float32), gl.FLOAT, gl.VEC3, gl.ARRAY_BUFFER, bounds=True)
        a_nrm = blob.accessor(om.normals.astype(np.float32), gl.FLOAT, gl.VEC3, gl.ARRAY_BUFFER)
        a_idx = blob.accessor(idx, gl.UNSIGNED_SHORT if small else gl.UNSIGNED_INT, gl.SCALAR, gl.ELEMENT_ARRAY_BUFFER)
        prim = gl.Primitive(attributes=gl.Attributes(POSITION=a_pos, NORMAL=a_nrm), indices=a_idx,
                            material=index[default[i]], mode=gl.TRIANGLES)
        mappings = {}
        for vi, v in enumerate(variants):
            m = v.materials.get(om.name)
            k = default[i] if m is None else material_key(m)
            mappings.setdefault(index[k], []).append(vi)
        if variants:
            prim.extensions = {"KHR_materials_variants": {"mappings": [
                {"material": mi, "variants": vs} for mi, vs in mappings.items()]}}
        doc.meshes.append(gl.Mesh(name=om.name, primitives=[prim]))
        doc.nodes.append(gl.Node(name=om.name, mesh=i))
    if variants:
        used.add("KHR_materials_variants")
        doc.extensions = {"KHR_materials_variants": {"variants": [{"name": v.label} for v in variants]}}
    doc.extensionsUsed = sorted(used)
    doc.scenes = [gl.Scene(nodes=list(range(len(meshes))))]
    doc.scene = 0
    data = b"".join(blob.parts)
    doc.buffers = [gl.Buffer(byteLength=len(data))]
    doc.set_binary_blob(data)
    out = doc.save_to_bytes()
    payload = out if isinstance(out, (bytes, bytearray)) else b"".join(out)
    atomic_write(Path(path), bytes(payload))
    return len(payload)
