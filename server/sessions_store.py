"""The stored state of interactive sessions: a write-behind cache of the sessions whose streams
this process serves, per-session locks, and compare-and-set writes, owned by ``AppState``
(``st.sessions``) and used by the session routes and ``AppState.session_payload``.

Client messages and worker events are applied to the stored state by the protocol's own
``apply`` and ``apply_event`` (worker/protocol), and stored as their classes declare
(``storage``): "batched" ones change the cached copy, written at most FLUSH_S later (by the next
batch, the stream's idle timer, its end, a worker event or a restore); "rows" ones write rows of
their own (strokes, their undone flags) before they are forwarded and leave the state to the
same timer; any other ("state") is written, with everything before it, before it is forwarded.
A camera dragged at 60 Hz by eight designers is hundreds of messages a second, and a
transaction for each (reading, validating and rewriting the ~30 KB state) made the server the
bottleneck; rewriting the state on every stroke put 10-70 ms on it under load. A server crash
can lose at most FLUSH_S of camera moves (and a fit, which the replayed strokes redo); never a
stroke, a material or a save.

Several API processes may serve one session (a reconnect that lands on another process, two
tabs behind a load balancer). Each row carries a ``version``, bumped by every write, and a
process writes only over the version it read (compare-and-set); when another process wrote
first, it reads the row again and re-applies the changes it has not written yet on top, so
neither loses the other's: a camera one moved survives the light the other changed.

The store also keeps the bookkeeping of the streams this process serves (``attach`` /
``detach``): a session may have several streams at once (a reload, a second tab), which share
its one worker session and all receive its frames and events; the limits on open streams are
checked and a slot taken in one step. Each stream numbers its own messages; the store numbers
them in the session (``persist_batch``: a message whose seq another stream already used is given
the next one), so two tabs never refuse each other's input.
"""
from __future__ import annotations

import io
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

from sqlalchemy import select, update

from worker.protocol import (ClientMsg, EnvPreset, EnvironmentMsg, ErrorEvent, ObjectMsg, RecordStroke, Redo, RejectStroke,
                             SavedEvent, SessionState, StateError, StoreSave, Undo, apply, apply_event,
                             restore_state, worker_event)

from .db import Asset, MaterialDesign, Scene, Session, SessionSave, StrokeRow, now

FLUSH_S = 0.5            # the longest a batched change (camera, light, object move, fit) stays unwritten
CAS_TRIES = 20           # compare-and-set attempts before a write gives up (another process keeps winning)
# a design version's thumbnail: the session's last frame, shrunk to fit this box (pixels), as a
# JPEG of at most THUMB_MAX_BYTES (192×144 of the bunny studio frames: 4.1-4.6 KB at quality 80)
THUMB_BOX = (192, 144)
THUMB_MAX_BYTES = 32 * 1024


class StreamRefused(Exception):
    """A stream over the limits: close code, message, HTTP status."""

    def __init__(self, code: int, message: str, http: int):
        super().__init__(message)
        self.code, self.message, self.http = code, message, http


@dataclass
class SessionStreams:
    """The open streams of one session in this process. conns : stream -> the client it counts
    against (the session's owner, or the address of a viewer); pump : the task that fans the
    worker session's frames and events out to them (set by the stream that opened it); ready :
    set once that worker session is open (an asyncio.Event, made by the routes); failed : why it
    could not be opened; last_frame : (header dict, JPEG bytes) of the newest frame, for a
    stream that joins and for a saved version's thumbnail."""
    conns: dict = field(default_factory=dict)
    pump: object = None
    ready: object = None
    failed: str | None = None
    last_frame: tuple[dict, bytes] | None = None


class WriteConflict(RuntimeError):
    """A session's state could not be written: other processes kept writing it first."""


@dataclass
class _Entry:
    """A session's state as this process has it. base : the row's state at ``version``;
    state : base with ``pending`` applied (client messages and worker events not written yet,
    in order); since : time.monotonic() of the first of them (None: nothing unwritten)."""
    base: SessionState
    version: int
    state: SessionState
    pending: list = field(default_factory=list)
    since: float | None = None

    def copy(self) -> "_Entry":
        """A working copy: a transaction changes it, and it replaces the cached entry only once
        the transaction has committed (states are copy-on-write, so sharing them is safe)."""
        return _Entry(self.base, self.version, self.state, list(self.pending), self.since)


class _Lock:
    __slots__ = ("lock", "users")

    def __init__(self):
        self.lock = threading.Lock()
        self.users = 0            # threads holding or waiting for it


class SessionStore:
    """db : the sessionmaker (AppState.db); blobs : the BlobStore."""

    def __init__(self, db, blobs=None):
        self.db = db
        self.blobs = blobs          # for saved versions' thumbnails (None: none are stored)
        self._guard = threading.Lock()
        self._locks: dict[str, _Lock] = {}
        # sessions whose stream this process serves, from their first stored batch to their end
        self._entries: dict[str, _Entry] = {}
        # the streams this process serves, by session (attach/detach run on the event loop's
        # thread; the thumbnail's read of last_frame, on a worker thread, takes a reference)
        self._streams: dict[str, SessionStreams] = {}

    # -- streams ----------------------------------------------------------------------------------
    def attach(self, sid: str, conn: object, client: str, max_total: int, max_per_client: int
               ) -> tuple[SessionStreams, bool]:
        """Check the stream limits and register ``conn`` as a stream of ``sid`` in one step (no
        await between, so concurrent connects cannot all pass the check before any registers).
        Returns (the session's streams, whether this one opens its worker session: the first);
        raises StreamRefused over a limit (max_total streams in this process, max_per_client
        of one client)."""
        total = self.open_streams()
        if total >= max_total:
            raise StreamRefused(4503, f"the server is at its limit of {max_total} open session streams "
                                      f"({total} open, max_sessions); try again later", 503)
        mine = sum(c == client for ss in self._streams.values() for c in ss.conns.values())
        if mine >= max_per_client:
            raise StreamRefused(4429, f"this client ({client}) already has {mine} open session streams, the "
                                      f"limit is {max_per_client} (max_sessions_per_client); close one first", 429)
        ss = self._streams.get(sid)
        first = ss is None
        if first:
            ss = self._streams[sid] = SessionStreams()
        ss.conns[conn] = client
        return ss, first

    def detach(self, sid: str, conn: object) -> bool:
        """Unregister a stream; whether it was the session's last here (its worker session and
        cached state can go)."""
        ss = self._streams.get(sid)
        if ss is None or ss.conns.pop(conn, None) is None:
            return False
        if ss.conns:
            return False
        del self._streams[sid]
        return True

    def streams(self, sid: str) -> SessionStreams | None:
        return self._streams.get(sid)

    def is_streamed(self, sid: str) -> bool:
        return sid in self._streams

    def open_streams(self) -> int:
        return sum(len(ss.conns) for ss in self._streams.values())

    def keep_frame(self, sid: str, hdr: dict, jpeg: bytes) -> None:
        ss = self._streams.get(sid)
        if ss is not None:
            ss.last_frame = (hdr, jpeg)

    def thumbnail(self, sid: str) -> bytes | None:
        """A small JPEG of the session's newest frame (None: no stream here has had one), at
        most THUMB_BOX pixels and THUMB_MAX_BYTES."""
        from PIL import Image

        ss = self._streams.get(sid)
        frame = ss.last_frame if ss is not None else None
        if frame is None:
            return None
        im = Image.open(io.BytesIO(frame[1])).convert("RGB")
        im.thumbnail(THUMB_BOX, Image.Resampling.LANCZOS)
        for q in (80, 60, 40):
            buf = io.BytesIO()
            im.save(buf, "JPEG", quality=q, optimize=True)
            if buf.tell() <= THUMB_MAX_BYTES:
                return buf.getvalue()
        return None

    # -- locks ------------------------------------------------------------------------------------
    @contextmanager
    def lock(self, sid: str):
        """Read-modify-write of a session's state is serialised per session in this process
        (the client's messages and the worker's events arrive on different threads); across
        processes the row's version does it. A session's lock exists while a thread holds or
        waits for it, so the table stays as small as the sessions in use and a held lock is
        never dropped."""
        with self._guard:
            lk = self._locks.get(sid)
            if lk is None:
                lk = self._locks[sid] = _Lock()
            lk.users += 1
        try:
            with lk.lock:
                yield
        finally:
            with self._guard:
                lk.users -= 1
                if lk.users == 0 and self._locks.get(sid) is lk:
                    del self._locks[sid]

    def locks_in_use(self) -> int:
        with self._guard:
            return len(self._locks)

    # -- reading and writing the row --------------------------------------------------------------
    def _read(self, s, sid: str) -> _Entry | None:
        r = s.execute(select(Session.state, Session.version, Session.scene_id).where(Session.id == sid)
                      .with_for_update()).one_or_none()
        if r is None:
            return None
        state, _ = restore_state(r.state, s.get(Scene, r.scene_id).spec)
        return _Entry(base=state, version=r.version, state=state)

    @staticmethod
    def _replay(base: SessionState, pending: list) -> SessionState:
        state = base
        for m in pending:
            try:
                state = apply(state, m)[0] if isinstance(m, ClientMsg) else apply_event(state, m)[0]
            except StateError:
                pass                # no longer applies to the other process's state: it wins
        return state

    def _cas(self, s, sid: str, e: _Entry) -> bool:
        """Write ``e.state`` over the row's version ``e.version``; when another process wrote
        first, read its state and re-apply ``e.pending`` over it, and try again. Returns False
        when the row is gone."""
        for _ in range(CAS_TRIES):
            res = s.execute(update(Session).where(Session.id == sid, Session.version == e.version)
                            .values(state=e.state.model_dump(mode="json"), version=e.version + 1,
                                    last_active=now())
                            .execution_options(synchronize_session=False))
            if res.rowcount == 1:
                e.base, e.version, e.pending, e.since = e.state, e.version + 1, [], None
                return True
            fresh = self._read(s, sid)
            if fresh is None:
                return False
            e.base, e.version = fresh.base, fresh.version
            e.state = self._replay(fresh.base, e.pending)
        raise WriteConflict(f"session {sid}: its state changed {CAS_TRIES} times while it was being written")

    def _write_locked(self, sid: str) -> None:
        """Write a session's unsaved state (the caller holds ``lock(sid)``)."""
        e = self._entries.get(sid)
        if e is None or e.since is None:
            return
        w = e.copy()
        with self.db() as s, s.begin():
            written = self._cas(s, sid, w)
        if written:
            self._entries[sid] = w
        else:
            self._entries.pop(sid, None)

    def flush(self, sid: str) -> None:
        """Write what a session's stream has not written yet (before anything reads its row)."""
        with self.lock(sid):
            self._write_locked(sid)

    def forget(self, sid: str) -> None:
        """The stream ended: write its unsaved state and drop the copy."""
        with self.lock(sid):
            self._write_locked(sid)
            self._entries.pop(sid, None)

    def has_unsaved(self, sid: str) -> bool:
        e = self._entries.get(sid)
        return e is not None and e.since is not None

    def cached_state(self, sid: str) -> SessionState | None:
        """This process's copy of a streamed session's state (None: not streamed here)."""
        e = self._entries.get(sid)
        return None if e is None else e.state

    # -- client messages --------------------------------------------------------------------------
    def persist_batch(self, sid: str, msgs: list, renumber: bool = False) -> list[tuple[dict | None, dict | None]]:
        """Apply validated messages in order to the stored state and record them before the
        worker sees them, each as its class's ``storage`` says (module docstring): (error event,
        None) for one that cannot apply (nothing stored or forwarded), else (None, the message
        to forward, with the seq it has in the session). renumber : a message whose seq is not
        above the session's last one gets the next one (the stream checked that its seqs
        increase; another stream of the session used these), instead of being refused."""
        out = []
        with self.lock(sid):
            e = self._entries.get(sid)
            w = None if e is None else e.copy()
            if w is not None and all(m.storage != "state" for m in msgs):
                rows = any(m.storage == "rows" for m in msgs)
                # strokes, undo and redo are their rows (written now, in one transaction); the
                # state they leave is written like a camera move
                if rows:
                    with self.db() as s, s.begin():
                        out += [self._apply_one(s, sid, w, msg, renumber) for msg in msgs]
                else:
                    out += [self._apply_one(None, sid, w, msg, renumber) for msg in msgs]
                self._entries[sid] = w
                if w.since is not None and time.monotonic() - w.since >= FLUSH_S:
                    self._write_locked(sid)
                return out
            with self.db() as s, s.begin():
                if w is None:
                    w = self._read(s, sid)
                    if w is None:
                        raise LookupError(f"no session {sid!r}")
                for msg in msgs:
                    out.append(self._apply_one(s, sid, w, msg, renumber))
                if w.since is not None:
                    self._cas(s, sid, w)
            self._entries[sid] = w
        return out

    def _apply_one(self, s, sid: str, e: _Entry, msg, renumber: bool = False) -> tuple[dict | None, dict | None]:
        """One message against the entry's state: (error event, None), or (None, forwarded) with
        the entry's state advanced. s : the database session (None for a batch of batched
        messages only, which touch no other row)."""
        before = e.state
        if renumber and msg.seq <= before.last_seq:
            msg = msg.model_copy(update={"seq": before.last_seq + 1})
        if msg.seq <= before.last_seq:
            # refused before anything is stored: the worker would skip it (it treats such a seq
            # as already applied), so storing it would bring it back, unseen, on the next restore
            return ErrorEvent(seq=msg.seq, message=f"seq {msg.seq} is not above the last one, {before.last_seq}: "
                                                   "number messages on from the hello event's state.last_seq"
                              ).model_dump(), None
        if isinstance(msg, EnvironmentMsg) and msg.asset_id is not None:
            # an uploaded map (e.g. a capture): the stored file goes into the state as a preset
            a = s.get(Asset, msg.asset_id)
            if a is None or a.kind != "envmap":
                return ErrorEvent(seq=msg.seq, message=f"environment: {msg.asset_id!r} is not an uploaded "
                                                       "environment map").model_dump(), None
            msg = msg.model_copy(update={"asset_id": None, "preset": EnvPreset(
                label=a.filename, sha256=a.sha256, filename=a.filename, rotation_deg=0.0)})
        try:
            state, eff = apply(before, msg)
        except StateError as ex:
            return ErrorEvent(seq=msg.seq, message=str(ex)).model_dump(), None
        rows = _ROW_EFFECTS.get(type(eff))
        if rows is not None:
            rows(s, sid, before.epoch, msg, eff)
        if isinstance(msg, ObjectMsg):
            # the worker replays the picked object's own strokes (its epoch's rows)
            msg = msg.model_copy(update={"strokes": _epoch_strokes(s, sid, state.epoch)})
        e.state = state
        e.pending.append(msg)
        if e.since is None:
            e.since = time.monotonic()
        return None, msg.model_dump(mode="json")

    # -- worker events ----------------------------------------------------------------------------
    def apply_worker_event(self, sid: str, ev: dict) -> dict | None:
        """A worker event applied to the stored state (protocol/events.py): a fit result updates
        the session's material, a rejected stroke is never replayed, a save stores a material
        version (once per seq, even when a restarted worker runs it again). Returns the event
        for the client (None: nothing)."""
        wev = worker_event(ev)
        if wev is None:
            return ev
        if wev.storage == "rows":
            # rows of its own only (a rejected stroke's flag), no state: no lock, and nothing to
            # do for most (a stroke's event comes before its frame, which must not wait)
            store = _STORE_EFFECTS.get(type(wev.apply(None)))
            if store is None:
                return ev
            with self.db() as s, s.begin():
                out = store(self, s, sid, wev.apply(None))
            return ev if out is None else out
        with self.lock(sid):
            e = self._entries.get(sid)
            if wev.storage == "batched" and e is not None:
                e.state, _ = apply_event(e.state, wev)
                e.pending.append(wev)
                if e.since is None:
                    e.since = time.monotonic()
                return ev
            with self.db() as s, s.begin():
                w = e.copy() if e is not None else self._read(s, sid)
                if w is None:
                    return ev
                state, eff = apply_event(w.state, wev)
                store = _STORE_EFFECTS.get(type(eff))
                out = store(self, s, sid, eff) if store is not None else None
                w.state = state
                w.pending.append(wev)
                w.since = w.since or time.monotonic()
                self._cas(s, sid, w)
            if e is not None:                 # a session streamed here keeps its copy
                self._entries[sid] = w
        return ev if out is None else out


# -- what each effect stores besides the state -----------------------------------------------------


def _record_stroke(s, sid: str, epoch: int, msg, eff: RecordStroke) -> None:
    # a new stroke drops the redo stack
    for r in s.scalars(select(StrokeRow).where(StrokeRow.session_id == sid, StrokeRow.epoch == epoch,
                                               StrokeRow.undone.is_(True), StrokeRow.dropped.is_(False))):
        r.dropped = True
    s.add(StrokeRow(session_id=sid, epoch=epoch, seq=msg.seq, body=eff.stroke))
    s.flush()


def _undo_redo(s, sid: str, epoch: int, msg, eff) -> None:
    undo = isinstance(eff, Undo)
    q = select(StrokeRow).where(StrokeRow.session_id == sid, StrokeRow.epoch == epoch,
                                StrokeRow.dropped.is_(False), StrokeRow.rejected.is_(False),
                                StrokeRow.undone.is_(not undo))
    q = q.order_by(StrokeRow.seq.desc() if undo else StrokeRow.seq.asc())
    r = s.scalars(q.limit(1)).first()
    if r is not None:
        r.undone = undo
        s.flush()


def _epoch_strokes(s, sid: str, epoch: int) -> list[dict]:
    """The stroke records of one epoch a worker replays (as AppState.session_payload gives them)."""
    rows = s.scalars(select(StrokeRow).where(StrokeRow.session_id == sid, StrokeRow.epoch == epoch,
                                             StrokeRow.dropped.is_(False), StrokeRow.rejected.is_(False))
                     .order_by(StrokeRow.seq)).all()
    return [{**r.body, "seq": r.seq, "undone": r.undone} for r in rows]


# effect class -> handler(db session, sid, epoch before the message, message, effect)
_ROW_EFFECTS = {RecordStroke: _record_stroke, Undo: _undo_redo, Redo: _undo_redo}


def _reject_stroke(store: SessionStore, s, sid: str, eff: RejectStroke) -> None:
    for r in s.scalars(select(StrokeRow).where(StrokeRow.session_id == sid, StrokeRow.seq == eff.seq)):
        r.rejected = True


def _store_save(store: SessionStore, s, sid: str, eff: StoreSave) -> dict:
    """The design version of a save request (its pending save is dropped from the state by
    SaveRequest.apply, whatever this makes of it): the saved event, or an error event."""
    from .routes.materials import add_version

    seq = eff.seq
    done = s.scalars(select(SessionSave).where(SessionSave.session_id == sid, SessionSave.seq == seq)).first()
    if done is not None:                       # stored before the worker restarted
        d = s.get(MaterialDesign, done.design_id)
        return SavedEvent(seq=seq, material_id=d.id, version=done.version, name=d.name).model_dump()
    d = s.get(MaterialDesign, eff.material_id) if eff.material_id else None
    if eff.material_id and d is None:
        return ErrorEvent(seq=seq, message=f"save: no material {eff.material_id!r}", code=404).model_dump()
    if d is not None and d.archived:
        return ErrorEvent(seq=seq, message=f"save: material {d.id!r} is archived (409): restore it or save "
                                           "under a new name", code=409).model_dump()
    if d is None:
        scene_id = s.scalar(select(Session.scene_id).where(Session.id == sid))
        d = MaterialDesign(name=eff.name or f"{eff.object} design", scene_id=scene_id, object=eff.object)
        s.add(d)
        s.flush()
    # the frame the designer saw when saving: the version list shows it
    thumb = store.thumbnail(sid) if store.blobs is not None else None
    v = add_version(s, d, eff.material, note=f"saved from session {sid}", name=eff.name or "",
                    thumbnail_sha256=store.blobs.put(thumb) if thumb else None)
    s.flush()
    s.add(SessionSave(session_id=sid, seq=seq, design_id=d.id, version=v.version))
    return SavedEvent(seq=seq, material_id=d.id, version=v.version, name=d.name).model_dump()


# worker-event effect class -> handler(store, db session, sid, effect) -> the client's event or None
_STORE_EFFECTS = {RejectStroke: _reject_stroke, StoreSave: _store_save}
