"""The ``paint`` renderer: cosine lobes by prefiltered environment maps (cacad-cosine-lobes §5).

Precomputation (content-keyed parts):
  * ``lobe maps``: the environment prefiltered for the diffuse map and every basis exponent
    (prefilter.py), keyed by the map's pixels and the exponents. ~1.4 s for a 1K HDRI (BENCHMARKS),
    so switching environments is interactive (``set_environment`` recomputes them in place).
  * ``visibility`` (option ``visibility: true``): per-vertex visibility harmonics from the cut
    renderer's cuts (visibility.py), keyed by the geometry (option ``cuts_dir``: where the cut
    renderer caches its cuts).
Rendering: one Embree first-hit pass per camera (cached while the camera stays), then per frame
one C pass over the pixels (render.shade): interpolated normal, reflected view direction, the
maps summed with the material's weights. A paint or light change costs only that pass.
Materials that are not lobes on the renderer's basis (GGX, Lambert, lobes on other exponents…)
are converted the designer's way: measured in the industry geometry and fitted (fit.py).
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ...core.lighting import direction_to_uv
from ...core.render import camera_rays
from ...keys import content_key
from ...paint.basis import default_exponents
from ...scene import Lobes
from ..base import FrameRequest, Part, Precomputation, Rendered, Renderer
from ..layers import Layers, LayersCache
from . import DECLARATION
from .prefilter import LobeMaps, prefilter_all
from .render import background, material_rows, shade

VERSION = 3     # of the stored parts' keys (worker/keys.py; "paint-v2" before content_key)


def _maps_recipe() -> dict:
    """Everything besides the map and the exponents that the prefiltered maps depend on."""
    from . import prefilter as pf
    return {"pixels_per_sigma": pf.PIXELS_PER_SIGMA, "min_rows": pf.MIN_ROWS, "support": pf.SUPPORT,
            "vector_max_e": pf.VECTOR_MAX_E}


def basis_of(options: Mapping[str, Any]) -> tuple[float, ...]:
    ex = options.get("exponents") or default_exponents()
    return tuple(float(e) for e in ex)


def as_basis(material, exponents) -> Lobes:
    """A lobes material on the given exponents: itself when it already is one, else the fit of its
    industry measurements (measure -> fit_measurements), the paint designer's conversion."""
    ex = tuple(float(e) for e in exponents)
    if isinstance(material, Lobes) and tuple(float(e) for e in material.exponents) == ex:
        return material
    key = (json.dumps(material.model_dump(), sort_keys=True), ex)
    hit = _converted.get(key)
    if hit is None:
        from ...paint.fit import fit_measurements
        from ...paint.geometry import measure
        hit = fit_measurements(measure(material), ex).material
        _converted[key] = hit
    return hit


_converted: dict = {}


@dataclass
class PaintData:
    maps: LobeMaps
    vertex_vis: np.ndarray | None          # (V, 18) float32 or None


class PaintPrecomputation(Precomputation):
    """Prefiltered lobe maps (and, optionally, per-vertex visibility); kernels: the backend that
    prefilters (default: the process's, chosen when first needed)."""
    kind = DECLARATION.kind

    def parts(self, scene, options):
        ex = basis_of(options)
        out = [Part(content_key("paint-maps", VERSION, envmap=scene.envmap, exponents=np.asarray(ex, np.float64),
                                recipe=_maps_recipe()), "prefiltered lobe maps",
                    work=len(ex) + 1, meta={"what": "maps"})]
        if options.get("visibility"):
            m = scene.mesh
            out.append(Part(content_key("paint-visibility", VERSION, vertices=m.vertices, faces=m.faces,
                                        normals=m.normals),
                            "per-vertex visibility harmonics (from cuts)", work=len(m.vertices), meta={"what": "vis"}))
        return out

    def compute(self, scene, part, options, chunk=None, progress=None, threads=2):
        if part.meta["what"] == "maps":
            return prefilter_all(scene.envmap, basis_of(options), self.kernels, progress=progress).to_bytes()
        from .visibility import vertex_visibility
        # progress counts vertices as the cut tracing does (nothing when the cuts are cached)
        vis = vertex_visibility(scene, options.get("cuts_dir"), progress=progress, threads=threads)
        return vis.astype(np.float32).tobytes()

    def load(self, scene, blobs, options):
        parts = self.parts(scene, options)
        maps = LobeMaps.from_bytes(blobs[parts[0].key])
        vis = None
        if len(parts) > 1:
            vis = np.frombuffer(blobs[parts[1].key], np.float32).reshape(-1, 18)
        return PaintData(maps, vis)


@dataclass
class _View:
    camera: Any
    hit: np.ndarray        # (K,) pixel indices that hit the scene
    normals: np.ndarray    # (K, 3) float32 interpolated unit normals
    views: np.ndarray      # (K, 3) float32 unit directions towards the eye
    obj: np.ndarray        # (K,) int32 object index
    vsh: np.ndarray | None  # (K, 18) float32 interpolated visibility harmonics
    bg: np.ndarray         # (B,) pixel indices of the background
    bg_uv: np.ndarray      # (B, 2) float32 unrotated map coordinates of the background rays
    object_id: np.ndarray  # (H, W) int32
    corners: np.ndarray    # (K, 3) int32 the vertices of each hit's face
    bary: np.ndarray       # (K, 3) float32 each hit's barycentric weights over them


class PaintRenderer(Renderer):
    """Renders a scene's objects as lobes materials from prefiltered maps.

    Attributes set by callers: ``cosine`` ("vector", "albedo" or "paper", render.py), ``fresnel`` (bool),
    ``visibility`` (bool, used when the data has it)."""

    kind = DECLARATION.kind
    controls = DECLARATION.controls

    def __init__(self, scene, data: PaintData, kernels=None):
        super().__init__(scene, data, kernels)
        from ...native.kernels import kernels as _kernels

        # the backend it was built with (default: the process's), used for every kernel below
        self.k = kernels or _kernels()
        from ...trace.embree import Tracer
        self.tracer = Tracer(scene.mesh.vertices, scene.mesh.faces)
        self.cosine = "vector"
        self.fresnel = False
        self.visibility = data.vertex_vis is not None
        self.envmap = scene.envmap
        self._view: _View | None = None
        self._layers = LayersCache(scene)

    @property
    def exponents(self) -> tuple[float, ...]:
        return self.data.maps.exponents[1:]

    def set_environment(self, envmap: np.ndarray) -> float:
        """Prefilter another environment (H, W, 3) float32; returns the seconds it took."""
        t0 = time.perf_counter()
        self.data = PaintData(prefilter_all(envmap, self.exponents, self.k), self.data.vertex_vis)
        self.envmap = envmap
        return time.perf_counter() - t0

    def view(self, camera) -> _View:
        if self._view is not None and self._view.camera == camera:
            return self._view
        m = self.scene.mesh
        o, d = camera_rays(camera.eye, camera.target, camera.up, camera.fov_y_deg, camera.width, camera.height,
                           kernels=self.k)
        tri, uv, _ = self.tracer.first_hit(o, d)
        hit = np.nonzero(tri >= 0)[0].astype(np.int64)
        f = m.faces[tri[hit]]
        u, v = uv[hit, 0:1], uv[hit, 1:2]
        bary = np.concatenate([1 - u - v, u, v], axis=1).astype(np.float32)
        nrm = np.einsum("kj,kjc->kc", bary, m.normals[f])
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-20)
        views = -d[hit]
        # a shading normal facing away from the eye (interpolated across a silhouette) is bent
        # back to the eye's side of the geometric face, as renderers commonly do
        back = (nrm * views).sum(1) < 0
        if back.any():
            nrm[back] -= 1.0001 * (nrm[back] * views[back]).sum(1, keepdims=True) * views[back]
            nrm[back] /= np.linalg.norm(nrm[back], axis=1, keepdims=True)
        vsh = None
        if self.data.vertex_vis is not None:
            vsh = np.einsum("kj,kjc->kc", bary, self.data.vertex_vis[f]).astype(np.float32)
        obj = self.scene.object_of_face[tri[hit]].astype(np.int32)
        oid = np.full(len(tri), -1, np.int32); oid[hit] = obj
        bg = np.nonzero(tri < 0)[0].astype(np.int64)
        u, w = direction_to_uv(d[bg].astype(np.float64))
        self._view = _View(camera, hit, nrm.astype(np.float32), views.astype(np.float32), obj, vsh, bg,
                           np.stack([u, w], 1).astype(np.float32), oid.reshape(camera.height, camera.width),
                           f.astype(np.int32), bary)
        return self._view

    def render(self, req: FrameRequest) -> Rendered:
        t0 = time.perf_counter()
        cam = req.camera
        v = self.view(cam)
        t1 = time.perf_counter()
        materials = list(req.materials or self.scene.materials)
        layers = self._layers.get(materials)
        mats = [as_basis(mt, self.exponents) for mt in (materials if layers is None else layers.flat)]
        rows = material_rows(mats, self.exponents)
        t2 = time.perf_counter()
        # every pixel is either background or shaded: the kernels write the image in place
        img = np.empty((cam.width * cam.height, 3), np.float32)
        background(v.bg_uv, self.envmap, req.lighting.rotation_deg, req.lighting.intensity,
                   self.k, out=img, dst=v.bg)
        vsh = v.vsh if self.visibility else None
        if layers is None:
            shade(v.normals, v.views, v.obj, rows, self.data.maps, self.cosine, self.fresnel, vsh,
                  req.lighting.rotation_deg, req.lighting.intensity, self.k, out=img, dst=v.hit)
        else:
            src, slot, wt = layers.expand_faces(v.obj, v.corners, v.bary)
            rad = shade(v.normals[src], v.views[src], slot, rows, self.data.maps, self.cosine, self.fresnel,
                        None if vsh is None else vsh[src], req.lighting.rotation_deg, req.lighting.intensity,
                        self.k)
            img[v.hit] = Layers.blend(rad, src, wt, len(v.hit))
        t3 = time.perf_counter()
        return Rendered(img.reshape(cam.height, cam.width, 3), v.object_id,
                        {"view": 1e3 * (t1 - t0), "materials": 1e3 * (t2 - t1), "shade": 1e3 * (t3 - t2)},
                        {"exponents": list(self.exponents), "cosine": self.cosine, "fresnel": self.fresnel,
                         "visibility": self.visibility and self.data.vertex_vis is not None})

    def object_mask(self, camera) -> np.ndarray:
        return self.view(camera).object_id

