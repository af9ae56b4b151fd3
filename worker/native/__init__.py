"""The C kernels' library (every src/*.c linked into one _glintk*.so, built by `make install`)
and the helpers to bind them: ``bind`` declares a kernel's parameters by name and C type, so a
signature reads like the C prototype it mirrors and a wrong call fails in ctypes, not in C.

``lib`` is None when the library has not been built; worker/native/kernels.py then serves the
NumPy references. The library's BRDF branch ids and packed layout are checked against
worker/models when it loads (``model_id``), never copied by hand.
ctypes releases the GIL during each call; OpenMP threads do the work.

Nothing outside worker/native decides between the C kernels and the references: code asks the
backend object (``worker.native.kernels.kernels()``, chosen once per process) and calls its
methods, e.g. ``k.shade_points(...)``, ``k.fields.combine(...)``, ``k.gi.sample(...)``,
``k.paint.prefilter(...)``, ``k.capture.merge(...)``. ``GLINT_NO_NATIVE=1`` in the environment
leaves the library unloaded (``lib`` None), as if it had not been built: the process then runs
the NumPy references only (tests use it to show a "numpy" backend never needs the library).

Angles: every C entry point that takes a rotation takes it in radians (``double``), about +Y
for the environment (world φ reads map φ + rotation) and for a capture's yaw: glk_light_tables,
glk_background, glk_env_lookup, glp_shade, glp_background, gi_sample, glk_fisheye_map. The
Python side speaks degrees (scene files, lighting requests); the typed wrappers of the
backend convert, and nothing else passes an angle to C.
"""
from __future__ import annotations

import ctypes
import glob
import logging
import os
from pathlib import Path

import numpy as np

log = logging.getLogger("glint.native")
_here = Path(__file__).parent
# Idle OpenMP threads sleep instead of spinning (libgomp reads this when the library loads): on
# a shared machine spinning threads take the cores the other threads of a frame are waiting
# for; measured on 2 loaded cores, the light tables took 128 ms spinning and 15 ms sleeping
# (BENCHMARKS.md). Set OMP_WAIT_POLICY=ACTIVE to spin.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# C parameter types, named like the C side
f32p = np.ctypeslib.ndpointer(np.float32, flags="C_CONTIGUOUS")
f64p = np.ctypeslib.ndpointer(np.float64, flags="C_CONTIGUOUS")
i32p = np.ctypeslib.ndpointer(np.int32, flags="C_CONTIGUOUS")
i64p = np.ctypeslib.ndpointer(np.int64, flags="C_CONTIGUOUS")
u8p = np.ctypeslib.ndpointer(np.uint8, flags="C_CONTIGUOUS")
u16p = np.ctypeslib.ndpointer(np.uint16, flags="C_CONTIGUOUS")
u32p = np.ctypeslib.ndpointer(np.uint32, flags="C_CONTIGUOUS")
u64p = np.ctypeslib.ndpointer(np.uint64, flags="C_CONTIGUOUS")
i64, i32, f64, f32 = ctypes.c_int64, ctypes.c_int, ctypes.c_double, ctypes.c_float
voidp, charp = ctypes.c_void_p, ctypes.c_char_p


class LibraryMismatch(ImportError):
    """The built library does not match the Python side (rebuild it: `make build`)."""


def _load():
    for cand in sorted(glob.glob(str(_here / "_glintk*.so"))):
        try:
            return ctypes.CDLL(cand)
        except OSError as e:
            log.warning("cannot load %s: %s", cand, e)
    return None


# GLINT_NO_NATIVE=1: behave as if the library were not built (the references run)
lib = None if os.environ.get("GLINT_NO_NATIVE", "") not in ("", "0") else _load()


def bind(cname: str, restype=None, **params):
    """Declare C function ``cname``: params in C order, ``name=ctype`` (Python keeps keyword
    order). Returns the ctypes function, or None without a library."""
    if lib is None:
        return None
    fn = getattr(lib, cname)
    fn.argtypes = list(params.values())
    fn.restype = restype
    fn.param_names = tuple(params)
    return fn


def available() -> bool:
    return lib is not None


def c(a, dtype):
    """C-contiguous view/copy with the given dtype."""
    return np.ascontiguousarray(a, dtype=dtype)


_model_ids: dict[str, int] = {}


def model_id(kernel: str | None) -> int:
    """The library's id of a BRDF kernel branch (worker/models ``kernel``), −1 for none."""
    if kernel is None or lib is None:
        return -1
    if kernel not in _model_ids:
        _model_ids[kernel] = int(_glk_model_id(kernel.encode()))
    return _model_ids[kernel]


def max_threads() -> int:
    return int(lib.glk_max_threads()) if lib is not None else 1


def set_threads(n: int) -> None:
    """OpenMP threads for every kernel (0 leaves OpenMP's default: one per core)."""
    if lib is not None and n > 0:
        lib.glk_set_threads(int(n))


if lib is not None:
    _glk_model_id = bind("glk_model_id", i32, name=charp)
    bind("glk_layout", i32, what=i32)
    bind("glk_max_threads", i32)
    bind("glk_set_threads", None, n=i32)

    def _check_layout():
        from ..models.base import N_PARAMS, TABLE_N

        got = (lib.glk_layout(0), lib.glk_layout(1))
        if got != (N_PARAMS, TABLE_N):
            raise LibraryMismatch(f"C kernels built with N_PARAMS, TABLE_N = {got}, Python expects "
                                  f"{(N_PARAMS, TABLE_N)}: rebuild them (make build)")
        from ..models import models

        for name, cls in models().items():
            if cls.kernel is not None and model_id(cls.kernel) < 0:
                raise LibraryMismatch(f"BRDF model {name!r} names kernel branch {cls.kernel!r}, which the "
                                      "built library lacks: rebuild it (make build)")
    _check_layout()
