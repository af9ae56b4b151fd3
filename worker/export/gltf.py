"""glTF 2.0 binary (.glb) of a scene: one mesh a object (positions, normals, indices, world
space: Glint's +Y up and metres are glTF's), one fitted metallic-roughness material per distinct
Glint material (approx.py), and the design variants through ``KHR_materials_variants``.

Painted regions (worker/models/regions.py) blend materials per vertex, which glTF's materials
cannot: an object whose material (or a variant's) has regions is split into primitives by each
face's dominant layer (the layer of the largest mean effective weight over its corners, under
every material the object takes, so one split serves all variants), each primitive bound to its
layer's fitted material; the primitives share the object's vertices. The raw weights travel
with the mesh for tools that can blend, listed in the mesh's ``extras.glint.regions``:

- as **textures** (8-bit greyscale PNG, one per region, texture.py) read through the mesh's own
  texture coordinates (``TEXCOORD_0``), where the mesh has coordinates that give every face texels
  of its own;
- else as application-specific **vertex attributes** (float, one per region,
  common.region_attribute; the names the MaterialX export's ``geompropvalue`` nodes read), and the
  mesh's extras and the report say why (no texture coordinates, or a layout that repeats or
  shares texels, as a tiling wood grain does).

Written with pygltflib (the document model and the GLB container); the buffer layout (one
buffer, a view per accessor, 4-byte aligned) is the plain one the spec describes.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib as gl

from ..atomic import atomic_write
from ..models import BRDFModel, has_regions
from .approx import Approximation, GltfMaterial
from . import texture
from .common import (
    ObjectMesh,
    Variant,
    effective_weights,
    layer_materials,
    material_key,
    region_attribute,
    region_weights,
)

GENERATOR = "Glint (worker/export/gltf.py)"
WEIGHT_TEXTURE = 1024          # the side of a region weight texture, in texels
# largest difference between a weight texture (as sampled at the faces' centroids) and the weights
# it holds before the vertex attributes are written instead (8-bit quantisation alone is 0.002)
MAX_TEXTURE_ERROR = 0.02


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

    def add(self, a: np.ndarray | bytes, target: int | None) -> int:
        data = a if isinstance(a, bytes) else a.tobytes()
        self.doc.bufferViews.append(gl.BufferView(buffer=0, byteOffset=self.size, byteLength=len(data), target=target))
        pad = (-len(data)) % 4
        self.parts.append(data + b"\0" * pad)
        self.size += len(data) + pad
        return len(self.doc.bufferViews) - 1

    def accessor(self, a: np.ndarray, ctype: int, kind: str, target: int, bounds: bool = False) -> int:
        view = self.add(np.ascontiguousarray(a), target)
        acc = gl.Accessor(bufferView=view, componentType=ctype, count=len(a), type=kind)
        if bounds:
            flat = a.reshape(len(a), -1)          # a scalar's bounds are one-element arrays too
            acc.min = flat.min(0).astype(float).tolist()
            acc.max = flat.max(0).astype(float).tolist()
        self.doc.accessors.append(acc)
        return len(self.doc.accessors) - 1


def face_groups(om: ObjectMesh, materials: list[BRDFModel]) -> tuple[np.ndarray, np.ndarray]:
    """Faces grouped by their dominant layer under each material: (groups (G, M) int64, the layer
    index (into layer_materials) of each group under each of the M materials; group (F,) int64,
    each face's group). A plain material is layer 0 everywhere."""
    cols = []
    for m in materials:
        best = np.zeros(len(om.faces), np.int64)
        if has_regions(m):
            a = effective_weights(m, om)
            top = np.full(len(om.faces), -1.0, np.float32)
            for layer in range(len(a)):       # one layer at a time: (L, F, 3) would be GBs at the limits
                f = a[layer][om.faces].mean(1)
                better = f > top
                best[better], top[better] = layer, f[better]
        cols.append(best)
    groups, group = np.unique(np.stack(cols, 1), axis=0, return_inverse=True)
    return groups, group.reshape(-1)


def region_storage(om: ObjectMesh, materials: list[BRDFModel]) -> dict:
    """How the region weights of ``materials`` (the object's regions materials) travel in the
    glTF: {"storage": "texture", "bake": texture.Bake of every region's weights (rows in the
    order of the materials and their regions), "texture_size", "texture_error"} where the
    object's texture coordinates allow it, else {"storage": "vertex attribute", "why": str}."""
    if om.uvs is None:
        return {"storage": "vertex attribute", "why": "the mesh has no texture coordinates"}
    if np.isnan(om.uvs).any():
        return {"storage": "vertex attribute",
                "why": f"{int(np.isnan(om.uvs).any(1).sum())} of its {len(om.uvs)} vertices have no texture coordinates"}
    w = np.concatenate([region_weights(m, om) for m in materials])
    b = texture.bake(texture.gltf_uv(om.uvs), om.faces, w, WEIGHT_TEXTURE)
    if b.overlap > texture.MAX_OVERLAP:
        return {"storage": "vertex attribute",
                "why": "its texture coordinates put several faces on the same texels (a repeating or shared "
                       f"layout{'' if b.overlap >= 1 else f': {100 * b.overlap:.0f}% of the covered texels'}), "
                       "so a texture cannot hold a weight per face"}
    if b.error > MAX_TEXTURE_ERROR:
        return {"storage": "vertex attribute",
                "why": f"a {WEIGHT_TEXTURE}² texture differs from the weights by up to {b.error:.3f} at the faces' "
                       "centroids (faces smaller than a texel)"}
    return {"storage": "texture", "bake": b, "texture_size": WEIGHT_TEXTURE, "texture_error": round(b.error, 4)}


def write_glb(path: Path, meshes: list[ObjectMesh], default: list[BRDFModel], variants: list[Variant],
              approx: dict[str, Approximation], labels: dict[str, str], report: dict) -> int:
    """Write the .glb atomically; returns its size in bytes.

    meshes : the objects' meshes; default : each object's own material; variants : the design
    variants; approx : material_key of every plain material (common.layer_materials) -> its fitted
    glTF material; labels : material_key -> a human name; report : the export's figures (asset
    extras; where an object has regions, ``report["regions"]`` gets how their weights were
    written, region_storage without the bake)."""
    doc = gl.GLTF2(asset=gl.Asset(version="2.0", generator=GENERATOR, extras={"glint": report}))
    every = default + [m for v in variants for m in v.materials.values()]
    keys = list(dict.fromkeys(material_key(x) for m in every for x in layer_materials(m)))
    index = {k: i for i, k in enumerate(keys)}
    for k in keys:
        doc.materials.append(material_json(labels[k], approx[k].material, {"material_key": k, **approx[k].public()}))
    blob = _Blob(doc)
    used = set()
    for m in approx.values():
        used.update(m.material.extensions)
    for i, om in enumerate(meshes):
        # the object's materials: its own, then each variant's (deduplicated by content)
        own = [default[i]] + [v.materials.get(om.name, default[i]) for v in variants]
        mats = list({material_key(m): m for m in own}.values())
        which = [next(j for j, m in enumerate(mats) if material_key(m) == material_key(x)) for x in own]
        groups, group = face_groups(om, mats)
        small = len(om.vertices) < 65535
        a_pos = blob.accessor(om.vertices.astype(np.float32), gl.FLOAT, gl.VEC3, gl.ARRAY_BUFFER, bounds=True)
        a_nrm = blob.accessor(om.normals.astype(np.float32), gl.FLOAT, gl.VEC3, gl.ARRAY_BUFFER)
        attrs = {"POSITION": a_pos, "NORMAL": a_nrm}
        extras = []
        painted = [m for m in mats if has_regions(m)]
        store = region_storage(om, painted) if painted else None
        if store is not None:
            report.setdefault("regions", []).append(
                {"object": om.name, **{k: v for k, v in store.items() if k != "bake"}})
        row = 0
        for m in painted:
            names = []
            if store["storage"] == "texture":
                if "TEXCOORD_0" not in attrs:
                    attrs["TEXCOORD_0"] = blob.accessor(texture.gltf_uv(om.uvs), gl.FLOAT, gl.VEC2, gl.ARRAY_BUFFER)
                    if not doc.samplers:      # linear, mipmapped, repeating (the bake wraps too)
                        doc.samplers.append(gl.Sampler(magFilter=gl.LINEAR, minFilter=gl.LINEAR_MIPMAP_LINEAR,
                                                       wrapS=gl.REPEAT, wrapT=gl.REPEAT))
                for k, r in enumerate(m.regions):
                    view = blob.add(texture.png(store["bake"].values[row]), None)
                    row += 1
                    doc.images.append(gl.Image(bufferView=view, mimeType="image/png", name=region_attribute(m, k)))
                    doc.textures.append(gl.Texture(sampler=0, source=len(doc.images) - 1, name=region_attribute(m, k)))
                    names.append({"region": r.name, "texture": len(doc.textures) - 1, "texCoord": 0,
                                  "material_key": material_key(r.material)})
            else:
                w = region_weights(m, om)
                for k, r in enumerate(m.regions):
                    attrs[region_attribute(m, k)] = blob.accessor(np.ascontiguousarray(w[k]), gl.FLOAT, gl.SCALAR,
                                                                  gl.ARRAY_BUFFER, bounds=True)
                    names.append({"region": r.name, "attribute": region_attribute(m, k),
                                  "material_key": material_key(r.material)})
            extras.append({"material_key": material_key(m), "base_material_key": material_key(m.base),
                           "storage": store["storage"], **({"why": store["why"]} if "why" in store else {}),
                           "regions": names})
        prims = []
        for g, layers in enumerate(groups):
            faces = om.faces[group == g]
            idx = faces.reshape(-1).astype(np.uint16 if small else np.uint32)
            a_idx = blob.accessor(idx, gl.UNSIGNED_SHORT if small else gl.UNSIGNED_INT, gl.SCALAR,
                                  gl.ELEMENT_ARRAY_BUFFER)

            def material_of(j: int) -> int:
                return index[material_key(layer_materials(mats[j])[layers[j]])]

            at = gl.Attributes(POSITION=a_pos, NORMAL=a_nrm, TEXCOORD_0=attrs.get("TEXCOORD_0"))
            for name, acc in attrs.items():
                if name.startswith("_"):
                    setattr(at, name, acc)      # glTF 2.0: application-specific attribute semantics start with "_"
            prim = gl.Primitive(attributes=at, indices=a_idx, material=material_of(which[0]), mode=gl.TRIANGLES)
            if variants:
                mappings = {}
                for vi in range(len(variants)):
                    mappings.setdefault(material_of(which[vi + 1]), []).append(vi)
                prim.extensions = {"KHR_materials_variants": {"mappings": [
                    {"material": mi, "variants": vs} for mi, vs in mappings.items()]}}
            prims.append(prim)
        mesh = gl.Mesh(name=om.name, primitives=prims)
        if extras:
            mesh.extras = {"glint": {"regions": extras}}
        doc.meshes.append(mesh)
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
