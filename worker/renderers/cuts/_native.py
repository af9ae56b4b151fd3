"""The cut-field kernels of worker/native/src/fields.c, declared by name (worker.native.bind).

Each kernel has a typed wrapper in the module that owns its NumPy reference (grid/combine:
lookup; rotate: nearest_leaves; combine: RotatedSamples.ensure / ensure_cells, combine_native);
``available()`` is False when the C library is not built, and those fall back to the references.
"""
from __future__ import annotations

import ctypes

import numpy as np

from ...native import available as _lib_built
from ...native import bind, c, f32p, f64p, i32, i32p, i64, i64p, u8p, voidp

__all__ = ["available", "c", "cells", "combine", "gather", "lookup", "nearest_leaves", "pointers", "rotate"]

vpp = ctypes.POINTER(ctypes.c_void_p)     # an array of n_occ array pointers

lookup = bind("glf_lookup", None, P=i64, pos=f32p, nrm=f32p, m=f64p, grid=f64p, dirs=f64p, radii=f64p,
              face_table=i32p, clearance=voidp, cells=i32p, w=f32p, test=u8p)
nearest_leaves = bind("glf_nearest_leaves", None, P=i64, dirs=f64p, table=i32p, R=i32, neigh=i32p, k=i32,
                      leaves=f32p, out=i32p)
rotate = bind("glf_rotate", None, n=i64, ids=i32p, f_off=i64p, f_hp=u8p, f_bits=u8p, H=i32, hmin=i32,
              identity=i32, inv_off=i32p, inv_idx=i32p, cap=i64, out_s=i32p, out_h=u8p, out_q=u8p, pos=i64p,
              counts=i32p, used=i64p)
cells = bind("glf_cells", None, n=i64, corners=i32p, p_off=i64p, p_cnt=i32p, p_s=i32p, p_h=u8p, p_q=u8p, H=i32,
             cap=i64, out_a=i32p, out_b=i32p, out_v=u8p, pos=i64p, counts=i32p, used=i64p)
combine = bind("glf_combine", None, V=i64, cut_of=i32p, b_off=i64p, b_h=u8p, b_q=u8p, b_skip=voidp, H=i32, n_occ=i32,
               delta=i32,
               cslot=i32p, wts=f32p, c_off=vpp, c_cnt=vpp, c_a=vpp, c_b=vpp, c_v=vpp, cap=i64, out_h=u8p,
               out_q=u8p, pos=i64p, counts=i32p, used=i64p)
_gather = bind("glf_gather", None, n=i64, pos=i64p, counts=i32p, src=voidp, esize=i64, dst_off=i64p, dst=voidp)


def available() -> bool:
    return _lib_built() and lookup is not None


def gather(pos: np.ndarray, counts: np.ndarray, src: np.ndarray, dst_off: np.ndarray, dst: np.ndarray) -> None:
    """glf_gather: items placed at pos (counts elements each) into dst at dst_off (same dtype;
    trailing dimensions are part of an element)."""
    esize = src.itemsize * int(np.prod(src.shape[1:], dtype=np.int64))
    _gather(len(pos), pos, counts, src.ctypes.data, esize, dst_off, dst.ctypes.data)


def pointers(arrays) -> ctypes.Array:
    """A C array of the data pointers of C-contiguous arrays (kept alive by the caller)."""
    return (ctypes.c_void_p * len(arrays))(*[a.ctypes.data for a in arrays])
