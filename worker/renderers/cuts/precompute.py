"""Precomputation of the self-visibility cuts of every vertex of a scene.

cyber-worlds §V.A.1 and inverse-brdf-modeling §4.1: per vertex, rays towards the 2^15 tree
directions are traced against the whole static scene; the cosine-weighted visibility
Ṽ(x, ω) = V(x, ω)·max(0, n·ω) fills the leaves, which are clustered into a cut.
Only directions above the vertex's horizon are traced (the others are zero by the cosine).

As a ``Precomputation`` (renderers/base.py): one part, the cut set, content-keyed by the
world-space geometry, normals, τ and the tree height; it splits into vertex ranges that can run
anywhere (threads here, Ray tasks across a cluster) and assemble byte for byte into the same
blob as a single run. A scene with a ``ground`` (the shadow catcher, ground.py) has a second
part: the cuts of the ground's sample points, keyed by the geometry and the grid.
"""
from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ...core import cuts as cutmod
from ...core.cuts import DEFAULT_TAU, CutSet
from ...core.directions import DirectionTree, get_tree
from ...keys import content_key
from ...trace.embree import Tracer
from ..base import Part, Precomputation
from . import DECLARATION

BATCH = 4           # vertices per tracing batch (2^15 rays each): 4 keeps its arrays (~5 MB) near the
                    # core's cache; 16 (~20 MB) made two concurrent processes ~12% slower per CPU second


@dataclass(eq=False)
class CutData:
    """What the cut renderer draws from: the per-vertex cut set of the whole scene, and what
    every renderer of the scene shares once it is built (the Embree scene, the drag-time cuts,
    the leaf lighting of each map), so that many sessions on one scene cost one copy.

    A scene with movable objects (moving.py) has ``moving`` (MovingData: static cuts, self cuts,
    fields), and ``cuts`` holds its static vertices' cuts only."""
    cuts: CutSet
    tau: float = DEFAULT_TAU
    ground: object = None          # ground.GroundData when the scene has a shadow-catcher ground
    moving: object = None

    def __post_init__(self):
        self._lock = threading.Lock()
        self._tracer = None
        self._coarse: dict = {}
        self._lighting: dict = {}

    def tracer(self, scene) -> Tracer:
        with self._lock:
            if self._tracer is None:
                self._tracer = Tracer(scene.mesh.vertices, scene.mesh.faces)
            return self._tracer

    def coarse(self, tau: float, kernels=None) -> CutSet:
        """The cut set coarsened to τ (cuts.coarsen), built once per τ."""
        with self._lock:
            if tau not in self._coarse:
                self._coarse[tau] = cutmod.coarsen(self.cuts, tau, kernels)
            return self._coarse[tau]

    def lighting(self, envmap, tree):
        """LeafLighting of a map (by identity), shared; the last few maps are kept."""
        from ...core.lighting import LeafLighting

        with self._lock:
            key = id(envmap)
            hit = self._lighting.pop(key, None)          # re-inserted last: least recently used first out
            if hit is None or hit[0] is not envmap:
                if len(self._lighting) >= 4:
                    self._lighting.pop(next(iter(self._lighting)))
                hit = (envmap, LeafLighting(envmap, tree))
            self._lighting[key] = hit
            return hit[1]


def vertex_visibility(tracer: Tracer, tree: DirectionTree, points: np.ndarray, normals: np.ndarray,
                      eps: float) -> tuple[np.ndarray, int]:
    """(B, N) float32 cosine-weighted visibility at B points with unit normals (B, 3), and the
    number of rays traced (directions above each point's horizon).

    Origins are pushed eps along the normal and along the ray (Embree's tnear is 0)."""
    dirs = tree.leaves
    cos = normals.astype(np.float32) @ dirs.T                  # (B, N)
    out = np.zeros_like(cos)
    bi, li = np.nonzero(cos > 0)
    if len(bi) == 0:
        return out, 0
    d = dirs[li]
    e = np.asarray(eps, np.float32)
    e = e[bi, None] if e.ndim else e
    o = points[bi] + e * normals[bi] + e * d
    vis = ~tracer.occluded(o, d)
    out[bi[vis], li[vis]] = cos[bi[vis], li[vis]]
    return out, len(bi)


def ray_epsilon(vertices: np.ndarray) -> float:
    """Origin offset: 1e-4 of the scene's bounding-box diagonal."""
    diag = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))) if len(vertices) else 1.0
    return 1e-4 * max(diag, 1e-6)


# A vertex's visibility stands for the surface around it: vertex shading interpolates it over
# the vertex's faces. Traced from the vertex itself, a shell lying a fraction of an edge above it
# (a gutter strip over a roof panel's edge, glass inside its frame: real meshes are layered)
# darkens every face of the vertex, where the surface the eye sees there is lit. Rays start
# OFFSET_EDGE of the vertex's mean edge length off the surface (and along the ray), so an occluder
# nearer than that, which interpolation could not show anyway, is left out; the offset is at
# least ray_epsilon and at most OFFSET_MAX of the scene's diagonal (a ground of two triangles).
# 0.1 was chosen on the fordFocus's greenhouse against Mitsuba (0.03 / 0.1 / 0.3: the greenhouse
# 5.9 / 4.3 / 4.6%, roof 2.4% each; a fixed 1e-4 of the diagonal: 18.3%, roof 5.5%) and
# reported on held-out scenes in docs/benchmarks/history/2026-12-07-ray-offsets.md.
OFFSET_EDGE = 0.1
OFFSET_MAX = 1e-2


def ray_offsets(vertices: np.ndarray, faces: np.ndarray | None) -> np.ndarray:
    """(V,) float32 origin offset of each vertex's rays (scene units): OFFSET_EDGE times the mean
    length of the edges at the vertex, within [ray_epsilon, OFFSET_MAX × diagonal]; ray_epsilon
    for every vertex when there are no faces (the ground's sample points). O(V + F)."""
    base = ray_epsilon(vertices)
    out = np.full(len(vertices), base, np.float32)
    if faces is None or not len(faces) or OFFSET_EDGE <= 0:
        return out
    f = np.asarray(faces, np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    v = np.asarray(vertices, np.float64)
    length = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    total = np.bincount(e.ravel(), weights=np.repeat(length, 2), minlength=len(v))
    count = np.bincount(e.ravel(), minlength=len(v))
    mean = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    top = base * (OFFSET_MAX / 1e-4)
    return np.maximum(out, np.minimum(OFFSET_EDGE * mean, top).astype(np.float32))


def precompute_cuts(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, tau: float = DEFAULT_TAU,
                    tree: DirectionTree | None = None, threads: int = 2, batch: int = BATCH, progress=None,
                    start: int = 0, stop: int | None = None, kernels=None, tracer: Tracer | None = None):
    """Cuts of vertices [start, stop) of the (static, whole-scene) mesh.

    vertices (V, 3) float32 world space, faces (F, 3) int32, normals (V, 3) float32 unit.
    progress: optional callable(n_done_vertices) for progress bars.
    Returns (CutSet of stop − start vertices, rays traced, seconds).
    """
    tree = tree or get_tree()
    t0 = time.perf_counter()
    tracer = tracer or Tracer(vertices, faces)
    eps = ray_offsets(vertices, faces)
    stop = len(vertices) if stop is None else stop
    starts = list(range(start, stop, batch))
    results: list[CutSet | None] = [None] * len(starts)
    rays = [0]
    lock = threading.Lock()

    def work(k: int):
        s = starts[k]
        e = min(s + batch, stop)
        vis, n_rays = vertex_visibility(tracer, tree, vertices[s:e], normals[s:e], eps[s:e])
        results[k] = cutmod.build_cuts(vis, tau, kernels)
        with lock:
            rays[0] += n_rays
            if progress:
                progress(e - s)

    with ThreadPoolExecutor(max_workers=max(1, threads)) as ex:
        list(ex.map(work, range(len(starts))))
    cuts = CutSet.concat(results) if results else CutSet(np.zeros(1, np.int64), np.zeros(0, np.uint8),
                                                          np.zeros(0, np.uint8), tree.height)
    return cuts, rays[0], time.perf_counter() - t0


CUTS_VERSION = 3    # of the stored cuts' key (worker/keys.py): 3 when ray origins moved off by edge length


def geometry_key(vertices, faces, normals, tau: float, height: int) -> str:
    """Content key of everything the cuts depend on (world-space geometry, normals, τ, H, the
    ray offset rule)."""
    return content_key("cuts", CUTS_VERSION, vertices=vertices, faces=faces, normals=normals,
                       tau=float(tau), height=int(height), offset_edge=float(OFFSET_EDGE),
                       offset_max=float(OFFSET_MAX))


def storage_stats(cs: CutSet, blob_bytes: int, index_deflated: int | None = None) -> dict:
    """Sizes of the stored cuts, like against like: the raw height encoding (4-bit
    heights, 8-bit values, 2-byte counts) against the raw index encoding (2-byte node indices,
    8-bit values, 2-byte counts), and each deflated (the blob as stored is the deflated height
    encoding). The headline saving compares the deflated forms. ``index_deflated``: the
    deflated index encoding's size if already computed (``index_encoded_bytes(cs, True)``)."""
    raw_h = cutmod.height_encoded_bytes(cs)
    raw_i = cutmod.index_encoded_bytes(cs)
    defl_i = cutmod.index_encoded_bytes(cs, deflate=True) if index_deflated is None else index_deflated
    return {"vertices": cs.n_vertices, "directions": 1 << cs.height,
            "mean_cut_size": float(cs.sizes().mean()) if cs.n_vertices else 0.0,
            "bytes_height_raw": raw_h, "bytes_index_raw": raw_i,
            "bytes_height_deflated": blob_bytes, "bytes_index_deflated": defl_i,
            "saving_raw": 1.0 - raw_h / max(raw_i, 1), "saving_deflated": 1.0 - blob_bytes / max(defl_i, 1)}


class CutPrecomputation(Precomputation):
    """The cut set of the whole scene (options: ``tau``; ``ground``: False skips, True forces the
    ground-shadow part, which scenes with a ``ground`` field have by default). A scene with
    movable objects has other parts instead (moving.py: static cuts, self cuts, fields; options
    also ``field_grid``), and no ground shadow yet: the ground's cuts would change as objects move.

    kernels : the backend that builds the cuts (worker/native/kernels.py; default: the
        process's, chosen when first needed).
    """

    kind = DECLARATION.kind

    def parts(self, scene, options) -> list[Part]:
        from .moving import movable_names, moving_parts

        if movable_names(scene):
            return moving_parts(scene, options)
        tau = float(options.get("tau", DEFAULT_TAU))
        m = scene.mesh
        key = geometry_key(m.vertices, m.faces, m.normals, tau, get_tree().height)
        parts = [Part(key, "visibility cuts", len(m.vertices), {"tau": tau})]
        g = getattr(scene.spec, "ground", None)
        want = options.get("ground")
        if (g is not None and want is not False) or want is True:
            from .ground import ground_grid, ground_key

            grid = ground_grid(m.vertices, g.height if g is not None else None)
            parts.append(Part(ground_key(m.vertices, m.faces, grid, tau, get_tree().height), "ground shadow cuts",
                              grid.n * grid.n, {"tau": tau, "ground": grid}))
        return parts

    def chunks(self, scene, part, options, n):
        if "kind" in part.meta:
            from .moving import moving_chunks

            return moving_chunks(scene, part, n, BATCH)
        if "ground" in part.meta:
            return [None]
        nv = len(scene.mesh.vertices)
        # ranges on batch boundaries so that every chunking traces the same batches
        step = max(BATCH, -(-nv // max(1, n) // BATCH) * BATCH)
        return [(s, min(s + step, nv)) for s in range(0, nv, step)] or [(0, 0)]

    def compute(self, scene, part, options, chunk=None, progress=None, threads=2):
        if "kind" in part.meta:
            from .moving import compute_moving

            return compute_moving(scene, part, options, chunk, progress, threads, self.kernels)
        m = scene.mesh
        if "ground" in part.meta:
            from .ground import precompute_ground

            cs, rays, secs = precompute_ground(Tracer(m.vertices, m.faces), part.meta["ground"], part.meta["tau"],
                                               threads=threads, progress=progress, kernels=self.kernels)
            return {"cuts": cs, "rays": rays, "seconds": secs}
        s, e = chunk if chunk is not None else (0, len(m.vertices))
        cs, rays, secs = precompute_cuts(m.vertices, m.faces, m.normals, tau=part.meta["tau"], threads=threads,
                                         progress=progress, start=s, stop=e, kernels=self.kernels)
        return {"cuts": cs, "rays": rays, "seconds": secs}

    def assemble(self, scene, part, options, results):
        if "kind" in part.meta:
            from .moving import assemble_moving

            return assemble_moving(part, results)
        cs = CutSet.concat([r["cuts"] for r in results])
        secs = sum(r["seconds"] for r in results)
        if "ground" in part.meta:    # its own names: a job's stats merge the parts' into one dict
            blob = cutmod.encode(cs)
            return blob, {"ground_points": cs.n_vertices - 1, "ground_rays_traced": int(sum(r["rays"] for r in results)),
                          "ground_seconds_tracing": secs}
        # the index encoding's deflate (a stat) beside the blob's: both deflates release the GIL,
        # so on two cores the serial assembly after the chunks takes about half as long
        with ThreadPoolExecutor(max_workers=1) as ex:
            index_deflated = ex.submit(cutmod.index_encoded_bytes, cs, True)
            blob = cutmod.encode(cs)
            index_deflated = index_deflated.result()
        samples = cs.n_vertices * (1 << cs.height)
        stats = {"rays_traced": int(sum(r["rays"] for r in results)), "tau": part.meta["tau"],
                 "seconds_tracing": secs, "samples_per_second": samples / max(secs, 1e-9),
                 **storage_stats(cs, len(blob), index_deflated)}
        return blob, stats

    def describe(self, scene, part, blob):
        if "kind" in part.meta:
            from .moving import describe_moving

            return describe_moving(part, blob)
        if "ground" in part.meta:
            return {"ground_points": part.meta["ground"].n ** 2, "ground_bytes": len(blob)}
        return {"tau": part.meta["tau"], **storage_stats(cutmod.decode(blob), len(blob))}

    def load(self, scene, blobs, options):
        from .moving import load_moving, movable_names

        if movable_names(scene):
            return load_moving(scene, blobs, options)
        part, *rest = self.parts(scene, options)
        cs = cutmod.decode(blobs[part.key])
        if cs.n_vertices != len(scene.mesh.vertices):
            raise ValueError(f"stored cuts are for {cs.n_vertices} vertices, the scene has {len(scene.mesh.vertices)}")
        ground = None
        for p in rest:
            from .ground import GroundData

            grid = p.meta["ground"]
            gc = cutmod.decode(blobs[p.key])
            if gc.n_vertices != grid.n * grid.n + 1:
                raise ValueError(f"stored ground cuts are for {gc.n_vertices - 1} points, the grid has {grid.n ** 2}")
            ground = GroundData(grid, gc)
        return CutData(cs, part.meta["tau"], ground)
