"""The files of published bundles (frames, manifests): which blobs are public, and a bounded
in-memory cache of them.

Only blobs a finished build registered are served (``register``: ``<blobs>/published/<name>``
per file, a hard link to its blob), so the public endpoint cannot be used to read any other
blob of the store (uploaded photos, meshes) by its digest. Because the links hold the files'
bytes under their public names, that folder is a static site's file tree: a static server in
front of the service (nginx, docker/nginx.conf; a CDN's origin) serves
``/v1/bundle-files/<name>`` straight from it with sendfile, and no request reaches Python
(docs/guides/publishing.md, "Serving at scale"). The cache holds the most recently
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

NAME = re.compile(r"^([0-9a-f]{64})\.(avif|jpg|json|glb)$")
MEDIA = {"avif": "image/avif", "jpg": "image/jpeg", "json": "application/json", "glb": "model/gltf-binary"}
CACHE_BYTES = 256 * 2**20


def _marker_dir(st) -> Path:
    return Path(st.blobs.root) / "published"


def register(st, names) -> None:
    """Make files public (after their blobs are stored): ``published/<name>`` becomes a hard link
    to the blob (a copy where the filesystem has no hard links; an older empty marker, or a
    link to a blob since rewritten, is replaced). The folder is fsynced once at the end, so the
    names survive a crash after the build is recorded as done. Blocking."""
    import shutil

    d = _marker_dir(st)
    d.mkdir(parents=True, exist_ok=True)
    for n in names:
        m = NAME.match(n)
        if not m:
            raise ValueError(f"not a bundle file name: {n!r}")
        p, blob = d / n, st.blobs.path(m.group(1))
        try:
            if p.exists() and os.path.samefile(p, blob):
                continue
        except FileNotFoundError:
            raise ValueError(f"bundle file {n!r}: its blob is missing") from None
        tmp = d / f".{n}.{os.getpid()}.tmp"
        tmp.unlink(missing_ok=True)
        try:
            os.link(blob, tmp)
        except OSError:                      # no hard links here: the bytes, copied
            shutil.copyfile(blob, tmp)
        # readable by a static server's own user (the blob store writes 0600): the file is public
        os.chmod(tmp, 0o644)
        os.replace(tmp, p)
    fd = os.open(d, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def relink_markers(st) -> int:
    """Replace the empty markers that older versions made in ``published/`` with links to
    their blobs, so a static server in front serves those bundles too (at start-up; a marker
    whose blob is gone is left, and still answered 404 by the service). Returns how many."""
    d = _marker_dir(st)
    if not d.is_dir():
        return 0
    names = []
    for p in d.iterdir():
        m = NAME.match(p.name)
        try:
            if m and p.stat().st_size == 0 and st.blobs.path(m.group(1)).stat().st_size > 0:
                names.append(p.name)
        except FileNotFoundError:
            continue
    if names:
        register(st, names)
    return len(names)


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
