"""The cut renderer: direct environment light through per-vertex visibility cuts.

cyber-worlds eq. 3 / inverse-brdf-modeling eq. 22: B(x, ωo) = Σ_k l_k v_k f_r(ω_k, ωo) over the
point's cut, with l_k the map integrated over cluster k (core/lighting.py), v_k its mean
cosine-weighted visibility and ω_k its light-weighted centroid. Two shading modes:

* ``vertex`` (default): radiance at the vertices of the triangles the camera sees, then
  barycentric interpolation per pixel. Fast: cost scales with visible vertices.
* ``pixel``: every pixel shades its three vertices' cuts with its own interpolated normal and
  view direction and blends them by barycentric weight (equal to interpolating the cuts, the
  integral being linear in visibility). Sharper glossy highlights on coarse meshes.

It caches what a frame reuses (the hit buffer per camera, the per-node light per lighting, the
packed materials per material list), so a BRDF or light change reuses the hit buffer and the
cuts, and a view change reuses the cuts and the lighting. The drag level of detail shades
cuts coarsened to τ = 16 at half resolution.

Besides frames, it answers the paint-to-BRDF fitter's questions through named methods
(``surface_samples``, ``vertex_samples``, ``transfer``, ``shade_samples``, ``light``): where an
object is seen, the SRBF transfer rows there, and its radiance under a material.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from ...core import cuts as cutmod
from ...core.directions import get_tree
from ...core.lighting import node_lighting
from ...core.render import MaterialTable, camera_rays, env_lookup, interpolate, shade_points
from ...native.kernels import kernels as _kernels
from ..base import FrameRequest, Lighting, Rendered, Renderer, Unsupported
from .precompute import CutData

DRAG_TAU = 16.0     # drag level of detail: cuts coarsened to τ = 16 (0.4% image change on the demo chair)


@dataclass
class View:
    """Primary visibility of one camera: tri (P,) int32 face per pixel (−1 background), uv
    (P, 2) float32 Embree barycentrics, dirs (P, 3) float32 ray directions, visible (K,) int32
    vertices of the faces seen."""
    camera: object
    tri: np.ndarray
    uv: np.ndarray
    dirs: np.ndarray
    visible: np.ndarray


@dataclass
class Samples:
    """Surface points to shade or fit: pix (N,) flat pixel index (or vertex id for vertex
    samples), positions (N, 3), normals (N, 3) unit, wo (N, 3) unit towards the eye, verts
    (N, 3) int32 vertex (cut) indices, bary (N, 3) float32 weights of those cuts; all float32."""
    pix: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    wo: np.ndarray
    verts: np.ndarray
    bary: np.ndarray

    def __len__(self) -> int:
        return len(self.pix)


class CutRenderer(Renderer):
    """Renders one loaded scene from its cut set (CutData).

    kernels : the kernel backend (worker/native/kernels.py); default: the process's.
    """

    kind = "cuts"
    controls = frozenset({"camera", "light", "materials", "environment", "move"})
    _moving = None          # MovingFrames (moving.py) of a scene with movable objects

    def __init__(self, scene, data: CutData, kernels=None):
        super().__init__(scene, data, kernels)
        self.k = kernels or _kernels()
        self.cuts = data.cuts
        self.tree = get_tree(self.cuts.height)
        self.tracer = data.tracer(scene)                    # shared by the scene's renderers
        self.lighting = data.lighting(scene.envmap, self.tree)
        self._view: View | None = None
        self._light_key = None
        self._node_light = None
        self._mats_key = None
        self._mats: MaterialTable | None = None
        self._lock = threading.RLock()      # the session thread and its background builder
        self._moving = None                 # frames of a scene with movable objects (moving.py)
        if data.moving is not None:
            from .moving import MovingFrames

            self._moving = MovingFrames(self, data.moving)

    # -- caches -----------------------------------------------------------------------------------
    def set_environment(self, envmap: np.ndarray) -> None:
        """Light with another (H, W, 3) float32 map. Cuts are geometry only, so they stay; the
        per-node light is rebuilt on the next frame."""
        with self._lock:
            self.lighting = self.data.lighting(envmap, self.tree)
            self._light_key = None

    def view(self, camera) -> View:
        """Primary hits of a camera (cached for the last camera)."""
        if self._moving is not None:           # the movable objects where the last frame had them
            with self._lock:
                mv = self._moving.view(camera, self._moving.W)
            return View(camera, mv.tri, mv.uv, mv.dirs, mv.visible)
        v = self._view
        if v is not None and v.camera == camera:
            return v
        o, d = camera_rays(camera.eye, camera.target, camera.up, camera.fov_y_deg, camera.width, camera.height)
        tri, uv, _ = self.tracer.first_hit(o, d)
        seen = np.unique(tri[tri >= 0])
        visible = np.unique(self.scene.mesh.faces[seen]).astype(np.int32)
        v = self._view = View(camera, tri, uv, d, visible)
        return v

    def light(self, lighting: Lighting):
        """(node_l (2N−1, 3) float32 radiance×sr, node_w (2N−1, 3) float32 unit centroid
        directions) for a lighting (cached for the last one)."""
        with self._lock:
            key = (float(lighting.rotation_deg), float(lighting.intensity), id(self.lighting))
            if key != self._light_key:
                l, ld = self.lighting.leaf_radiance(lighting.rotation_deg, lighting.intensity)
                self._node_light = node_lighting(l, ld, self.tree)
                self._light_key = key
            return self._node_light

    def material_table(self, materials) -> MaterialTable:
        """Packed materials (cached by the identity of the list's items)."""
        key = tuple(id(m) for m in materials)
        if key != self._mats_key:
            self._mats = MaterialTable([m.pack() for m in materials])
            self._mats_key = key
            self._mats_refs = list(materials)        # keep them alive: ids stay unique
        return self._mats

    def coarse_cuts(self) -> cutmod.CutSet:
        """The drag-time cut set (cuts coarsened to DRAG_TAU), built once per scene (≈0.1 s
        for 21K vertices in C)."""
        if self._moving is not None:
            self._moving.level("drag")              # the movable objects' drag-time cuts too
        return self.data.coarse(DRAG_TAU, self.k)

    # -- frames -----------------------------------------------------------------------------------
    def render(self, req: FrameRequest) -> Rendered:
        if self._moving is not None:
            return self._render_moving(req)
        if req.transforms and any(self.scene.spec.objects[self._index(n)].transform != t
                                  for n, t in req.transforms.items()):
            raise Unsupported("this scene has no movable objects (mark them \"movable\": true in the scene file)")
        t = {}
        t0 = time.perf_counter()
        camera = req.camera
        drag = req.lod == "drag"
        cuts = self.coarse_cuts() if drag else self.cuts
        if drag and camera.width >= 320:
            camera = camera.model_copy(update={"width": camera.width // 2, "height": camera.height // 2})
        materials = list(req.materials) or self.scene.materials
        if len(materials) != len(self.scene.spec.objects):
            raise ValueError(f"{len(materials)} materials for {len(self.scene.spec.objects)} objects")
        v = self.view(camera)
        t1 = time.perf_counter(); t["view"] = (t1 - t0) * 1e3
        node_l, node_w = self.light(req.lighting)
        mats = self.material_table(materials)
        t2 = time.perf_counter(); t["light"] = (t2 - t1) * 1e3
        mesh = self.scene.mesh
        img = np.zeros((len(v.tri), 3), np.float32)
        bg = v.tri < 0
        env_lookup(v.dirs, self.lighting.map, req.lighting.rotation_deg, req.lighting.intensity, mask=bg, out=img,
                   kernels=self.k)
        if req.shading == "vertex":
            known = {} if drag else dict(req.vertex_radiance or {})
            vi = v.visible
            if known:
                vi = vi[~np.isin(vi, np.concatenate([ids for ids, _ in known.values()]))]
            wo = np.asarray(camera.eye, np.float32) - mesh.vertices[vi]
            wo /= np.linalg.norm(wo, axis=1, keepdims=True)
            rad = shade_points(mesh.normals[vi], wo, vi, self.scene.object_of_vertex[vi], cuts,
                               node_l, node_w, self.tree, mats, self.k)
            vert = np.zeros((len(mesh.vertices), 3), np.float32)
            vert[vi] = rad
            for ids, r in known.values():
                vert[ids] = r
            t3 = time.perf_counter(); t["shade"] = (t3 - t2) * 1e3
            interpolate(v.tri, v.uv, mesh.faces, vert, img, self.k)
            t["interpolate"] = (time.perf_counter() - t3) * 1e3
        elif req.shading == "pixel":
            s = self._pixel_samples(v, camera, np.nonzero(~bg)[0])
            img[s.pix] = self._shade(s, cuts, node_l, node_w, mats, self.scene.object_of_vertex)
            t["shade"] = (time.perf_counter() - t2) * 1e3
        else:
            raise ValueError(f"unknown shading mode {req.shading!r} (vertex or pixel)")
        obj = np.where(v.tri >= 0, self.scene.object_of_face[np.maximum(v.tri, 0)], -1).astype(np.int32)
        return Rendered(img.reshape(camera.height, camera.width, 3), obj.reshape(camera.height, camera.width), t,
                        {"lod": req.lod, "tau": DRAG_TAU if drag else self.data.tau, "width": camera.width,
                         "height": camera.height, "visible_vertices": int(len(v.visible))})

    def _index(self, name: str) -> int:
        return [o.name for o in self.scene.spec.objects].index(name)

    @property
    def cuts(self) -> cutmod.CutSet:
        """The cut of every scene vertex (cut v for vertex v). With movable objects: as they
        stand in the last frame (moving.py MovingFrames.cuts; a moved object's own cuts are over
        its frame's leaves, see ``_frame_of``)."""
        if self._moving is not None:
            with self._lock:
                return self._moving.cuts()
        return self._cuts

    @cuts.setter
    def cuts(self, cs: cutmod.CutSet) -> None:
        self._cuts = cs

    def place(self, transforms) -> None:
        """Where movable objects stand for the fitter's questions until the next frame (a
        session restoring its strokes places them first); no-op without movable objects."""
        if self._moving is not None:
            with self._lock:
                self._moving.place(transforms)

    def _geometry(self):
        """(vertices, normals) (V, 3) float32 of the scene as it stands (world)."""
        if self._moving is not None:
            with self._lock:
                return self._moving.geometry()
        return self.scene.mesh.vertices, self.scene.mesh.normals

    def _frame_of(self, object_index: int):
        """world_from_frame (3, 3) of an object's cuts when it is not the world's (a movable
        object's own cuts), else None."""
        return None if self._moving is None else self._moving.frame(object_index)

    def _frame_light(self, q, lighting: Lighting):
        with self._lock:
            return self._moving.frame_light(q, lighting)

    def _render_moving(self, req: FrameRequest) -> Rendered:
        """A frame of a scene with movable objects, placed by req.transforms (moving.py)."""
        with self._lock:
            return self._moving.render(req)

    def object_mask(self, camera) -> np.ndarray:
        """(H, W) int32 object index per pixel, −1 background."""
        v = self.view(camera)
        m = np.where(v.tri >= 0, self.scene.object_of_face[np.maximum(v.tri, 0)], -1)
        return m.reshape(camera.height, camera.width).astype(np.int32)

    # -- what the fitter asks ------------------------------------------------------------------
    def _pixel_samples(self, v: View, camera, pix: np.ndarray) -> Samples:
        mesh = self.scene.mesh
        vx, vn = self._geometry()
        f = mesh.faces[v.tri[pix]]
        u, w2 = v.uv[pix, 0:1], v.uv[pix, 1:2]
        bary = np.concatenate([1 - u - w2, u, w2], axis=1).astype(np.float32)
        nrm = (bary[:, :, None] * vn[f]).sum(1)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        pos = (bary[:, :, None] * vx[f]).sum(1)
        wo = np.asarray(camera.eye, np.float32) - pos
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        return Samples(pix, pos.astype(np.float32), nrm.astype(np.float32), wo.astype(np.float32),
                       f.astype(np.int32), bary)

    def surface_samples(self, camera, object_index: int) -> Samples:
        """The object's pixels in a view at the camera's resolution, each with its own normal and
        view direction and its triangle's three cuts blended by barycentric weight
        (inverse-brdf-modeling §4.1)."""
        if self._moving is not None:
            with self._lock:
                tri, uv, d = self._moving.hits(camera)
        else:
            o, d = camera_rays(camera.eye, camera.target, camera.up, camera.fov_y_deg, camera.width, camera.height)
            tri, uv, _ = self.tracer.first_hit(o, d)
        obj_of = np.where(tri >= 0, self.scene.object_of_face[np.maximum(tri, 0)], -1)
        pix = np.nonzero(obj_of == object_index)[0]
        return self._pixel_samples(View(camera, tri, uv, d, np.zeros(0, np.int32)), camera, pix)

    def vertex_samples(self, camera, object_index: int) -> Samples:
        """The object's vertices the camera sees (vertex-mode shading points)."""
        vx, vn = self._geometry()
        vis = self.view(camera).visible
        ids = vis[self.scene.object_of_vertex[vis] == object_index].astype(np.int32)
        wo = np.asarray(camera.eye, np.float32) - vx[ids]
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        bary = np.zeros((len(ids), 3), np.float32)
        bary[:, 0] = 1.0
        return Samples(ids, vx[ids], vn[ids], wo.astype(np.float32),
                       np.repeat(ids[:, None], 3, axis=1), bary)

    def transfer(self, samples: Samples, basis, lighting: Lighting):
        """SRBF transfer rows at samples (fit/transfer.py, inverse-brdf-modeling eq. 21):
        (T (3, N, J) float32, E (N, 3) float32)."""
        from ...fit.transfer import transfer

        nrm, wo, (node_l, node_w) = self._in_frame(samples, lighting)
        return transfer(nrm, wo, samples.verts, samples.bary, self.cuts, node_l, node_w,
                        self.tree, basis, self.k)

    def _in_frame(self, s: Samples, lighting: Lighting):
        """(normals, wo, node lighting) of samples of one object in the frame of its cuts: the
        world's, or a moved object's own (normals and view directions turned by R^T, the light
        turned into the frame)."""
        q = self._frame_of(int(self.scene.object_of_vertex[s.verts[0, 0]])) if len(s) else None
        if q is None:
            return s.normals, s.wo, self.light(lighting)
        return ((s.normals @ q).astype(np.float32), (s.wo @ q).astype(np.float32), self._frame_light(q, lighting))

    def shade_samples(self, samples: Samples, material, object_index: int, lighting: Lighting) -> np.ndarray:
        """(N, 3) float64 radiance of the samples under a material, shaded like pixel mode."""
        nrm, wo, (node_l, node_w) = self._in_frame(samples, lighting)
        mats = MaterialTable([material.pack()])
        s = Samples(samples.pix, samples.positions, nrm, wo, samples.verts, samples.bary)
        return self._shade(s, self.cuts, node_l, node_w, mats, None).astype(np.float64)

    def _shade(self, s: Samples, cuts, node_l, node_w, mats, mat_of_vertex) -> np.ndarray:
        n = len(s)
        flat = s.verts.reshape(-1)
        mat_of = np.zeros(3 * n, np.int32) if mat_of_vertex is None else mat_of_vertex[flat]
        rad = shade_points(np.repeat(s.normals, 3, 0), np.repeat(s.wo, 3, 0), flat, mat_of, cuts, node_l, node_w,
                           self.tree, mats, self.k).reshape(n, 3, 3)
        return (s.bary[:, :, None] * rad).sum(1)
