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

Such a session is *shared* (its tabs see each other's changes, as two tabs on one process do):
each process serving a stream of it has a row in ``session_servers`` (``announce``), with a
heartbeat. While a session has more than one, every process writes each client message before
forwarding it, with a number the database makes unique (``session_log``, unique on session and
seq, written in the transaction that writes the state), and every process forwards the others'
logged messages to its worker session and its streams in seq order (``poll``, ``take_peers``),
so the worker sessions of all processes apply the same messages in the same order. A process
that joins waits (``ACK_WAIT_S`` at most) until the others have seen it (their row's ``peers``
names it): by then they have written what they held and log what they store, so nothing falls
between the state it starts from and the log. Alone on a session a process writes as above
(batched), and logs nothing.

The store also keeps the bookkeeping of the streams this process serves (``attach`` /
``detach``): a session may have several streams at once (a reload, a second tab), which share
its one worker session and all receive its frames and events; the limits on open streams are
checked and a slot taken in one step. Each stream numbers its own messages; the store numbers
them in the session (``persist_batch``: a message whose seq another stream already used is given
the next one), so two tabs never refuse each other's input.
"""
from __future__ import annotations

import datetime as dt
import io
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

from sqlalchemy import delete, select, update
from sqlalchemy.exc import IntegrityError

from worker.protocol import (MAX_REGION_STEPS, ClientMsg, Convert, EnvPreset, EnvironmentMsg, ErrorEvent, FitPaint,
                             NewMaterial, ObjectMsg, RecordStroke, Redo, RegionsChanged, RejectStroke, SavedEvent,
                             SessionState, StateError, StoreSave, Undo, apply, apply_event, restore_state,
                             worker_event)

from .db import (Asset, MaterialDesign, RegionStepRow, Scene, Session, SessionLogRow, SessionSave, SessionServer, StrokeRow,
                 new_id, now)

FLUSH_S = 0.5            # the longest a batched change (camera, light, object move, fit) stays unwritten
CAS_TRIES = 20           # compare-and-set attempts before a write gives up (another process keeps winning)
# a design version's thumbnail: the session's last frame, shrunk to fit this box (pixels), as a
# JPEG of at most THUMB_MAX_BYTES (192×144 of the bunny studio frames: 4.1-4.6 KB at quality 80)
THUMB_BOX = (192, 144)
THUMB_MAX_BYTES = 32 * 1024
# sessions shared across API processes (module docstring)
POLL_S = 0.2             # how often a process looks for the others' messages of the sessions it streams
HEARTBEAT_S = 2.0        # how often it says it still serves them
STALE_S = 10.0           # a process not heard of for this long serves them no more (it stopped or died)
ACK_WAIT_S = 3.0         # the longest a joining process waits for the others to see it
LOG_KEEP_S = 120.0       # logged messages older than this are deleted (every process has long forwarded them)


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
    order: object = None      # an asyncio.Lock: what goes to the worker session, in seq order


@dataclass
class _Share:
    """A session this process streams, as others may too. others : the other processes serving
    it (empty: alone, nothing is logged); hwm : the highest session seq this process's worker
    session has been given (its own and the others'); backlog : the others' messages read,
    in seq order, not yet forwarded (``take_peers``)."""
    others: frozenset = frozenset()
    hwm: int = -1
    backlog: list = field(default_factory=list)


class _Lost(Exception):
    """A shared write lost the race for the row's version or for a seq: start it again."""


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
        # sid -> an asyncio.Event set when the session's last stream here has ended it (routes)
        self.ending: dict[str, object] = {}
        # sessions shared across processes (module docstring): this process's name in
        # session_servers and session_log, and its sessions there
        self.origin = new_id()
        self._share: dict[str, _Share] = {}
        self._beat = 0.0                # time.monotonic() of the last heartbeat
        self._pruned = 0.0              # of the last deletion of old log rows

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

    def _cas(self, s, sid: str, e: _Entry, log: bool = False) -> bool:
        """Write ``e.state`` over the row's version ``e.version``; when another process wrote
        first, read its state and re-apply ``e.pending`` over it, and try again. Returns False
        when the row is gone. log : also log the pending client messages (a session another
        process has just joined: what this one held, for it to forward)."""
        for _ in range(CAS_TRIES):
            res = s.execute(update(Session).where(Session.id == sid, Session.version == e.version)
                            .values(state=e.state.model_dump(mode="json"), version=e.version + 1,
                                    last_active=now())
                            .execution_options(synchronize_session=False))
            if res.rowcount == 1:
                if log:
                    self._log(s, sid, [m.model_dump(mode="json") for m in e.pending if isinstance(m, ClientMsg)])
                e.base, e.version, e.pending, e.since = e.state, e.version + 1, [], None
                return True
            fresh = self._read(s, sid)
            if fresh is None:
                return False
            e.base, e.version = fresh.base, fresh.version
            e.state = self._replay(fresh.base, e.pending)
        raise WriteConflict(f"session {sid}: its state changed {CAS_TRIES} times while it was being written")

    def _write_locked(self, sid: str, log: bool = False) -> None:
        """Write a session's unsaved state (the caller holds ``lock(sid)``)."""
        e = self._entries.get(sid)
        if e is None or e.since is None:
            return
        w = e.copy()
        with self.db() as s, s.begin():
            written = self._cas(s, sid, w, log)
        if written:
            self._entries[sid] = w
        else:
            self._entries.pop(sid, None)

    def flush(self, sid: str) -> None:
        """Write what a session's stream has not written yet (before anything reads its row)."""
        with self.lock(sid):
            self._write_locked(sid)

    def forget(self, sid: str) -> None:
        """The stream ended: write its unsaved state and drop the copy; this process no longer
        serves the session."""
        with self.lock(sid):
            self._write_locked(sid)
            self._entries.pop(sid, None)
            if self._share.pop(sid, None) is not None:
                with self.db() as s, s.begin():
                    s.execute(delete(SessionServer).where(SessionServer.session_id == sid,
                                                          SessionServer.origin == self.origin))

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
            sh = self._share.get(sid)
            if sh is not None and sh.others:
                return self._persist_shared(sid, msgs, sh)
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

    def _persist_shared(self, sid: str, msgs: list, sh: _Share) -> list:
        """``persist_batch`` of a session other processes serve too (the caller holds the lock):
        in one transaction, read the row (the others' changes), number the messages on from its
        last seq, apply and log them, and write the state over the version read; a lost race
        (the version, or a seq another process logged first) starts again from the new row. The
        others' messages logged since this process's worker last got one go to ``sh.backlog``
        first: they come before these (their seqs are lower)."""
        for _ in range(CAS_TRIES):
            e = self._entries.get(sid)
            try:
                with self.db() as s, s.begin():
                    fresh = self._read(s, sid)
                    if fresh is None:
                        raise LookupError(f"no session {sid!r}")
                    pend = list(e.pending) if e is not None else []       # worker events (fits) unwritten
                    w = _Entry(base=fresh.base, version=fresh.version, state=self._replay(fresh.base, pend),
                               pending=pend, since=(e.since if e is not None else None))
                    peers = self._logged(s, sid, sh.hwm)
                    out = [self._apply_one(s, sid, w, m, True) for m in msgs]
                    self._log(s, sid, [fwd for err, fwd in out if err is None])
                    res = s.execute(update(Session).where(Session.id == sid, Session.version == w.version)
                                    .values(state=w.state.model_dump(mode="json"), version=w.version + 1,
                                            last_active=now())
                                    .execution_options(synchronize_session=False))
                    if res.rowcount != 1:
                        raise _Lost()
                    s.flush()
            except (_Lost, IntegrityError):
                continue
            self._entries[sid] = _Entry(base=w.state, version=w.version + 1, state=w.state)
            sh.backlog += peers
            sh.hwm = max([sh.hwm, w.state.last_seq] + [p["seq"] for p in peers])
            return out
        raise WriteConflict(f"session {sid}: its state changed {CAS_TRIES} times while it was being written")

    def _log(self, s, sid: str, fwds: list[dict]) -> None:
        for f in fwds:
            s.add(SessionLogRow(session_id=sid, seq=f["seq"], origin=self.origin, body=f))
        if fwds:
            s.flush()               # a seq another process logged first fails here (IntegrityError)

    def _logged(self, s, sid: str, after: int) -> list[dict]:
        """The other processes' logged messages of ``sid`` with a seq above ``after``, in order."""
        rows = s.scalars(select(SessionLogRow.body).where(
            SessionLogRow.session_id == sid, SessionLogRow.seq > after, SessionLogRow.origin != self.origin)
            .order_by(SessionLogRow.seq)).all()
        return list(rows)

    # -- sessions shared across processes ---------------------------------------------------------
    def announce(self, sid: str) -> int:
        """This process serves streams of ``sid`` from now on (its first stream here, before
        the state it starts from is read): say so in session_servers, and wait (ACK_WAIT_S at
        most) until every other process serving it has seen this one. Returns how many others
        serve it."""
        t = now()
        with self.db() as s, s.begin():
            row = s.get(SessionServer, (sid, self.origin))
            if row is None:
                s.add(SessionServer(session_id=sid, origin=self.origin, seen=t, peers=[]))
            else:
                row.seen, row.peers = t, []
        deadline = time.monotonic() + ACK_WAIT_S
        while True:
            others = self._present(sid)
            if all(self.origin in peers for peers in others.values()) or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        with self.lock(sid):
            self._share[sid] = _Share(others=frozenset(others))
        return len(others)

    def started_at(self, sid: str, seq: int) -> None:
        """The worker session of ``sid`` starts from the stored state whose last seq is ``seq``."""
        with self.lock(sid):
            sh = self._share.get(sid)
            if sh is not None:
                sh.hwm = max(sh.hwm, seq)

    def _present(self, sid: str | None = None) -> dict:
        """The other processes serving ``sid`` (None: any session this one serves) and heard of
        within STALE_S: {origin: its peers} for one session, {sid: {origin: peers}} for all."""
        cutoff = now() - dt.timedelta(seconds=STALE_S)
        mine = select(SessionServer.session_id).where(SessionServer.origin == self.origin)
        q = select(SessionServer.session_id, SessionServer.origin, SessionServer.peers).where(
            SessionServer.origin != self.origin, SessionServer.seen > cutoff)
        q = q.where(SessionServer.session_id == sid) if sid is not None else q.where(SessionServer.session_id.in_(mine))
        out: dict = {}
        with self.db() as s:
            for r in s.execute(q):
                out.setdefault(r.session_id, {})[r.origin] = list(r.peers or [])
        return out.get(sid, {}) if sid is not None else out

    def poll(self) -> list[str]:
        """One look at the other processes (every POLL_S, from the routes' share loop): which
        sessions streamed here others serve too. A session another process has just joined is
        written now, with the client messages held (logged, for it to forward), before this
        one's row names it (the acknowledgement the joiner waits for); the heartbeat goes out
        every HEARTBEAT_S. Returns the shared sessions (for ``take_peers``)."""
        if not self._share:
            return []
        present = self._present()
        changed = False
        for sid in list(self._share):
            others = frozenset(present.get(sid, {}))
            with self.lock(sid):
                sh = self._share.get(sid)
                if sh is None or others == sh.others:
                    continue
                if others - sh.others:
                    self._write_locked(sid, log=True)
                sh.others = others
                changed = True
        t = time.monotonic()
        if changed or t - self._beat >= HEARTBEAT_S:
            self._beat = t
            with self.db() as s, s.begin():
                s.execute(update(SessionServer).where(SessionServer.origin == self.origin)
                          .values(seen=now()).execution_options(synchronize_session=False))
                for sid, sh in list(self._share.items()):
                    if changed:
                        s.execute(update(SessionServer).where(SessionServer.session_id == sid,
                                                              SessionServer.origin == self.origin)
                                  .values(peers=sorted(sh.others)).execution_options(synchronize_session=False))
        if t - self._pruned >= LOG_KEEP_S / 4:
            self._pruned = t
            with self.db() as s, s.begin():
                s.execute(delete(SessionLogRow).where(SessionLogRow.created < now() - dt.timedelta(seconds=LOG_KEEP_S)))
        return [sid for sid, sh in list(self._share.items()) if sh.others]

    def take_peers(self, sid: str, read: bool = True) -> list[dict]:
        """The other processes' messages of a shared session that this process's worker has not
        had yet, in seq order: the backlog ``persist_batch`` read, then (read) those logged
        since. Forward them before anything else of the session. After ``persist_batch``,
        read=False: what the others logged since has higher seqs than the batch, and goes after it."""
        sh = self._share.get(sid)
        if sh is None or not (read or sh.backlog):
            return []            # the common case after a batch (the caller orders them): no lock
        with self.lock(sid):
            sh = self._share.get(sid)
            if sh is None:
                return []
            if read and sh.others:
                with self.db() as s:
                    new = self._logged(s, sid, sh.hwm)
                if new:
                    sh.backlog += new
                    sh.hwm = max(sh.hwm, new[-1]["seq"])
            out, sh.backlog = sh.backlog, []
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
            rows(s, sid, before, state, msg, eff)
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
        for attempt in range(2):
            try:
                return self._apply_worker_event(sid, ev, wev)
            except IntegrityError:
                # another process stored the same event first: a session several processes
                # serve runs each save in each one's worker; the one stored is answered
                if attempt:
                    raise

    def _apply_worker_event(self, sid: str, ev: dict, wev) -> dict | None:
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


def _record_stroke(s, sid: str, before: SessionState, after: SessionState, msg, eff: RecordStroke) -> None:
    # a new stroke drops the redo stack: its strokes', and the region steps undone
    for r in s.scalars(select(StrokeRow).where(StrokeRow.session_id == sid, StrokeRow.epoch == before.epoch,
                                               StrokeRow.undone.is_(True), StrokeRow.dropped.is_(False))):
        r.dropped = True
    _drop_undone_steps(s, sid)
    s.add(StrokeRow(session_id=sid, epoch=before.epoch, seq=msg.seq, body=eff.stroke))
    s.flush()


def _undo_redo(s, sid: str, before: SessionState, after: SessionState, msg, eff) -> None:
    """The worker's undo (redo): the epoch's last stroke (first undone one) when there is one,
    else the edited object's last region step (first undone one), as worker/jobs/runtime.py
    ``_undo_redo`` decides: the same rows, so a reopened session has the same stacks."""
    undo = isinstance(eff, Undo)
    q = select(StrokeRow).where(StrokeRow.session_id == sid, StrokeRow.epoch == before.epoch,
                                StrokeRow.dropped.is_(False), StrokeRow.rejected.is_(False),
                                StrokeRow.undone.is_(not undo))
    q = q.order_by(StrokeRow.seq.desc() if undo else StrokeRow.seq.asc())
    r = s.scalars(q.limit(1)).first()
    if r is not None:
        r.undone = undo
        s.flush()
        return
    q = select(RegionStepRow).where(RegionStepRow.session_id == sid, RegionStepRow.dropped.is_(False),
                                    RegionStepRow.undone.is_(not undo))
    step = s.scalars(q.order_by(RegionStepRow.seq.desc() if undo else RegionStepRow.seq.asc()).limit(1)).first()
    if step is not None and step.object == before.object:
        step.undone = undo
        s.flush()


def _drop_undone_steps(s, sid: str) -> None:
    for r in s.scalars(select(RegionStepRow).where(RegionStepRow.session_id == sid, RegionStepRow.undone.is_(True),
                                                   RegionStepRow.dropped.is_(False))):
        r.dropped = True


def _region_step(s, sid: str, before: SessionState, after: SessionState, msg, eff: RegionsChanged) -> None:
    """A rename, erase, merge or region material (``eff.before`` set; painting or stopping a
    region is no step): its row, the steps undone dropped, and only the last MAX_REGION_STEPS
    kept, as the worker's stack keeps them."""
    if eff.before is None:
        return
    _drop_undone_steps(s, sid)
    s.add(RegionStepRow(session_id=sid, seq=msg.seq, object=eff.object, before=eff.before.model_dump(mode="json"),
                        after=after.materials[after.objects.index(eff.object)].model_dump(mode="json"),
                        region_before=eff.region_before, region_after=after.region))
    s.flush()
    old = s.scalars(select(RegionStepRow).where(RegionStepRow.session_id == sid, RegionStepRow.dropped.is_(False))
                    .order_by(RegionStepRow.seq.desc()).offset(MAX_REGION_STEPS)).all()
    for r in old:
        r.dropped = True


def _forget_steps(s, sid: str, before: SessionState, after: SessionState, msg, eff) -> None:
    """The object's material was set otherwise (a material message, the paint designer, a
    conversion): undoing a region step would bring back a material from before it."""
    for r in s.scalars(select(RegionStepRow).where(RegionStepRow.session_id == sid, RegionStepRow.object == eff.object,
                                                   RegionStepRow.dropped.is_(False))):
        r.dropped = True


def region_steps(s, sid: str) -> list[dict]:
    """The session's region steps a worker restores (runtime.py ``_restore_region_steps``), in order."""
    rows = s.scalars(select(RegionStepRow).where(RegionStepRow.session_id == sid, RegionStepRow.dropped.is_(False))
                     .order_by(RegionStepRow.seq)).all()
    return [{"seq": r.seq, "object": r.object, "before": r.before, "after": r.after, "region_before": r.region_before,
             "region_after": r.region_after, "undone": r.undone} for r in rows]


def _epoch_strokes(s, sid: str, epoch: int) -> list[dict]:
    """The stroke records of one epoch a worker replays (as AppState.session_payload gives them)."""
    rows = s.scalars(select(StrokeRow).where(StrokeRow.session_id == sid, StrokeRow.epoch == epoch,
                                             StrokeRow.dropped.is_(False), StrokeRow.rejected.is_(False))
                     .order_by(StrokeRow.seq)).all()
    return [{**r.body, "seq": r.seq, "undone": r.undone} for r in rows]


# effect class -> handler(db session, sid, state before the message, state after, message, effect)
_ROW_EFFECTS = {RecordStroke: _record_stroke, Undo: _undo_redo, Redo: _undo_redo, RegionsChanged: _region_step,
                NewMaterial: _forget_steps, FitPaint: _forget_steps, Convert: _forget_steps}


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
