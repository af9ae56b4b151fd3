"""The cut renderer: direct environment light through per-vertex visibility cuts.

cyber-worlds eq. 3 / inverse-brdf-modeling eq. 22: B(x, ωo) = Σ_k l_k v_k f_r(ω_k, ωo) over the
point's cut, with l_k the map integrated over cluster k (core/lighting.py), v_k its mean
cosine-weighted visibility and ω_k its light-weighted centroid. Three shading modes:

* ``vertex``: radiance at the vertices of the triangles the camera sees, barycentric
  interpolation per pixel (Gouraud). Its cost scales with the visible vertices; sharp lobes are
  smeared across a triangle. A session's one-sample frames while something moves.
* ``refined`` (default; a session's settled frames): vertex shading plus per-pixel shading on the faces where its
  interpolation is wrong: those whose vertices' mirror directions span more than a fraction of
  their material's lobe and whose vertex radiance differs by more than their object's mean, or
  whose radiance at the centroid departs from the interpolation (refine.py). Per-pixel accuracy for glossy lobes at a cost that scales with the visible
  vertices plus the refined pixels (none for Lambert). Vertices whose radiance the request
  brings (a stroke's transfer) are refined alike, their pixels shaded with the object's
  material, so a stroke's settled frame is the settled frame. The drag and quick levels of
  detail are not refined (their anti-aliased still is).
* ``pixel``: every pixel shades the blend of its three vertices' cuts by barycentric weight
  (equal to blending their shading, the integral being linear in visibility) with its own
  interpolated normal and view direction, as one cluster list (core/render.py shade_blend).

It caches what a frame reuses (per camera and sample count: the hit buffer, the visible
vertices and their view directions, the background's map coordinates and the object ids; per
lighting: the per-node light tables (C, lighting.c) and the ground shadow; per view and lighting:
the background; per material list: the packed materials), so a BRDF change costs the shading
of the visible vertices and the resolve, a light change adds the light tables and the
background, and a view change adds the primary rays. The drag level of detail shades cuts
coarsened to τ = 16 at half resolution.

Anti-aliasing (``FrameRequest.samples`` S > 1, vertex and refined modes): S primary rays per pixel through
a pattern symmetric about the pixel centre (render.sample_offsets); the vertices of every
sample's triangle are shaded once, and each pixel is the mean of its samples' interpolations
or background (C glk_resolve). Inside a triangle this equals one sample exactly; silhouettes
and the background's edges get S levels of coverage. It costs S× primary rays (once per view)
and S× interpolation, no extra shading beyond the few vertices only a sub-pixel sample sees.
With ``FrameRequest.antialias = "edges"`` (a session's settled frames, publications) the S
samples are taken only where they change the pixel (edges.py): next to silhouettes, occlusions,
object boundaries and creases (found once per view from the one-sample hits, traced through
Embree) and where refined shading is curved at the pixel scale (found per frame); every other
pixel is the one-sample frame's.

Ground shadow (ground.py): when the scene's precomputation has the ground part and the frame
asks for it (``FrameRequest.ground_shadow``, default the scene's ``ground.shadow``), background
samples whose rays go down through the ground plane are darkened by the occlusion ratio.

Besides frames, it answers the paint-to-BRDF fitter's questions through named methods
(``surface_samples``, ``vertex_samples``, ``transfer``, ``shade_samples``, ``light``): where an
object is seen, the SRBF transfer rows there, and its radiance under a material.
"""
from __future__ import annotations

import copy
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ...core import cuts as cutmod
from ...core.directions import get_tree
from ...core.lighting import light_tables
from ...core.primary import primary_hits
from ...core.render import (
    MaterialTable,
    background,
    camera_dirs,
    camera_rays,
    env_coords,
    pixel_dirs,
    resolve,
    seen_vertices,
    shade_blend,
    shade_points,
)
from ...models.base import packed
from ...models.regions import has_regions
from ...native.kernels import kernels as _kernels
from ..base import (
    FrameCancelled,
    FrameRequest,
    Lighting,
    Rendered,
    Renderer,
    Unsupported,
)
from ..layers import Layers, LayersCache
from . import DECLARATION
from . import edges as edgemod
from . import refine as refinemod
from .edges import edge_pixels
from .precompute import CutData
from .refine import Refinement

DRAG_REFINE = 0.1   # drag level of detail: clusters refined to no finer than 0.1 rad (a GGX α = 0.05's)
CANCEL_CHUNK = 1024  # vertices shaded between checkpoints (FrameRequest.cancelled): ~10 ms of a fitted srbf, one core
LIGHTS_KEPT = 4     # light tables (and ground shadows) of the last few lightings, for frames that alternate
DRAG_TAU = 16.0     # drag level of detail: cuts coarsened to τ = 16 (0.4% image change on the demo chair)
# the quick level (a session's first answer to an edit; its settled frame follows) shades the
# drag level's coarse cuts at full resolution: on the demo chair 0.4% (GGX) and 1.1% (a fitted
# srbf) from the full-quality vertex frame, and the srbf's shading 29 → 8 ms (stroke → frame p95
# in one session 86 → 52 ms)
QUICK_COARSE = True
_pool = None


@lru_cache(maxsize=1)
def _placeholder_model():
    from ...models import Lambert

    return Lambert()


@lru_cache(maxsize=1)
def _placeholder():
    """The packed material of objects no point of a frame is shaded with (never read)."""
    from ...models import Lambert

    return Lambert().pack()


def _tracing_pool():
    """(pool, size): threads for primary rays, shared by the process's renderers, as many as the
    kernels' OpenMP threads (a service worker given one core traces on one)."""
    global _pool
    if _pool is None:
        from concurrent.futures import ThreadPoolExecutor

        from ... import native

        n = max(1, native.max_threads())
        _pool = (ThreadPoolExecutor(max_workers=n, thread_name_prefix="glint-trace"), n)
    return _pool


@dataclass(eq=False)
class View:
    """Primary visibility of one camera with S samples per pixel (rows p·S + s): tri (P·S,) int32
    face per sample (−1 background), uv (P·S, 2) float32 Embree barycentrics, dirs (P·S, 3)
    float32 ray directions, visible (K,) int32 vertices of the faces seen, wo (K, 3) float32 unit
    directions from them to the eye, bg (n,) int64 the background sample rows and uv0 (n, 2)
    float32 their map coordinates (render.env_coords), obj (H, W) int32
    object per pixel (from the pixel centres, −1 background); bgbuf (P·S, 3) float32 the
    background last drawn (bg_key: its lighting and ground shadow)."""
    camera: object
    tri: np.ndarray
    uv: np.ndarray
    dirs: np.ndarray
    visible: np.ndarray
    samples: int = 1
    wo: np.ndarray | None = None
    bg: np.ndarray | None = None
    uv0: np.ndarray | None = None
    obj: np.ndarray | None = None
    bgbuf: np.ndarray | None = None
    bg_key: object = None
    refinement: Refinement | None = None
    traced: int = 0          # primary rays traced (the others cannot hit the mesh: ``_screen_box``)
    # edge sampling (edges.py): on a one-sample view, its edge views by sample count; on an edge
    # view, pix (n,) int64 the frame's pixels its rows belong to (rows i·S + s: pixel pix[i])
    edges: dict | None = None
    pix: np.ndarray | None = None
    hits: tuple | None = None       # (rows (h,) int64 of the samples that hit, their faces (h,) int32)

    def hit_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """(rows (h,) int64 ascending of the samples that hit a face, their faces (h,) int32),
        made once per view: a refined frame reads its faces' weights there, not over the
        whole image (the object is a tenth of the oak chair's)."""
        if self.hits is None:
            rows = np.flatnonzero(self.tri >= 0)
            self.hits = (rows, self.tri[rows])
        return self.hits


@dataclass
class Samples:
    """Surface points to shade or fit: pix (N,) flat pixel index (or vertex id for vertex
    samples), positions (N, 3), normals (N, 3) unit, wo (N, 3) unit towards the eye, verts
    (N, 3) int32 vertex (cut) indices, bary (N, 3) float32 weights of those cuts; all float32;
    face (N,) int32 the face of each sample when it is one (pixel samples), else None."""
    pix: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    wo: np.ndarray
    verts: np.ndarray
    bary: np.ndarray
    face: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.pix)


def _blend3(bary, x, f) -> np.ndarray:
    """(n, 3): Σ_i bary[:, i] · x[f[:, i]] for bary (n, 3) float32, x (V, 3), f (n, 3) int."""
    out = bary[:, 0:1] * x[f[:, 0]]
    out += bary[:, 1:2] * x[f[:, 1]]
    out += bary[:, 2:3] * x[f[:, 2]]
    return out


def face_centres(faces, vertices, normals) -> tuple[np.ndarray, np.ndarray]:
    """(centroids (F, 3), unit normals there (F, 3)) float32 of faces (F, 3) int, the normal the
    normalised mean of the vertex normals (an interpolated normal at barycentre ⅓, ⅓, ⅓)."""
    vx, vn = vertices[faces], normals[faces]
    nrm = vn.sum(1)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), np.float32(1e-30))
    return vx.mean(1).astype(np.float32), nrm.astype(np.float32)


class CutRenderer(Renderer):
    """Renders one loaded scene from its cut set (CutData).

    kernels : the kernel backend (worker/native/kernels.py); default: the process's.
    """

    kind = DECLARATION.kind
    controls = DECLARATION.controls
    capabilities = frozenset({"place", "drag_level", "view_cache", "stroke_fit", "vertex_transfer"})
    _moving = None          # MovingFrames (moving.py) of a scene with movable objects
    primary = "project"     # how a view finds its primary hits: "project" (core.primary) or "embree"

    def __init__(self, scene, data: CutData, kernels=None):
        super().__init__(scene, data, kernels)
        self.k = kernels or _kernels()
        self.cuts = data.cuts
        self.tree = get_tree(self.cuts.height)
        self.tracer = data.tracer(scene)                    # shared by the scene's renderers
        self.lighting = data.lighting(scene.envmap, self.tree)
        self._view: View | None = None
        self._views: list[View] = []        # the last few (camera, samples): still frames re-use moving ones'
        self._light_key = None
        self._node_light = None
        self._node8 = None
        self._lights: OrderedDict = OrderedDict()   # light key -> (its LeafLighting, node_light, node8)
        self._ground_key = None
        self._ground_factor = None
        self._grounds: OrderedDict = OrderedDict()  # ground key -> (its LeafLighting, factor grid)
        self._vert = np.zeros((len(scene.mesh.vertices), 3), np.float32)
        self._centres = None              # face centroids and their normals (a still scene's, for the probe)
        vx = np.asarray(scene.mesh.vertices, np.float64)
        self._bounds = (vx.min(0), vx.max(0)) if len(vx) else (np.zeros(3), np.zeros(3))
        self._mats_key = None
        self._mats: MaterialTable | None = None
        self._layers = LayersCache(scene)
        self._drag_mats = self._drag_mats_of = None             # drag-level table, and the table it came from
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

    def has_view(self, camera, samples: int = 1, antialias: str = "full") -> bool:
        """Whether the primary hits of (camera, samples, antialias) are cached: a frame of them
        costs only shading. Movable-object scenes draw one sample (always ready)."""
        if self._moving is not None:
            return True
        with self._lock:
            if antialias == "edges" and samples > 1:
                return any(v.samples == 1 and v.camera == camera and samples in (v.edges or {})
                           for v in self._views)
            return any(v.samples == samples and v.camera == camera for v in self._views)

    def forget_views(self, min_pixels: int) -> int:
        """Drop the cached primary hits (and their backgrounds) of cameras of at least
        ``min_pixels`` (width × height): a closed session's big frame must not keep its worker
        above resting memory while a background build still holds this renderer (a 1920×1080
        still's hits and their buffers are ~0.7 GB). Returns how many went."""
        with self._lock:
            keep = [v for v in self._views if v.camera.width * v.camera.height < min_pixels]
            n = len(self._views) - len(keep)
            self._views = keep
            if self._view is not None and self._view not in keep:
                self._view = keep[0] if keep else None
            return n

    def view(self, camera, samples: int = 1) -> View:
        """Primary hits of a camera with S samples per pixel (cached for the last few). With
        movable objects: one sample, the objects where the last frame had them."""
        if self._moving is not None:
            with self._lock:
                mv = self._moving.view(camera, self._moving.W)
            v = View(camera, mv.tri, mv.uv, mv.dirs, mv.visible)
            v.obj = self.object_of(mv.tri).reshape(camera.height, camera.width)
            return v
        with self._lock:
            for v in self._views:
                if v.samples == samples and v.camera == camera:
                    self._view = v
                    return v
        d = camera_dirs(camera.eye, camera.target, camera.up, camera.fov_y_deg, camera.width, camera.height,
                        samples, kernels=self.k)
        tri, uv, traced = self._primary_hits(camera, samples, d)
        mesh = self.scene.mesh
        visible = seen_vertices(tri, mesh.faces, len(mesh.vertices))
        wo = np.asarray(camera.eye, np.float32) - mesh.vertices[visible]
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        bg = np.nonzero(tri < 0)[0]
        v = View(camera, tri, uv, d, visible, samples, wo, bg, env_coords(d, self.k, rows=bg), traced=traced)
        if samples == 1:
            v.obj = self.object_of(tri).reshape(camera.height, camera.width)
        else:
            v.obj = self._object_map(camera)
        with self._lock:
            self._views = [v] + [x for x in self._views if x is not v][:2]
            self._view = v
        return v

    def object_of(self, tri: np.ndarray) -> np.ndarray:
        """(…) int32 object index of each hit face in ``tri`` (int32, −1: a miss, which maps to −1):
        one gather from the scene's face → object table with a −1 appended."""
        t = getattr(self, "_object_of_face1", None)
        if t is None:
            t = self._object_of_face1 = np.append(self.scene.object_of_face, -1).astype(np.int32)
        return t[tri]

    def _object_map(self, camera) -> np.ndarray:
        """(H, W) int32 object per pixel centre (−1 background) of a camera: the one-sample
        view's when it is cached; else, projecting, the one-sample hits alone (a tenth of a
        one-sample view, which also gathers vertices and background coordinates); traced, the
        one-sample view."""
        with self._lock:
            for x in self._views:
                if x.samples == 1 and x.camera == camera:
                    return x.obj
        if self.primary != "project":
            return self.view(camera, 1).obj
        d = camera_dirs(camera.eye, camera.target, camera.up, camera.fov_y_deg, camera.width, camera.height, 1,
                        kernels=self.k)
        tri, _, _ = self._primary_hits(camera, 1, d)
        obj = self.object_of(tri)
        return obj.reshape(camera.height, camera.width)

    def _primary_hits(self, camera, samples: int, d: np.ndarray):
        """(tri (P·S,) int32, uv (P·S, 2) float32, traced: rays traced through Embree) of the
        primary rays d (P·S, 3) float32 of a camera. ``primary = "project"`` (the default)
        projects the faces into the image (core.primary: the rays all start at the eye, so no
        ray is traced; the hits are the tracer's but on shared edges and silhouettes within
        rounding); ``"embree"`` traces the rays of the mesh's screen box."""
        if self.primary == "project":
            tri, uv, _ = primary_hits(self.scene.mesh.vertices, self.scene.mesh.faces, camera, samples, d, self.k)
            return tri, uv, 0
        rows = self._box_rows(camera, samples)
        eye = np.asarray(camera.eye, np.float32)
        if rows is None:
            tri, uv = self._first_hit(np.broadcast_to(eye, d.shape).copy(), d)
            return tri, uv, len(d)
        # the rest of the frame sees the background: its rays are not traced
        tri = np.full(len(d), -1, np.int32)
        uv = np.zeros((len(d), 2), np.float32)
        if len(rows):
            tri[rows], uv[rows] = self._first_hit(np.broadcast_to(eye, (len(rows), 3)).copy(), d[rows])
        return tri, uv, len(rows)

    def _screen_box(self, camera) -> tuple[int, int, int, int] | None:
        """(row0, row1, col0, col1): the pixels (rows row0 ≤ y < row1, columns col0 ≤ x < col1)
        whose footprints meet the projection of the mesh's bounding box, or None when every
        pixel must be traced (a box corner at or behind the eye's plane). A pinhole projects the
        box inside the rectangle spanned by its eight projected corners, so a ray through any
        other pixel (any sub-pixel sample) misses the mesh: a big frame of a small object
        traces a fraction of its rays. Same camera model as core.render.camera_rays."""
        lo, hi = self._bounds
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        eye = np.asarray(camera.eye, np.float64)
        fwd = np.asarray(camera.target, np.float64) - eye
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, np.asarray(camera.up, np.float64))
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        q = corners - eye
        z = q @ fwd
        if (z <= 1e-6 * max(1.0, float(np.abs(q).max()))).any():
            return None
        w, h = int(camera.width), int(camera.height)
        t = np.tan(np.radians(float(camera.fov_y_deg)) / 2.0)
        px = ((q @ right) / (z * t * (w / h)) + 1.0) * (w / 2.0)     # continuous pixel coordinates
        py = (1.0 - (q @ up) / (z * t)) * (h / 2.0)
        # one pixel of margin on each side for the float32 rays
        c0, c1 = max(0, int(np.floor(px.min())) - 1), min(w, int(np.ceil(px.max())) + 1)
        r0, r1 = max(0, int(np.floor(py.min())) - 1), min(h, int(np.ceil(py.max())) + 1)
        return (r0, max(r0, r1), c0, max(c0, c1))

    def _box_rows(self, camera, samples: int) -> np.ndarray | None:
        """(n,) int64 sample rows (p·S + s) of the pixels of ``_screen_box``, or None when all
        rows must be traced (no box, or a box over most of the frame: then the gather costs
        more than it saves)."""
        box = self._screen_box(camera)
        w, h = int(camera.width), int(camera.height)
        if box is None or (box[1] - box[0]) * (box[3] - box[2]) > 0.7 * w * h:
            return None
        r0, r1, c0, c1 = box
        pix = (np.arange(r0, r1, dtype=np.int64)[:, None] * w + np.arange(c0, c1, dtype=np.int64)[None, :]).ravel()
        return (pix[:, None] * samples + np.arange(samples, dtype=np.int64)[None, :]).ravel()

    def _first_hit(self, o, d):
        """(tri, uv) of primary rays, traced in slices on the tracing threads (Embree releases
        the GIL, so two slices take about half the time on two cores)."""
        n = len(d)
        pool, parts = _tracing_pool()
        if n < 4096 or parts < 2:
            tri, uv, _ = self.tracer.first_hit(o, d)
            return tri, uv
        cut = [n * i // parts for i in range(parts + 1)]
        res = list(pool.map(lambda i: self.tracer.first_hit(o[cut[i]:cut[i + 1]], d[cut[i]:cut[i + 1]]),
                            range(parts)))
        return np.concatenate([r[0] for r in res]), np.concatenate([r[1] for r in res])

    def light(self, lighting: Lighting):
        """(node_l (2N−1, 3) float32 radiance×sr, node_w (2N−1, 3) float32 unit centroid
        directions) for a lighting (cached for the last one); the packed node records of the
        shading kernel are kept beside them (``_node8``)."""
        with self._lock:
            key = (float(lighting.rotation_deg), float(lighting.intensity), id(self.lighting))
            old = self._light_key
            if key == old:
                return self._node_light
            hit = self._lights.get(key)
            if hit is not None and hit[0] is self.lighting:
                # a lighting drawn a moment ago (a bundle's views alternate between its
                # environments camera by camera): its tables again, not rebuilt
                self._node_light, self._node8 = hit[1], hit[2]
                self._lights.move_to_end(key)
            elif old is not None and old[0] == key[0] and old[2] == key[2] and old[1] > 0 and key[1] > 0:
                # intensity alone: radiance scales, the light-weighted centroids do not move
                f = np.float32(key[1] / old[1])
                nl = self._node_light[0] * f
                n8 = self._node8.copy()
                n8[:, 0:3] *= f
                self._node_light, self._node8 = (nl, self._node_light[1]), n8
            else:
                nl, nw, n8 = light_tables(self.lighting, lighting.rotation_deg, lighting.intensity, self.tree, self.k)
                self._node_light, self._node8 = (nl, nw), n8
            # the LeafLighting is kept with its tables: its id in the key is not reused meanwhile
            self._lights[key] = (self.lighting, self._node_light, self._node8)
            while len(self._lights) > LIGHTS_KEPT:
                self._lights.popitem(last=False)
            self._light_key = key
            return self._node_light

    def ground_available(self) -> bool:
        """Whether this scene's precomputation has the ground shadow part."""
        return self.data.ground is not None

    def _ground(self, req: FrameRequest):
        """(factor grid (G, G, 3) float32, (x0, z0, step, y)) for the frame's lighting, or None
        when the frame has no ground shadow."""
        g, spec = self.data.ground, getattr(self.scene.spec, "ground", None)
        on = req.ground_shadow if req.ground_shadow is not None else bool(spec is not None and spec.shadow)
        if not on or g is None:
            return None
        k = req.ground_intensity if req.ground_intensity is not None else (spec.intensity if spec is not None else 1.0)
        key = (self._light_key, float(k))
        if key != self._ground_key:
            hit = self._grounds.pop(key, None)
            if hit is not None and hit[0] is self.lighting:
                f = hit[1]
            else:
                node_l, node_w = self._node_light
                f = g.factor(g.shadow(node_l, node_w, self._node8, self.tree, self.k), k)
            self._grounds[key] = (self.lighting, f)   # most recent last; its lighting kept with it
            while len(self._grounds) > LIGHTS_KEPT:
                self._grounds.popitem(last=False)
            self._ground_factor, self._ground_key = f, key
        return self._ground_factor, g.grid.geometry()

    def _background(self, v: View, lighting: Lighting, shadow, key) -> np.ndarray:
        """(P·S, 3) float32 buffer holding the view's background samples for this lighting and
        ground shadow (key: the light and ground keys they were made with; redrawn only when one
        of them changed)."""
        if v.bgbuf is None or v.bg_key != key:
            if v.bgbuf is None:
                v.bgbuf = np.zeros((len(v.tri), 3), np.float32)
            background(v.bg, v.dirs, v.uv0, self.lighting.map, lighting.rotation_deg, lighting.intensity,
                       v.bgbuf, shadow, v.camera.eye, kernels=self.k)
            v.bg_key = key
        return v.bgbuf

    def material_table(self, materials, needed=None) -> MaterialTable:
        """Packed materials (cached by the identity of the list's items). needed: the indices of
        the materials any point will be shaded with (default all); the others get a placeholder,
        so a vertex-mode frame whose edited object is all known radiance (strokes) does not pack
        its srbf (a refined frame does: its refined pixels of that object are shaded with it)."""
        needed = frozenset(range(len(materials)) if needed is None else needed)
        key = (tuple(id(m) for m in materials), needed)
        if key != self._mats_key:
            self._mats = MaterialTable([self._pack(m) if i in needed else _placeholder()
                                        for i, m in enumerate(materials)])
            self._mats_key = key
            self._mats_refs = list(materials)        # keep them alive: ids stay unique
        return self._mats

    def _drag_materials(self, mats: MaterialTable) -> MaterialTable:
        """The drag level of detail's materials: clusters refined to no finer than DRAG_REFINE
        (a fitted srbf's finest level asks for 0.03 rad, 2.5× the frame; a blurrier highlight
        while the camera moves, the full one when it stops)."""
        if self._drag_mats_of is not mats:
            d = copy.copy(mats)
            d.refine = np.maximum(mats.refine, np.float32(DRAG_REFINE))
            self._drag_mats, self._drag_mats_of = d, mats
        return self._drag_mats

    def _pack(self, m):
        """m.pack(), remembered by content (models.base.packed): a session's state is copied by
        every message, so the same material arrives as a new object each frame, and packing an
        srbf (its p(h) table over every centre) costs ~50 ms, more than the frame."""
        return packed(m)

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
        quick = req.lod == "quick"          # full resolution, one sample, coarse cuts, DRAG_REFINE clusters
        cuts = self.coarse_cuts() if (drag or (quick and QUICK_COARSE)) else self.cuts
        k = max(1, int(req.drag_scale))
        if drag and camera.width >= 160 * k:
            camera = camera.model_copy(update={"width": camera.width // k, "height": camera.height // k})
        samples = 1 if drag or quick else int(req.samples)
        if samples < 1:
            raise ValueError(f"samples: {samples} per pixel (at least 1)")
        if req.antialias not in ("full", "edges"):
            raise ValueError(f"antialias: {req.antialias!r} (full or edges)")
        materials = list(req.materials) or self.scene.materials
        if len(materials) != len(self.scene.spec.objects):
            raise ValueError(f"{len(materials)} materials for {len(self.scene.spec.objects)} objects")
        # edge sampling: the one-sample view, and S samples only at the pixels next to an edge
        ev = None
        if samples > 1 and req.antialias == "edges" and req.shading in ("vertex", "refined"):
            v = self.view(camera, 1)
            ev = self.edge_view(v, samples)
        else:
            v = self.view(camera, samples)
        t1 = time.perf_counter(); t["view"] = (t1 - t0) * 1e3
        with self._lock:        # the tables of one lighting, even if the fitter's thread asks for another
            node_l, node_w = self.light(req.lighting)
            node8 = self._node8
            shadow = self._ground(req)
            bg_key = (self._light_key, self._ground_key if shadow is not None else None)
        t2 = time.perf_counter(); t["light"] = (t2 - t1) * 1e3
        bg = self._background(v, req.lighting, shadow, bg_key)
        t3 = time.perf_counter(); t["background"] = (t3 - t2) * 1e3
        mesh = self.scene.mesh
        img = np.empty((camera.width * camera.height, 3), np.float32)
        n_refined = n_steep = 0
        if req.shading in ("vertex", "refined"):
            known = {} if drag else dict(req.vertex_radiance or {})
            vi, wo = v.visible, v.wo
            if ev is not None and len(ev.visible):       # vertices only a sub-pixel edge sample sees
                vi, wo = np.concatenate([vi, ev.visible]), np.concatenate([wo, ev.wo])
            if known:
                keep = ~np.isin(vi, np.concatenate([ids for ids, _ in known.values()]))
                vi, wo = vi[keep], wo[keep]
            mat_of = self.scene.object_of_vertex[vi]
            layers = self.layers(materials)
            # a quick frame (one sample, drag-level clusters; the anti-aliased still follows when
            # the session is idle) is not refined either: on the demo scene under load a refined
            # quick frame cost 1.5-1.9× a vertex one, for an image shown ~0.2 s
            refining = req.shading == "refined" and not drag and not quick
            needed = set(np.unique(mat_of).tolist())
            if refining:        # objects whose vertex radiance the request brings are refined too
                needed |= set(known)
            objs = sorted(needed)
            mats = (self.material_table(materials, objs) if layers is None
                    else self.material_table(layers.flat, layers.needed(objs)))
            # faces to shade per pixel, chosen by the materials' own lobes (not the drag level's)
            radius = self._refine_radius(mats, needed, layers) if refining else None
            if drag or quick:
                mats = self._drag_materials(mats)
            if req.cancelled is None:
                rad = self._shade_vertices(vi, wo, mat_of, cuts, node_l, node_w, mats, node8, layers)
            else:                       # a frame that may give way: in parts, a checkpoint between them
                rad = np.empty((len(vi), 3), np.float32)
                for a in range(0, len(vi), CANCEL_CHUNK):
                    if req.cancelled():
                        raise FrameCancelled()
                    b = min(a + CANCEL_CHUNK, len(vi))
                    rad[a:b] = self._shade_vertices(vi[a:b], wo[a:b], mat_of[a:b], cuts, node_l, node_w, mats,
                                                    node8, layers)
            vert = self._vert            # only the visible vertices' rows are read
            vert[vi] = rad
            for ids, r in known.values():
                vert[ids] = r
            t4 = time.perf_counter(); t["shade"] = (t4 - t3) * 1e3
            tri, scale, rows, face_w = v.tri, None, np.zeros(0, np.int64), None
            if radius is not None and np.isfinite(radius).any() and len(v.visible):
                scale = refinemod.object_scale(v.visible, self.scene.object_of_vertex, vert, len(materials))
                tri, rows, face_w = self._refine(v, camera, radius, vert, scale, bg, mats, layers, cuts, node_l,
                                                 node_w, node8, req.cancelled)
                n_refined = len(rows)
            t5 = time.perf_counter(); t["refine"] = (t5 - t4) * 1e3
            resolve(tri, v.uv, mesh.faces, vert, bg, v.samples, img, self.k)
            t6 = time.perf_counter(); t["resolve"] = (t6 - t5) * 1e3
            if ev is not None:
                # S samples where the surface seen changes (cached with the view) and where a
                # refined highlight changes steeply between pixels (this frame's)
                hp = (edgemod.steep_pixels(img, rows, ev.pix, v.obj, scale, camera.height, camera.width)
                      if len(rows) else np.zeros(0, np.int64))
                n_steep = len(hp)
                for sv in ([ev] if len(ev.pix) else []) + ([self._sample_view(v, hp, samples)] if len(hp) else []):
                    if sv is not ev and len(sv.visible):      # vertices only its sub-pixel samples see
                        vert[sv.visible] = self._shade_vertices(sv.visible, sv.wo, self.scene.object_of_vertex[sv.visible],
                                                                cuts, node_l, node_w, mats, node8, layers)
                    sbg = self._background(sv, req.lighting, shadow, bg_key)
                    stri = sv.tri
                    if face_w is not None:      # the faces the one-sample view refined
                        stri, srows, _ = self._refine(sv, camera, radius, vert, scale, sbg, mats, layers, cuts,
                                                      node_l, node_w, node8, req.cancelled, faces=face_w)
                        n_refined += len(srows)
                    out = np.empty((len(sv.pix), 3), np.float32)
                    resolve(stri, sv.uv, mesh.faces, vert, sbg, samples, out, self.k)
                    img[sv.pix] = out
                t["edges"] = (time.perf_counter() - t6) * 1e3
        elif req.shading == "pixel":
            hit = np.nonzero(v.tri >= 0)[0]
            layers = self.layers(materials)
            mats = self.material_table(materials if layers is None else layers.flat)
            s = self._pixel_samples(v, camera, hit)
            val = bg.copy()
            val[hit] = self._shade(s, cuts, node_l, node_w, mats, self.scene.object_of_vertex, node8, layers)
            img[:] = val.reshape(-1, samples, 3).mean(1)
            t["shade"] = (time.perf_counter() - t3) * 1e3
        else:
            raise ValueError(f"unknown shading mode {req.shading!r} (vertex, refined or pixel)")
        return Rendered(img.reshape(camera.height, camera.width, 3), v.obj, t,
                        {"lod": req.lod, "tau": DRAG_TAU if drag else self.data.tau, "width": camera.width,
                         "height": camera.height, "visible_vertices": int(len(v.visible)), "samples": samples,
                         "antialias": "edges" if ev is not None else "full",
                         "edge_pixels": 0 if ev is None else int(len(ev.pix)),
                         "steep_pixels": 0 if ev is None else n_steep,
                         "refined_samples": n_refined,
                         "ground_shadow": None if self.data.ground is None else shadow is not None})

    @staticmethod
    def _refine_radius(mats: MaterialTable, seen, layers: Layers | None = None) -> np.ndarray:
        """(O,) float32 radians: each object's refine radius (refine.py) for the objects in view
        (seen: their indices, shaded now or with their vertex radiance brought by the request:
        both are refined alike, so a stroke frame is the settled frame), inf elsewhere (their
        material is a placeholder); an object with regions takes its narrowest layer's."""
        on = np.zeros(len(mats.refine), bool)
        on[list(seen)] = True
        out = np.where(on, mats.refine, np.inf).astype(np.float32)
        for o, (slots, _, _) in (layers.objects.items() if layers is not None else ()):
            if on[o]:
                out[o] = mats.refine[slots].min()
        return out

    def _refine(self, v: View, camera, radius, vert, scale, bg, mats, layers, cuts, node_l, node_w, node8,
                cancelled, faces=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Shade per pixel the sample rows of view v the refinement picks (refine.py), writing
        them into bg (the background buffer's rows of hit samples are never read as background,
        so they carry the per-pixel radiance into the resolve). faces : (F + 1,) float32 the
        frame's weight per mesh face (−1: not chosen yet; last slot, the background rows', 0)
        when another view of the frame chose them (an edge view takes its one-sample view's:
        the same faces, no second probe; only faces that view did not see are chosen here);
        None: all chosen here. Returns (tri (P·S,) int32 with those rows set to −1, so the
        resolve reads bg there; the refined rows (m,) int64; the weight per mesh face)."""
        if faces is None:
            faces = np.full(len(self.scene.mesh.faces) + 1, -1.0, np.float32)
            faces[-1] = 0.0
            ref = self._refinement(v, camera)
        else:
            new = np.zeros(len(faces), bool)
            new[v.tri] = True
            new &= faces < 0
            ref = None
            if new.any():                    # faces only its sub-pixel samples see
                ref = Refinement.of_view(np.where(new[v.tri], v.tri, -1), self.scene.mesh.faces,
                                         self.scene.mesh.vertices, self.scene.mesh.normals, camera.eye,
                                         self.scene.object_of_face, self.k)
        if ref is not None:
            w_seen = ref.face_weights(radius, vert, scale, self.k, refinemod.SPREAD_FRACTION, refinemod.CONTRAST,
                                      refinemod.RAMP,
                                      None if layers is None else ref.face_radius(radius, mats.refine, layers),
                                      probe=self._probe(ref, camera, self._probe_cuts(), node_l, node_w, mats, node8, layers)
                                      if refinemod.PROBE is not None else None,
                                      probe_limit=refinemod.PROBE or 0.0)
            faces[ref.faces] = w_seen[:-1]
        hit, hit_face = v.hit_rows()
        w = faces[hit_face]
        k = np.flatnonzero(w > 0)
        rows, weight = hit[k], w[k]
        if not len(rows):
            return v.tri, rows, faces
        part = self._pixel_samples(v, camera, rows)
        px = self._shade_chunked(part, cuts, node_l, node_w, mats, node8, cancelled, layers)
        ramp = weight < 1
        if ramp.any():      # faces near a threshold: partly the interpolation
            g = _blend3(part.bary[ramp], vert, part.verts[ramp])
            px[ramp] = g + weight[ramp, None] * (px[ramp] - g)
        bg[rows] = px
        tri = v.tri.copy()
        tri[rows] = -1
        return tri, rows, faces

    def _probe_cuts(self) -> cutmod.CutSet:
        """The cuts the refinement's probe shades with: the drag level's (τ = DRAG_TAU), whatever the
        frame's. The probe looks for a lobe peak between a face's vertices, and the cluster walk
        splits nodes about the mirror direction down to the lobe's refine radius from either cut,
        so the peak is the same; what the coarse cut changes is the rest of the sphere (diffuse and
        far light, ~0.4% of the image on the demo chair), far below the probe's limit (PROBE × the
        object's mean radiance). Full-τ cuts made the probe as costly as shading every vertex
        again (on the oak chair's orbit frames with an srbf, 19 of 69 ms); the coarse ones are a
        sixth of their entries. The coarse set is built once per scene."""
        return self.data.coarse(DRAG_TAU, self.k)

    def _probe(self, ref: Refinement, camera, cuts, node_l, node_w, mats, node8, layers):
        """The refinement's probe (refine.py face_weights): radiance at the centroids of seen
        faces (indices into ref.faces)."""

        def probe(idx):
            s = self._centroid_samples(ref.faces[idx], camera)
            if layers is not None:
                return self._shade(s, cuts, node_l, node_w, mats, self.scene.object_of_vertex, node8, layers)
            # one vertex's cut with the centroid's normal and view direction: the probe looks for a
            # lobe peak the vertices miss, not for visibility (linear, interpolated exactly); a
            # third of the cost of blending the face's three cuts
            v0 = np.ascontiguousarray(s.verts[:, 0])
            return shade_points(s.normals, s.wo, v0, self.scene.object_of_vertex[v0].astype(np.int32), cuts,
                                node_l, node_w, self.tree, mats, self.k, node8=node8)

        return probe

    def edge_view(self, v: View, samples: int) -> View:
        """The edge samples of a one-sample view v (edges.py): S rays through each pixel next to
        an edge of the surface seen (rows i·S + s of pixel ``pix[i]``), traced through Embree,
        with what a View carries for them (``visible``: only the vertices the one-sample view
        does not see, ``wo`` theirs; background rows, directions and map coordinates). Kept with
        v, by S."""
        with self._lock:
            got = (v.edges or {}).get(samples)
        if got is not None:
            return got
        e = self._sample_view(v, self._edge_pixels(v), samples)
        with self._lock:
            v.edges = {**(v.edges or {}), samples: e}
        return e

    def _edge_pixels(self, v: View) -> np.ndarray:
        """(n,) int64 flat indices of a one-sample view's pixels next to a silhouette, an occlusion
        or a crease (edges.edge_pixels): where the anti-aliased frame takes its samples."""
        cam = v.camera
        return edge_pixels(v.tri, self.scene.mesh.faces, self.scene.object_of_face, cam.height, cam.width, self.k)

    def _trace_pixels(self, cam, pix: np.ndarray, samples: int):
        """The S sample rays through each of the camera's pixels pix (n,) int64 (rows i·S + s,
        render.sample_offsets) traced through Embree: (dirs (n·S, 3) float32, tri (n·S,) int32
        face or −1, uv (n·S, 2) float32)."""
        d = pixel_dirs(cam.eye, cam.target, cam.up, cam.fov_y_deg, cam.width, cam.height, pix, samples,
                       kernels=self.k)
        if not len(d):
            return d, np.zeros(0, np.int32), np.zeros((0, 2), np.float32)
        tri, uv = self._first_hit(np.broadcast_to(np.asarray(cam.eye, np.float32), d.shape).copy(), d)
        return d, tri, uv

    def _sample_view(self, v: View, pix: np.ndarray, samples: int) -> View:
        """A View of S samples through each of the pixels pix (n,) int64 of the one-sample view
        v (rows i·S + s of pixel pix[i]), traced through Embree: its ``visible`` only the vertices
        v does not see (``wo`` theirs), with its background rows, directions and map coordinates."""
        cam = v.camera
        mesh = self.scene.mesh
        d, tri, uv = self._trace_pixels(cam, pix, samples)
        vmask = np.zeros(len(mesh.vertices), bool)
        vmask[mesh.faces[tri[tri >= 0]].reshape(-1)] = True
        vmask[v.visible] = False
        extra = np.nonzero(vmask)[0].astype(np.int32)
        wo = np.asarray(cam.eye, np.float32) - mesh.vertices[extra]
        wo /= np.maximum(np.linalg.norm(wo, axis=1, keepdims=True), np.float32(1e-30))
        bg = np.nonzero(tri < 0)[0]
        return View(cam, tri, uv, d, extra, samples, wo.astype(np.float32), bg, env_coords(d, self.k, rows=bg),
                    traced=len(d), pix=pix)

    def _refinement(self, v: View, camera) -> Refinement:
        """The view's refinement geometry (refine.py Refinement), made once per view."""
        if v.refinement is None:
            mesh = self.scene.mesh
            v.refinement = Refinement.of_view(v.tri, mesh.faces, mesh.vertices, mesh.normals, camera.eye,
                                              self.scene.object_of_face, self.k)
        return v.refinement

    def _shade_chunked(self, s: Samples, cuts, node_l, node_w, mats, node8, cancelled, layers=None) -> np.ndarray:
        """_shade of samples, in parts with a checkpoint between them when the frame may give way."""
        if cancelled is None:
            return self._shade(s, cuts, node_l, node_w, mats, self.scene.object_of_vertex, node8, layers)
        out = np.empty((len(s), 3), np.float32)
        step = CANCEL_CHUNK                                  # a blended cut a sample: about a vertex's cost
        for a in range(0, len(s), step):
            if cancelled():
                raise FrameCancelled()
            b = min(a + step, len(s))
            part = Samples(s.pix[a:b], s.positions[a:b], s.normals[a:b], s.wo[a:b], s.verts[a:b], s.bary[a:b],
                           None if s.face is None else s.face[a:b])
            out[a:b] = self._shade(part, cuts, node_l, node_w, mats, self.scene.object_of_vertex, node8, layers)
        return out

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
        return self.view(camera).obj

    def edge_mask(self, camera) -> np.ndarray:
        """(H, W) bool: the pixels the anti-aliased frame samples as edges (edges.edge_pixels:
        next to a silhouette, an occlusion or a crease)."""
        out = np.zeros(camera.height * camera.width, bool)
        out[self._edge_pixels(self.view(camera))] = True
        return out.reshape(camera.height, camera.width)

    # -- what the fitter asks ------------------------------------------------------------------
    def _pixel_samples(self, v: View, camera, pix: np.ndarray) -> Samples:
        mesh = self.scene.mesh
        vx, vn = self._geometry()
        tri = v.tri[pix]
        f = mesh.faces[tri]
        u, w2 = v.uv[pix, 0:1], v.uv[pix, 1:2]
        bary = np.concatenate([1 - u - w2, u, w2], axis=1).astype(np.float32)
        # Σ_i b_i x_i term by term: (b[:, :, None] * x[f]).sum(1), in the same order, without the
        # (n, 3, 3) temporaries and the strided reduction (sofa2's ~3.8K refined samples: 1.3 → 0.8 ms)
        nrm, pos = _blend3(bary, vn, f), _blend3(bary, vx, f)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        wo = np.asarray(camera.eye, np.float32) - pos
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        return Samples(pix, pos.astype(np.float32), nrm.astype(np.float32), wo.astype(np.float32),
                       f.astype(np.int32), bary, tri)

    def _centroid_samples(self, faces: np.ndarray, camera) -> Samples:
        """Samples at the centroids of faces (k,) int64, shaded like pixels (refine.py's probe)."""
        mesh = self.scene.mesh
        f = mesh.faces[faces]
        if self._moving is None:        # a still scene's face centres, made once (~1 ms a frame)
            if self._centres is None:
                self._centres = face_centres(mesh.faces, mesh.vertices, mesh.normals)
            pos, nrm = self._centres[0][faces], self._centres[1][faces]
        else:
            pos, nrm = face_centres(f, *self._geometry())
        wo = np.asarray(camera.eye, np.float32) - pos
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        bary = np.full((len(faces), 3), np.float32(1.0 / 3.0), np.float32)
        return Samples(np.asarray(faces, np.int64), pos, nrm, wo.astype(np.float32), f.astype(np.int32), bary,
                       np.asarray(faces, np.int32))

    def surface_samples(self, camera, object_index: int, pixels: np.ndarray | None = None) -> Samples:
        """The object's pixels in a view at the camera's resolution, each with its own normal and
        view direction and its triangle's three cuts blended by barycentric weight
        (inverse-brdf-modeling §4.1). pixels : (M,) int64 flat indices of the camera's pixels
        to look at (the fitter's fit pixels on view-pixel centres); then ``pix`` indexes
        ``pixels`` instead of the image."""
        if self._moving is not None:
            with self._lock:
                tri, uv, d = self._moving.hits(camera)
            if pixels is not None:
                tri, uv, d = tri[pixels], uv[pixels], d[pixels]
        else:
            o, d = camera_rays(camera.eye, camera.target, camera.up, camera.fov_y_deg, camera.width, camera.height,
                               kernels=self.k)
            if pixels is not None:
                o, d = o[pixels], d[pixels]
            tri, uv = self._first_hit(o, d)
        pix = np.nonzero(self.object_of(tri) == object_index)[0]
        return self._pixel_samples(View(camera, tri, uv, d, np.zeros(0, np.int32)), camera, pix)

    def area_samples(self, camera, object_index: int, pixels: np.ndarray, samples: int) -> Samples:
        """S samples over each of the camera's pixels (flat indices, (n,) int64), at the
        anti-aliased frame's offsets (render.sample_offsets), that see the object: Samples whose
        ``pix`` is i·S + s for sample s of pixels[i], as ``surface_samples``'."""
        if self._moving is not None:
            raise Unsupported("samples over a pixel's area are not made for scenes with movable objects")
        d, tri, uv = self._trace_pixels(camera, np.asarray(pixels, np.int64), int(samples))
        rows = np.nonzero(self.object_of(tri) == object_index)[0]
        return self._pixel_samples(View(camera, tri, uv, d, np.zeros(0, np.int32)), camera, rows)

    def vertex_samples(self, camera, object_index: int, samples: int = 1, antialias: str = "full") -> Samples:
        """The object's vertices the camera sees (vertex-mode shading points): with samples S > 1,
        those of the one-sample and the S-sample views (antialias "edges": its edge samples'),
        so that radiance known for them (``FrameRequest.vertex_radiance``) covers anti-aliased
        frames too."""
        vx, vn = self._geometry()
        v1 = self.view(camera)
        vis = v1.visible
        if samples > 1 and antialias == "edges" and self._moving is None:
            vis = np.union1d(vis, self.edge_view(v1, samples).visible).astype(np.int32)
        elif samples > 1:
            vis = np.union1d(vis, self.view(camera, samples).visible).astype(np.int32)
        ids = vis[self.scene.object_of_vertex[vis] == object_index].astype(np.int32)
        wo = np.asarray(camera.eye, np.float32) - vx[ids]
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        bary = np.zeros((len(ids), 3), np.float32)
        bary[:, 0] = 1.0
        return Samples(ids, vx[ids], vn[ids], wo.astype(np.float32),
                       np.repeat(ids[:, None], 3, axis=1), bary)

    def transfer(self, samples: Samples, basis, lighting: Lighting, coarse: bool = False):
        """SRBF transfer rows at samples (fit/transfer.py, inverse-brdf-modeling eq. 21):
        (T (3, N, J) float32, E (N, 3) float32). coarse : on the drag level's cuts
        (``_fit_cuts``)."""
        from ...fit.transfer import transfer

        nrm, wo, (node_l, node_w) = self._in_frame(samples, lighting)
        return transfer(nrm, wo, samples.verts, samples.bary, self._fit_cuts(coarse), node_l, node_w,
                        self.tree, basis, self.k)

    def _fit_cuts(self, coarse: bool) -> cutmod.CutSet:
        """The cuts for fit rows: the drag level's (DRAG_TAU) for a quick view, except in a
        scene with movable objects, whose drag-level cuts belong to the frame being drawn."""
        if coarse and self._moving is None:
            return self.data.coarse(DRAG_TAU, self.k)
        return self.cuts

    def _in_frame(self, s: Samples, lighting: Lighting):
        """(normals, wo, node lighting) of samples of one object in the frame of its cuts: the
        world's, or a moved object's own (normals and view directions turned by R^T, the light
        turned into the frame)."""
        q = self._frame_of(int(self.scene.object_of_vertex[s.verts[0, 0]])) if len(s) else None
        if q is None:
            return s.normals, s.wo, self.light(lighting)
        return ((s.normals @ q).astype(np.float32), (s.wo @ q).astype(np.float32), self._frame_light(q, lighting))

    def shade_samples(self, samples: Samples, material, object_index: int, lighting: Lighting,
                      coarse: bool = False) -> np.ndarray:
        """(N, 3) float64 radiance of the samples under a material, shaded like pixel mode
        (coarse : on the cuts ``transfer`` uses for a quick view)."""
        with self._lock:
            nrm, wo, (node_l, node_w) = self._in_frame(samples, lighting)
            # the packed node records belong to the world frame's tables only
            node8 = self._node8 if self._node_light is not None and node_l is self._node_light[0] else None
        s = Samples(samples.pix, samples.positions, nrm, wo, samples.verts, samples.bary, samples.face)
        if not has_regions(material):
            mats = MaterialTable([packed(material)])
            return self._shade(s, self._fit_cuts(coarse), node_l, node_w, mats, None, node8).astype(np.float64)
        # a material with regions: its layers in the object's slot (the others are never shaded)
        mlist = [_placeholder_model()] * len(self.scene.spec.objects)
        mlist[object_index] = material
        layers = Layers(mlist, self.scene.object_of_vertex, self.scene.vertex_source)
        mats = MaterialTable([self._pack(m) if i in layers.needed([object_index]) else _placeholder()
                              for i, m in enumerate(layers.flat)])
        return self._shade(s, self._fit_cuts(coarse), node_l, node_w, mats, self.scene.object_of_vertex, node8,
                           layers).astype(np.float64)

    def layers(self, materials) -> Layers | None:
        """The frame's region layers (renderers/layers.py), or None when no material has regions; cached
        by the identity of the list's items, as the material table is."""
        return self._layers.get(materials)

    def _shade_vertices(self, vi, wo, mat_of, cuts, node_l, node_w, mats, node8, layers) -> np.ndarray:
        """(K, 3) float32 vertex-mode radiance of vertices vi (K,) with view directions wo and
        objects mat_of: one shading per vertex, or per layer of weight > 0 with regions."""
        nrm = self.scene.mesh.normals
        if layers is None:
            return shade_points(nrm[vi], wo, vi, mat_of, cuts, node_l, node_w, self.tree, mats, self.k, node8=node8)
        (src, slot, wt), blend = layers.expand_cached(vi, mat_of, mat_of)
        g = layers.gathered
        if g is None or g[0] is not vi or g[1] is not wo:
            vs = vi[src]
            g = layers.gathered = (vi, wo, vs, np.ascontiguousarray(nrm[vs]), np.ascontiguousarray(wo[src]))
        _, _, vs, n_s, wo_s = g
        rad = shade_points(n_s, wo_s, vs, slot, cuts, node_l, node_w, self.tree, mats, self.k, node8=node8)
        return np.asarray(blend @ rad, np.float32)

    def _shade(self, s: Samples, cuts, node_l, node_w, mats, mat_of_vertex, node8=None, layers=None) -> np.ndarray:
        """(N, 3) float32 per-pixel radiance of samples: each shades the blend of its triangle's
        three cuts by barycentric weight with its own normal and view direction (one cluster
        list, core/render.py shade_blend; B is linear in visibility, inverse-brdf-modeling
        eq. 22). mat_of_vertex : (V,) object of each vertex (a face's three share it), or None:
        every sample has material 0. With region layers (renderers/layers.py) a sample shades each layer
        its corners carry, weighted by the corners' layer weights interpolated barycentrically, so
        the frame stays linear in every layer's radiance (the blend of a face's cuts is the same
        for every layer)."""
        n = len(s)
        if layers is None or mat_of_vertex is None:
            mat_of = np.zeros(n, np.int32) if mat_of_vertex is None else mat_of_vertex[s.verts[:, 0]].astype(np.int32)
            return shade_blend(s.normals, s.wo, s.verts, s.bary, mat_of, cuts, node_l, node_w, self.tree, mats,
                               self.k, node8=node8, face=s.face)
        flat = s.verts.reshape(-1)
        mat_of = mat_of_vertex[flat]
        src, slot, wt = layers.expand(flat, mat_of, mat_of)              # per corner and layer
        # a sample's weight of a layer: its corners' weights by barycentric weight
        n_slots = int(slot.max()) + 1 if len(slot) else 1
        key = (src // 3) * n_slots + slot
        uk, inv = np.unique(key, return_inverse=True)
        w = np.bincount(inv, weights=wt * s.bary.reshape(-1)[src]).astype(np.float32)
        si, sl = uk // n_slots, (uk % n_slots).astype(np.int32)
        # face grouping (shade_blend's ``face``) assumes one material per face: not passed here
        rad = shade_blend(s.normals[si], s.wo[si], s.verts[si], s.bary[si], sl, cuts, node_l, node_w, self.tree,
                          mats, self.k, node8=node8)
        return Layers.blend(rad, si, w, n)
