"""The 2^15 sample directions ordered as the leaves of a perfect binary tree.

cyber-worlds-lighting-material-design §V.A.1-2: near-uniform directions from point repulsion,
clustered by a binary tree whose every node is a contiguous leaf range, so a cut is the sequence
of its node heights and any cluster integral of a leaf quantity is a prefix-sum difference.

Construction (deterministic, no I/O): spherical Fibonacci points relaxed by a few steps of
nearest-neighbour repulsion, then ordered by recursive median splits along the widest axis of
each subset, which makes every subtree spatially coherent.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.spatial import cKDTree

HEIGHT = 15
N_LEAVES = 1 << HEIGHT


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) float64 unit vectors on a spherical Fibonacci lattice."""
    i = np.arange(n, dtype=np.float64) + 0.5
    y = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - y * y))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=1)


def relax(points: np.ndarray, iterations: int = 12, k: int = 8) -> np.ndarray:
    """Point repulsion restricted to k nearest neighbours (the far field cancels on a
    near-uniform set), projected back onto the sphere each step.

    points : (n, 3) float64 unit vectors. Returns a new (n, 3) array.
    """
    p = points.copy()
    n = len(p)
    spacing = np.sqrt(4.0 * np.pi / n)
    for _ in range(iterations):
        _, idx = cKDTree(p).query(p, k=k + 1)
        d = p[:, None, :] - p[idx[:, 1:]]                      # (n, k, 3)
        r2 = np.einsum("nki,nki->nk", d, d) + 1e-12
        force = (d / (r2[..., None] ** 1.5)).sum(axis=1)       # Coulomb 1/r^2
        force -= np.einsum("ni,ni->n", force, p)[:, None] * p  # tangential part
        step = 0.05 * spacing / (np.linalg.norm(force, axis=1, keepdims=True) + 1e-12)
        p += force * np.minimum(step, 0.05 * spacing ** 3)
        p /= np.linalg.norm(p, axis=1, keepdims=True)
    return p


def tree_order(points: np.ndarray) -> np.ndarray:
    """Permutation that orders (2^h, 3) points as leaves of a perfect binary tree built by
    recursive median splits along each subset's widest axis."""
    n = len(points)
    assert n & (n - 1) == 0, "need a power of two"
    order = np.arange(n)
    size = n
    while size > 1:
        groups = order.reshape(n // size, size)
        pts = points[groups]                                  # (g, size, 3)
        axis = np.argmax(pts.max(axis=1) - pts.min(axis=1), axis=1)
        keys = np.take_along_axis(pts, axis[:, None, None].repeat(size, 1), axis=2)[..., 0]
        srt = np.argsort(keys, axis=1, kind="stable")
        order = np.take_along_axis(groups, srt, axis=1).reshape(n)
        size //= 2
    return order


@dataclass(frozen=True, eq=False)  # hashed by identity (lru_cache keys)
class DirectionTree:
    """Leaf directions and per-node geometry of the perfect binary tree.

    Node (h, j) covers leaves [j*2^h, (j+1)*2^h). Flat node index: ``level_offset[h] + j``.

    Attributes
    ----------
    leaves : (N, 3) float32 unit vectors, tree order.
    node_dir : (2N-1, 3) float32 normalised mean direction of each node's leaves.
    node_radius : (2N-1,) float32 largest angle (radians) between node_dir and a leaf of the node.
    level_offset : (H+2,) int64 start of each level in the flat node arrays (level 0 = leaves).
    leaf_solid_angle : float, sr; leaves are treated as equal-area cells (4π/N).
    """

    leaves: np.ndarray
    node_dir: np.ndarray
    node_radius: np.ndarray
    level_offset: np.ndarray
    height: int

    @property
    def n_leaves(self) -> int:
        return len(self.leaves)

    @property
    def leaf_solid_angle(self) -> float:
        return 4.0 * np.pi / self.n_leaves

    def node_index(self, h: np.ndarray, start: np.ndarray) -> np.ndarray:
        """Flat node index of the node of height h whose first leaf is `start`."""
        return self.level_offset[h] + (start >> h)


def build_tree(height: int = HEIGHT) -> DirectionTree:
    n = 1 << height
    pts = relax(fibonacci_sphere(n)) if n >= 64 else fibonacci_sphere(n)
    leaves = pts[tree_order(pts)]
    dirs, radii, offs = [], [], [0]
    for h in range(height + 1):
        grp = leaves.reshape(n >> h, 1 << h, 3)
        m = grp.sum(axis=1)
        m /= np.linalg.norm(m, axis=1, keepdims=True) + 1e-30
        cosmin = np.einsum("gki,gi->gk", grp, m).min(axis=1)
        dirs.append(m)
        radii.append(np.arccos(np.clip(cosmin, -1.0, 1.0)))
        offs.append(offs[-1] + (n >> h))
    return DirectionTree(
        leaves=leaves.astype(np.float32),
        node_dir=np.concatenate(dirs).astype(np.float32),
        node_radius=np.concatenate(radii).astype(np.float32),
        level_offset=np.array(offs, dtype=np.int64),
        height=height,
    )


_adopted: dict[int, DirectionTree] = {}


@lru_cache(maxsize=4)
def _built_tree(height: int) -> DirectionTree:
    return build_tree(height)


def get_tree(height: int = HEIGHT) -> DirectionTree:
    """The process-wide direction tree (about 1 s to build for height 15)."""
    t = _adopted.get(height)
    return t if t is not None else _built_tree(height)


def adopt_tree(tree: DirectionTree) -> None:
    """Use ``tree``, a ``build_tree`` result made by another process, as this process's
    ``get_tree(tree.height)``: a Ray chunk task gets its coordinator's tree through the object
    store instead of spending a second building it again (ray_actors.py)."""
    _adopted[tree.height] = tree
