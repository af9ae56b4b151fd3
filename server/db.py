"""Metadata in a relational database (SQLite by default, PostgreSQL by URL) through SQLAlchemy 2.

Nothing is overwritten: materials are rows of versions, strokes are appended (undo and redo flip
a flag), deletions archive. Blobs (meshes, maps, cuts, images) live in the blob store and are
referenced here by SHA-256.
"""
from __future__ import annotations

import datetime as dt
import secrets
import sqlite3
import threading
import uuid

from sqlalchemy import (JSON, Boolean, DateTime, Float, ForeignKey, Integer, String, UniqueConstraint, false,
                        create_engine, event, select)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, sessionmaker


def now() -> dt.datetime:
    return dt.datetime.now(dt.timezone.utc)


def new_id() -> str:
    return uuid.uuid4().hex[:16]


def new_secret() -> str:
    return secrets.token_urlsafe(24)


class Base(DeclarativeBase):
    type_annotation_map = {dict: JSON, list: JSON}


class Asset(Base):
    __tablename__ = "assets"
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    kind: Mapped[str] = mapped_column(String(16))            # mesh | envmap | image
    filename: Mapped[str] = mapped_column(String(255))
    sha256: Mapped[str] = mapped_column(String(64), index=True)
    size: Mapped[int] = mapped_column(Integer)
    meta: Mapped[dict] = mapped_column(JSON, default=dict)
    created: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now)


class Scene(Base):
    __tablename__ = "scenes"
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    name: Mapped[str] = mapped_column(String(255), default="")
    spec: Mapped[dict] = mapped_column(JSON)                  # scene file v1, asset ids for files
    created: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now)


class Precomputation(Base):
    __tablename__ = "precomputations"
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    scene_id: Mapped[str] = mapped_column(ForeignKey("scenes.id"), index=True)
    kind: Mapped[str] = mapped_column(String(16), default="cuts", server_default="cuts")   # the renderer
    status: Mapped[str] = mapped_column(String(16), default="queued")   # queued running done failed
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    message: Mapped[str] = mapped_column(String(1000), default="")
    # content key -> blob sha256 of each part (worker/renderers/base.py); release 0.3 stored
    # the one cut blob in cuts_sha256 (the worker adopts it under its key on first use)
    parts: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    cuts_sha256: Mapped[str | None] = mapped_column(String(64), nullable=True)
    stats: Mapped[dict] = mapped_column(JSON, default=dict)
    created: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now)
    updated: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now, onupdate=now)


class MaterialDesign(Base):
    __tablename__ = "materials"
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    name: Mapped[str] = mapped_column(String(255))
    scene_id: Mapped[str | None] = mapped_column(String(32), nullable=True)
    object: Mapped[str | None] = mapped_column(String(255), nullable=True)
    archived: Mapped[bool] = mapped_column(Boolean, default=False)
    created: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now)


class MaterialVersion(Base):
    __tablename__ = "material_versions"
    __table_args__ = (UniqueConstraint("design_id", "version"),)
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    design_id: Mapped[str] = mapped_column(ForeignKey("materials.id"), index=True)
    version: Mapped[int] = mapped_column(Integer)
    body: Mapped[dict] = mapped_column(JSON)                  # a scene-file material
    note: Mapped[str] = mapped_column(String(1000), default="")
    # the designer's label for this version ("" for none); the design's name is the design's
    name: Mapped[str] = mapped_column(String(255), default="", server_default="")
    # a small JPEG of the frame it was saved from, in the blob store (None: saved over REST)
    thumbnail_sha256: Mapped[str | None] = mapped_column(String(64), nullable=True)
    created: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now)


class Session(Base):
    __tablename__ = "sessions"
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    scene_id: Mapped[str] = mapped_column(ForeignKey("scenes.id"), index=True)
    token_sha256: Mapped[str] = mapped_column(String(64))
    state: Mapped[dict] = mapped_column(JSON, default=dict)   # worker/protocol/state.py SessionState
    # bumped by every write of ``state`` (compare-and-set: server/sessions_store.py), so API
    # processes sharing the database never overwrite a state newer than the one they read
    version: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    closed: Mapped[bool] = mapped_column(Boolean, default=False)
    # who opened it (API token id, or the client address of anonymous and viewer sessions), for limits
    client: Mapped[str] = mapped_column(String(64), default="", server_default="")
    last_active: Mapped[dt.datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    created: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now)
    updated: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now, onupdate=now)


class StrokeRow(Base):
    __tablename__ = "strokes"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    session_id: Mapped[str] = mapped_column(ForeignKey("sessions.id"), index=True)
    epoch: Mapped[int] = mapped_column(Integer, default=0)    # bumps when the base material changes
    seq: Mapped[int] = mapped_column(Integer)
    body: Mapped[dict] = mapped_column(JSON)                  # the stroke, with its view's camera
    undone: Mapped[bool] = mapped_column(Boolean, default=False)
    dropped: Mapped[bool] = mapped_column(Boolean, default=False)   # left on the redo stack when a new stroke came
    # the worker could not apply it (e.g. the object is off screen): never replayed
    rejected: Mapped[bool] = mapped_column(Boolean, default=False, server_default=false())
    created: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now)


class RegionStepRow(Base):
    """A step on an object's painted regions (rename, erase, merge, a region's material): the
    object's material before and after it, and the region painted before and after, so that undo
    and redo cover it after the session is reopened (worker/jobs/runtime.py region steps). Like
    strokes, undo and redo flip ``undone``; a new edit drops the steps undone (``dropped``)."""
    __tablename__ = "region_steps"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    session_id: Mapped[str] = mapped_column(ForeignKey("sessions.id"), index=True)
    seq: Mapped[int] = mapped_column(Integer)
    object: Mapped[str] = mapped_column(String(200))
    before: Mapped[dict] = mapped_column(JSON)
    after: Mapped[dict] = mapped_column(JSON)
    region_before: Mapped[str | None] = mapped_column(String(100), nullable=True)
    region_after: Mapped[str | None] = mapped_column(String(100), nullable=True)
    undone: Mapped[bool] = mapped_column(Boolean, default=False)
    dropped: Mapped[bool] = mapped_column(Boolean, default=False)
    created: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now)


class SessionServer(Base):
    """An API process serving streams of a session (server/sessions_store.py, sessions shared
    across processes): ``origin`` names the process, ``seen`` is its last heartbeat, ``peers``
    the other processes it knows serve the session too (its acknowledgement that it logs every
    message it stores, so a joining process may start)."""
    __tablename__ = "session_servers"
    session_id: Mapped[str] = mapped_column(ForeignKey("sessions.id"), primary_key=True)
    origin: Mapped[str] = mapped_column(String(32), primary_key=True)
    seen: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now)
    peers: Mapped[list] = mapped_column(JSON, default=list)


class SessionLogRow(Base):
    """A client message as stored (with its session seq) by a process serving a session that
    other processes serve too: they forward it to their worker sessions and their streams. The
    seq is unique per session, so two processes can never give two messages one number."""
    __tablename__ = "session_log"
    __table_args__ = (UniqueConstraint("session_id", "seq"),)
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    session_id: Mapped[str] = mapped_column(ForeignKey("sessions.id"), index=True)
    seq: Mapped[int] = mapped_column(Integer)
    origin: Mapped[str] = mapped_column(String(32))
    body: Mapped[dict] = mapped_column(JSON)
    created: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now, index=True)


class SessionSave(Base):
    """A session's save, once stored: (session, seq) is unique, so a save re-run after a worker
    restart stores one version, and its client still gets ``saved``."""
    __tablename__ = "session_saves"
    __table_args__ = (UniqueConstraint("session_id", "seq"),)
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    session_id: Mapped[str] = mapped_column(ForeignKey("sessions.id"), index=True)
    seq: Mapped[int] = mapped_column(Integer)
    design_id: Mapped[str] = mapped_column(ForeignKey("materials.id"))
    version: Mapped[int] = mapped_column(Integer)
    created: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now)


class Capture(Base):
    """A lighting capture: the uploaded zip (a blob) processed by a job into an envmap asset."""
    __tablename__ = "captures"
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    status: Mapped[str] = mapped_column(String(16), default="queued")    # queued running done failed
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    message: Mapped[str] = mapped_column(String(1000), default="")
    zip_sha256: Mapped[str] = mapped_column(String(64))
    asset_id: Mapped[str | None] = mapped_column(ForeignKey("assets.id"), nullable=True)
    preview_sha256: Mapped[str | None] = mapped_column(String(64), nullable=True)
    stats: Mapped[dict] = mapped_column(JSON, default=dict)
    created: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now)
    updated: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now, onupdate=now)


class Publication(Base):
    """A set of material designs published for the shopper viewer (read-only, public)."""
    __tablename__ = "publications"
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    name: Mapped[str] = mapped_column(String(255))
    scene_id: Mapped[str] = mapped_column(ForeignKey("scenes.id"))
    object: Mapped[str] = mapped_column(String(255))
    variants: Mapped[list] = mapped_column(JSON)        # [{"label", "material_id", "version", "material"}]
    environments: Mapped[list] = mapped_column(JSON)    # [{"label", "asset_id", "rotation_deg"}]
    # the shopper viewer may open a live (streaming, free camera) session; else only the bundle
    live: Mapped[bool] = mapped_column(Boolean, default=False, server_default=false())
    bundle: Mapped[dict | None] = mapped_column(JSON, nullable=True)   # the bundle options
    # the latest build: {"id", "status", "progress", "message", "stats", "manifest_sha256" (the
    # last finished build's manifest, served while a rebuild runs)}
    build: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    created: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now)


class ApiToken(Base):
    __tablename__ = "api_tokens"
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    name: Mapped[str] = mapped_column(String(255))
    token_sha256: Mapped[str] = mapped_column(String(64), unique=True)
    revoked: Mapped[bool] = mapped_column(Boolean, default=False)
    created: Mapped[dt.datetime] = mapped_column(DateTime(timezone=True), default=now)


# One writer at a time in this process, queued here rather than in SQLite. SQLite lets one
# connection write; another that tries gets SQLITE_BUSY and its busy handler sleeps 1, 2, 5, 10,
# ... up to 100 ms between retries, so under load (eight sessions' strokes and state writes) a
# write could sleep tens of ms after the lock was free: 70-85 ms on a stroke's row.
# Writers of other processes (the CLI) still meet the busy timeout.
_WRITE_LOCK = threading.RLock()
_READS = ("SELECT", "PRAGMA", "EXPLAIN")


class _WriterCursor(sqlite3.Cursor):
    """Takes the process's write lock at a connection's first statement that writes."""

    def execute(self, sql, *args):
        self.connection._writing(sql)
        return super().execute(sql, *args)

    def executemany(self, sql, *args):
        self.connection._writing(sql)
        return super().executemany(sql, *args)


class _WriterConnection(sqlite3.Connection):
    """An SQLite connection that holds ``_WRITE_LOCK`` from its first write to its commit or
    rollback (the transaction SQLite would hold its own write lock for)."""
    holds = False

    def cursor(self, factory=_WriterCursor):
        return super().cursor(factory)

    def _writing(self, sql: str) -> None:
        if not self.holds and not sql.lstrip()[:7].upper().startswith(_READS):
            # past the timeout SQLite's own busy handling decides, as before
            self.holds = _WRITE_LOCK.acquire(timeout=30)

    def _done(self) -> None:
        if self.holds:
            self.holds = False
            try:
                _WRITE_LOCK.release()
            except RuntimeError:         # closed by another thread (a collected connection)
                pass

    def commit(self):
        try:
            return super().commit()
        finally:
            self._done()

    def rollback(self):
        try:
            return super().rollback()
        finally:
            self._done()

    def close(self):
        try:
            return super().close()
        finally:
            self._done()


def make_engine(url: str):
    """SQLAlchemy engine. SQLite gets WAL and a busy timeout so the server's threads and the CLI
    can share the file, and its writers in this process queue on a lock (``_WriterConnection``);
    PostgreSQL a pool that checks connections before use."""
    kw = {}
    if url.startswith("sqlite"):
        kw["connect_args"] = {"check_same_thread": False, "timeout": 30, "factory": _WriterConnection}
    else:
        kw["pool_pre_ping"] = True
    # JSON columns in pieces: one json.loads/dumps of a 20 000-object scene spec held the GIL,
    # and so stalled the event loop, for ~100 ms (server/jsonchunks.py)
    from . import jsonchunks

    engine = create_engine(url, json_serializer=jsonchunks.dumps, json_deserializer=jsonchunks.loads, **kw)
    if url.startswith("sqlite"):
        @event.listens_for(engine, "connect")
        def _pragmas(conn, _):
            cur = conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.close()
    return engine


def make_sessionmaker(url: str, upgrade: bool = True):
    """Session factory on an up-to-date schema: Alembic migrations (server/migrations) run first,
    so a database made by an earlier release is upgraded in place (``glint db upgrade``)."""
    engine = make_engine(url)
    if upgrade:
        from .migrate import upgrade as _upgrade

        _upgrade(engine)
    return sessionmaker(engine, expire_on_commit=False)


def token_hash(token: str) -> str:
    import hashlib

    return hashlib.sha256(token.encode()).hexdigest()


def create_api_token(Session_, name: str) -> str:
    """Store a new API token (hashed); returns the token, shown once."""
    token = "glint_" + secrets.token_urlsafe(32)
    with Session_() as s, s.begin():
        s.add(ApiToken(name=name, token_sha256=token_hash(token)))
    return token


def latest_version(s, design_id: str) -> MaterialVersion | None:
    return s.scalars(select(MaterialVersion).where(MaterialVersion.design_id == design_id)
                     .order_by(MaterialVersion.version.desc()).limit(1)).first()
