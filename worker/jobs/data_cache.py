"""Loaded scenes, their renderers' data and decoded environment maps, shared by a worker's jobs
and sessions."""
from __future__ import annotations

import os
import shutil
import threading
from collections import OrderedDict
from pathlib import Path

from .ipc import JobError
from .settings import WorkerSettings


class DataCache:
    """Loaded scenes and their renderers' data in this worker, shared by its jobs and sessions
    (a few, least recently used first out), and decoded environment maps."""

    def __init__(self, settings: WorkerSettings):
        from worker.blobs import BlobStore, PartStore

        self.settings = settings
        self.blobs = BlobStore(settings.blob_root)
        # precomputed parts may come from a folder other data directories share; published frames
        # (same store, their own keys) are this directory's own: a build renders what it lacks
        self.parts = PartStore(self.blobs, settings.shared_parts)
        self.frames = PartStore(self.blobs)
        self.tmp = Path(settings.tmp_dir)
        self.tmp.mkdir(parents=True, exist_ok=True)
        self._scenes: OrderedDict = OrderedDict()
        self._data: OrderedDict = OrderedDict()
        self._maps: OrderedDict = OrderedDict()
        self._lock = threading.RLock()

    def linked(self, f: dict) -> Path:
        """A verified blob under a name with its original extension (readers dispatch on it)."""
        src = self.blobs.verified_path(f["sha256"])
        link = self.tmp / (f["sha256"] + Path(f["filename"]).suffix.lower())
        if not link.exists():
            try:
                os.symlink(src, link)
            except FileExistsError:
                pass
        return link

    def scene(self, p: dict):
        from worker.scene import LoadedScene, SceneError, parse_scene

        with self._lock:
            key = p["scene_id"]
            if key in self._scenes:
                self._scenes.move_to_end(key)
                return self._scenes[key]

            def resolve(ref: str) -> Path:
                f = p["files"].get(ref)
                if f is None:
                    raise SceneError(f"{ref!r} is not an uploaded asset")
                return self.linked(f)

            sc = LoadedScene(parse_scene(p["spec"]), self.tmp, resolver=resolve)
            self._scenes[key] = sc
            while len(self._scenes) > self.settings.scenes:
                self._scenes.popitem(last=False)
            return sc

    def renderer(self, p: dict, kind: str | None = None):
        """A new renderer for a scene payload (cheap: the heavy data is shared)."""
        from worker.native.kernels import kernels
        from worker.renderers import get, load

        if not p.get("parts"):
            raise JobError("the scene has no finished precomputation; start one first", 409)
        own = p.get("renderer") or "cuts"
        kind = kind or own
        options = (p.get("options") or {}) if kind == own else {}
        cls, pre = get(kind)
        sc = self.scene(p)
        if "legacy-cuts" in p["parts"] and kind == "cuts":
            # release 0.3 stored the cut blob without a key: adopt it under its content key
            (part,) = pre.parts(sc, options)
            if self.parts.sha(part.key) is None:
                self.parts.adopt(part.key, p["parts"]["legacy-cuts"])
            p = {**p, "parts": {part.key: p["parts"]["legacy-cuts"]}}
        with self._lock:
            key = (p["scene_id"], kind, tuple(sorted(p["parts"].items())))
            data = self._data.get(key)
            if data is None:
                data = load(pre, sc, self.parts, options)
                self._data[key] = data
                while len(self._data) > self.settings.scenes:
                    self._data.popitem(last=False)
            else:
                self._data.move_to_end(key)
        return cls(sc, data, kernels=kernels(self.settings.kernels))

    def envmap(self, f):
        """An environment map blob (verified), decoded once (a few kept)."""
        from worker.envmap import load_envmap

        sha = f["sha256"] if isinstance(f, dict) else f.sha256
        name = f["filename"] if isinstance(f, dict) else f.filename
        with self._lock:
            if sha not in self._maps:
                if len(self._maps) >= 4:
                    self._maps.popitem(last=False)
                self._maps[sha] = load_envmap(self.linked({"sha256": sha, "filename": name}))
            return self._maps[sha]

    def close(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)
