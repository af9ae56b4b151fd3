"""Precomputation of self-visibility cuts for every vertex of a scene.

cyber-worlds §V.A.1 and inverse-brdf-modeling §4.1: per vertex, rays towards the 2^15 tree
directions are traced against the whole static scene; the cosine-weighted visibility
Ṽ(x, ω) = V(x, ω)·max(0, n·ω) fills the leaves, which are clustered into a cut.
Only directions above the vertex's horizon are traced (the others are zero by the cosine).
"""
from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .core.cuts import CutSet, build_cuts
from .core.directions import DirectionTree, get_tree
from .trace.embree import Tracer

DEFAULT_TAU = 1.0   # cut error threshold, leaf units (see cuts.build_cuts_numpy)


@dataclass
class PrecomputeStats:
    seconds: float
    vertices: int
    directions: int
    rays: int
    mean_cut_size: float


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
    o = points[bi] + eps * normals[bi] + eps * d
    vis = ~tracer.occluded(o, d)
    out[bi[vis], li[vis]] = cos[bi[vis], li[vis]]
    return out, len(bi)


def precompute_cuts(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray,
                    tau: float = DEFAULT_TAU, tree: DirectionTree | None = None,
                    threads: int = 2, batch: int = 16, progress=None) -> tuple[CutSet, PrecomputeStats]:
    """Cuts for all vertices of the (static, whole-scene) mesh.

    vertices (V, 3) float32 world space, faces (F, 3) int32, normals (V, 3) float32 unit.
    progress: optional callable(n_done_vertices) for progress bars.
    """
    tree = tree or get_tree()
    t0 = time.perf_counter()
    tracer = Tracer(vertices, faces)
    diag = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    eps = 1e-4 * max(diag, 1e-6)
    nv = len(vertices)
    starts = list(range(0, nv, batch))
    results: list[CutSet | None] = [None] * len(starts)
    rays = [0]
    lock = threading.Lock()

    def work(k: int):
        s = starts[k]
        e = min(s + batch, nv)
        vis, n_rays = vertex_visibility(tracer, tree, vertices[s:e], normals[s:e], eps)
        results[k] = build_cuts(vis, tau)
        with lock:
            rays[0] += n_rays
            if progress:
                progress(e - s)

    with ThreadPoolExecutor(max_workers=max(1, threads)) as ex:
        list(ex.map(work, range(len(starts))))
    cuts = CutSet.concat(results) if results else CutSet(np.zeros(1, np.int64), np.zeros(0, np.uint8), np.zeros(0, np.uint8))
    stats = PrecomputeStats(time.perf_counter() - t0, nv, tree.n_leaves, rays[0], float(cuts.sizes().mean()) if nv else 0.0)
    return cuts, stats
