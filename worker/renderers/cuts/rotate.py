"""Re-expressing an object's field cuts over the leaves of another frame (a rotated object).

The 2^15-leaf direction tree is the same set of directions in every frame, but a rotation Q
(source → receiver: d_receiver = Q d_source) does not map leaves onto leaves, nor tree nodes onto
tree nodes. Receiver leaf j therefore reads the source leaf nearest to Q^T d_j,

    π_Q(j) = argmin_l ∠(Q^T d_j, d_l)                (a resampling at leaf resolution, ≤ ~0.7°)

and a binary field cut, being exact at leaf level, is rotated by rebuilding its cut over the
receiver's leaves (``rotate_samples``). Only the blocked source leaves are touched, through the
inverse map {j : π(j) = l} (a CSR table), so the cost follows the object's apparent size.

π is read from a cube-map table of nearest leaves (6 × 256² cells of ≤ 0.35°, built once per
process with a k-d tree) and refined among that leaf's 9 nearest neighbours, so a new rotation
costs a few ms instead of a 32K-point k-d query (~25 ms), with the same result.

``rotate_samples_numpy`` is the reference of the C kernel ``glf_rotate`` (fields.c).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.spatial import cKDTree

from ...core.directions import DirectionTree
from .grid import FACE_AXES

TABLE_RES = 256


@lru_cache(maxsize=2)
def _nearest_leaf_table(tree: DirectionTree, res: int = TABLE_RES) -> np.ndarray:
    """(6, res, res) int32 nearest leaf of each equi-angular cube-map cell centre."""
    g = np.tan(np.pi / 4 * ((np.arange(res) + 0.5) / res * 2 - 1))
    a, tu, tv = FACE_AXES[:, 0], FACE_AXES[:, 1], FACE_AXES[:, 2]
    d = a[:, None, None, :] + g[None, :, None, None] * tu[:, None, None, :] + g[None, None, :, None] * tv[:, None, None, :]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    _, idx = cKDTree(tree.leaves.astype(np.float64)).query(d.reshape(-1, 3))
    return idx.reshape(6, res, res).astype(np.int32)


@lru_cache(maxsize=2)
def _leaf_neighbours(tree: DirectionTree, k: int = 10) -> np.ndarray:
    """(N, k) int32: each leaf and its k − 1 nearest leaves."""
    _, idx = cKDTree(tree.leaves.astype(np.float64)).query(tree.leaves.astype(np.float64), k=k)
    return idx.astype(np.int32)


def nearest_leaves(tree: DirectionTree, dirs: np.ndarray, kernels=None) -> np.ndarray:
    """(P,) int32 leaf nearest to each unit direction (P, 3): the cube-map table's leaf for the
    direction's cell, then the nearest among that leaf and its neighbours (exact unless the
    table is off by more than a neighbour, which a 0.35° cell cannot be). kernels: the
    backend (glf_nearest_leaves, or nearest_leaves_numpy); default: the process's."""
    from ...native.kernels import kernels as _kernels

    return (kernels or _kernels()).fields.nearest_leaves(tree, np.ascontiguousarray(dirs, np.float64))


def nearest_leaves_numpy(tree: DirectionTree, dirs: np.ndarray) -> np.ndarray:
    """Reference of glf_nearest_leaves (``nearest_leaves``; dirs (P, 3) float64)."""
    d = np.ascontiguousarray(dirs, np.float64)
    tab = _nearest_leaf_table(tree)
    res = tab.shape[1]
    major = np.argmax(np.abs(d), axis=1)
    face = 2 * major + (d[np.arange(len(d)), major] < 0)
    fa = FACE_AXES[face]
    am = (d * fa[:, 0]).sum(1)
    u = (4 / np.pi) * np.arctan((d * fa[:, 1]).sum(1) / am)
    v = (4 / np.pi) * np.arctan((d * fa[:, 2]).sum(1) / am)
    i = np.clip(((u + 1) * 0.5 * res).astype(np.int64), 0, res - 1)
    j = np.clip(((v + 1) * 0.5 * res).astype(np.int64), 0, res - 1)
    cand = _leaf_neighbours(tree)[tab[face, i, j]]                          # (P, k)
    dots = np.einsum("pkc,pc->pk", tree.leaves[cand].astype(np.float64), d)
    return cand[np.arange(len(d)), np.argmax(dots, axis=1)]


def rotation_part(m: np.ndarray) -> tuple[np.ndarray, float]:
    """(Q (3, 3) float64 rotation, s uniform scale) of a 4×4 similarity transform; ValueError
    when it shears, scales unevenly or mirrors (a field cannot follow those)."""
    a = np.asarray(m, np.float64)[:3, :3]
    s = float(np.cbrt(np.linalg.det(a)))
    if not s > 0:
        raise ValueError("transform mirrors or collapses the object")
    q = a / s
    if np.abs(q @ q.T - np.eye(3)).max() > 1e-5:
        raise ValueError("transform is not a rotation, uniform scale and translation")
    return q, s


def is_identity(q: np.ndarray, tol: float = 1e-9) -> bool:
    return bool(np.abs(np.asarray(q) - np.eye(3)).max() <= tol)


class LeafMap:
    """π_Q and its inverse for one rotation Q (source → receiver).

    perm : (N,) int32 source leaf read by each receiver leaf.
    inv_off : (N+1,) int32, inv_idx : (N,) int32 — receiver leaves j with π(j) = l are
        inv_idx[inv_off[l]:inv_off[l+1]].
    identity : Q is the identity (perm is arange).
    kernels : the backend that finds the nearest leaves (default: the process's).
    """

    def __init__(self, tree: DirectionTree, q: np.ndarray, kernels=None):
        self.q = np.asarray(q, np.float64)
        self.identity = is_identity(self.q)
        n = tree.n_leaves
        if self.identity:
            self.perm = np.arange(n, dtype=np.int32)
        else:
            # receiver leaf j in the source frame: Q^T d_j (rows: d_j^T Q)
            self.perm = nearest_leaves(tree, tree.leaves.astype(np.float64) @ self.q, kernels)
        order = np.argsort(self.perm, kind="stable")
        self.inv_idx = order.astype(np.int32)
        self.inv_off = np.zeros(n + 1, np.int32)
        np.cumsum(np.bincount(self.perm, minlength=n), out=self.inv_off[1:])


def coarse_cut_numpy(free: np.ndarray, hmin: int) -> tuple[np.ndarray, np.ndarray]:
    """Cut of one leaf array (N,) bool (True = free): nodes uniform over their leaves, or of
    height hmin with their free fraction (quant = round(255 · fraction)). Left to right."""
    n = len(free)
    H = int(np.log2(n))
    zeros = [(~free).astype(np.int64)]
    for _ in range(H):
        zeros.append(zeros[-1].reshape(-1, 2).sum(1))
    keep = []
    for h in range(H + 1):
        z = zeros[h]
        keep.append((z == 0) | (z == (1 << h)) | (h <= hmin))
    hs, starts, qs = [], [], []
    for h in range(H + 1):
        sel = keep[h].copy()
        if h < H:
            sel &= ~np.repeat(keep[h + 1], 2)
        j = np.nonzero(sel)[0]
        hs.append(np.full(len(j), h)); starts.append(j << h)
        qs.append(np.rint(255.0 * ((1 << h) - zeros[h][j]) / (1 << h)))
    st = np.concatenate(starts)
    o = np.argsort(st)
    return np.concatenate(hs)[o].astype(np.uint8), np.concatenate(qs)[o].astype(np.uint8)


def rotate_samples_numpy(field, ids: np.ndarray, lmap: LeafMap, hmin: int) -> list[tuple[np.ndarray, ...]]:
    """Reference of glf_rotate: each sample's binary cut over the receiver's leaves (receiver
    leaf j is free iff source leaf π(j) is), rebuilt by ``coarse_cut_numpy``; only the nodes
    that are not wholly free are returned, as (starts int32, heights uint8, quant uint8)."""
    from ...core.cuts import decode_to_leaves, node_starts

    out = []
    for i in ids:
        h, q = field.sample_cut(int(i))
        src_free = decode_to_leaves(h, q) > 0.5
        h, q = coarse_cut_numpy(src_free[lmap.perm], hmin)
        st = node_starts(h)
        k = q < 255
        out.append((st[k].astype(np.int32), h[k], q[k]))
    return out
