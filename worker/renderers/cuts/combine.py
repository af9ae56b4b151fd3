"""Cuts of vertices under moved objects: the vertex's own cut times the occluders' fields.

cyber-worlds eq. 4 and §V.A.3-4: V(x, ω) = V_s(x, ω) Π_i V_i(x, ω). For each vertex and each
occluder i not culled (§V.B: its bounding sphere below the vertex's horizon, or the vertex
outside the outermost shell), the eight field samples at the corners of the cell holding the
vertex (in i's local frame) are blended trilinearly and multiplied into the vertex's cut.

Three stages, each a kernel of the backend's ``fields`` family (worker/native/fields.py: C in
fields.c, NumPy references here or in grid.py/rotate.py):
  1. ``lookup`` (glf_lookup): the cell and the 8 corner weights of every vertex, or culled.
  2. ``RotatedSamples.ensure`` (glf_rotate): corner samples re-expressed over the receiver
     frame's leaves, kept as their non-free nodes; ``ensure_cells`` (glf_cells): the 8 corners
     of a cell merged once into stretches with 8 values each, shared by the vertices in it.
     Both are cached per (field, rotation, h_min): while an object is only translated, a
     sample or cell is computed once and reused by later frames.
  3. ``k.fields.combine`` (glf_combine; reference combine_numpy): each vertex's cut copied node by node, scaled by
     F = Π_i Σ_c w_ic v_ic / Σ_c w_ic where a cell stretch covers it, split at stretch bounds.
"""
from __future__ import annotations

import time
from collections import OrderedDict
from itertools import pairwise

import numpy as np

from ...core.cuts import CutSet, node_starts
from ...core.directions import DirectionTree, get_tree
from ...native import c as _c
from .field import Field
from .grid import cell_corners
from .grid import lookup_numpy as grid_lookup_numpy
from .rotate import LeafMap, rotate_samples_numpy, rotation_part

# field cuts are kept to nodes of ≥ 2^5 = 32 leaves (fields.py). Chosen on the sliding chair of
# bench/move.json: frames 0.07-0.10% (relative RMS) from exact field cuts (h_min 3: 0.05-0.08%),
# 0.366% from the static renderer of the same placement (h_min 0: 0.357%), a sliding frame a
# fifth faster (glf_combine's stretch bounds are the field cuts' node bounds). Held out (the
# sofa of bench/move-sofa.json): 0.28-0.30% from exact (h_min 3: 0.11%), 1.876% from the static
# renderer (h_min 0: 1.859%): the fields' own interpolation dominates.
DEFAULT_HMIN = 5


# --- stencils ----------------------------------------------------------------------------------

def lookup(field: Field, local_from_receiver: np.ndarray, positions: np.ndarray, normals: np.ndarray,
           kernels=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Trilinear stencils of receiver points in a field, with culling (§V.B).

    local_from_receiver : (4, 4) similarity from the receiver's frame to the field's.
    positions, normals : (P, 3) float32 in the receiver's frame (normals unit).
    Returns (cells (P,) int32, −1 when culled; weights (P, 8) float32 of the cell's corners
    (grid.cell_corners order), 0 when culled; test (P,) uint8, bit c set when corner c has
    weight > 0 and lies beyond 0.9 × its clearance, so that the segment to it may cross the
    object (``validate`` traces those)). A point is culled when it lies outside the outermost
    shell or the bounding sphere is wholly below its horizon: n · (c − x) < −r.
    kernels : the backend (worker/native/kernels.py; default: the process's).
    """
    from ...native.kernels import kernels as _kernels

    m = np.ascontiguousarray(np.asarray(local_from_receiver, np.float64)[:3, :4])
    pos = _c(positions, np.float32)
    nrm = _c(normals, np.float32)
    clr = None if field.clearance is None else _c(field.clearance, np.float32)
    return (kernels or _kernels()).fields.lookup(field, m, pos, nrm, clr)


def lookup_numpy(field: Field, m: np.ndarray, pos: np.ndarray, nrm: np.ndarray, clr: np.ndarray | None):
    """Reference of glf_lookup (``lookup`` with m (3, 4) float64 rows of local_from_receiver,
    pos / nrm (P, 3) float32, clr the field's clearances (S,) float32 or None)."""
    grid = field.grid
    xl = pos.astype(np.float64) @ m[:, :3].T + m[:, 3]
    nl = nrm.astype(np.float64) @ m[:, :3].T
    nl /= np.maximum(np.linalg.norm(nl, axis=1, keepdims=True), 1e-300)
    cells, w, inside = grid_lookup_numpy(grid, xl)
    culled = ~inside | ((nl * (grid.center - xl)).sum(1) < -grid.radius)
    cells[culled] = -1
    w[culled] = 0.0
    test = np.zeros(len(pos), np.uint8)
    if clr is not None:
        act = np.nonzero(cells >= 0)[0]
        corners = cell_corners(grid, cells[act])
        d2 = ((grid.positions(corners.reshape(-1)).reshape(-1, 8, 3) - xl[act, None, :]) ** 2).sum(-1)
        far = (d2 >= (0.9 * clr[corners].astype(np.float64)) ** 2) & (w[act] > 0)
        test[act] = (far * (1 << np.arange(8))).sum(1).astype(np.uint8)
    return cells, w, test


def validate(field: Field, local_from_receiver: np.ndarray, positions: np.ndarray, cells: np.ndarray,
             weights: np.ndarray, test: np.ndarray) -> tuple[np.ndarray, int]:
    """Drop the corners a receiver cannot see: where ``test`` flags a corner, trace the segment
    from the receiver to the sample through the object (its local mesh, ``Field.attach``); a
    blocked corner gets weight 0 (the kernels renormalise by the weight sum). A sample inside
    the object or across a thin part (a table top, a floor) describes another side of it.
    When no corner is left, the weights stay as they were. Returns (weights, segments traced)."""
    rows = np.nonzero(test)[0]
    if len(rows) == 0 or field.tracer is None:
        return weights, 0
    bits = ((test[rows, None] >> np.arange(8)) & 1).astype(bool)
    r, c = np.nonzero(bits)
    v = rows[r]
    corner = cell_corners(field.grid, cells[v])[np.arange(len(v)), c]
    m = np.asarray(local_from_receiver, np.float64)
    xl = positions[v].astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    d = field.grid.positions(corner) - xl
    dist = np.linalg.norm(d, axis=1)
    ok = dist > 0
    d[ok] /= dist[ok, None]
    eps = 1e-4 * field.grid.radius                 # off a surface the receiver may rest on
    blocked = np.zeros(len(v), bool)
    far = ok & (dist > 2 * eps)
    if far.any():
        o = (xl[far] + eps * d[far]).astype(np.float32)
        # Tracer.occluded has no ray length: Embree's run takes one (tfar) as dists
        r = field.tracer.scene.run(o, np.ascontiguousarray(d[far], np.float32),
                                   dists=np.ascontiguousarray(dist[far] - 2 * eps, np.float32), query="OCCLUDED")
        blocked[far] = np.asarray(r) == 0
    w = weights.copy()
    w[v[blocked], c[blocked]] = 0.0
    empty = (w[rows] == 0).all(1)
    w[rows[empty]] = weights[rows[empty]]
    return w, len(v)


# --- rotated samples and cells -----------------------------------------------------------------

class _Pool:
    """Variable-length items in growable arrays: item slot k holds rows off[k] : off[k] + cnt[k]
    of every array in ``arrays`` (name -> (dtype, trailing shape))."""

    def __init__(self, n_keys: int, arrays: dict):
        self.slot = np.full(n_keys, -1, np.int32)
        self.off = np.zeros(1024, np.int64)
        self.cnt = np.zeros(1024, np.int32)
        self.names = list(arrays)
        for name, (dt, shape) in arrays.items():
            setattr(self, name, np.empty((1 << 16, *shape), dt))
        self.n = 0
        self.used = 0

    @property
    def nbytes(self) -> int:
        return sum(getattr(self, k).nbytes for k in self.names) + self.off.nbytes + self.cnt.nbytes + self.slot.nbytes

    def reserve(self, keys: np.ndarray, counts: np.ndarray) -> np.ndarray:
        """Slots and room for the keys' items of the given lengths; returns their row offsets."""
        k = len(keys)
        if self.n + k > len(self.off):
            size = max(2 * len(self.off), self.n + k)
            self.off = np.resize(self.off, size)
            self.cnt = np.resize(self.cnt, size)
        total = int(counts.sum())
        first = getattr(self, self.names[0])
        if self.used + total > len(first):
            size = max(2 * len(first), self.used + total)
            for name in self.names:
                old = getattr(self, name)
                new = np.empty((size, *old.shape[1:]), old.dtype)
                new[:self.used] = old[:self.used]
                setattr(self, name, new)
        dst = self.used + np.concatenate([[0], np.cumsum(counts[:-1], dtype=np.int64)]).astype(np.int64)
        self.off[self.n:self.n + k] = dst
        self.cnt[self.n:self.n + k] = counts
        self.slot[keys] = np.arange(self.n, self.n + k, dtype=np.int32)
        self.n += k
        self.used += total
        return dst

    def rows(self, slot: int):
        a, n = int(self.off[slot]), int(self.cnt[slot])
        return tuple(getattr(self, k)[a:a + n] for k in self.names)


def _placed(run, n: int, cap: int, arrays: dict):
    """Call a kernel that places n variable-length items at atomically taken offsets (fields.c
    bump): allocates ``arrays`` (name -> (dtype, trailing shape)) with room for cap rows, and
    retries with the room it needed when that was too small. Returns (buffers, pos, counts)."""
    while True:
        bufs = {k: np.empty((cap, *shape), dt) for k, (dt, shape) in arrays.items()}
        pos, counts, used = np.empty(n, np.int64), np.empty(n, np.int32), np.zeros(1, np.int64)
        run(cap, bufs, pos, counts, used)
        if used[0] <= cap:
            return bufs, pos, counts
        cap = int(used[0])


def rotate_samples_into_numpy(rs: "RotatedSamples", need: np.ndarray) -> None:
    """Reference of glf_rotate: samples need (n,) int32 of rs's field rotated (rotate_samples_numpy)
    and kept in rs.samples."""
    sp = rs.samples
    cuts = rotate_samples_numpy(rs.field, need, rs.lmap, rs.hmin)
    counts = np.array([len(h) for _, h, _ in cuts], np.int32)
    dst = sp.reserve(need, counts)
    for (st, h, q), d in zip(cuts, dst):
        sp.s[d:d + len(h)], sp.h[d:d + len(h)], sp.q[d:d + len(h)] = st, h, q


def merge_cells_into_numpy(rs: "RotatedSamples", need: np.ndarray, cslots: np.ndarray) -> None:
    """Reference of glf_cells: cells need (n,) int32 merged from their corners' kept samples
    (pool slots cslots (n, 8) int32, cells_numpy) and kept in rs.cells."""
    sp, cp = rs.samples, rs.cells
    items = [cells_numpy([sp.rows(s) for s in row]) for row in cslots]
    counts = np.array([len(a) for a, _, _ in items], np.int32)
    dst = cp.reserve(need, counts)
    for (a, b, v), d in zip(items, dst):
        cp.a[d:d + len(a)], cp.b[d:d + len(a)], cp.v[d:d + len(a)] = a, b, v


class RotatedSamples:
    """One field seen from a receiver frame: its samples re-expressed over the frame's leaves
    (only their non-free nodes: first leaf s, height h, free fraction q·255), and its cells
    (stretches [a, b) where any of the 8 corners is inside a non-free node, with the 8 corner
    values v). Both are computed on demand and kept."""

    def __init__(self, field: Field, lmap: LeafMap, hmin: int, kernels=None):
        from ...native.kernels import kernels as _kernels

        self.field, self.lmap, self.hmin = field, lmap, int(hmin)
        self.k = kernels or _kernels()
        self.samples = _Pool(field.n_samples, {"s": (np.int32, ()), "h": (np.uint8, ()), "q": (np.uint8, ())})
        self.cells = _Pool(field.grid.n_cells, {"a": (np.int32, ()), "b": (np.int32, ()), "v": (np.uint8, (8,))})

    @property
    def nbytes(self) -> int:
        return self.samples.nbytes + self.cells.nbytes

    def ensure(self, ids: np.ndarray) -> int:
        """Rotate the samples among ids (any shape, −1 ignored) not yet kept; returns how many."""
        sp = self.samples
        ids = np.asarray(ids).reshape(-1)
        ids = ids[ids >= 0]
        need = np.unique(ids[sp.slot[ids] < 0]).astype(np.int32)
        if len(need) == 0:
            return 0
        self.k.fields.rotate_samples(self, need)
        return len(need)

    def ensure_cells(self, cells: np.ndarray) -> int:
        """Merge the cells among ``cells`` (−1 ignored) not yet kept (rotating their corner
        samples first); returns how many."""
        cp = self.cells
        cells = np.asarray(cells).reshape(-1)
        cells = cells[cells >= 0]
        need = np.unique(cells[cp.slot[cells] < 0]).astype(np.int32)
        if len(need) == 0:
            return 0
        corners = cell_corners(self.field.grid, need)
        self.ensure(corners)
        cslots = np.ascontiguousarray(self.samples.slot[corners], np.int32)
        self.k.fields.merge_cells(self, need, cslots)
        return len(need)

    def nodes(self, sample: int):
        """(starts, heights, quant) of the non-free nodes of a kept sample, left to right."""
        return self.samples.rows(int(self.samples.slot[sample]))

    def cut(self, sample: int) -> tuple[np.ndarray, np.ndarray]:
        """A kept sample's whole cut (heights, quant), free stretches as maximal tree nodes."""
        st, h, q = self.nodes(sample)
        H = self.field.height
        ends = st.astype(np.int64) + (1 << h.astype(np.int64))
        bounds = np.unique(np.concatenate([[0, 1 << H], st, ends]))
        nz = dict(zip(st.tolist(), zip(h.tolist(), q.tolist())))
        hs, qs = [], []
        for a, b in pairwise(bounds):
            if a in nz:
                hs.append(nz[a][0]); qs.append(nz[a][1])
            else:
                for _, hh in _dyadic(int(a), int(b), H):
                    hs.append(hh); qs.append(255)
        return np.array(hs, np.uint8), np.array(qs, np.uint8)


def _dyadic(a: int, b: int, H: int):
    """[a, b) as maximal aligned tree nodes: (first leaf, height) pairs, left to right."""
    while a < b:
        h = (a & -a).bit_length() - 1 if a else H
        while a + (1 << h) > b:
            h -= 1
        yield a, h
        a += 1 << h


def _bounds(corner_nodes) -> np.ndarray:
    """Sorted first and end leaves of every non-free node of the given (s, h, q) lists."""
    parts = [np.zeros(0, np.int64)]
    for st, h, _ in corner_nodes:
        parts += [st.astype(np.int64), st.astype(np.int64) + (1 << h.astype(np.int64))]
    return np.unique(np.concatenate(parts))


def _values_at(corner_nodes, x: int) -> tuple[list[int], bool]:
    """The 8 corner values at leaf x (255 outside non-free nodes) and whether any is inside one."""
    vals, busy = [], False
    for st, h, q in corner_nodes:
        j = int(np.searchsorted(st, x, side="right")) - 1
        inside = j >= 0 and x < int(st[j]) + (1 << int(h[j]))
        vals.append(int(q[j]) if inside else 255)
        busy |= inside
    return vals, busy


def cells_numpy(corner_nodes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference of glf_cells for one cell: corner_nodes is a list of 8 (starts, heights, quant)
    non-free node lists. Returns (a (T,) int32, b (T,) int32, v (T, 8) uint8): the stretches
    where some corner is inside a non-free node, between consecutive node bounds, adjacent ones
    with the same eight values made one."""
    bounds = _bounds(corner_nodes)
    a, b, v = [], [], []
    for x0, x1 in pairwise(bounds):
        vals, busy = _values_at(corner_nodes, int(x0))
        if busy:
            if b and b[-1] == x0 and v[-1] == vals:
                b[-1] = x1
            else:
                a.append(x0); b.append(x1); v.append(vals)
    return np.array(a, np.int32), np.array(b, np.int32), np.array(v, np.uint8).reshape(-1, 8)


# --- the product -------------------------------------------------------------------------------

def combine_numpy(base: CutSet, cut_of: np.ndarray, cells: np.ndarray, weights: np.ndarray,
                  pools: list[RotatedSamples], delta: bool = False) -> CutSet:
    """Reference of glf_combine, from the rotated corner samples: the result's node bounds are
    the base cut's, plus the bounds of each occluder's cell stretches (``cells_numpy``: where its
    eight corner values change), except inside base nodes of value 0; each stretch
    between bounds becomes maximal aligned tree nodes valued v_base · Π_o F_o, with
    F_o = Σ_c (w_oc / (255 Σ_c w_oc)) v_oc where some corner of o is inside a non-free node,
    else 1 (v_oc = 255 outside non-free nodes).

    base : CutSet; cut_of (V,) its cut per vertex. cells (V, O) int32 cell per occluder (−1:
    culled), weights (V, O, 8) float32. Returns V cuts. delta: what the occluders take away
    instead, v_base − round(v_base · Π_o F_o), 0 outside the occluders' stretches, with runs of
    zeros as maximal aligned nodes (glf_combine's delta mode; the C kernel merges only runs of
    untouched base nodes, so the two agree leaf by leaf, not node by node).
    """
    H = base.height
    n = 1 << H
    V, O = cells.shape
    hs, qs, counts = [], [], []
    for v in range(V):
        a, b = base.offsets[cut_of[v]], base.offsets[cut_of[v] + 1]
        bh, bq = base.heights[a:b], base.quant[a:b].astype(np.int64)
        bs = node_starts(bh)
        occ = []
        for o in range(O):
            if cells[v, o] < 0:
                continue
            corners = cell_corners(pools[o].field.grid, cells[v, o:o + 1])[0]
            w = weights[v, o].astype(np.float64)
            ws = 0.0
            for x in w:                       # summed in the kernel's order
                ws += x
            occ.append(([pools[o].nodes(int(c)) for c in corners], w / (255.0 * ws)))
        bounds = np.unique(np.concatenate([bs, [n]] + [np.concatenate(cells_numpy(cn)[:2]).astype(np.int64)
                                                       for cn, _ in occ]))
        bi = np.searchsorted(bs, bounds, side="right") - 1
        bi = np.minimum(bi, len(bs) - 1)
        bounds = bounds[(bounds == n) | (bq[bi] > 0) | (bounds == bs[bi])]
        out_h, out_q = [], []
        for x0, x1 in pairwise(bounds):
            k = int(np.searchsorted(bs, x0, side="right")) - 1
            if bq[k] == 0:
                out_h.append(bh[k]); out_q.append(0)
                continue
            F = 1.0
            for cn, w in occ:
                vals, busy = _values_at(cn, int(x0))
                if busy:
                    s = 0.0
                    for c in range(8):
                        s += w[c] * vals[c]
                    F *= s
            qq = int(np.clip(np.rint(bq[k] * F), 0, 255))
            if delta:
                qq = int(bq[k]) - qq
            for _, hh in _dyadic(int(x0), int(x1), H):
                out_h.append(hh); out_q.append(qq)
        if delta:
            out_h, out_q = _merge_zero_runs(out_h, out_q, H)
        hs.append(np.array(out_h, np.uint8)); qs.append(np.array(out_q, np.uint8)); counts.append(len(out_h))
    off = np.zeros(V + 1, np.int64)
    np.cumsum(counts, out=off[1:])
    return CutSet(off, np.concatenate(hs) if hs else np.zeros(0, np.uint8),
                  np.concatenate(qs) if qs else np.zeros(0, np.uint8), H)


def _merge_zero_runs(hs, qs, H):
    """A cut with every run of 0-valued nodes rewritten as maximal aligned nodes."""
    out_h, out_q, x, z = [], [], 0, None
    for h, q in zip(hs, qs):
        if q == 0:
            z = x if z is None else z
        else:
            if z is not None:
                out_h += [hh for _, hh in _dyadic(z, x, H)]; out_q += [0] * (len(out_h) - len(out_q))
                z = None
            out_h.append(h); out_q.append(q)
        x += 1 << int(h)
    if z is not None:
        out_h += [hh for _, hh in _dyadic(z, x, H)]; out_q += [0] * (len(out_h) - len(out_q))
    return out_h, out_q


SKIP = 32          # glf_combine's skip blocks (fields.c SKIP)


def skip_table(cs: CutSet) -> np.ndarray:
    """(⌈M / SKIP⌉ + 1,) int32: the leaf where node g·SKIP of the cut set's node array starts
    within its own cut (glf_combine's b_skip, for the delta mode)."""
    span = np.left_shift(np.int64(1), cs.heights.astype(np.int64))
    start = np.cumsum(span) - span
    first = np.repeat(start[cs.offsets[:-1]], cs.sizes())
    local = (start - first).astype(np.int32)
    return np.concatenate([local[::SKIP], [0]]).astype(np.int32)


# --- the API the renderer calls ---------------------------------------------------------------

class Combiner:
    """Combines vertex cuts with occluders' fields, keeping rotated samples and cells between
    calls (one per session or renderer).

    hmin : field cuts are rebuilt with nodes of at least 2^hmin leaves (0: exact).
    kernels : the kernel backend (worker/native/kernels.py; default: the process's): "native"
        runs the C kernels of fields.c, "numpy" their references.
    max_pools : (field, rotation) pools kept; a rotation drag makes a new one every frame.
    pool_bytes : a pool larger than this is dropped and rebuilt on demand.
    Not thread-safe: one per session or renderer.
    """

    def __init__(self, hmin: int = DEFAULT_HMIN, tree: DirectionTree | None = None, kernels=None,
                 max_pools: int = 8, pool_bytes: int = 512 << 20):
        from ...native.kernels import kernels as default_kernels

        self.k = kernels or default_kernels()
        self.hmin = int(hmin)
        self.tree = tree or get_tree()
        self.max_pools = max_pools
        self.pool_bytes = pool_bytes
        self._pools: OrderedDict = OrderedDict()
        self._maps: OrderedDict = OrderedDict()       # rotation -> LeafMap
        self._caps: dict[str, int] = {}
        self.last_stats: dict = {}

    def pool(self, field: Field, q: np.ndarray) -> RotatedSamples:
        """The kept samples and cells of a field seen through rotation q (source → receiver)."""
        qk = np.round(np.asarray(q, np.float64), 9).tobytes()
        key = (field.key or id(field), qk, self.hmin)
        p = self._pools.get(key)
        if p is None or p.nbytes > self.pool_bytes:
            p = RotatedSamples(field, self.leaf_map(q, qk), self.hmin, self.k)
            self._pools[key] = p
        self._pools.move_to_end(key)
        while len(self._pools) > self.max_pools:
            self._pools.popitem(last=False)
        return p

    def leaf_map(self, q: np.ndarray, qk: bytes | None = None) -> LeafMap:
        """The LeafMap of rotation q, shared by the pools of every field seen through it (a
        turned chair sees the floor and the table through the same rotation), kept for the
        last few rotations."""
        qk = qk or np.round(np.asarray(q, np.float64), 9).tobytes()
        m = self._maps.get(qk)
        if m is None:
            m = self._maps[qk] = LeafMap(self.tree, q, self.k)
        self._maps.move_to_end(qk)
        while len(self._maps) > 4:
            self._maps.popitem(last=False)
        return m

    def stencils(self, positions: np.ndarray, normals: np.ndarray, occluders) -> tuple[np.ndarray, np.ndarray, int]:
        """The trilinear stencils of K receivers in each occluder's field, culled (§V.B) and with
        the corners they cannot see dropped (``lookup`` then ``validate``).

        positions, normals : (K, 3) float32 in the receiver frame; occluders : list of (Field,
        receiver_from_local (4, 4)). Returns (cells (K, O) int32, −1 where culled; weights
        (K, O, 8) float32; segments traced). A receiver with every cell −1 keeps its own cut.
        """
        K, O = len(positions), len(occluders)
        cells = np.full((K, O), -1, np.int32)
        weights = np.zeros((K, O, 8), np.float32)
        segments = 0
        for o, (fld, m) in enumerate(occluders):
            lfr = np.linalg.inv(np.asarray(m, np.float64))
            cells[:, o], w, test = lookup(fld, lfr, positions, normals, self.k)
            weights[:, o], n_seg = validate(fld, lfr, positions, cells[:, o], w, test)
            segments += n_seg
        return cells, weights, segments

    def combine(self, base: CutSet, cut_ids: np.ndarray, positions: np.ndarray, normals: np.ndarray,
                occluders, delta: bool = False, stencils=None, tag: str = "", skip: np.ndarray | None = None,
                placed: bool = False):
        """Cuts of K receiver vertices with the occluders multiplied in (cyber-worlds eq. 4).

        base : CutSet of the receivers' own cuts (over their frame's leaves); cut_ids (K,) int
            the cut of each receiver in it. positions, normals : (K, 3) float32, receiver frame.
        occluders : list of (Field, receiver_from_local (4, 4) similarity).
        delta : return what the occluders take away, v_base − v_base · Π F (glf_combine's delta
            mode), for a caller that already has the radiance of the base cuts.
        stencils : (cells, weights) from ``stencils`` for these receivers (else computed here).
        skip : ``skip_table(base)`` for the delta mode (faster; the same result).
        tag : names the call site, whose output size sizes the next call's buffer.
        Returns a CutSet of K cuts over the receiver frame's leaves (cut k for receiver k),
        ready for glk_shade_points with cut_of = arange(K); placed: (cuts, cut_of (K,) int32)
        with receiver k's cut at cuts[cut_of[k]], as the kernel left them (no copy into receiver
        order). ``last_stats`` says what it cost.
        """
        t0 = time.perf_counter()
        cut_ids = np.asarray(cut_ids, np.int32)
        K = len(cut_ids)
        segments = 0
        if stencils is None:
            cells, weights, segments = self.stencils(positions, normals, occluders)
        else:
            cells, weights = stencils
        pools, rot, merged = [], 0, 0
        t_rot = 0.0
        for o, (fld, m) in enumerate(occluders):
            q, _ = rotation_part(np.asarray(m, np.float64))
            pool = self.pool(fld, q)
            t1 = time.perf_counter()
            before = pool.samples.n
            merged += pool.ensure_cells(cells[:, o])
            rot += pool.samples.n - before
            t_rot += time.perf_counter() - t1
            pools.append(pool)
        t2 = time.perf_counter()
        est = int(1.5 * base.sizes()[cut_ids].sum()) + 1024
        res = self.k.fields.combine(base, cut_ids, cells, weights, pools, delta, max(est, self._caps.get(tag, 0)), skip,
                                    placed=placed)
        out = res[0] if placed else res
        self._caps[tag] = int(1.2 * out.n_nodes) + 1024
        t3 = time.perf_counter()
        self.last_stats = {"ms_lookup": 1e3 * (t2 - t0 - t_rot), "ms_rotate_and_cells": 1e3 * t_rot,
                           "ms_product": 1e3 * (t3 - t2), "ms_total": 1e3 * (t3 - t0),
                           "samples_rotated": rot, "cells_merged": merged, "segments_traced": segments, "receivers": K,
                           "receivers_affected": int((cells >= 0).any(axis=1).sum()) if len(occluders) else 0,
                           "mean_cut_in": float(base.sizes()[cut_ids].mean()) if K else 0.0,
                           "mean_cut_out": float(out.sizes().mean()) if K else 0.0}
        return res


def combined_cuts(base: CutSet, cut_ids, positions, normals, occluders, hmin: int = DEFAULT_HMIN,
                  kernels=None) -> CutSet:
    """One-off ``Combiner(hmin, kernels=kernels).combine(...)`` (nothing kept between calls)."""
    return Combiner(hmin, kernels=kernels).combine(base, cut_ids, positions, normals, occluders)
