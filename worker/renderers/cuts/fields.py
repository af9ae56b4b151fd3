"""Visibility cut fields: moving rigid objects in the cut renderer (cyber-worlds §V, eq. 4).

V(x, ω) = V_s(x, ω) Π_i V_i(x, ω): a vertex's visibility is its self-visibility (static geometry,
or a movable object's own geometry) times the occlusion by every other object i, read from i's
visibility cut field (VCF) at the vertex's position in i's local frame.

What is precomputed (``field_parts``; content-keyed by meshes alone, so moving never
invalidates anything):
  * per object, its field (field.py): binary occlusion cuts at the sample points of K
    concentric spheres × (6n² + 2) cube-map points (grid.py), over the 2^15 tree directions,
    clustered only where children are equal (lossless), height-encoded (4-bit heights + 1-bit
    values, deflated), plus each sample's clearance (nearest hit).
    Static objects need fields too, as soon as the scene has a movable object: a moved
    object's own vertices are shaded against every other object (the floor, walls, furniture),
    in its own frame, and nothing but a field says what the floor hides from a chair leg
    wherever it goes. (Measured: without the floor's and the table's fields, oakTable's own
    vertices are 11% too bright on average, 14% near the floor; with them 0.4%.)
  * per movable object, the self-visibility cuts of its vertices with the object alone, in its
    local frame (``precompute_cuts`` on the local mesh).
  * the renderer's static cuts: static vertices against static geometry only (``static_cuts``).

Grid (GridSpec defaults K = 24 shells, n = 24, radii 0.25 r … 8 r, geometric): measured against
ray tracing at random points 0.5-6 r around oakChair and oakTable (BENCHMARKS.md "Cut fields"),
the uniform-sky irradiance error of the interpolated occlusion stays below 0.3% (p95) of the
unoccluded irradiance from 16 × 16² to 32 × 32² samples, because interpolation blurs shadows
without moving their mass; the shadow-shape error (L1 over the cosine-weighted hemisphere)
falls slowly with density: around oakChair 0.057, 0.044, 0.037 at 16 × 16², 24 × 24², 32 × 32²
(the occluded part is 0.11). 24 × 24² keeps most of the paper's (32 × 32²) accuracy for 42% of
its samples and tracing time. Geometric radii keep each cell's size proportional to its distance, as the
occluded set changes on that scale. The innermost shell (0.25 r) reaches under tables and chair
seats; points inside it read it. Beyond 8 r the object is culled: a sphere of radius r seen
from 8 r covers at most 1/64 of the cosine-weighted hemisphere, and the object in it less: 0.3%
(oakChair) and 0.7% (oakTable) on average for a receiver facing it, 1.3% at most. What is lost
is a faint darkening, and a sun shadow longer than 8 r (a sun below ~7° over an object standing
on the floor); it ends at 8 r rather than fading.

Rendering (combine.py, rotate.py; C kernels in worker/native/src/fields.c):
  1. ``glf_lookup``: each receiver vertex in each occluder's local frame → its cell and the 8
     corner weights (linear in log ρ between shells, bilinear within a cube face), or culled
     when the bounding sphere lies below the vertex's horizon (§V.B) or the vertex is beyond
     8 r. A corner farther from the vertex than its clearance may lie inside the object or
     across a thin part of it (a table top, the floor); those segments are traced and blocked
     corners dropped (``validate``; near the table, this halves the mean error and cuts its
     p95 five-fold).
  2. rotation (``glf_rotate``): the leaf tree is fixed in the receiver's frame — the world for
     static vertices, the object's local frame for a moved object's own vertices, lit by the
     environment turned into that frame (``frame_lighting``; a yaw is a column shift of the map,
     exact). A sample's binary cut is re-expressed over the receiver's leaves through the
     nearest-leaf map π_Q (receiver leaf j reads the source leaf nearest to Q^T d_j), touching
     only its blocked leaves, and rebuilt with nodes of at least 2^h_min = 32 leaves: uniform
     nodes stay whole, mixed ones keep their free fraction, only non-free nodes are kept.
     ``glf_cells`` then merges a cell's 8 corners once for all the vertices in it. Samples and
     cells are cached per (field, rotation): translating an object re-uses them.
  3. ``glf_combine``: the counter walk of §V.A.3 over the vertex's cut and its cells, with the
     all-free stretches skipped: v = v_s · Π_i Σ_c w_ic v_ic / Σ_c w_ic, base nodes split only
     where a stretch starts or ends inside them, dark base nodes (below the horizon,
     self-occluded) kept whole. The output is an ordinary CutSet over the receiver frame's
     leaves, shaded by glk_shade_points.
  h_min = 5: the interpolation, not the coarser field nodes, dominates the error (shadow-shape
  error 0.018-0.052 of the hemisphere at h_min = 0, +0.003-0.007 at h_min = 3, +0.007-0.017 at
  h_min = 5; irradiance error unchanged), the field cuts get 2-3× shorter at 3 and shorter
  again at 5. Frames (BENCHMARKS.md, moving objects) differ from exact field cuts by ~0.1%
  relative RMS at 3 and at 5; a sliding frame costs a fifth less at 5.

Rotation, the options measured (BENCHMARKS.md "Cut fields", per frame at 10K receivers):
  * re-expressing each vertex's (or its combined) cut over rotated leaves: a 2^15-leaf gather
    and a re-clustering per vertex, ≥ 0.4 ms of CPU each: seconds per frame. Rejected.
  * expressing the lighting and the other cuts in the occluder's frame: exact and free for a
    moved object's own vertices (chosen there), but a static receiver's cut lives in the world
    frame and would need the leaf-level rotation above. Rejected for static receivers.
  * rotating the binary field samples (chosen): a sample's blocked leaves once per rotation and
    sample, then cells once per rotation and cell; a frame touches about one new sample per two
    receivers while rotating and almost none while translating. The per-vertex work is then the
    walk above, a few µs.
"""
from __future__ import annotations

import copy
import threading
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core import cuts as cutmod
from ...core.cuts import DEFAULT_TAU, CutSet
from ...core.directions import get_tree
from ...core.lighting import LeafLighting, node_lighting, rotate_map
from ...errors import GlintError
from ...keys import content_key
from .precompute import OFFSET_EDGE, OFFSET_MAX
from ..base import Part
from .combine import DEFAULT_HMIN, Combiner, combined_cuts, lookup  # noqa: F401  (the API)
from .field import Field, FieldError, bounding_sphere, field_key, trace_field  # noqa: F401
from .grid import FieldGrid, GridSpec
from .rotate import rotation_part

__all__ = [
    "Combiner",
    "Field",
    "FieldGrid",
    "FrameGroup",
    "GridSpec",
    "MovingScene",
    "ObjectShape",
    "combined_cuts",
    "compute_part",
    "field_parts",
    "frame_light_tables",
    "frame_lighting",
    "load_part",
    "object_shape",
    "static_cuts",
    "trace_field",
]


class MoveError(GlintError):
    """A transform a movable object cannot take, or a field that does not fit its object."""


# --- objects in their local frames -----------------------------------------------------------

@dataclass
class ObjectShape:
    """An object's mesh in its local ("shape") frame and where that frame is in the world.

    vertices (V, 3) float32, faces (F, 3) int32, normals (V, 3) float32: the mesh file's
    coordinates, times the object's scale when the scale is not uniform (then it is part of
    the shape). world_from_local : (4, 4) float64 similarity (uniform scale, rotation,
    translation) of the object's current transform.
    """
    name: str
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    world_from_local: np.ndarray
    shape_scale: tuple[float, float, float] | None = None


def split_transform(transform) -> tuple[tuple[float, float, float] | None, np.ndarray]:
    """(shape scale or None when uniform, world_from_local 4×4) of a scene Transform."""
    from ...scene import Transform

    s = np.ones(3) * np.asarray(transform.scale, np.float64)
    if np.allclose(s, s[0], rtol=1e-9, atol=0):
        m = Transform(scale=float(s[0]), rotate_deg=transform.rotate_deg, translate=transform.translate).matrix()
        return None, m
    m = Transform(scale=1.0, rotate_deg=transform.rotate_deg, translate=transform.translate).matrix()
    return tuple(float(x) for x in s), m


def object_shape(scene, index: int, transform=None) -> ObjectShape:
    """The object's mesh in its local frame (re-read from its file, so the content key does not
    depend on where it stands) and world_from_local for ``transform`` (default: the scene's)."""
    obj = scene.spec.objects[index]
    shape_scale, m = split_transform(transform or obj.transform)
    mesh = _local_mesh(scene.resolve(obj.mesh), shape_scale)
    return ObjectShape(obj.name, mesh.vertices, mesh.faces, mesh.normals, m, shape_scale)


_MESHES: OrderedDict = OrderedDict()       # (path, mtime, size, shape scale) -> Mesh, a few kept
_MESHES_LOCK = threading.Lock()


def _local_mesh(path, shape_scale):
    """A mesh file in its own coordinates (times a non-uniform shape scale), read once while the
    file is unchanged: parts are listed often (ensure, load, the CLI's progress bar), and a
    21K-vertex OBJ takes about a second to parse."""
    from pathlib import Path

    from ...scene import Transform, load_mesh

    p = Path(path)
    try:
        st = p.stat()
        key = (str(p.resolve()), st.st_mtime_ns, st.st_size, shape_scale)
    except OSError:
        key = None
    with _MESHES_LOCK:
        if key is not None and key in _MESHES:
            _MESHES.move_to_end(key)
            return _MESHES[key]
    mesh = load_mesh(p, Transform(scale=shape_scale) if shape_scale else None)
    for a in (mesh.vertices, mesh.faces, mesh.normals):
        a.setflags(write=False)                     # shared: nobody may edit it in place
    if key is not None:
        with _MESHES_LOCK:
            _MESHES[key] = mesh
            while len(_MESHES) > 16:
                _MESHES.popitem(last=False)
    return mesh


def receiver_from_local(world_from_receiver: np.ndarray, world_from_local: np.ndarray) -> np.ndarray:
    """(4, 4) map from an occluder's local frame to a receiver frame (both given to the world)."""
    return np.linalg.inv(world_from_receiver) @ world_from_local


# --- precomputed parts -------------------------------------------------------------------------

SELF_CUTS_VERSION = 3   # of the self-visibility cuts' key (worker/keys.py); 3: ray offsets by edge length


def self_cuts_key(shape: ObjectShape, tau: float, height: int) -> str:
    """Content key of a movable object's self-visibility cuts: its local geometry and normals
    (float32, int32), τ and the direction tree's height."""
    return content_key("self-cuts", SELF_CUTS_VERSION, vertices=np.asarray(shape.vertices, np.float32),
                       faces=np.asarray(shape.faces, np.int32), normals=np.asarray(shape.normals, np.float32),
                       tau=float(tau), height=int(height), offset_edge=float(OFFSET_EDGE),
                       offset_max=float(OFFSET_MAX))


def field_parts(scene, movable: list[str], options: Mapping[str, Any] | None = None) -> list[Part]:
    """The parts moving objects need: a field per object (when anything is movable) and the
    self-visibility cuts of each movable object alone, in its local frame.

    movable : names of the movable objects. options : ``tau`` (self cuts, default DEFAULT_TAU),
    ``field_grid`` (GridSpec or dict of its fields).
    Part.meta: {"kind": "field" | "self_cuts", "object": index}.
    """
    options = dict(options or {})
    names = [o.name for o in scene.spec.objects]
    unknown = [m for m in movable if m not in names]
    if unknown:
        raise MoveError(f"movable objects not in the scene: {', '.join(unknown)}")
    if not movable:
        return []
    spec = _grid_spec(options)
    tau = float(options.get("tau", DEFAULT_TAU))
    H = get_tree().height
    parts = []
    for i, name in enumerate(names):
        shape = object_shape(scene, i)
        parts.append(Part(field_key(shape.vertices, shape.faces, spec, H), f"cut field of {name!r}",
                          spec.shells * (6 * spec.face ** 2 + 2), {"kind": "field", "object": i}))
        if name in movable:
            parts.append(Part(self_cuts_key(shape, tau, H), f"self-visibility cuts of {name!r}",
                              len(shape.vertices), {"kind": "self_cuts", "object": i}))
    return parts


def _grid_spec(options: Mapping[str, Any]) -> GridSpec:
    g = options.get("field_grid")
    if g is None:
        return GridSpec()
    if isinstance(g, GridSpec):
        return g
    try:
        return GridSpec(**dict(g))
    except (TypeError, ValueError) as e:
        raise GlintError(f"field_grid: {e}") from None


def compute_part(scene, part: Part, options: Mapping[str, Any] | None = None, progress=None,
                 threads: int = 2, kernels=None) -> tuple[bytes, dict]:
    """The bytes and stats of one part of ``field_parts`` (kernels: the backend that builds the
    self cuts; default: the process's)."""
    from .precompute import precompute_cuts

    options = dict(options or {})
    shape = object_shape(scene, part.meta["object"])
    if part.meta["kind"] == "field":
        f = trace_field(shape.vertices, shape.faces, _grid_spec(options), threads=threads, progress=progress, key=part.key)
        blob = f.encode()
        return blob, {**f.stats, **f.storage(len(blob))}
    if part.meta["kind"] == "self_cuts":
        cs, rays, secs = precompute_cuts(shape.vertices, shape.faces, shape.normals,
                                         tau=float(options.get("tau", DEFAULT_TAU)), threads=threads, progress=progress,
                                         kernels=kernels)
        blob = cutmod.encode(cs)
        return blob, {"seconds": secs, "vertices": cs.n_vertices, "rays_traced": rays,
                      "mean_cut_size": float(cs.sizes().mean()) if cs.n_vertices else 0.0, "bytes_height_encoded": len(blob)}
    raise ValueError(f"not a cut-field part: {part.meta}")


def load_part(scene, part: Part, blob: bytes):
    """A part's data: a Field (with its object's local mesh attached, for the receivers'
    segment tests) or a CutSet (self cuts)."""
    if part.meta["kind"] == "field":
        sh = object_shape(scene, part.meta["object"])
        return Field.decode(blob).attach(sh.vertices, sh.faces)
    return cutmod.decode(blob)


# --- static cuts without the movable objects -------------------------------------------------

def static_cuts(scene, movable: list[str], tau: float = DEFAULT_TAU, threads: int = 2, progress=None) -> tuple[CutSet, np.ndarray]:
    """Self-visibility cuts of the static objects' vertices against static geometry only
    ("static self-visibility cuts leave movable objects out of the occluders").
    Returns (CutSet, vertex ids (K,) int32 in scene.mesh of its cuts, in order)."""
    from .precompute import precompute_cuts

    names = [o.name for o in scene.spec.objects]
    mov = np.array([n in movable for n in names])
    keep_v = ~mov[scene.object_of_vertex]
    keep_f = ~mov[scene.object_of_face]
    ids = np.nonzero(keep_v)[0].astype(np.int32)
    remap = np.full(len(keep_v), -1, np.int64)
    remap[ids] = np.arange(len(ids))
    m = scene.mesh
    faces = remap[m.faces[keep_f]].astype(np.int32)
    cs, _, _ = precompute_cuts(m.vertices[ids], faces, m.normals[ids], tau=tau, threads=threads, progress=progress)
    return cs, ids


# --- lighting in a rotated frame ------------------------------------------------------------

def frame_lighting(lighting: LeafLighting, world_from_frame: np.ndarray, rotation_deg: float = 0.0,
                   intensity: float = 1.0):
    """Per-node lighting (node_l, node_w as lighting.node_lighting) over the leaves of a frame
    rotated by world_from_frame (3×3 or 4×4; the rotation part is used): leaf j of the frame is
    the world direction R d_j. Shade a moved object's own cuts with it, and its normals and
    view directions turned into the frame (R^T).

    A rotation about +Y by θ is exact: φ(R_y(θ) d) = φ(d) − θ in the map's convention
    u = atan2(x, −z)/2π, so it is the environment rotated by −θ (a column shift). Any other
    rotation resamples the map bilinearly first (``_frame_lighting_resampled``).
    """
    q, _ = rotation_part(_as4(world_from_frame))
    yaw = yaw_of(q)
    if yaw is not None:
        l, ld = lighting.leaf_radiance(rotation_deg - yaw, intensity)
        return node_lighting(l, ld, lighting.tree)
    return _frame_lighting_resampled(lighting, q, rotation_deg, intensity)


def yaw_of(q: np.ndarray) -> float | None:
    """The angle θ in degrees of a (3, 3) rotation about +Y (q = R_y(θ)), None for any other."""
    yaw = float(np.degrees(np.arctan2(q[0, 2], q[0, 0])))
    c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
    return yaw if np.abs(q - np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])).max() < 1e-9 else None


def frame_light_tables(lighting: LeafLighting, world_from_frame: np.ndarray, rotation_deg: float = 0.0,
                       intensity: float = 1.0, kernels=None):
    """``frame_lighting`` with the shading kernel's packed node records: (node_l, node_w
    (2N−1, 3), node8 (2N−1, 8)) float32. A yaw is the world's light tables at rotation_deg − θ,
    built by the kernel backend (glk_light_tables: a frame of a turning object costs ~1 ms
    instead of ~10 ms; float32 rounding apart, the same tables); other rotations resample."""
    from ...core.lighting import light_tables, pack_nodes

    q, _ = rotation_part(_as4(world_from_frame))
    yaw = yaw_of(q)
    if yaw is not None:
        return light_tables(lighting, rotation_deg - yaw, intensity, lighting.tree, kernels)
    nl, nw = _frame_lighting_resampled(lighting, q, rotation_deg, intensity)
    return nl, nw, pack_nodes(nl, nw)


def _frame_lighting_resampled(lighting: LeafLighting, world_from_frame: np.ndarray, rotation_deg: float,
                              intensity: float):
    """frame_lighting for any rotation: the map as seen from the frame (bilinear, cv2.remap),
    then its leaf integrals."""
    import cv2

    from ...core.lighting import pixel_directions

    q, _ = rotation_part(_as4(world_from_frame))
    env = rotate_map(lighting.map, rotation_deg)
    h, w, _ = env.shape
    d, _ = pixel_directions(h, w)                          # frame directions of the frame map's pixels
    dw = d.reshape(-1, 3) @ q.T                            # the same directions in the world
    u = np.mod(np.arctan2(dw[:, 0], -dw[:, 2]) / (2 * np.pi), 1.0) * w - 0.5
    v = np.arccos(np.clip(dw[:, 1], -1, 1)) / np.pi * h - 0.5
    # columns wrap around; rows are clipped inside the map, so the wrap never applies to them
    mapped = cv2.remap(np.ascontiguousarray(env, np.float32), u.reshape(h, w).astype(np.float32),
                       np.clip(v, 0, h - 1).reshape(h, w).astype(np.float32), cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_WRAP)
    lt = copy.copy(lighting)
    lt.map = np.ascontiguousarray(mapped, np.float32)
    l, ld = lt.leaf_radiance(0.0, intensity)
    return node_lighting(l, ld, lighting.tree)


def _as4(m: np.ndarray) -> np.ndarray:
    m = np.asarray(m, np.float64)
    if m.shape == (4, 4):
        return m
    out = np.eye(4)
    out[:3, :3] = m
    return out


# --- per frame: what the renderer calls ---------------------------------------------------------

@dataclass
class FrameGroup:
    """Receivers whose cuts share a frame. Shade them with the node lighting of that frame
    (``frame_lighting(lighting, world_from_frame, …)``; the world's own when it is the identity),
    with their normals in the frame (``normals``) and their view directions turned into it:
    wo_frame = world_from_frame^T · wo_world.

    vertex_ids (k,) int32 scene vertex ids; cuts : CutSet of k cuts (cut i for vertex_ids[i]);
    world_from_frame (3, 3); normals (k, 3) float32 in the frame; positions (k, 3) float32 in the
    world (where they are now); object : the movable object's index, or None for static vertices.
    """
    vertex_ids: np.ndarray
    cuts: CutSet
    world_from_frame: np.ndarray
    normals: np.ndarray
    positions: np.ndarray
    object: int | None


class MovingScene:
    """A scene with movable objects, as the cut renderer holds it between frames.

    scene : LoadedScene (objects at their precomputation transforms); movable : their names;
    static : (CutSet, vertex ids) from ``static_cuts``; self_cuts : object index -> CutSet of
    its vertices alone, local frame; fields : object index -> Field (mesh attached) for every
    object. ``cuts(vertex_ids, transforms)`` gives the FrameGroups of a frame. kernels: the
    kernel backend (worker/native/kernels.py).
    """

    def __init__(self, scene, movable, static: tuple[CutSet, np.ndarray], self_cuts: Mapping[int, CutSet],
                 fields: Mapping[int, Field], hmin: int = DEFAULT_HMIN, kernels=None):
        self.scene = scene
        names = [o.name for o in scene.spec.objects]
        self.movable = {names.index(m) for m in movable}
        self.static_cuts, static_ids = static
        self.static_row = np.full(len(scene.mesh.vertices), -1, np.int64)
        self.static_row[static_ids] = np.arange(len(static_ids))
        self.self_cuts = dict(self_cuts)
        self.fields = dict(fields)
        missing = [names[i] for i in range(len(names)) if i not in self.fields]
        if missing:
            raise MoveError(f"no cut field for {', '.join(missing)}")
        self.shapes = {i: object_shape(scene, i) for i in self.movable}
        first = np.searchsorted(scene.object_of_vertex, np.arange(len(names)))
        self.first_vertex = first
        self.combiner = Combiner(hmin, kernels=kernels)

    def world_from_local(self, transforms: Mapping[str, Any] | None = None) -> list[np.ndarray]:
        """(4, 4) per object: its transform now (``transforms``, scene.Transform by object name,
        overrides the scene's for movable objects; a static object never moves)."""
        names = [o.name for o in self.scene.spec.objects]
        fixed = [n for n in (transforms or {}) if n not in names or names.index(n) not in self.movable]
        if fixed:
            raise MoveError(f"not movable: {', '.join(fixed)}")
        out = []
        for i, o in enumerate(self.scene.spec.objects):
            t = (transforms or {}).get(o.name) if i in self.movable else None
            shape_scale, m = split_transform(t or o.transform)
            if t is not None and shape_scale != self.shapes[i].shape_scale:
                raise MoveError(f"{o.name}: moving cannot change a non-uniform scale (it is part of the shape)")
            out.append(m)
        return out

    def cuts(self, vertex_ids: np.ndarray, transforms: Mapping[str, Any] | None = None) -> list[FrameGroup]:
        """Cuts of the given scene vertices (e.g. the visible ones) for objects placed by
        ``transforms``: static vertices × every movable object's field; each movable object's
        vertices × every other object's field, in its own frame."""
        vertex_ids = np.asarray(vertex_ids, np.int64)
        W = self.world_from_local(transforms)
        obj = self.scene.object_of_vertex[vertex_ids]
        groups = []
        stat = vertex_ids[~np.isin(obj, list(self.movable))]
        if len(stat):
            occ = [(self.fields[i], W[i]) for i in sorted(self.movable)]
            rows = self.static_row[stat]
            if (rows < 0).any():
                raise MoveError("static cuts do not cover every static vertex")
            x, n = self.scene.mesh.vertices[stat], self.scene.mesh.normals[stat]
            cs = self.combiner.combine(self.static_cuts, rows, x, n, occ)
            groups.append(FrameGroup(stat.astype(np.int32), cs, np.eye(3), n, x, None))
        for i in sorted(self.movable):
            ids = vertex_ids[obj == i]
            if not len(ids):
                continue
            local = ids - self.first_vertex[i]
            sh = self.shapes[i]
            inv = np.linalg.inv(W[i])
            occ = [(self.fields[j], inv @ W[j]) for j in range(len(W)) if j != i]
            cs = self.combiner.combine(self.self_cuts[i], local, sh.vertices[local], sh.normals[local], occ)
            xw = (sh.vertices[local].astype(np.float64) @ W[i][:3, :3].T + W[i][:3, 3]).astype(np.float32)
            q, _ = rotation_part(W[i])
            groups.append(FrameGroup(ids.astype(np.int32), cs, q, sh.normals[local], xw, i))
        return groups
