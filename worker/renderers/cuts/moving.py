"""Scenes with movable objects in the cut renderer: what is precomputed, and how a frame is drawn
after objects moved (cyber-worlds §V, eq. 4: V(x, ω) = V_s(x, ω) Π_i V_i(x, ω)).

Precomputation (parts, all content-keyed by geometry that never moves, so a move, or an edited
scene file with other transforms of its movable objects, needs nothing new):
  * the **static cuts**: the vertices of the static objects against static geometry only
    (``geometry_key`` of the static submesh: the same key, and bytes, as a scene made of the
    static objects alone);
  * per movable object, its **self cuts** (its vertices against itself alone, local frame) and
    per object, movable or not, its **field** (fields.py ``field_parts``): a moved chair is
    shaded against the floor, the walls and the table as much as they are against it.
A scene file may set the field grid (``"cuts": {"field_grid": {"shells": K, "face": n}}``).

A frame (``MovingFrames.render``), for the objects placed by FrameRequest.transforms:
  1. **Primary visibility**: the static geometry's hits are kept per camera; each movable
     object's faces, placed in the world, are projected into the image (core.primary, as a
     static view's) and keep the samples they hit nearer than what was hit before. When the
     renderer traces (``primary`` "embree"), the object's own Embree scene (local frame) is
     traced instead with the camera rays turned into its frame, only for the pixels inside its
     projected bounding box, nearer than the ray's tfar; barycentrics are the same in both.
  2. **Static vertices**: their radiance with the static cuts is kept per eye, lighting and
     materials; a moving object changes only the vertices whose stencils in its field survive
     culling (§V.B). For those, the combination kernel's delta mode gives what the fields take
     away, v_s − v_s Π_i F_i, whose non-zero nodes are only where an object is seen, and
     radiance = kept radiance − shade(delta cut). For a Lambertian surface this is exactly the
     full product's radiance (the cluster sums are additive); for a glossy one the clusters an
     object splits are evaluated at their pieces' centroids in the subtracted part, as the full
     product would.
     At full quality this part runs on a second thread beside part 3 (its own Combiner).
  3. **Each movable object's vertices**: its self cuts × every other object's field, in its own
     frame (fields.py), shaded with the light turned into that frame (``frame_lighting``,
     kept per yaw) and the view directions turned by world_from_frame^T.
Both levels rebuild field cuts with nodes ≥ 2^5 leaves (h_min = 5, combine.DEFAULT_HMIN). The
drag level of detail uses the static and self cuts coarsened to τ = 16, half resolution, part 2
on the frame's own thread, and the object's yaw snapped to SNAP_DEG for
the fields and the light (not for where it is drawn), so that a turn re-uses rotated samples,
cells and frame lighting from earlier frames.
"""
from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Mapping
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...core import cuts as cutmod
from ...core.cuts import DEFAULT_TAU, CutSet
from ...core.directions import get_tree
from ...core.primary import primary_hits
from ...core.render import (
    camera_rays,
    env_lookup,
    interpolate,
    seen_vertices,
    shade_points,
)
from ...trace.embree import Tracer
from ..base import Part, Rendered, Unsupported
from ..layers import Layers
from .combine import DEFAULT_HMIN, Combiner
from .fields import (
    MoveError,
    ObjectShape,
    compute_part,
    field_parts,
    frame_light_tables,
    load_part,
    object_shape,
    split_transform,
)
from .rotate import rotation_part

DRAG_HMIN = 5          # field cuts of the drag level of detail: nodes of ≥ 32 leaves (fields.py)
SNAP_DEG = 5.0         # drag: the yaw the fields and the frame light use, snapped (samples re-used)
DRAG_TAU = 16.0        # the static and self cuts of the drag level of detail (as renderer.DRAG_TAU)


def movable_names(scene) -> list[str]:
    """Names of the scene file's objects marked ``"movable": true``, in scene order."""
    return [o.name for o in scene.spec.objects if getattr(o, "movable", False)]


def cut_options(scene, options: Mapping[str, Any] | None) -> dict:
    """The precomputation options with the scene file's ``cuts`` settings (the field grid)
    filled in where the caller gave none."""
    out = dict(options or {})
    st = getattr(scene.spec, "cuts", None)
    if st is not None and st.field_grid is not None and "field_grid" not in out:
        out["field_grid"] = st.field_grid.model_dump()
    return out


# --- the static submesh ---------------------------------------------------------------------------

@dataclass
class StaticMesh:
    """The static objects' part of a scene mesh. ids (S,) int32 their vertices in scene.mesh,
    vertices (S, 3) float32, normals (S, 3) float32, faces (G, 3) int32 into ids, face_ids (G,)
    int32 those faces in scene.mesh."""
    ids: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    face_ids: np.ndarray


def static_mesh(scene, movable: list[str]) -> StaticMesh:
    names = [o.name for o in scene.spec.objects]
    mov = np.array([n in movable for n in names])
    keep_v = ~mov[scene.object_of_vertex]
    face_ids = np.nonzero(~mov[scene.object_of_face])[0].astype(np.int32)
    ids = np.nonzero(keep_v)[0].astype(np.int32)
    remap = np.full(len(keep_v), -1, np.int64)
    remap[ids] = np.arange(len(ids))
    m = scene.mesh
    return StaticMesh(ids, m.vertices[ids], remap[m.faces[face_ids]].astype(np.int32), m.normals[ids], face_ids)


# --- precomputation ---------------------------------------------------------------------------------

def moving_parts(scene, options: Mapping[str, Any] | None) -> list[Part]:
    """The parts of a scene with movable objects: static cuts (when anything is static), then
    per object its field, and per movable object its self cuts (fields.field_parts)."""
    from .precompute import geometry_key

    movable = movable_names(scene)
    options = cut_options(scene, options)
    tau = float(options.get("tau", DEFAULT_TAU))
    sm = static_mesh(scene, movable)
    parts = []
    if len(sm.ids):
        parts.append(Part(geometry_key(sm.vertices, sm.faces, sm.normals, tau, get_tree().height),
                          "static visibility cuts (movable objects left out)", len(sm.ids),
                          {"kind": "static_cuts", "tau": tau}))
    return parts + field_parts(scene, movable, options)


def moving_chunks(scene, part: Part, n: int, batch: int) -> list:
    if part.meta["kind"] != "static_cuts":
        return [None]
    nv = int((~np.isin(scene.object_of_vertex, _movable_indices(scene))).sum())
    step = max(batch, -(-nv // max(1, n) // batch) * batch)
    return [(s, min(s + step, nv)) for s in range(0, nv, step)] or [(0, 0)]


def _movable_indices(scene) -> list[int]:
    return [i for i, o in enumerate(scene.spec.objects) if getattr(o, "movable", False)]


def compute_moving(scene, part: Part, options, chunk=None, progress=None, threads: int = 2, kernels=None) -> dict:
    """One chunk of a moving scene's part (kernels: the precomputation's backend)."""
    from .precompute import precompute_cuts

    options = cut_options(scene, options)
    if part.meta["kind"] == "static_cuts":
        sm = static_mesh(scene, movable_names(scene))
        s, e = chunk if chunk is not None else (0, len(sm.ids))
        cs, rays, secs = precompute_cuts(sm.vertices, sm.faces, sm.normals, tau=part.meta["tau"], threads=threads,
                                         progress=progress, start=s, stop=e, kernels=kernels)
        return {"cuts": cs, "rays": rays, "seconds": secs}
    t0 = time.perf_counter()
    blob, stats = compute_part(scene, part, options, progress, threads, kernels)
    return {"blob": blob, "stats": {"seconds": time.perf_counter() - t0, **stats}}


def assemble_moving(part: Part, results: list) -> tuple[bytes, dict]:
    from .precompute import storage_stats

    if part.meta["kind"] != "static_cuts":
        (r,) = results
        return r["blob"], {"kind": part.meta["kind"], **r["stats"]}
    cs = CutSet.concat([r["cuts"] for r in results])
    blob = cutmod.encode(cs)
    secs = sum(r["seconds"] for r in results)
    return blob, {"kind": "static_cuts", "rays_traced": int(sum(r["rays"] for r in results)), "tau": part.meta["tau"],
                  "seconds_tracing": secs, "samples_per_second": cs.n_vertices * (1 << cs.height) / max(secs, 1e-9),
                  **storage_stats(cs, len(blob))}


def describe_moving(part: Part, blob: bytes) -> dict:
    """Stats of a stored part without decoding all of it (a field's header holds its stats)."""
    from .precompute import storage_stats

    kind = part.meta["kind"]
    if kind == "field":
        import json
        import zlib

        from .field import MAGIC

        raw = zlib.decompressobj().decompress(blob[len(MAGIC):], 1 << 16)
        head = json.loads(raw[4:4 + int.from_bytes(raw[:4], "little")])
        st = head.get("stats", {})
        ns, nn = head["samples"], head["nodes"]
        return {"kind": kind, "bytes": len(blob), "samples": ns, "nodes": nn, "mean_cut_size": nn / max(ns, 1),
                "grid": head["grid"], "bytes_compressed": len(blob),
                "bytes_raw": 2 * ns + (nn + 1) // 2 + (nn + 7) // 8,          # as Field.storage
                "bytes_index_encoded": 2 * ns + 2 * nn + (nn + 7) // 8,
                **{k: st[k] for k in ("seconds", "rays_traced", "rays_per_second", "triangles", "threads") if k in st}}
    if kind == "static_cuts":
        return {"kind": kind, "tau": part.meta["tau"], **storage_stats(cutmod.decode(blob), len(blob))}
    return {"kind": kind, "bytes": len(blob)}


def load_moving(scene, blobs: Mapping[str, bytes], options):
    """CutData for a scene with movable objects (MovingData attached)."""
    from .precompute import CutData

    parts = moving_parts(scene, options)
    movable = movable_names(scene)
    sm = static_mesh(scene, movable)
    tau = float(cut_options(scene, options).get("tau", DEFAULT_TAU))
    H = get_tree().height
    static = CutSet(np.zeros(1, np.int64), np.zeros(0, np.uint8), np.zeros(0, np.uint8), H)
    self_cuts, fields = {}, {}
    for p in parts:
        k = p.meta["kind"]
        if k == "static_cuts":
            static = cutmod.decode(blobs[p.key])
            if static.n_vertices != len(sm.ids):
                raise ValueError(f"stored static cuts are for {static.n_vertices} vertices, the scene has {len(sm.ids)}")
        elif k == "self_cuts":
            self_cuts[p.meta["object"]] = load_part(scene, p, blobs[p.key])
        else:
            fields[p.meta["object"]] = load_part(scene, p, blobs[p.key])
    md = MovingData(scene, movable, sm, static, self_cuts, fields, tau)
    return CutData(static, tau, moving=md)


# --- shared data of a scene with movable objects ----------------------------------------------------

class MovingData:
    """What every renderer of a scene with movable objects shares: the static cuts and mesh, the
    movable objects' self cuts and local meshes, every object's field, and (built on first use)
    the Embree scenes for primary rays and the drag-time cut sets.

    static : CutSet of sm.ids (the static vertices, in order); self_cuts : object index ->
    CutSet of its vertices (local frame); fields : object index -> Field (mesh attached)."""

    def __init__(self, scene, movable: list[str], sm: StaticMesh, static: CutSet, self_cuts: dict, fields: dict,
                 tau: float):
        names = [o.name for o in scene.spec.objects]
        self.movable = sorted(names.index(m) for m in movable)
        self.sm = sm
        self.static = static
        self.self_cuts = self_cuts
        self.fields = fields
        self.tau = tau
        missing = [names[i] for i in range(len(names)) if i not in fields]
        if missing:
            raise MoveError(f"no cut field for {', '.join(missing)}")
        self.static_row = np.full(len(scene.mesh.vertices), -1, np.int64)
        self.static_row[sm.ids] = np.arange(len(sm.ids))
        self.shapes: dict[int, ObjectShape] = {i: object_shape(scene, i) for i in self.movable}
        self.first_vertex = np.searchsorted(scene.object_of_vertex, np.arange(len(names))).astype(np.int64)
        self.first_face = np.searchsorted(scene.object_of_face, np.arange(len(names))).astype(np.int64)
        self.is_movable = np.zeros(len(names), bool)
        self.is_movable[self.movable] = True
        self._lock = threading.Lock()
        self._tracers: dict = {}
        self._coarse: dict = {}

    def static_tracer(self) -> Tracer | None:
        with self._lock:
            if "static" not in self._tracers:
                sm = self.sm
                self._tracers["static"] = Tracer(sm.vertices, sm.faces) if len(sm.faces) else None
            return self._tracers["static"]

    def object_tracer(self, i: int) -> Tracer:
        with self._lock:
            if i not in self._tracers:
                sh = self.shapes[i]
                self._tracers[i] = Tracer(sh.vertices, sh.faces)
            return self._tracers[i]

    def skip(self, cs: CutSet) -> np.ndarray:
        """combine.skip_table of a cut set (the static cuts or their coarse level), once."""
        from .combine import skip_table

        with self._lock:
            key = ("skip", id(cs))
            hit = self._coarse.get(key)
            if hit is None or hit[0] is not cs:
                hit = self._coarse[key] = (cs, skip_table(cs))
            return hit[1]

    def coarse(self, i: int, tau: float, kernels=None) -> CutSet:
        """A movable object's self cuts coarsened to τ, built once (the static cuts' are
        CutData.coarse)."""
        with self._lock:
            key = (i, tau)
            if key not in self._coarse:
                self._coarse[key] = cutmod.coarsen(self.self_cuts[i], tau, kernels)
            return self._coarse[key]


# --- per renderer: frames -------------------------------------------------------------------------

@dataclass
class MovingView:
    """Primary visibility of one camera and placement: tri (P,) int32 scene face per pixel (−1
    background), uv (P, 2) float32 barycentrics, t (P,) float32 ray length (∞ on a miss), dirs
    (P, 3) float32, visible (K,) int32 scene vertices of the faces seen."""
    tri: np.ndarray
    uv: np.ndarray
    t: np.ndarray
    dirs: np.ndarray
    visible: np.ndarray


@dataclass
class _Level:
    """One level of detail: its combiner (rotated samples and cells kept between frames)."""
    combiner: Combiner
    static: CutSet
    self_cuts: dict
    snap: float | None
    skip: np.ndarray | None = None      # combine.skip_table(static)
    # the static receivers' own (they are combined on another thread: a Combiner is not
    # thread-safe)
    static_combiner: Combiner | None = None


@dataclass
class _StaticShading:
    """Radiance of static vertices with the static cuts, for one eye, light and material table
    (the objects it depends on are held, so their ids cannot be reused while it is kept)."""
    eye: tuple
    node_l: Any
    mats: Any
    lod: str
    rad: np.ndarray
    have: np.ndarray
    refs: list = field(default_factory=list)


class MovingFrames:
    """Frames of a scene with movable objects for one CutRenderer (not thread-safe: one per
    renderer, as the renderer's caches)."""

    def __init__(self, renderer, data: MovingData):
        self.r = renderer
        self.d = data
        k = renderer.k
        self.levels = {
            "full": _Level(Combiner(DEFAULT_HMIN, kernels=k), data.static, data.self_cuts, None,
                           static_combiner=Combiner(DEFAULT_HMIN, kernels=k)),
            "drag": _Level(Combiner(DRAG_HMIN, kernels=k, max_pools=24), None, {}, SNAP_DEG,
                           static_combiner=Combiner(DRAG_HMIN, kernels=k, max_pools=24)),
        }
        self._pool: ThreadPoolExecutor | None = None
        self._hits: OrderedDict = OrderedDict()        # camera -> static hits
        self._static: dict[str, _StaticShading] = {}
        self._frame_light: OrderedDict = OrderedDict()
        self._bg = None
        self._placed_key, self._placed_W, self._placed = None, None, {}
        self.last_stats: dict = {}

    # -- placement ---------------------------------------------------------------------------------
    def placement(self, transforms: Mapping[str, Any] | None) -> list[np.ndarray]:
        """(4, 4) world_from_local per object: the request's transforms for movable objects,
        the scene file's otherwise. MoveError for unknown or static objects, or a changed
        non-uniform scale (it is part of a movable object's shape)."""
        spec = self.r.scene.spec
        names = [o.name for o in spec.objects]
        transforms = dict(transforms or {})
        unknown = [n for n in transforms if n not in names]
        if unknown:
            raise MoveError(f"no object {', '.join(map(repr, unknown))} in the scene (objects: {', '.join(names)})")
        fixed = [n for n in transforms if not self.d.is_movable[names.index(n)] and
                 transforms[n] != spec.objects[names.index(n)].transform]
        if fixed:
            raise MoveError(f"not movable: {', '.join(fixed)} (mark it \"movable\": true in the scene file)")
        out = []
        for i, o in enumerate(spec.objects):
            t = transforms.get(o.name) if self.d.is_movable[i] else None
            shape_scale, m = split_transform(t or o.transform)
            if t is not None and shape_scale != self.d.shapes[i].shape_scale:
                raise MoveError(f"{o.name}: moving cannot change a non-uniform scale (it is part of the shape)")
            out.append(m)
        return out

    @staticmethod
    def snapped(m: np.ndarray, snap: float | None) -> np.ndarray:
        """m with a rotation about +Y snapped to multiples of ``snap`` degrees (other rotations
        and None: unchanged). The translation of the object's local origin is kept."""
        if not snap:
            return m
        q, s = rotation_part(m)
        yaw = np.degrees(np.arctan2(q[0, 2], q[0, 0]))
        c, sn = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
        if np.abs(q - np.array([[c, 0, sn], [0, 1, 0], [-sn, 0, c]])).max() > 1e-9:
            return m
        y = np.radians(snap * np.round(yaw / snap))
        out = m.copy()
        out[:3, :3] = s * np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
        return out

    def level(self, lod: str) -> _Level:
        """The level of detail's combiner and cuts (the drag level's coarse cuts built once)."""
        lv = self.levels["drag" if lod == "drag" else "full"]
        if lv.static is None:
            st = self.r.data.cuts
            lv.static = self.r.data.coarse(DRAG_TAU, self.r.k) if st.n_vertices else st
            lv.self_cuts = {i: self.d.coarse(i, DRAG_TAU, self.r.k) for i in self.d.movable}
        if lv.skip is None:
            lv.skip = self.d.skip(lv.static)
        return lv

    def _static_thread(self) -> ThreadPoolExecutor:
        """The one thread a frame's static receivers are computed on (made on first use)."""
        if self._pool is None:
            # its kernels keep OpenMP's team of one thread per core, as the moved objects' do:
            # measured faster than one thread for it (each part waits less for the other)
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="glint-moving-static")
        return self._pool

    # -- primary visibility ------------------------------------------------------------------------
    def static_hits(self, camera):
        """(tri scene faces (P,), uv (P, 2), t (P,), dirs (P, 3)) of the static geometry (kept for
        the last few cameras)."""
        key = camera.model_dump_json()
        hit = self._hits.get(key)
        if hit is not None:
            self._hits.move_to_end(key)
            return hit
        o, d = camera_rays(camera.eye, camera.target, camera.up, camera.fov_y_deg, camera.width, camera.height,
                           kernels=self.r.k)
        tr = self.d.static_tracer()
        if tr is None:
            tri = np.full(len(d), -1, np.int32)
            uv = np.zeros((len(d), 2), np.float32)
            t = np.full(len(d), np.inf, np.float32)
        else:
            prim, uv, t = tr.first_hit(o, d)
            tri = np.where(prim >= 0, self.d.sm.face_ids[np.maximum(prim, 0)], -1).astype(np.int32)
            t = np.where(prim >= 0, t, np.inf).astype(np.float32)
        hit = (tri, uv, t, d)
        self._hits[key] = hit
        while len(self._hits) > 2:
            self._hits.popitem(last=False)
        return hit

    def view(self, camera, W: list[np.ndarray]) -> MovingView:
        """Primary visibility with the movable objects placed by W (see the module docstring)."""
        tri0, uv0, t0, d = self.static_hits(camera)
        tri, uv, t = tri0.copy(), uv0.copy(), t0.copy()
        eye = np.asarray(camera.eye, np.float64)
        project = getattr(self.r, "primary", "embree") == "project"
        for i in self.d.movable:
            sh = self.d.shapes[i]
            if project:
                # the object's faces placed in the world and projected (core.primary, as a static
                # view's): no per-ray tracing, and its threads (embreex's first-hit queries keep
                # the GIL: one thread)
                wl = np.asarray(W[i], np.float64)
                vw = (sh.vertices.astype(np.float64) @ wl[:3, :3].T + wl[:3, 3]).astype(np.float32)
                # drawn over the hits so far, where nearer (the kernel's z-buffer starts from them)
                primary_hits(vw, sh.faces, camera, 1, d, kernels=self.r.k, into=(tri, uv, t, int(self.d.first_face[i])))
                continue
            pix = self._candidates(camera, W[i], sh)
            if len(pix) == 0:
                continue
            q, s = rotation_part(W[i])
            o_l = ((eye - W[i][:3, 3]) @ q) / s                       # Q^T (eye − T) / s
            d_l = np.ascontiguousarray(d[pix] @ q.astype(np.float32), np.float32)
            far = np.minimum(t[pix] / np.float32(s), np.float32(3.4e38)).astype(np.float32)
            prim, u, vv, tl = self._trace(self.d.object_tracer(i), o_l.astype(np.float32), d_l, far)
            hit = prim >= 0
            tl = np.where(hit, tl, 0).astype(np.float32) * np.float32(s)
            hit &= tl < t[pix]
            p = pix[hit]
            tri[p] = self.d.first_face[i] + prim[hit]
            uv[p, 0] = u[hit]
            uv[p, 1] = vv[hit]
            t[p] = tl[hit]
        mesh = self.r.scene.mesh
        return MovingView(tri, uv, t, d, seen_vertices(tri, mesh.faces, len(mesh.vertices)))

    @staticmethod
    def _trace(tracer: Tracer, origin: np.ndarray, dirs: np.ndarray, far: np.ndarray):
        """Nearest hits nearer than ``far`` of rays from one origin: (prim (R,) int32, u, v (R,)
        float32, t (R,) float32). One call: embreex's first-hit queries keep the GIL, so two
        Python threads measured no faster."""
        r = tracer.scene.run(np.broadcast_to(origin, dirs.shape).copy(), dirs, dists=far, output=1)
        return (np.asarray(r["primID"], np.int32), np.asarray(r["u"], np.float32),
                np.asarray(r["v"], np.float32), np.asarray(r["tfar"], np.float32))

    @staticmethod
    def _candidates(camera, W: np.ndarray, shape: ObjectShape) -> np.ndarray:
        """Flat pixel indices whose rays may meet the object: inside the projection of its
        placed bounding box (all pixels when the box reaches behind the eye)."""
        lo, hi = shape.vertices.min(0).astype(np.float64), shape.vertices.max(0).astype(np.float64)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        cw = corners @ W[:3, :3].T + W[:3, 3]
        eye = np.asarray(camera.eye, np.float64)
        fwd = np.asarray(camera.target, np.float64) - eye
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, np.asarray(camera.up, np.float64))
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        rel = cw - eye
        z = rel @ fwd
        w, h = camera.width, camera.height
        if (z <= 1e-6 * max(1.0, np.abs(rel).max())).any():
            return np.arange(w * h)
        ty = np.tan(np.radians(camera.fov_y_deg) / 2.0)
        px = ((rel @ right) / z / (ty * w / h) + 1.0) * 0.5 * w
        py = (1.0 - (rel @ up) / z / ty) * 0.5 * h
        x0, x1 = max(0, int(np.floor(px.min())) - 1), min(w, int(np.ceil(px.max())) + 1)
        y0, y1 = max(0, int(np.floor(py.min())) - 1), min(h, int(np.ceil(py.max())) + 1)
        if x0 >= x1 or y0 >= y1:
            return np.zeros(0, np.int64)
        ys, xs = np.mgrid[y0:y1, x0:x1]
        return (ys * w + xs).reshape(-1)

    # -- light --------------------------------------------------------------------------------------
    def frame_light(self, q: np.ndarray, lighting):
        """Node lighting (node_l, node_w) over the leaves of a frame turned by q
        (world_from_frame), kept for the last few frames and lightings."""
        return self.frame_light_tables(q, lighting)[:2]

    def frame_light_tables(self, q: np.ndarray, lighting):
        """(node_l, node_w, node8) of ``frame_light`` (fields.frame_light_tables)."""
        lt = self.r.lighting
        key = (np.round(q, 9).tobytes(), float(lighting.rotation_deg), float(lighting.intensity), id(lt))
        hit = self._frame_light.get(key)
        if hit is not None and hit[0] is lt:
            self._frame_light.move_to_end(key)
            return hit[1]
        tables = frame_light_tables(lt, q, lighting.rotation_deg, lighting.intensity, self.r.k)
        self._frame_light[key] = (lt, tables)
        while len(self._frame_light) > 24:
            self._frame_light.popitem(last=False)
        return tables

    # -- a frame ------------------------------------------------------------------------------------
    def render(self, req) -> Rendered:
        r = self.r
        # per-pixel refinement needs the three cuts of a face, which a moved object's frame
        # combines per vertex only: refined frames of these scenes are vertex shading
        if req.shading not in ("vertex", "refined"):
            raise Unsupported("scenes with movable objects are shaded per vertex (shading: vertex or refined)")
        t = {}
        t0 = time.perf_counter()
        drag = req.lod == "drag"
        camera = req.camera
        if drag and camera.width >= 320:
            camera = camera.model_copy(update={"width": camera.width // 2, "height": camera.height // 2})
        materials = list(req.materials) or r.scene.materials
        if len(materials) != len(r.scene.spec.objects):
            raise ValueError(f"{len(materials)} materials for {len(r.scene.spec.objects)} objects")
        lv = self.level(req.lod)
        self.place(req.transforms)
        W = self.W
        Wf = [self.snapped(m, lv.snap) if self.d.is_movable[i] else m for i, m in enumerate(W)]
        v = self.view(camera, W)
        t1 = time.perf_counter(); t["view"] = (t1 - t0) * 1e3
        node_l, node_w = r.light(req.lighting)
        node8 = r._node8                     # set with node_l (the renderer's lock is held)
        layers = r.layers(materials)         # painted regions (renderers/layers.py), or None
        mats = r.material_table(materials if layers is None else layers.flat)
        t2 = time.perf_counter(); t["light"] = (t2 - t1) * 1e3
        mesh, d = r.scene.mesh, self.d
        img = self._background(camera, v.dirs, req.lighting).copy()      # surfaces are drawn over it
        eye = np.asarray(camera.eye, np.float64)
        vert = np.zeros((len(mesh.vertices), 3), np.float32)
        obj_of = r.scene.object_of_vertex
        vis = v.visible
        stats = {"affected_static": 0, "visible_static": 0, "moving_vertices": 0, "samples_rotated": 0,
                 "cells_merged": 0}

        # static vertices: kept radiance minus what the moved objects' fields take away; at full
        # quality on a thread of their own while this one does the moved objects' vertices (the
        # kernels release the GIL: the NumPy and ray-test stretches of one overlap the other's
        # kernels)
        def static_part():
            s0 = time.perf_counter()
            sv = vis[~d.is_movable[obj_of[vis]]]
            st = {"affected_static": 0, "visible_static": len(sv), "samples_rotated": 0, "cells_merged": 0}
            if not len(sv):
                return sv, None, st, 0.0
            cb = lv.static_combiner
            rad = self._static_radiance(sv, eye, node_l, node_w, mats, lv, req.lod, node8, layers)
            occ = [(d.fields[i], Wf[i]) for i in d.movable]
            x, n = mesh.vertices[sv], mesh.normals[sv]
            cells, wts, _ = cb.stencils(x, n, occ)
            aff = np.nonzero((cells >= 0).any(axis=1))[0]
            st["affected_static"] = len(aff)
            if len(aff):
                delta, dcut = cb.combine(lv.static, d.static_row[sv[aff]], x[aff], n[aff], occ, delta=True,
                                         stencils=(cells[aff], wts[aff]), tag="static", skip=lv.skip, placed=True)
                self._count(st, cb.last_stats)
                wo = _unit(eye - x[aff])
                dr = _shade(n[aff], wo, dcut, sv[aff], obj_of[sv[aff]], delta,
                            node_l, node_w, r, mats, node8, layers)
                rad = rad.copy()
                rad[aff] = np.maximum(rad[aff] - dr, 0.0)
            return sv, rad, st, (time.perf_counter() - s0) * 1e3

        if drag:
            # the drag level's parts are small: two teams of kernel threads on the same cores
            # cost more than they overlap (measured 14 → 18 ms a frame on the held-out sofa)
            static = Future()
            static.set_result(static_part())
        else:
            static = self._static_thread().submit(static_part)
        t3 = time.perf_counter()

        # each movable object's own vertices, in its frame, against every other object
        try:
            for i in d.movable:
                ids = vis[obj_of[vis] == i]
                if not len(ids):
                    continue
                local = (ids - d.first_vertex[i]).astype(np.int64)
                sh = d.shapes[i]
                inv = np.linalg.inv(Wf[i])
                occ = [(d.fields[j], inv @ Wf[j]) for j in range(len(W)) if j != i]
                cs, ccut = lv.combiner.combine(lv.self_cuts[i], local, sh.vertices[local], sh.normals[local], occ,
                                               tag=f"object {i}", placed=True)
                self._count(stats, lv.combiner.last_stats)
                q, _ = rotation_part(Wf[i])
                xw = sh.vertices[local].astype(np.float64) @ W[i][:3, :3].T + W[i][:3, 3]
                wo = _unit((eye - xw) @ q)                                   # into the object's frame
                nl, nw, n8 = self.frame_light_tables(q, req.lighting)
                vert[ids] = _shade(sh.normals[local], wo, ccut, ids, obj_of[ids], cs, nl, nw,
                                   r, mats, n8, layers)
                stats["moving_vertices"] += len(ids)
        except BaseException:
            wait([static])                     # nothing of this frame runs on after it
            raise
        t4 = time.perf_counter(); t["moving"] = (t4 - t3) * 1e3
        sv, rad, st, t["static"] = static.result()
        if rad is not None:
            vert[sv] = rad
        stats["visible_static"], stats["affected_static"] = st["visible_static"], st["affected_static"]
        self._count(stats, st)
        t5 = time.perf_counter(); t["static_wait"] = (t5 - t4) * 1e3     # what the static part took longer
        t4 = t5
        interpolate(v.tri, v.uv, mesh.faces, vert, img, r.k)
        t["interpolate"] = (time.perf_counter() - t4) * 1e3
        obj = r.object_of(v.tri)
        self.last_stats = stats
        return Rendered(img.reshape(camera.height, camera.width, 3), obj.reshape(camera.height, camera.width), t,
                        {"lod": req.lod, "tau": DRAG_TAU if drag else d.tau, "width": camera.width,
                         "height": camera.height, "visible_vertices": len(vis), "refined_samples": 0, "moving": stats,
                         "hmin": lv.combiner.hmin})

    # -- the current placement: what the fitter's questions are answered for --------------------------
    def place(self, transforms: Mapping[str, Any] | None) -> None:
        """Where the movable objects stand for the fitter's questions (``surface_samples``,
        ``transfer``, …): the request's transforms of the last frame, or as set here."""
        W = self.placement(transforms)
        key = np.stack(W).round(9).tobytes()
        if key != self._placed_key:
            self._placed_key, self._placed_W = key, W
            self._placed = {}

    @property
    def W(self) -> list[np.ndarray]:
        if self._placed_W is None:
            self.place(None)
        return self._placed_W

    def geometry(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (V, 3), normals (V, 3)) float32 of the scene mesh as it stands (world)."""
        if "geometry" not in self._placed:
            mesh, W = self.r.scene.mesh, self.W
            x, n = mesh.vertices.copy(), mesh.normals.copy()
            for i in self.d.movable:
                sh, s = self.d.shapes[i], slice(self.d.first_vertex[i], self.d.first_vertex[i] + len(self.d.shapes[i].vertices))
                q, _ = rotation_part(W[i])
                x[s] = (sh.vertices.astype(np.float64) @ W[i][:3, :3].T + W[i][:3, 3]).astype(np.float32)
                n[s] = (sh.normals.astype(np.float64) @ q.T).astype(np.float32)
            self._placed["geometry"] = (x, n)
        return self._placed["geometry"]

    def cuts(self) -> CutSet:
        """Every scene vertex's cut as things stand (cut v for vertex v): static vertices × the
        movable objects' fields over the world's leaves, each movable object's vertices × the
        others' fields over its own frame's leaves (``frame``). Built once per placement (a
        few µs per vertex)."""
        if "cuts" not in self._placed:
            d, W, mesh = self.d, self.W, self.r.scene.mesh
            cb = Combiner(DEFAULT_HMIN, kernels=self.r.k)
            V = len(mesh.vertices)
            parts: list[tuple[np.ndarray, CutSet]] = []
            if len(d.sm.ids):
                occ = [(d.fields[i], W[i]) for i in d.movable]
                parts.append((d.sm.ids, cb.combine(d.static, np.arange(len(d.sm.ids)), d.sm.vertices, d.sm.normals,
                                                   occ, tag="static")))
            for i in d.movable:
                sh = d.shapes[i]
                inv = np.linalg.inv(W[i])
                occ = [(d.fields[j], inv @ W[j]) for j in range(len(W)) if j != i]
                ids = d.first_vertex[i] + np.arange(len(sh.vertices))
                parts.append((ids, cb.combine(d.self_cuts[i], np.arange(len(ids)), sh.vertices, sh.normals, occ,
                                              tag=f"object {i}")))
            sizes = np.zeros(V, np.int64)
            for ids, cs in parts:
                sizes[ids] = cs.sizes()
            off = np.zeros(V + 1, np.int64)
            np.cumsum(sizes, out=off[1:])
            h = np.empty(off[-1], np.uint8)
            q = np.empty(off[-1], np.uint8)
            for ids, cs in parts:
                dst = np.repeat(off[ids] - cs.offsets[:-1], cs.sizes()) + np.arange(cs.n_nodes)
                h[dst], q[dst] = cs.heights, cs.quant
            self._placed["cuts"] = CutSet(off, h, q, d.static.height)
        return self._placed["cuts"]

    def frame(self, object_index: int) -> np.ndarray | None:
        """(3, 3) world_from_frame of an object's cuts, None for the world (static objects)."""
        if not self.d.is_movable[object_index]:
            return None
        return rotation_part(self.W[object_index])[0]

    def hits(self, camera):
        """(tri, uv, dirs) of the camera as things stand."""
        v = self.view(camera, self.W)
        return v.tri, v.uv, v.dirs

    def _background(self, camera, dirs, lighting) -> np.ndarray:
        """(P, 3) float32 environment radiance along every primary ray, kept for the camera and
        lighting (a moving object changes which pixels show it, not what they would show)."""
        r = self.r
        key = (camera.model_dump_json(), float(lighting.rotation_deg), float(lighting.intensity), id(r.lighting.map))
        if self._bg is None or self._bg[0] != key or self._bg[1] is not r.lighting.map:
            img = np.zeros((len(dirs), 3), np.float32)
            env_lookup(dirs, r.lighting.map, lighting.rotation_deg, lighting.intensity, out=img, kernels=r.k)
            self._bg = (key, r.lighting.map, img)
        return self._bg[2]

    @staticmethod
    def _count(stats, cs):
        stats["samples_rotated"] += int(cs.get("samples_rotated", 0))
        stats["cells_merged"] += int(cs.get("cells_merged", 0))

    def _static_radiance(self, sv: np.ndarray, eye: np.ndarray, node_l, node_w, mats, lv: _Level, lod: str,
                         node8=None, layers=None):
        """(len(sv), 3) float32 radiance of static vertices with the static cuts alone (no movable
        object), kept for the eye, lighting and materials (with their regions' layers: the table
        of a new regions material is a new table); missing vertices are shaded here."""
        r, d = self.r, self.d
        key = tuple(np.round(eye, 9).tolist())
        st = self._static.get(lod)
        if st is None or st.eye != key or st.node_l is not node_l or st.mats is not mats:
            nv = len(r.scene.mesh.vertices)
            st = self._static[lod] = _StaticShading(key, node_l, mats, lod, np.zeros((nv, 3), np.float32),
                                                    np.zeros(nv, bool), [node_w])
        miss = sv[~st.have[sv]]
        if len(miss):
            mesh = r.scene.mesh
            wo = _unit(eye - mesh.vertices[miss])
            st.rad[miss] = _shade(mesh.normals[miss], wo, d.static_row[miss].astype(np.int32), miss,
                                  r.scene.object_of_vertex[miss], lv.static, node_l, node_w, r, mats, node8, layers)
            st.have[miss] = True
        return st.rad[sv]


def _shade(normals, wo, cut_of, vids, obj_of, cuts, node_l, node_w, r, mats, node8, layers) -> np.ndarray:
    """(K, 3) float32 radiance of K points (vertices ``vids`` of the scene, objects ``obj_of``)
    shaded with cuts[cut_of]: once per point, or with painted regions once per layer of weight
    > 0 at its vertex, blended by the layers' weights (renderers/layers.py; shading is linear in the
    material, so a delta cut's radiance blends the same way)."""
    if layers is None:
        return shade_points(normals, wo, cut_of, obj_of, cuts, node_l, node_w, r.tree, mats, r.k, node8=node8)
    src, slot, wt = layers.expand(np.asarray(vids, np.int64), obj_of, obj_of)
    rad = shade_points(np.ascontiguousarray(normals[src]), np.ascontiguousarray(wo[src]),
                       np.ascontiguousarray(np.asarray(cut_of)[src]), slot, cuts, node_l, node_w, r.tree, mats, r.k,
                       node8=node8)
    return Layers.blend(rad, src, wt, len(vids))


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return (v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)).astype(np.float32)


__all__ = ["DRAG_HMIN", "SNAP_DEG", "MovingData", "MovingFrames", "MovingView", "cut_options", "load_moving",
           "movable_names", "moving_parts", "static_mesh"]
