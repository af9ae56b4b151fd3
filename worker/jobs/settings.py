"""What a worker process needs to know, passed explicitly by the pool (the worker reads no
environment variables)."""
from __future__ import annotations

from pydantic import BaseModel


class WorkerSettings(BaseModel):
    """What a worker process needs to know, passed explicitly by the pool.

    blob_root : the blob store. tmp_dir : this worker's scratch folder (removed on exit).
    threads : the jobs' ray-tracing threads (0: one per core); session steps set their own
    OpenMP threads (Priority.kernel_threads). kernels : "native", "numpy"
    or None (native when built). scenes : loaded scenes kept (LRU). nice : niceness added to
    the process (the API server's messages and frames go first under load).
    preview_min_vertices : a precomputation of a scene with at least this many vertices first
    draws a preview (renderers/cuts/preview.py). shared_parts : a folder of parts shared with
    other data directories (blobs.PartStore), or None."""
    blob_root: str
    tmp_dir: str
    threads: int = 0
    kernels: str | None = None
    nice: int = 0
    scenes: int = 4
    preview_min_vertices: int = 8000
    shared_parts: str | None = None
