"""ctypes signatures of the paint-to-BRDF kernels in worker/native/src/fit.c.

Each kernel has a typed wrapper with its NumPy reference beside it: ``transfer.transfer``
(reference ``transfer.transfer_numpy``) and ``basis.energy_rows_at`` (its NumPy body is the
reference). ``lib`` is None when the C library has not been built.
"""
from __future__ import annotations

from .. import native
from ..native import _dbl, _f32, _f64, _i32, _i64, _i64s, _int, _u8

lib = native.lib

if lib is not None:
    lib.glk_fit_transfer.restype = None
    lib.glk_fit_transfer.argtypes = [
        _i64s, _f32, _f32, _i32, _f32,                 # P, normals, wo, verts, bary
        _i64, _u8, _u8, _f32, _f32, _f32, _f32, _f32, _i64, _int,   # cuts, node light/dir, tree
        _int, _f64, _f64,                              # refinement pairs
        _int, _dbl,                                    # J, xcut
        _int, _dbl, _dbl,                              # static kind, α, F0
        _int, _i32, _i32, _f32, _f32, _int,            # cube cells, candidate lists, exp table
        _f32, _f32]                                    # T, E
    lib.glk_energy_rows.restype = None
    lib.glk_energy_rows.argtypes = [_i64s, _f64, _int, _f64, _f64, _dbl, _int, _dbl, _dbl, _int, _f64, _f64,
                                    _int, _f64]


def available() -> bool:
    return lib is not None
