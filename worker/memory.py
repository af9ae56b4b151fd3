"""A process's memory and garbage collection, for the long-lived ones (the API server, the
workers): return freed memory to the system, and keep start-up objects out of full collections.
glibc's malloc only (elsewhere the malloc calls do nothing); no heavy imports, so the server
may use it (it loads no numerical library)."""
from __future__ import annotations

import gc


def _libc():
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return libc if hasattr(libc, "malloc_trim") else None     # glibc only
    except OSError:
        return None


_LIBC = _libc()


def trim_malloc() -> None:
    """Return the free memory at the top of malloc's heaps to the system."""
    if _LIBC is not None:
        _LIBC.malloc_trim(0)


def cap_malloc_arenas(n: int = 2) -> None:
    """A few malloc arenas, not eight per core: the memory freed by many threads stays in fewer
    places, and trim_malloc returns more of it."""
    if _LIBC is not None:
        _LIBC.mallopt(-8, n)            # M_ARENA_MAX


def release_memory() -> None:
    """Give the memory freed by a closed session back to the system: collect, then trim.
    Resident memory grew ~100 MiB per worker from one run of eight sessions to the
    next while Python's own allocations (tracemalloc) stayed flat to 0.2 MiB: the kernels'
    per-thread scratch and the sessions' arrays were freed into malloc's per-thread arenas,
    which keep them until trimmed."""
    gc.collect()
    trim_malloc()


def freeze_start_up() -> None:
    """Keep every object that exists now for good, out of full collections (gc.freeze), after a
    last collection. Measured with gc.callbacks under load, a full collection walked
    every object the imports and start-up had made, holding the GIL (and so every stream or
    session of the process) for 50-170 ms in the server and 47-88 ms in a worker; after the
    freeze the largest during a run took 23 and 12 ms. Objects made later are collected as usual."""
    gc.collect()
    gc.freeze()


_paused = [0]
_pause_lock = __import__("threading").Lock()


class no_collections:
    """``with no_collections():`` the cyclic garbage collector is off while a thread builds and
    drops a large acyclic structure (a 20 000-object scene parsed and validated: ~1 M objects).
    Measured: the collections it triggered held the GIL, and so the event loop, for up to 124 ms;
    with them off the longest pause was 11 ms. Nested and concurrent uses share one count; the
    collector is on again when the last one ends (it was on before)."""

    def __enter__(self):
        with _pause_lock:
            if _paused[0] == 0:
                self._was = gc.isenabled()
                _paused.append(self._was)
                gc.disable()
            _paused[0] += 1
        return self

    def __exit__(self, *exc):
        with _pause_lock:
            _paused[0] -= 1
            if _paused[0] == 0 and _paused.pop():
                gc.enable()
        return False
