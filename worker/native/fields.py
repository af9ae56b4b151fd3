"""The cut-field kernels (src/fields.c) behind the backend's ``fields`` family, and their NumPy
references' entry points: ``k.fields.lookup``, ``nearest_leaves``, ``rotate_samples``,
``merge_cells``, ``combine`` take and return the same arrays in both backends (the references
live in worker/renderers/cuts/combine.py and rotate.py; tests/fields checks they agree).
The public functions (combine.lookup, rotate.nearest_leaves, RotatedSamples.ensure /
ensure_cells, Combiner.combine) check the arrays and call these.
"""
from __future__ import annotations

import ctypes

import numpy as np

from . import bind, c, f32p, f64p, i32, i32p, i64, i64p, lib, u8p, voidp

vpp = ctypes.POINTER(ctypes.c_void_p)     # an array of n_occ array pointers


def pointers(arrays) -> ctypes.Array:
    """A C array of the data pointers of C-contiguous arrays (kept alive by the caller)."""
    return (ctypes.c_void_p * len(arrays))(*[a.ctypes.data for a in arrays])


class NumpyFields:
    """The references of the cut-field kernels."""
    name = "numpy"

    def lookup(self, field, m, pos, nrm, clr):
        """(cells (P,) int32, weights (P, 8) float32, test (P,) uint8) of receivers in a field:
        m (3, 4) float64 local_from_receiver rows, pos / nrm (P, 3) float32, clr (S,) float32
        sample clearances or None (see combine.lookup)."""
        from ..renderers.cuts.combine import lookup_numpy
        return lookup_numpy(field, m, pos, nrm, clr)

    def nearest_leaves(self, tree, dirs):
        """(P,) int32 leaf nearest to each unit direction (P, 3) float64 (rotate.nearest_leaves)."""
        from ..renderers.cuts.rotate import nearest_leaves_numpy
        return nearest_leaves_numpy(tree, dirs)

    def rotate_samples(self, rs, need):
        """Rotate the samples need (n,) int32 (not yet kept) of RotatedSamples rs into its pool."""
        from ..renderers.cuts.combine import rotate_samples_into_numpy
        rotate_samples_into_numpy(rs, need)

    def merge_cells(self, rs, need, cslots):
        """Merge the cells need (n,) int32 of rs, whose corner samples are kept at the pool slots
        cslots (n, 8) int32, into its cell pool."""
        from ..renderers.cuts.combine import merge_cells_into_numpy
        merge_cells_into_numpy(rs, need, cslots)

    def combine(self, base, cut_of, cells, weights, pools, delta=False, cap_hint=None, skip=None, placed=False):
        """CutSet of the receivers' cuts with the occluders' fields multiplied in
        (combine.combine_numpy; cap_hint and skip only size and speed up the C kernel). placed:
        return (cuts, cut_of (K,) int32), receiver k's cut being cuts[cut_of[k]] (here arange)."""
        from ..renderers.cuts.combine import combine_numpy
        out = combine_numpy(base, cut_of, cells, weights, pools, delta)
        return (out, np.arange(out.n_vertices, dtype=np.int32)) if placed else out


class NativeFields:
    """Typed wrappers of glf_* (fields.c)."""
    name = "native"

    def __init__(self):
        if lib is None:
            raise RuntimeError("the C kernels are not built (make build)")
        self._lookup = bind("glf_lookup", None, P=i64, pos=f32p, nrm=f32p, m=f64p, grid=f64p, dirs=f64p,
                            radii=f64p, face_table=i32p, clearance=voidp, cells=i32p, w=f32p, test=u8p)
        self._nearest = bind("glf_nearest_leaves", None, P=i64, dirs=f64p, table=i32p, R=i32, neigh=i32p, k=i32,
                             leaves=f32p, out=i32p)
        self._rotate = bind("glf_rotate", None, n=i64, ids=i32p, f_off=i64p, f_hp=u8p, f_bits=u8p, H=i32, hmin=i32,
                            identity=i32, inv_off=i32p, inv_idx=i32p, cap=i64, out_s=i32p, out_h=u8p, out_q=u8p,
                            pos=i64p, counts=i32p, used=i64p)
        self._cells = bind("glf_cells", None, n=i64, corners=i32p, p_off=i64p, p_cnt=i32p, p_s=i32p, p_h=u8p,
                           p_q=u8p, H=i32, cap=i64, out_a=i32p, out_b=i32p, out_v=u8p, pos=i64p, counts=i32p,
                           used=i64p)
        self._combine = bind("glf_combine", None, V=i64, cut_of=i32p, b_off=i64p, b_h=u8p, b_q=u8p, b_skip=voidp,
                             H=i32, n_occ=i32, delta=i32, cslot=i32p, wts=f32p, c_off=vpp, c_cnt=vpp, c_a=vpp,
                             c_b=vpp, c_v=vpp, cap=i64, out_h=u8p, out_q=u8p, pos=i64p, counts=i32p, used=i64p)
        self._gather = bind("glf_gather", None, n=i64, pos=i64p, counts=i32p, src=voidp, esize=i64, dst_off=i64p,
                            dst=voidp)

    def gather(self, pos, counts, src, dst_off, dst) -> None:
        """glf_gather: items placed at pos (counts elements each) into dst at dst_off (same dtype;
        trailing dimensions are part of an element)."""
        esize = src.itemsize * int(np.prod(src.shape[1:], dtype=np.int64))
        self._gather(len(pos), pos, counts, src.ctypes.data, esize, dst_off, dst.ctypes.data)

    def lookup(self, field, m, pos, nrm, clr):
        grid = field.grid
        cells = np.empty(len(pos), np.int32)
        w = np.empty((len(pos), 8), np.float32)
        test = np.empty(len(pos), np.uint8)
        self._lookup(len(pos), pos, nrm, m.reshape(-1).copy(), grid.params(), grid.directions, grid.radii,
                     grid.face_table, None if clr is None else clr.ctypes.data, cells, w, test)
        return cells, w, test

    def nearest_leaves(self, tree, dirs):
        from ..renderers.cuts.rotate import _leaf_neighbours, _nearest_leaf_table

        d = c(dirs, np.float64)
        tab = _nearest_leaf_table(tree)
        nb = _leaf_neighbours(tree)
        out = np.empty(len(d), np.int32)
        self._nearest(len(d), d, tab, tab.shape[1], nb, nb.shape[1], tree.leaves, out)
        return out

    def rotate_samples(self, rs, need):
        from ..renderers.cuts.combine import _placed, rotate_samples_into_numpy

        f, H, sp = rs.field, rs.field.height, rs.samples
        if H < 6:            # the kernel's bitset has 64-leaf words: smaller trees take the reference
            rotate_samples_into_numpy(rs, need)
            return

        def run(cap, b, pos, counts, used):
            self._rotate(len(need), need, f.offsets, f.hpacked, f.bits, H, rs.hmin, int(rs.lmap.identity),
                         rs.lmap.inv_off, rs.lmap.inv_idx, cap, b["s"], b["h"], b["q"], pos, counts, used)
        bufs, pos, counts = _placed(run, len(need), max(1 << 16, 256 * len(need)), {
            "s": (np.int32, ()), "h": (np.uint8, ()), "q": (np.uint8, ())})
        dst = sp.reserve(need, counts)
        for k in sp.names:
            self.gather(pos, counts, bufs[k], dst, getattr(sp, k))

    def merge_cells(self, rs, need, cslots):
        from ..renderers.cuts.combine import _placed

        sp, cp = rs.samples, rs.cells

        def run(cap, b, pos, counts, used):
            self._cells(len(need), cslots, sp.off, sp.cnt, sp.s, sp.h, sp.q, rs.field.height, cap,
                        b["a"], b["b"], b["v"], pos, counts, used)
        bufs, pos, counts = _placed(run, len(need), max(1 << 16, 512 * len(need)), {
            "a": (np.int32, ()), "b": (np.int32, ()), "v": (np.uint8, (8,))})
        dst = cp.reserve(need, counts)
        for k in cp.names:
            self.gather(pos, counts, bufs[k], dst, getattr(cp, k))

    def combine(self, base, cut_of, cells, weights, pools, delta=False, cap_hint=None, skip=None, placed=False):
        """glf_combine (the pools' cells must be kept (ensure_cells); cap_hint: expected total
        output nodes; skip: ``combine.skip_table(base)``, which lets the delta mode pass untouched
        base nodes a block at a time). placed: return (cuts, cut_of (K,) int32) with the cuts
        where the kernel put them, receiver k's cut being cuts[cut_of[k]]: no gather into
        receiver order (a shader takes cut_of)."""
        from ..core.cuts import CutSet
        from ..renderers.cuts.combine import _placed

        V, O = cells.shape
        cut_of = c(cut_of, np.int32)
        cslot = np.full((V, O), -1, np.int32)
        for o, p in enumerate(pools):
            cslot[:, o] = np.where(cells[:, o] >= 0, p.cells.slot[np.maximum(cells[:, o], 0)], -1)
        weights = c(weights, np.float32)
        P = pointers
        cps = [p.cells for p in pools]

        def run(cap, b, pos, counts, used):
            self._combine(V, cut_of, c(base.offsets, np.int64), c(base.heights, np.uint8), c(base.quant, np.uint8),
                          skip.ctypes.data if (skip is not None and delta) else None, base.height, O,
                          int(bool(delta)), cslot, weights, P([p.off for p in cps]), P([p.cnt for p in cps]),
                          P([p.a for p in cps]), P([p.b for p in cps]), P([p.v for p in cps]),
                          cap, b["h"], b["q"], pos, counts, used)
        cap = int(cap_hint or int(1.5 * base.sizes()[cut_of].sum()) + 1024)
        bufs, pos, counts = _placed(run, V, cap, {"h": (np.uint8, ()), "q": (np.uint8, ())})
        if placed:
            # the kernel took each item's room with an atomic add, so the items lie back to back
            # from 0 in the order they were taken: sorted by offset they are a cut set as they
            # are (an empty item before the one that starts where it does)
            order = np.lexsort((counts, pos))
            n = int(counts.sum(dtype=np.int64))
            off = np.empty(V + 1, np.int64)
            off[:V], off[V] = pos[order], n
            rank = np.empty(V, np.int32)
            rank[order] = np.arange(V, dtype=np.int32)
            return CutSet(off, bufs["h"][:n], bufs["q"][:n], base.height), rank
        off = np.zeros(V + 1, np.int64)
        np.cumsum(counts, out=off[1:])
        h = np.empty(off[-1], np.uint8)
        q = np.empty(off[-1], np.uint8)
        self.gather(pos, counts, bufs["h"], off[:-1].copy(), h)
        self.gather(pos, counts, bufs["q"], off[:-1].copy(), q)
        return CutSet(off, h, q, base.height)


__all__ = ["NativeFields", "NumpyFields", "pointers"]
