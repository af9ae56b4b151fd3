"""The files of published bundles (frames, manifests): which blobs are public, and a bounded
in-memory cache of them.

Only blobs a finished build registered are served (``register``: an empty marker file
``<blobs>/published/<name>`` per file), so the public endpoint cannot be used to read any other
blob of the store (uploaded photos, meshes) by its digest. The cache holds the most recently
served files up to ``CACHE_BYTES`` (least recently used out first): a busy product page's
frames are served from memory, and the server's memory stays bounded however many are
published.
"""
from __future__ import annotations

import os
import re
import threading
from collections import OrderedDict
from pathlib import Path

NAME = re.compile(r"^([0-9a-f]{64})\.(webp|jpg|json)$")
MEDIA = {"webp": "image/webp", "jpg": "image/jpeg", "json": "application/json"}
CACHE_BYTES = 256 * 2**20


def _marker_dir(st) -> Path:
    return Path(st.blobs.root) / "published"


def register(st, names) -> None:
    """Make files public (after their blobs are stored). The markers' folder is fsynced once
    at the end, so they survive a crash after the build is recorded as done. Blocking."""
    d = _marker_dir(st)
    d.mkdir(parents=True, exist_ok=True)
    for n in names:
        if not NAME.match(n):
            raise ValueError(f"not a bundle file name: {n!r}")
        p = d / n
        if not p.exists():
            p.touch()
    fd = os.open(d, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class FileCache:
    """name -> bytes, at most ``limit`` bytes in all, least recently used out first."""

    def __init__(self, limit: int = CACHE_BYTES):
        self.limit = limit
        self.size = 0
        self._d: OrderedDict[str, bytes] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, name: str) -> bytes | None:
        with self._lock:
            b = self._d.get(name)
            if b is not None:
                self._d.move_to_end(name)
            return b

    def put(self, name: str, data: bytes) -> None:
        if len(data) > self.limit // 8:          # one huge file must not empty the cache
            return
        with self._lock:
            if name in self._d:
                return
            self._d[name] = data
            self.size += len(data)
            while self.size > self.limit:
                _, old = self._d.popitem(last=False)
                self.size -= len(old)


CACHE = FileCache()


def load(st, name: str) -> bytes | None:
    """The bytes of a public bundle file (verified against its digest), or None when the name
    is not one. Blocking on a cache miss (reads the blob store)."""
    m = NAME.match(name)
    if m is None:
        return None
    data = CACHE.get(name)
    if data is not None:
        return data
    if not (_marker_dir(st) / name).is_file():
        return None
    data = st.blobs.get(m.group(1))
    CACHE.put(name, data)
    return data
