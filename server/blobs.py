"""Content-addressed blob store on disk: ``<root>/<sha[:2]>/<sha>``.

Writes go to a temporary file in the same folder, are fsynced, then renamed, so a crash never
leaves a torn blob under a valid name; reads verify the hash, so a damaged blob is an error, not
a silent wrong answer. Used by the server and, for cuts, by the worker processes (plain files,
no shared state).
"""
from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

from worker.atomic import atomic_write


class BlobError(RuntimeError):
    pass


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

    def put(self, data: bytes) -> str:
        sha = hashlib.sha256(data).hexdigest()
        dest = self.path(sha)
        if dest.is_file():
            return sha
        self._write(dest, data)
        return sha

    def put_file(self, src: Path, sha: str) -> str:
        """Move an already-hashed temporary file into the store (upload streaming)."""
        dest = self.path(sha)
        dest.parent.mkdir(parents=True, exist_ok=True)
        if dest.is_file():
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
        """A named temporary file inside the store (same filesystem, so put_file can rename)."""
        tmp = self.root / "tmp"
        tmp.mkdir(exist_ok=True)
        return tempfile.NamedTemporaryFile(dir=tmp, delete=False)

    def _write(self, dest: Path, data: bytes) -> None:
        atomic_write(dest, data)
