"""Per-vertex self-shadowing for the paint renderer, from the cut renderer's visibility cuts.

This is the one place the paint renderer touches the cut renderer: it traces the scene's cuts
with the cut precomputation's own function (``_cuts_of``); the harmonics are what paint stores,
as a content-keyed part of its precomputation.

A vertex's cut holds its cosine-weighted visibility Ṽ(ω) = V(ω)·max(0, n·ω) over the 2^15
tree directions, clustered. We keep it as 9 spherical-harmonic coefficients (l ≤ 2):
    Ṽ_lm = Σ_nodes value · Ω_node · Y_lm(ω_node)
(Ω_node = 2^h leaf solid angles, ω_node the node's mean direction), and beside it the same
projection of the unoccluded max(0, n·ω), analytically A_l·Y_lm(n) with A_l = π, 2π/3, π/4
(Funk-Hecke for the clamped cosine). A lobe of exponent E about direction D then
sees the lobe-and-cosine-weighted visibility
    V_E(D) = Σ k̂_l(E) Ṽ_lm Y_lm(D) / Σ k̂_l(E) U_lm Y_lm(D)   clamped to [0, 1]
(render.zonal gives k̂_l; for E = 1 about N this is ambient occlusion). Order-2 harmonics keep
broad self-shadowing (under a car, wheel arches, a chair's seat over its legs), not sharp shadows.
"""
from __future__ import annotations

import numpy as np

from ...core.directions import get_tree
from .render import sh9

A_L = np.array([np.pi, 2 * np.pi / 3, np.pi / 4])     # Funk-Hecke: 2π∫max(0,t)P_l(t)dt


def _cuts_of(scene, cache_dir=None, progress=None, threads: int = 2):
    """The scene's visibility cuts: read from the cut renderer's folder store when ``cache_dir``
    is given (and stored there when traced), else traced here."""
    from .. import ensure, get, load

    _, pre = get("cuts")
    if cache_dir is not None:
        from ...artifacts import DirStore

        store = DirStore(cache_dir, "cuts")
        ensure(pre, scene, store, {}, progress, threads)
        return load(pre, scene, store, {}).cuts
    from ..cuts import precompute_cuts

    m = scene.mesh
    cs, _, _ = precompute_cuts(m.vertices, m.faces, m.normals, progress=progress, threads=threads)
    return cs


def cuts_to_sh(cs, normals: np.ndarray) -> np.ndarray:
    """(V, 18) float32: Ṽ_lm (9) and U_lm (9) per vertex from a CutSet and unit normals (V, 3)."""
    tree = get_tree(cs.height)
    h = cs.heights.astype(np.int64)
    span = np.left_shift(1, h)
    start = np.cumsum(span) - span                                   # global leaf position
    base = np.repeat(start[cs.offsets[:-1]], np.diff(cs.offsets))    # first leaf of each vertex
    node = tree.level_offset[h] + ((start - base) >> h)
    val = cs.quant.astype(np.float64) / 255.0 * span * tree.leaf_solid_angle
    contrib = val[:, None] * sh9(tree.node_dir[node].astype(np.float64))
    out = np.zeros((cs.n_vertices, 18))
    nz = np.diff(cs.offsets) > 0
    out[nz, :9] = np.add.reduceat(contrib, cs.offsets[:-1][nz], axis=0)
    out[:, 9:] = A_L[[0, 1, 1, 1, 2, 2, 2, 2, 2]] * sh9(np.asarray(normals, np.float64))
    return out.astype(np.float32)


def vertex_visibility(scene, cache_dir=None, progress=None, threads: int = 2) -> np.ndarray:
    """(V, 18) float32 per-vertex visibility harmonics of a loaded scene (see module doc);
    cache_dir: where the cut renderer caches its cuts (None: its default)."""
    return cuts_to_sh(_cuts_of(scene, cache_dir, progress, threads), scene.mesh.normals)
