"""Artifact stores for precomputed parts (renderers.base.ArtifactStore): a folder of files named
by content key, for the CLI and tests. The service keeps parts in its blob store instead."""
from __future__ import annotations

from pathlib import Path

from .atomic import atomic_write


class DirStore:
    """Parts as files ``<root>/<kind>/<key>``, written atomically (a crash never leaves a torn
    part under a valid name). A part that fails to load is the loader's to report."""

    def __init__(self, root: str | Path, kind: str):
        self.root = Path(root) / kind

    def path(self, key: str) -> Path:
        if not key or any(c not in "0123456789abcdef" for c in key):
            raise ValueError(f"not a content key: {key!r}")
        return self.root / key

    def get(self, key: str) -> bytes | None:
        p = self.path(key)
        return p.read_bytes() if p.is_file() else None

    def put(self, key: str, data: bytes) -> None:
        atomic_write(self.path(key), data)

    def discard(self, key: str) -> None:
        self.path(key).unlink(missing_ok=True)
