"""ctypes signatures of the cut-field kernels in worker/native/src/fields.c.

Each kernel has a typed wrapper in the module that owns its NumPy reference (grid.lookup,
rotate, combine); ``lib`` is None when the C library is not built.
"""
from __future__ import annotations

import ctypes

import numpy as np

from ... import native

lib = native.lib
c = native.c

_f32 = np.ctypeslib.ndpointer(np.float32, flags="C_CONTIGUOUS")
_f64 = np.ctypeslib.ndpointer(np.float64, flags="C_CONTIGUOUS")
_i32 = np.ctypeslib.ndpointer(np.int32, flags="C_CONTIGUOUS")
_i64 = np.ctypeslib.ndpointer(np.int64, flags="C_CONTIGUOUS")
_u8 = np.ctypeslib.ndpointer(np.uint8, flags="C_CONTIGUOUS")
_vpp = ctypes.POINTER(ctypes.c_void_p)
_n, _int = ctypes.c_int64, ctypes.c_int

if lib is not None and hasattr(lib, "glf_lookup"):
    lib.glf_lookup.argtypes = [_n, _f32, _f32, _f64, _f64, _f64, _f64, _i32, ctypes.c_void_p, _i32, _f32, _u8]
    lib.glf_rotate.argtypes = [_n, _i32, _i64, _u8, _u8, _int, _int, _int, _i32, _i32, _n, _i32, _u8, _u8, _i64,
                               _i32, _i64]
    lib.glf_cells.argtypes = [_n, _i32, _i64, _i32, _i32, _u8, _u8, _int, _n, _i32, _i32, _u8, _i64, _i32, _i64]
    lib.glf_combine.argtypes = [_n, _i32, _i64, _u8, _u8, _int, _int, _i32, _f32, _vpp, _vpp, _vpp, _vpp, _vpp,
                                _n, _u8, _u8, _i64, _i32, _i64]
    lib.glf_nearest_leaves.argtypes = [_n, _f64, _i32, _int, _i32, _int, _f32, _i32]
    lib.glf_gather.argtypes = [_n, _i64, _i32, ctypes.c_void_p, _n, _i64, ctypes.c_void_p]
else:
    lib = None


def available() -> bool:
    return lib is not None


def gather(pos: np.ndarray, counts: np.ndarray, src: np.ndarray, dst_off: np.ndarray, dst: np.ndarray) -> None:
    """glf_gather: items placed at pos (counts elements each) into dst at dst_off (same dtype;
    trailing dimensions are part of an element)."""
    esize = src.itemsize * int(np.prod(src.shape[1:], dtype=np.int64))
    lib.glf_gather(len(pos), pos, counts, src.ctypes.data, esize, dst_off, dst.ctypes.data)


def pointers(arrays) -> ctypes.Array:
    """A C array of the data pointers of C-contiguous arrays (kept alive by the caller)."""
    return (ctypes.c_void_p * len(arrays))(*[a.ctypes.data for a in arrays])
