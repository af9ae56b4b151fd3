"""What the routes share: settings, the database, the blob store, the worker pool, the
sessions' stored state (server/sessions_store.py), and the payloads the workers need (a scene
with its files and precomputed parts; a session with its state and strokes)."""
from __future__ import annotations

import logging

from sqlalchemy import select

from worker.blobs import BlobStore

from .config import Settings
from .db import (
    Asset,
    Capture,
    Precomputation,
    Publication,
    Scene,
    Session,
    StrokeRow,
    make_sessionmaker,
)
from .sessions_store import SessionStore, region_steps
from .workers import WorkerPool, make_pool

log = logging.getLogger("glint")


class NotFound(LookupError):
    pass


class Conflict(RuntimeError):
    pass


class AppState:
    def __init__(self, settings: Settings, pool: WorkerPool | None = None):
        self.settings = settings
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        self.db = make_sessionmaker(settings.db_url)
        self.blobs = BlobStore(settings.data_dir / "blobs")
        # interactive sessions' stored state: the streams' write-behind cache and their locks
        self.sessions = SessionStore(self.db, self.blobs)
        self._sweep_temp()
        from .services.bundle_files import relink_markers

        if relink_markers(self):
            log.info("published bundle files linked for static serving")
        self.pool = pool or make_pool(settings, restore=self.session_payload)
        self.precompute_tasks: dict[str, object] = {}
        self.demo: dict = {"state": "off"}       # the demo scene's preparation, for the studio
        self._fail_interrupted()

    def _sweep_temp(self) -> None:
        """Partial uploads and worker scratch that crashed processes left behind (kept: a live
        process's, and anything recent of another host's; worker/blobs.py sweep_temp)."""
        from worker.blobs import sweep_folder

        age = self.settings.stale_temp_seconds
        n, freed = self.blobs.sweep_temp(age)
        n2, freed2 = sweep_folder(self.settings.data_dir / "tmp", age)
        if n + n2:
            log.info("deleted %d leftover temporary file(s) or folder(s), %.1f MiB", n + n2, (freed + freed2) / 2**20)

    def _fail_interrupted(self) -> None:
        """Jobs of an earlier server process cannot finish: say so instead of showing them
        running forever (a new request starts them again; parts already stored are reused)."""
        with self.db() as s, s.begin():
            for p in s.scalars(select(Precomputation).where(Precomputation.status.in_(("queued", "running")))):
                p.status = "failed"
                p.message = "interrupted by a server restart; start the precomputation again (finished parts are kept)"
            for p in s.scalars(select(Publication).where(Publication.build.is_not(None))):
                if (p.build or {}).get("status") in ("queued", "running"):
                    p.build = {**p.build, "status": "failed", "message": "interrupted by a server restart; publish "
                               "again (frames already made are kept)"}
            for c in s.scalars(select(Capture).where(Capture.status.in_(("queued", "running")))):
                c.status = "failed"
                c.message = "interrupted by a server restart; upload the capture again"

    # -- payloads -------------------------------------------------------------------------------
    def scene_payload(self, s, scene_id: str, need_parts: bool = True) -> dict:
        sc = s.get(Scene, scene_id)
        if sc is None:
            raise NotFound(f"no scene {scene_id!r}")
        # distinct refs, looked up in bulk (a query per object was 20 000 for a 20 000-object scene)
        refs = list(dict.fromkeys([sc.spec["environment"]["map"]] + [o["mesh"] for o in sc.spec["objects"]]))
        found = {}
        for k in range(0, len(refs), 500):
            found.update({a.id: a for a in s.scalars(select(Asset).where(Asset.id.in_(refs[k:k + 500])))})
        files = {}
        for r in refs:
            a = found.get(r)
            if a is None:
                raise NotFound(f"scene {scene_id!r} refers to a missing asset {r!r}")
            files[r] = {"sha256": a.sha256, "filename": a.filename}
        kind = sc.spec.get("renderer", "cuts")
        pre = self.latest_precomputation(s, scene_id, done=True, kind=kind)
        if need_parts and pre is None:
            raise Conflict(f"scene {scene_id!r} has no finished precomputation: POST /v1/scenes/{scene_id}/precompute first")
        parts = None
        if pre is not None:
            parts = pre.parts or ({"legacy-cuts": pre.cuts_sha256} if pre.cuts_sha256 else None)
        # a renderer's options are the scene file's field of its name (e.g. "gi", "paint")
        return {"scene_id": sc.id, "spec": sc.spec, "files": files, "renderer": kind,
                "options": dict(sc.spec.get(kind) or {}), "parts": parts}

    @staticmethod
    def latest_precomputation(s, scene_id: str, done: bool = False, kind: str | None = None) -> Precomputation | None:
        q = select(Precomputation).where(Precomputation.scene_id == scene_id)
        if done:
            q = q.where(Precomputation.status == "done")
        if kind is not None:
            q = q.where(Precomputation.kind == kind)
        return s.scalars(q.order_by(Precomputation.created.desc()).limit(1)).first()

    def session_payload(self, sid: str) -> dict:
        """Everything a worker needs to (re)build a session: scene, state, strokes (those of the
        current epoch that are neither dropped from the redo stack nor rejected), region steps
        (sessions_store.region_steps: undo and redo cover them after a reopen too)."""
        self.sessions.flush(sid)         # what the stream holds but has not written yet
        with self.db() as s:
            row = s.get(Session, sid)
            if row is None:
                raise NotFound(f"no session {sid!r}")
            st = dict(row.state or {})
            strokes = s.scalars(select(StrokeRow).where(
                StrokeRow.session_id == sid, StrokeRow.epoch == st.get("epoch", 0), StrokeRow.dropped.is_(False),
                StrokeRow.rejected.is_(False)).order_by(StrokeRow.seq)).all()
            return {"scene": self.scene_payload(s, row.scene_id), "state": st,
                    "strokes": [{**r.body, "seq": r.seq, "undone": r.undone} for r in strokes],
                    "region_steps": region_steps(s, sid),
                    "ack": int(st.get("last_seq", -1))}
