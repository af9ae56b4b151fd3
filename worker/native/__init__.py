"""ctypes binding of the C kernels in src/glintk.c (built by `pip install` / setup.py).

`lib` is None when the library has not been built; callers then use the NumPy references
(worker/core), which compute the same things (tests/core/test_native.py).
ctypes releases the GIL during each call; OpenMP threads do the work.
"""
from __future__ import annotations

import ctypes
import glob
import os
from pathlib import Path

import numpy as np

_here = Path(__file__).parent


def _load():
    for cand in sorted(glob.glob(str(_here / "_glintk*.so"))):
        try:
            return ctypes.CDLL(cand)
        except OSError:
            continue
    return None


lib = _load()

_f32 = np.ctypeslib.ndpointer(np.float32, flags="C_CONTIGUOUS")
_f64 = np.ctypeslib.ndpointer(np.float64, flags="C_CONTIGUOUS")
_i32 = np.ctypeslib.ndpointer(np.int32, flags="C_CONTIGUOUS")
_i64 = np.ctypeslib.ndpointer(np.int64, flags="C_CONTIGUOUS")
_u8 = np.ctypeslib.ndpointer(np.uint8, flags="C_CONTIGUOUS")
_i64s, _int, _dbl = ctypes.c_int64, ctypes.c_int, ctypes.c_double

if lib is not None:
    lib.glk_max_threads.restype = _int
    lib.glk_set_threads.argtypes = [_int]
    lib.glk_build_cuts.argtypes = [_f32, _i64s, _int, _dbl, _u8, _u8, _i32]
    lib.glk_shade_points.argtypes = [_i64s, _f32, _f32, _i32, _i32, _i64, _u8, _u8, _f32, _f32,
                                     _f32, _f32, _i64, _int, _i32, _f32, _f32, _f32, _f32, _i64, _f32]
    lib.glk_interpolate.argtypes = [_i64s, _i32, _f32, _i32, _f32, _f32]
    lib.glk_env_lookup.argtypes = [_i64s, _f32, ctypes.c_void_p, _f32, _int, _int, _dbl, _dbl, _f32]
    lib.glk_coarsen.argtypes = [_i64s, _i64, _u8, _u8, _dbl, _u8, _u8, _i32]
    lib.glk_tonemap.argtypes = [_i64s, _f32, _dbl, _int, _u8]
    threads = int(os.environ.get("GLINT_THREADS", "0") or 0)
    if threads > 0:
        lib.glk_set_threads(threads)


def available() -> bool:
    return lib is not None


def c(a, dtype):
    """C-contiguous view/copy with the given dtype."""
    return np.ascontiguousarray(a, dtype=dtype)
