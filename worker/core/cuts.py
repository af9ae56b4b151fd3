"""Visibility cuts: build, encode (height-based), decode, and combine (product, interpolation).

cyber-worlds-lighting-material-design §V.A.2-3, inverse-brdf-modeling §4.1 (eq. 20).

A cut is the left-to-right sequence of the tree nodes that partition the leaves; because every
root-to-leaf path meets exactly one cut node, a node's position follows from the heights of the
nodes before it, so a height (0-15, 4 bits) is all a node needs besides its value.

In memory a CutSet keeps, for V vertices, ``offsets`` (V+1,) int64 into ``heights`` (M,) uint8
and ``quant`` (M,) uint8, the node's mean cosine-weighted visibility quantised as q/255.
"""
from __future__ import annotations

import io
import zlib
from dataclasses import dataclass

import numpy as np

QMAX = 255.0
DEFAULT_TAU = 1.0   # cut error threshold in leaf units (build_cuts_numpy): the precomputed level


@dataclass
class CutSet:
    offsets: np.ndarray   # (V+1,) int64
    heights: np.ndarray   # (M,) uint8
    quant: np.ndarray     # (M,) uint8, value = quant / 255
    height: int = 15      # tree height H (2^H leaves)

    @property
    def n_vertices(self) -> int:
        return len(self.offsets) - 1

    @property
    def n_nodes(self) -> int:
        return int(self.offsets[-1])

    def sizes(self) -> np.ndarray:
        return np.diff(self.offsets)

    def cut(self, v: int) -> tuple[np.ndarray, np.ndarray]:
        """(heights, values float32) of vertex v."""
        a, b = self.offsets[v], self.offsets[v + 1]
        return self.heights[a:b], self.quant[a:b].astype(np.float32) / QMAX

    @staticmethod
    def concat(parts: list["CutSet"]) -> "CutSet":
        sizes = np.concatenate([p.sizes() for p in parts])
        offsets = np.zeros(len(sizes) + 1, np.int64)
        np.cumsum(sizes, out=offsets[1:])
        return CutSet(offsets, np.concatenate([p.heights for p in parts]),
                      np.concatenate([p.quant for p in parts]), parts[0].height)


def build_cuts_numpy(values: np.ndarray, tau: float) -> CutSet:
    """NumPy reference of glk_build_cuts.

    values : (B, N) float32 leaf values in [0, 1] (cosine-weighted visibility), N = 2^H.
    tau : error threshold in leaf units: a node is kept when sqrt(n·Σ(v−mean)²) ≤ tau, which
          bounds its L1 error Σ|v − mean| by tau (Cauchy-Schwarz). Error shrinks towards the
          leaves, so the cut is every kept node whose parent is not kept.
    """
    b, n = values.shape
    hmax = int(np.log2(n))
    s = values.astype(np.float64)
    q = s * s
    kept, means = [], []
    for h in range(hmax + 1):
        if h:
            s = s.reshape(b, -1, 2).sum(axis=2)
            q = q.reshape(b, -1, 2).sum(axis=2)
        cnt = float(1 << h)
        sse = q - s * s / cnt
        err = np.sqrt(np.maximum(cnt * sse, 0.0))
        kept.append((err <= tau) | (h == 0))
        means.append(s / cnt)
    sel_b, sel_start, sel_h, sel_m = [], [], [], []
    for h in range(hmax + 1):
        sel = kept[h].copy()
        if h < hmax:
            sel &= ~np.repeat(kept[h + 1], 2, axis=1)
        bi, j = np.nonzero(sel)
        sel_b.append(bi); sel_start.append(j << h); sel_h.append(np.full(len(j), h)); sel_m.append(means[h][bi, j])
    bi = np.concatenate(sel_b); st = np.concatenate(sel_start)
    order = np.lexsort((st, bi))
    bi = bi[order]
    hs = np.concatenate(sel_h)[order].astype(np.uint8)
    ms = np.concatenate(sel_m)[order]
    counts = np.bincount(bi, minlength=b)
    offsets = np.zeros(b + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    quant = np.rint(np.clip(ms, 0.0, 1.0) * QMAX).astype(np.uint8)
    return CutSet(offsets, hs, quant, hmax)


def build_cuts(values: np.ndarray, tau: float, kernels=None) -> CutSet:
    """Cuts for a batch of vertices (see build_cuts_numpy); kernels: the backend."""
    from ..native.kernels import kernels as _kernels

    return (kernels or _kernels()).build_cuts(values, tau)


def decode_to_leaves(heights: np.ndarray, values: np.ndarray, height: int = 15) -> np.ndarray:
    """Expand one cut to its (2^H,) piecewise-constant leaf values."""
    return np.repeat(np.asarray(values, np.float32), 1 << np.asarray(heights, np.int64))


def coarsen(cs: CutSet, tau: float, kernels=None) -> CutSet:
    """A coarser cut set for interaction (level of detail while the user drags); see
    coarsen_numpy. kernels: the backend."""
    from ..native.kernels import kernels as _kernels

    return (kernels or _kernels()).coarsen(cs, tau)


def coarsen_numpy(cs: CutSet, tau: float) -> CutSet:
    """A coarser cut set for interaction (NumPy reference of glk_coarsen).

    Adjacent sibling nodes of a vertex's cut are merged into their parent, repeatedly, while the
    parent's error from its children's means, sqrt(n · Σ_i n_i (m_i − m)²) in leaf units, stays
    within τ. That is the build criterion of ``build_cuts`` with the children's own spread left
    out (it is not stored), so the merged cut is what a coarser τ would give, approximately.
    Vectorised over all vertices: one pass per tree level. The result covers every leaf once,
    like its input; values are the children's mean (exact up to quantisation).
    The C kernel ``glk_coarsen`` does the same with a per-vertex stack (same merges).
    """
    V = cs.n_vertices
    vert = np.repeat(np.arange(V), cs.sizes())
    h = cs.heights.astype(np.int64)
    m = cs.quant.astype(np.float64) / QMAX
    w = np.int64(1) << h
    csum = np.cumsum(w)
    first = np.repeat(cs.offsets[:-1], cs.sizes())
    start = csum - w - (csum[first] - w[first])            # first leaf of each node, per vertex
    between = np.zeros(len(h))                             # Σ n_i (m_i − m)² of merged nodes
    for _ in range(cs.height):
        if len(h) < 2:
            break
        # a left child starts on a 2^(h+1) boundary and its right sibling follows it
        sib = (vert[:-1] == vert[1:]) & (h[:-1] == h[1:]) & ((start[:-1] >> h[:-1]) % 2 == 0) \
            & (start[1:] == start[:-1] + (np.int64(1) << h[:-1]))
        i = np.nonzero(sib)[0]
        n = (np.int64(1) << h[i]).astype(np.float64)
        mm = 0.5 * (m[i] + m[i + 1])
        bb = between[i] + between[i + 1] + n * ((m[i] - mm) ** 2 + (m[i + 1] - mm) ** 2)
        ok = np.sqrt(2.0 * n * bb) <= tau
        i, mm, bb = i[ok], mm[ok], bb[ok]
        if len(i) == 0:
            break
        keep = np.ones(len(h), bool)
        keep[i + 1] = False
        h[i] += 1
        m[i] = mm
        between[i] = bb
        h, m, between, vert, start = h[keep], m[keep], between[keep], vert[keep], start[keep]
    off = np.zeros(V + 1, np.int64)
    off[1:] = np.cumsum(np.bincount(vert, minlength=V))
    return CutSet(off, h.astype(np.uint8), np.clip(np.rint(m * QMAX), 0, 255).astype(np.uint8), cs.height)


def node_starts(heights: np.ndarray) -> np.ndarray:
    """First leaf of every node of one cut (the running sum of 2^h)."""
    w = 1 << np.asarray(heights, np.int64)
    return np.concatenate([[0], np.cumsum(w)[:-1]])


def combine(cuts: list[tuple[np.ndarray, np.ndarray]], op) -> tuple[np.ndarray, np.ndarray]:
    """Combine m cuts node by node (cyber-worlds §V.A.3, Steps 1-4): walk all cuts left to
    right with a pointer and a counter each; at every step the result node has the smallest
    height among the operand nodes, whose values are passed to ``op`` (a function of a list
    of m floats). Counter c_j counts leaves of node j already covered.

    cuts : list of (heights (K_j,) uint8, values (K_j,) float). Returns (heights, values).
    Product of visibility (eq. 4): op = math.prod; interpolation with weights w: op =
    lambda vals: sum(w_j v_j).
    """
    m = len(cuts)
    ptr = [0] * m
    cnt = [0] * m
    out_h, out_v = [], []
    n_leaves = int(sum(1 << int(h) for h in cuts[0][0]))
    done = 0
    while done < n_leaves:
        hs = [int(cuts[j][0][ptr[j]]) for j in range(m)]
        hmin = min(hs)
        out_h.append(hmin)
        out_v.append(op([float(cuts[j][1][ptr[j]]) for j in range(m)]))
        for j in range(m):
            if hs[j] == hmin:
                ptr[j] += 1; cnt[j] = 0
            else:
                cnt[j] += 1 << hmin
                if cnt[j] >= 1 << hs[j]:
                    ptr[j] += 1; cnt[j] = 0
        done += 1 << hmin
    return np.array(out_h, np.uint8), np.array(out_v, np.float32)


# ---- storage --------------------------------------------------------------------------------

MAGIC = b"GLINTCUT1\n"


def encode(cs: CutSet) -> bytes:
    """Height-based encoding: per vertex a uint16 node count, then 4-bit heights packed two
    per byte and 8-bit quantised values, all deflated (zlib). Self-describing, little-endian."""
    counts = cs.sizes().astype(np.uint16)
    h = cs.heights.astype(np.uint8)
    if len(h) % 2:
        h = np.concatenate([h, [0]]).astype(np.uint8)
    packed = (h[0::2] | (h[1::2] << 4)).astype(np.uint8)
    raw = io.BytesIO()
    np.save(raw, np.array([cs.n_vertices, cs.n_nodes, cs.height], np.int64))
    # neighbouring nodes have similar values: store differences (mod 256), which deflate well
    delta = np.diff(cs.quant, prepend=np.uint8(0)).astype(np.uint8)
    raw.write(counts.tobytes()); raw.write(packed.tobytes()); raw.write(delta.tobytes())
    return MAGIC + zlib.compress(raw.getvalue(), 9)


def decode(blob: bytes) -> CutSet:
    if not blob.startswith(MAGIC):
        raise ValueError("not a Glint cut blob")
    raw = io.BytesIO(zlib.decompress(blob[len(MAGIC):]))
    nv, nn, hmax = (int(x) for x in np.load(raw))
    counts = np.frombuffer(raw.read(2 * nv), np.uint16)
    packed = np.frombuffer(raw.read((nn + 1) // 2), np.uint8)
    quant = np.cumsum(np.frombuffer(raw.read(nn), np.uint8), dtype=np.uint8)
    heights = np.empty(2 * len(packed), np.uint8)
    heights[0::2] = packed & 15
    heights[1::2] = packed >> 4
    offsets = np.zeros(nv + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    return CutSet(offsets, heights[:nn].copy(), quant, hmax)


def height_encoded_bytes(cs: CutSet) -> int:
    """Size of the height encoding before deflation: a uint16 count per vertex, 4-bit heights
    packed two per byte, 8-bit values (the like-for-like partner of index_encoded_bytes)."""
    return len(MAGIC) + 2 * cs.n_vertices + (cs.n_nodes + 1) // 2 + cs.n_nodes


def index_encoded_bytes(cs: CutSet, deflate: bool = False) -> int:
    """Size of the index-based encoding of the same cuts (the papers' previous method [5, 6]):
    per node a 2-byte node index and the same 8-bit value, plus a uint16 count per vertex.
    deflate=True also deflates it (with the same value deltas) for a like-for-like view."""
    idx = np.empty(cs.n_nodes, np.uint16)
    starts = np.concatenate([node_starts(cs.heights[a:b]) for a, b in zip(cs.offsets[:-1], cs.offsets[1:])]) \
        if cs.n_vertices else np.zeros(0, np.int64)
    # heap-style node index within a 2^16-node tree: level offset + position in level
    lev = np.concatenate([[0], np.cumsum([(1 << cs.height) >> h for h in range(cs.height + 1)])])
    idx[:] = (lev[cs.heights] + (starts >> cs.heights.astype(np.int64))).astype(np.uint16)
    if not deflate:
        return len(MAGIC) + 2 * cs.n_vertices + 3 * cs.n_nodes
    delta = np.diff(cs.quant, prepend=np.uint8(0)).astype(np.uint8)
    raw = cs.sizes().astype(np.uint16).tobytes() + idx.tobytes() + delta.tobytes()
    return len(MAGIC) + len(zlib.compress(raw, 9))
