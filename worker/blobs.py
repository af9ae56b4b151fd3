"""Content-addressed blob store on disk: ``<root>/<sha[:2]>/<sha>``.

Writes go to a temporary file in the same folder, are fsynced, then renamed, so a crash never
leaves a torn blob under a valid name; reads verify the hash, so a damaged blob is an error, not
a silent wrong answer. The server stores uploads here and the workers read and write
precomputed parts (plain files, no shared state).

Beyond one machine every node must reach the same blobs: a shared directory (NFS and the like)
works as it is. An S3-compatible store would implement the same five methods (``put``,
``put_file``, ``get``, ``has``, ``verified_path`` — the last one by downloading to a local cache
first), since nothing else in Glint touches the folder layout.

``PartStore`` keeps a precomputation's parts (renderers/base.py) in the blob store under their
content keys: ``<root>/keys/<key>`` holds the sha256 of the part's blob. Several data directories
on one machine (services, test servers) may share a folder of parts (``shared``): a part one of
them computed is copied, not computed again, by the others.
"""
from __future__ import annotations

import hashlib
import logging
import os
import tempfile
from pathlib import Path

from .atomic import atomic_write
from .errors import GlintError

log = logging.getLogger("glint.blobs")


class BlobError(GlintError):
    """A blob that is missing or damaged on disk (never served)."""

    status = 500


class BlobStore:
    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def path(self, sha: str) -> Path:
        if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
            raise BlobError(f"not a SHA-256 digest: {sha!r}")
        return self.root / sha[:2] / sha

    def has(self, sha: str) -> bool:
        return self.path(sha).is_file()

    def _intact(self, dest: Path, sha: str) -> bool:
        """An existing blob under this name whose content still has this hash (a damaged one is
        replaced by the next put of the same content)."""
        if not dest.is_file():
            return False
        try:
            self.verified_path(sha)
            return True
        except BlobError:
            return False

    def put(self, data: bytes) -> str:
        sha = hashlib.sha256(data).hexdigest()
        dest = self.path(sha)
        if self._intact(dest, sha):
            return sha
        self._write(dest, data)
        return sha

    def put_file(self, src: Path, sha: str) -> str:
        """Move an already-hashed temporary file into the store (upload streaming)."""
        dest = self.path(sha)
        dest.parent.mkdir(parents=True, exist_ok=True)
        if self._intact(dest, sha):
            Path(src).unlink(missing_ok=True)
            return sha
        with open(src, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(src, dest)
        return sha

    def get(self, sha: str) -> bytes:
        p = self.path(sha)
        if not p.is_file():
            raise BlobError(f"blob {sha[:12]}… is missing from the store")
        data = p.read_bytes()
        if hashlib.sha256(data).hexdigest() != sha:
            raise BlobError(f"blob {sha[:12]}… is damaged (hash mismatch)")
        return data

    def verified_path(self, sha: str) -> Path:
        """The blob's path after checking its hash (for readers that want a file)."""
        p = self.path(sha)
        h = hashlib.sha256()
        try:
            with open(p, "rb") as f:
                for chunk in iter(lambda: f.read(1 << 20), b""):
                    h.update(chunk)
        except FileNotFoundError:
            raise BlobError(f"blob {sha[:12]}… is missing from the store") from None
        if h.hexdigest() != sha:
            raise BlobError(f"blob {sha[:12]}… is damaged (hash mismatch)")
        return p

    def temp_file(self):
        """A named temporary file inside the store (same filesystem, so put_file can rename),
        named ``up-<host>-<pid>-…`` so that a later start can tell whose it was (sweep_temp)."""
        tmp = self.root / "tmp"
        tmp.mkdir(exist_ok=True)
        return tempfile.NamedTemporaryFile(dir=tmp, delete=False, prefix=f"up-{_HOST}-{os.getpid()}-")

    def sweep_temp(self, max_age_s: float = 3600.0) -> tuple[int, int]:
        """Delete partial uploads a crash left in ``<root>/tmp``: those of a process of this host
        that no longer runs, and any older than ``max_age_s`` (another host's, or unnamed). A
        live process's recent file is kept (several servers may share the store). Returns
        (files deleted, bytes freed)."""
        return sweep_folder(self.root / "tmp", max_age_s)

    def _write(self, dest: Path, data: bytes) -> None:
        atomic_write(dest, data)


_HOST = "".join(c if c.isalnum() else "_" for c in (os.uname().nodename if hasattr(os, "uname") else "host"))[:40] or "host"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _owner_dead(name: str) -> bool:
    """Whether a temp file named up-<host>-<pid>-… belongs to a dead process of this host."""
    parts = name.split("-")
    if len(parts) >= 4 and parts[0] == "up" and parts[1] == _HOST and parts[2].isdigit():
        return not _pid_alive(int(parts[2]))
    return False


def sweep_folder(folder: Path, max_age_s: float) -> tuple[int, int]:
    """sweep_temp for one folder: files and sub-folders (by their newest file's age)."""
    import shutil
    import time

    n = freed = 0
    if not folder.is_dir():
        return 0, 0
    now = time.time()
    for p in folder.iterdir():
        try:
            if p.is_dir() and not p.is_symlink():
                files = [f for f in p.rglob("*") if f.is_file()]
                newest = max([f.stat().st_mtime for f in files] + [p.stat().st_mtime])
                if now - newest > max_age_s:
                    size = sum(f.stat().st_size for f in files)
                    shutil.rmtree(p)
                    n, freed = n + 1, freed + size
            elif _owner_dead(p.name) or now - p.lstat().st_mtime > max_age_s:
                size = p.lstat().st_size
                p.unlink()
                n, freed = n + 1, freed + size
        except FileNotFoundError:
            continue                     # deleted meanwhile by its owner
    return n, freed


class PartStore:
    """renderers.base.ArtifactStore over a BlobStore: part bytes are blobs, ``keys/<key>`` names
    their digest (written atomically after the blob, so a key never points at nothing)."""

    def __init__(self, blobs: BlobStore, shared: str | Path | None = None):
        """shared : optional folder of parts shared with other data directories on this machine
        (``<shared>/<key>``, the part's bytes; read when a key is missing here, written after a
        put). Parts are content-keyed (worker/keys.py: every input and the format's version), so
        any store's bytes for a key are the same part."""
        self.blobs = blobs
        self.root = blobs.root / "keys"
        self.shared = Path(shared) if shared else None

    def _key_path(self, key: str) -> Path:
        if not key or any(c not in "0123456789abcdef" for c in key):
            raise BlobError(f"not a content key: {key!r}")
        return self.root / key

    def sha(self, key: str) -> str | None:
        p = self._key_path(key)
        if p.is_file():
            return p.read_text().strip()
        return self._from_shared(key)

    def _from_shared(self, key: str) -> str | None:
        """Adopt the shared folder's bytes for ``key`` into this store (its blob and key written
        as by put); None when the folder has no such part."""
        if self.shared is None:
            return None
        try:
            data = (self.shared / key).read_bytes()
        except FileNotFoundError:
            return None
        sha = self.blobs.put(data)
        atomic_write(self._key_path(key), sha.encode())
        return sha

    def get(self, key: str) -> bytes | None:
        sha = self.sha(key)
        return None if sha is None else self.blobs.get(sha)

    def put(self, key: str, data: bytes) -> str:
        """Store data as the part ``key``; returns its blob's SHA-256."""
        sha = self.blobs.put(data)
        atomic_write(self._key_path(key), sha.encode())
        if self.shared is not None and not (self.shared / key).is_file():
            try:
                atomic_write(self.shared / key, data)
            except OSError as e:         # the shared folder only saves time: this store has the part
                log.warning("part %s not written to the shared folder %s: %s", key[:12], self.shared, e)
        return sha

    def adopt(self, key: str, sha: str) -> None:
        """Name an existing blob as the part under ``key``."""
        if not self.blobs.has(sha):
            raise BlobError(f"blob {sha[:12]}… is missing from the store")
        atomic_write(self._key_path(key), sha.encode())
