"""Interactive sessions: created over REST (id and secret token), streamed over a WebSocket
(DESIGN.md §5). Every client message is validated and applied to the stored state by the same
``apply`` the worker renders with (worker/jobs/state.py), persisted in batches
(``persist_batch``: camera, light and object moves at most 0.5 s later, anything else before
it is forwarded; a fit's material, derived from the stored strokes, also at most 0.5 s later),
then forwarded to the worker holding the session, so a worker crash loses
nothing: the pool re-opens the session from here.

The stream's first message authenticates it: ``{"type": "auth", "token": …}`` (a token in the
URL, ``?token=``, is still accepted but is kept out of the access log). Streams are bounded per
client and in total (a slot reserved in one step as the stream opens), and closed when idle. A
malformed message gets an error event (not JSON, not a valid message, a seq not above the last
one) or closes the stream with its code (``receive_json``: 1003 binary, 1009 too big, 4400 too
deeply nested; 4403 for any malformed auth message); nothing of it is stored.
"""
from __future__ import annotations

import asyncio
import datetime as dt
import hmac
import json
import logging
import re
import threading
import time

from fastapi import APIRouter, Header, HTTPException, Query, Request, WebSocket, WebSocketDisconnect
from fastapi.concurrency import run_in_threadpool
from pydantic import ValidationError
from sqlalchemy import delete, select

from worker.jobs.state import (EnvPreset, ErrorEvent, HelloEvent, SavedEvent, SessionState, StateError, apply,
                               client_msg, encode_frame, new_state, restore_state)
from worker.memory import trim_malloc
from worker.models import parse_material

from ..db import Asset, MaterialDesign, Scene, Session, SessionSave, StrokeRow, new_secret, now, token_hash
from ..deps import DB, Client, State, check_host, check_origin, client_key
from ..schemas import SessionCreate, SessionOut
from ..state import Conflict, NotFound
from .materials import add_version

router = APIRouter(prefix="/v1/sessions", tags=["sessions"])
log = logging.getLogger("glint")
AUTH_SECONDS = 10.0      # a stream must authenticate within this
MAX_BATCH = 256          # client messages stored in one transaction at most
MAX_PENDING = 4096       # client messages waiting to be stored before the stream is refused
# resident memory a frame costs its worker per pixel of the camera: measured with the bunny at
# 1920×1080, an anti-aliased still (4 samples a pixel: primary hits, shading, tone mapping,
# JPEG): the worker's peak grew from 176 to 988 MiB, ~410 bytes a pixel; so the default
# max_frame_pixels (2560×1600) is ~1.7 GB, and 8192×8192 would be ~27 GB
FRAME_BYTES_PER_PIXEL = 410


def check_frame_size(settings, camera: dict | None) -> None:
    """Refuse (422) a session camera of more than ``max_frame_pixels`` (width × height), before
    any worker draws it. camera : a Camera dict (width, height in pixels), or None."""
    if not camera:
        return
    w, h = int(camera.get("width", 640)), int(camera.get("height", 480))
    if w * h > settings.max_frame_pixels:
        raise HTTPException(422, f"camera: {w}×{h} = {w * h} pixels is over this server's limit of "
                                 f"{settings.max_frame_pixels} pixels a frame (max_frame_pixels; a frame "
                                 f"costs ~{FRAME_BYTES_PER_PIXEL} bytes a pixel, ~{w * h * FRAME_BYTES_PER_PIXEL >> 20} "
                                 "MiB for this one)")


class _ClientUtf8Error(logging.Filter):
    """uvicorn closes a text frame that is not UTF-8 with 1007, as it should, but logs the
    client's mistake with a traceback, as if the server had failed: one line is enough."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.exc_info and str(record.msg).startswith("Invalid UTF-8 sequence received from client"):
            record.exc_info = None
            record.levelno, record.levelname = logging.INFO, "INFO"
            record.msg = "a client sent a text frame that is not UTF-8: closed with 1007"
        return True


if not any(isinstance(f, _ClientUtf8Error) for f in logging.getLogger("uvicorn.error").filters):
    logging.getLogger("uvicorn.error").addFilter(_ClientUtf8Error())


def _stream_url(sid: str) -> str:
    return f"/v1/sessions/{sid}/stream"


def _strokes(db, row: Session) -> list[dict]:
    rows = db.scalars(select(StrokeRow).where(StrokeRow.session_id == row.id).order_by(StrokeRow.id))
    return [{"seq": r.seq, "epoch": r.epoch, "undone": r.undone, "dropped": r.dropped, "rejected": r.rejected,
             **r.body} for r in rows]


@router.post("", response_model=SessionOut, status_code=201)
def create_session(req: SessionCreate, request: Request, st: State, db: DB, client: Client):
    sc = db.get(Scene, req.scene_id)
    if sc is None:
        raise HTTPException(404, f"no scene {req.scene_id!r}")
    try:
        st.scene_payload(db, sc.id)
    except Conflict as e:
        raise HTTPException(409, str(e)) from None
    except NotFound as e:
        raise HTTPException(404, str(e)) from None
    camera = req.camera.model_dump(mode="json") if req.camera else None
    check_frame_size(st.settings, camera or sc.spec.get("camera"))
    try:
        state = new_state(sc.spec, req.object, camera)
    except StateError as e:
        raise HTTPException(422, str(e)) from None
    token = new_secret()
    row = Session(scene_id=sc.id, token_sha256=token_hash(token), state=state.model_dump(mode="json"),
                  client=client_key(client, request))
    db.add(row)
    db.commit()
    return SessionOut(id=row.id, token=token, scene_id=sc.id, stream=_stream_url(row.id), state=row.state)


def _authorised(row: Session | None, token: str | None) -> bool:
    return row is not None and token is not None and hmac.compare_digest(row.token_sha256, token_hash(token))


@router.get("/{sid}", response_model=SessionOut)
def get_session(sid: str, st: State, db: DB, x_session_token: str | None = Header(None)):
    row = db.get(Session, sid)
    if row is None:
        raise HTTPException(404, f"no session {sid!r}")
    if not _authorised(row, x_session_token):
        raise HTTPException(403, "wrong or missing session token (X-Session-Token header)")
    if has_unsaved(sid):
        flush_session(st, sid)
        db.refresh(row)
    return SessionOut(id=row.id, scene_id=row.scene_id, stream=_stream_url(sid), state=row.state,
                      strokes=_strokes(db, row), closed=row.closed,
                      worker_pid=st.pool.worker_of(sid) if hasattr(st.pool, "worker_of") else None)


@router.delete("/{sid}", status_code=204)
def close_session(sid: str, st: State, db: DB, x_session_token: str | None = Header(None)):
    row = db.get(Session, sid)
    if not _authorised(row, x_session_token):
        raise HTTPException(404 if row is None else 403, "no such session or wrong token")
    row.closed = True
    db.commit()
    st.pool.close_session(sid)


# -- persistence of client messages ---------------------------------------------------------------
_locks: dict[str, threading.Lock] = {}
_locks_guard = threading.Lock()
# the state of each session whose stream this process serves: (SessionState, monotonic time of
# its first change not yet written, or None); read and written under _lock(sid)
_states: dict[str, tuple[SessionState, float | None]] = {}
EPHEMERAL = frozenset({"view", "light", "move", "display"})
# messages whose lasting effect is a row of their own (strokes, their undone flags): the row is
# written before the message is forwarded, the session's state (only its last seq changes)
# like a camera move
ROWS_ONLY = frozenset({"stroke", "undo", "redo"})
FLUSH_S = 0.5            # the longest a camera, light or object move stays unwritten


def _lock(sid: str) -> threading.Lock:
    """Read-modify-write of a session's state is serialised per session (the client's messages
    and the worker's events arrive on different threads); the row is also locked FOR UPDATE
    where the database supports it (PostgreSQL)."""
    with _locks_guard:
        lk = _locks.get(sid)
        if lk is None:
            if len(_locks) > 10_000:
                _locks.clear()
            lk = _locks[sid] = threading.Lock()
        return lk


def _row(s, sid: str) -> Session | None:
    return s.get(Session, sid, with_for_update=True)


def _load_state(s, row: Session) -> SessionState:
    state, _ = restore_state(row.state, s.get(Scene, row.scene_id).spec)
    return state


def persist_batch(st, sid: str, msgs: list) -> list[tuple[dict | None, dict | None]]:
    """Apply validated messages in order to the stored state and record them before the worker
    sees them: (error event, None) for one that cannot apply (nothing stored or forwarded), else
    (None, the message to forward).

    Issue 9: a camera dragged at 60 Hz by eight designers is hundreds of messages a second, and a
    transaction for each (reading, validating and rewriting the state, ~30 KB with a fitted
    srbf) made the server the bottleneck. So a batch is one transaction, and the state of a
    session with an open stream is kept here (``_states``): a batch of view, light, move and
    display messages only (EPHEMERAL) changes that copy and is written at most FLUSH_S later
    (by the next batch, the stream's idle timer, its end, a worker event or a restore). A batch
    that also holds strokes, undo or redo (ROWS_ONLY) writes their rows in one transaction
    before they are forwarded, and leaves the state to the same timer: rewriting it put 10-70 ms
    on every stroke under load. Any other message is written, with everything before it, before
    it is forwarded. A server crash can lose at most FLUSH_S of camera moves (and a fit, which
    the replayed strokes redo); never a stroke, a material or a save."""
    out = []
    with _lock(sid):
        cached = _states.get(sid)
        if cached is not None and all(m.type in EPHEMERAL or m.type in ROWS_ONLY for m in msgs):
            state, since = cached
            if any(m.type in ROWS_ONLY for m in msgs):
                # strokes, undo and redo are their rows (written now, in one transaction);
                # the state they leave is the state before them
                with st.db() as s, s.begin():
                    for msg in msgs:
                        err, fwd, state = _apply_one(s, sid, state, msg)
                        out.append((err, fwd))
            else:
                for msg in msgs:
                    err, fwd, state = _apply_one(None, sid, state, msg)
                    out.append((err, fwd))
            since = since if since is not None else time.monotonic()
            _states[sid] = (state, since)
            if time.monotonic() - since >= FLUSH_S:
                _write_locked(st, sid)
            return out
        with st.db() as s, s.begin():
            row = _row(s, sid)
            state = cached[0] if cached is not None else _load_state(s, row)
            for msg in msgs:
                err, fwd, state = _apply_one(s, sid, state, msg)
                out.append((err, fwd))
            row.state = state.model_dump(mode="json")
            row.last_active = now()
        _states[sid] = (state, None)
    return out


def _write_locked(st, sid: str) -> None:
    """Write a session's unsaved state (the caller holds ``_lock(sid)``)."""
    cached = _states.get(sid)
    if cached is None or cached[1] is None:
        return
    with st.db() as s, s.begin():
        row = _row(s, sid)
        if row is not None:
            row.state = cached[0].model_dump(mode="json")
            row.last_active = now()
    _states[sid] = (cached[0], None)


def flush_session(st, sid: str) -> None:
    """Write what a session's stream has not written yet (before anything reads its row)."""
    with _lock(sid):
        _write_locked(st, sid)


def forget_session(st, sid: str) -> None:
    """The stream ended: write its unsaved state and drop the copy."""
    with _lock(sid):
        _write_locked(st, sid)
        _states.pop(sid, None)


def has_unsaved(sid: str) -> bool:
    c = _states.get(sid)
    return c is not None and c[1] is not None


def _apply_one(s, sid: str, before: SessionState, msg):
    """One message against the state: (error event, None, before) or (None, forwarded, after).
    s : the database session (None for EPHEMERAL messages, which touch no other row)."""
    if msg.seq <= before.last_seq:
        # refused before anything is stored: the worker would skip it (it treats such a seq as
        # already applied), so storing it would bring it back, unseen, on the next restore
        return ErrorEvent(seq=msg.seq, message=f"seq {msg.seq} is not above the last one, {before.last_seq}: "
                                               "number messages on from the hello event's state.last_seq"
                          ).model_dump(), None, before
    if msg.type == "environment" and msg.asset_id is not None:
        # an uploaded map (e.g. a capture): the stored file goes into the state as a preset
        a = s.get(Asset, msg.asset_id)
        if a is None or a.kind != "envmap":
            return ErrorEvent(seq=msg.seq, message=f"environment: {msg.asset_id!r} is not an uploaded "
                                                   "environment map").model_dump(), None, before
        msg = msg.model_copy(update={"asset_id": None, "preset": EnvPreset(
            label=a.filename, sha256=a.sha256, filename=a.filename, rotation_deg=0.0)})
    try:
        state, eff = apply(before, msg)
    except StateError as e:
        return ErrorEvent(seq=msg.seq, message=str(e)).model_dump(), None, before
    epoch = before.epoch
    if eff.kind == "stroke":
        # a new stroke drops the redo stack
        for r in s.scalars(select(StrokeRow).where(StrokeRow.session_id == sid, StrokeRow.epoch == epoch,
                                                   StrokeRow.undone.is_(True), StrokeRow.dropped.is_(False))):
            r.dropped = True
        s.add(StrokeRow(session_id=sid, epoch=epoch, seq=msg.seq, body=eff.stroke))
        s.flush()
    elif eff.kind in ("undo", "redo"):
        q = select(StrokeRow).where(StrokeRow.session_id == sid, StrokeRow.epoch == epoch,
                                    StrokeRow.dropped.is_(False), StrokeRow.rejected.is_(False),
                                    StrokeRow.undone.is_(eff.kind == "redo"))
        q = q.order_by(StrokeRow.seq.desc() if eff.kind == "undo" else StrokeRow.seq.asc())
        r = s.scalars(q.limit(1)).first()
        if r is not None:
            r.undone = eff.kind == "undo"
            s.flush()
    return None, msg.model_dump(mode="json"), state


def on_worker_event(st, sid: str, ev: dict) -> dict | None:
    """Events that change what is stored: a fit result updates the session's material, a
    rejected stroke is never replayed, a save stores a material version (once per seq, even when
    a restarted worker runs it again). Returns the event for the client (None: nothing)."""
    t = ev.get("type")
    if t == "fit" and "material" in ev:
        # a fit is derived from the stored strokes (a restore replays them and fits again), so
        # with the stream's copy of the state here it is written like a camera move, at most
        # FLUSH_S later: the stroke's frame, which follows this event, does not wait for a
        # transaction that rewrites the ~30 KB state
        with _lock(sid):
            cached = _states.get(sid)
            if cached is not None and ev.get("object") in cached[0].objects:
                state, since = cached
                mats = list(state.materials)
                mats[state.objects.index(ev["object"])] = parse_material(ev["material"])
                _states[sid] = (state.model_copy(update={"materials": mats}),
                                since if since is not None else time.monotonic())
                return ev
    if t in ("fit", "paint") and "material" in ev:
        with _lock(sid), st.db() as s, s.begin():
            _write_locked(st, sid)
            _states.pop(sid, None)          # the row changes below: read it again next time
            row = _row(s, sid)
            state = dict(row.state)
            names = state.get("objects") or [o["name"] for o in s.get(Scene, row.scene_id).spec["objects"]]
            mats = list(state["materials"])
            mats[names.index(ev["object"])] = ev["material"]
            state["materials"] = mats
            if t == "paint" and ev["object"] == state.get("object"):
                state["base_material"] = ev["material"]      # strokes now paint over the paint
            row.state = state
        return ev
    if t == "stroke" and ev.get("rejected") and ev.get("seq") is not None:
        with st.db() as s, s.begin():
            for r in s.scalars(select(StrokeRow).where(StrokeRow.session_id == sid, StrokeRow.seq == ev["seq"])):
                r.rejected = True
        return ev
    if t == "save":
        return _store_save(st, sid, ev)
    return ev


def _store_save(st, sid: str, ev: dict) -> dict:
    seq = ev.get("seq")
    with _lock(sid), st.db() as s, s.begin():
        _write_locked(st, sid)
        _states.pop(sid, None)              # the row changes below: read it again next time
        row = _row(s, sid)
        state = dict(row.state)
        pending = [p for p in state.get("pending_saves", []) if p.get("seq") != seq]
        done = s.scalars(select(SessionSave).where(SessionSave.session_id == sid, SessionSave.seq == seq)).first()
        if done is not None:                       # stored before the worker restarted
            d = s.get(MaterialDesign, done.design_id)
            state["pending_saves"] = pending
            row.state = state
            return SavedEvent(seq=seq, material_id=d.id, version=done.version, name=d.name).model_dump()
        d = s.get(MaterialDesign, ev["material_id"]) if ev.get("material_id") else None
        err = None
        if ev.get("material_id") and d is None:
            err = f"save: no material {ev['material_id']!r}"
        elif d is not None and d.archived:
            err = f"save: material {d.id!r} is archived (409): restore it or save under a new name"
        if err:
            state["pending_saves"] = pending
            row.state = state
            return ErrorEvent(seq=seq, message=err, code=409 if d is not None else 404).model_dump()
        if d is None:
            d = MaterialDesign(name=ev.get("name") or f"{ev['object']} design", scene_id=row.scene_id, object=ev["object"])
            s.add(d)
            s.flush()
        v = add_version(s, d, ev["material"], note=f"saved from session {sid}")
        s.flush()
        s.add(SessionSave(session_id=sid, seq=seq, design_id=d.id, version=v.version))
        state["pending_saves"] = pending
        row.state = state
        return SavedEvent(seq=seq, material_id=d.id, version=v.version, name=d.name).model_dump()


# -- the stream ---------------------------------------------------------------------------------
async def _fail(ws: WebSocket, code: int, message: str, http: int) -> None:
    """A fatal error event, then the close code; a client that already left is not an error."""
    try:
        await ws.send_text(json.dumps(ErrorEvent(message=message, fatal=True, code=http).model_dump()))
        await ws.close(code=code)
    except (WebSocketDisconnect, RuntimeError, OSError):
        pass


class BadFrame(Exception):
    """A stream message that ends the stream: ``code`` the WebSocket close code, ``http`` the
    error event's status, the message says what was wrong (with the limit and the measured value)."""

    def __init__(self, code: int, message: str, http: int):
        super().__init__(message)
        self.code, self.http = code, http


# a JSON string (its closing quote optional, so an unterminated one is consumed in one match and
# nothing is scanned twice) or a bracket: what json_depth walks over, in linear time
_JSON_TOKENS = re.compile(r'"(?:[^"\\]|\\.)*"?|[\[\]{}]', re.S)


def json_depth(text: str, limit: int) -> int:
    """How deep the arrays and objects of a JSON text nest (strings skipped), counted up to
    ``limit + 1`` at most: json.loads recurses once a level, so a message nested 10^5 deep
    raised RecursionError in the server before this was checked."""
    d = deepest = 0
    for m in _JSON_TOKENS.finditer(text):
        c = m.group()
        if c in "[{":
            d += 1
            if d > deepest:
                deepest = d
                if d > limit:
                    break
        elif c in "]}":
            d -= 1
    return deepest


async def receive_json(ws: WebSocket, cfg, timeout: float):
    """The next stream message, parsed: binary frames (1003), text over
    ``max_stream_message_bytes`` (1009) and JSON nested deeper than ``max_stream_message_depth``
    (4400) raise BadFrame; text that is not JSON raises json.JSONDecodeError (the stream can go
    on); the client leaving raises WebSocketDisconnect; asyncio.TimeoutError after ``timeout`` s."""
    m = await asyncio.wait_for(ws.receive(), timeout)
    if m["type"] == "websocket.disconnect":
        raise WebSocketDisconnect(m.get("code", 1000))
    text = m.get("text")
    if text is None:
        n = len(m.get("bytes") or b"")
        raise BadFrame(1003, f"a binary frame ({n} bytes) is not a stream message: send JSON text messages", 415)
    limit = cfg.max_stream_message_bytes
    if len(text) > limit or (4 * len(text) > limit and len(text.encode("utf-8", "surrogatepass")) > limit):
        n = len(text.encode("utf-8", "surrogatepass"))
        raise BadFrame(1009, f"a message of {n} bytes is over the limit of {limit} bytes (max_stream_message_bytes)", 413)
    depth = json_depth(text, cfg.max_stream_message_depth)
    if depth > cfg.max_stream_message_depth:
        raise BadFrame(4400, f"a message nested more than {cfg.max_stream_message_depth} levels deep (at least "
                             f"{depth}) is refused (max_stream_message_depth)", 400)
    return json.loads(text)


async def _authenticate(ws: WebSocket, token: str | None, cfg) -> tuple[str | None, str]:
    """(the session token, why there is none): from the first message ({"type": "auth",
    "token": …}), else ?token=. Any malformed first message is an authentication failure."""
    if token:
        return token, ""
    try:
        raw = await receive_json(ws, cfg, AUTH_SECONDS)
    except asyncio.TimeoutError:
        return None, f"no auth message within {AUTH_SECONDS:.0f} s"
    except WebSocketDisconnect:
        return None, "the client left before it authenticated"
    except BadFrame as e:
        return None, f"the auth message is malformed: {e}"
    except json.JSONDecodeError as e:
        return None, f"the auth message is not JSON ({e.msg})"
    if isinstance(raw, dict) and raw.get("type") == "auth" and isinstance(raw.get("token"), str):
        return raw["token"], ""
    return None, "the first message must be {\"type\": \"auth\", \"token\": \"<the session token>\"}"


# the stream that owns each session's slot in st.streams (a reconnect replaces the one before)
_owners: dict[str, object] = {}


def _reserve(st, sid: str, client: str, me: object) -> tuple[int, str, int] | None:
    """Check the stream limits and take a slot in one step, with no await in between (so
    concurrent connects cannot all pass the check before any registers): None when taken, else
    (close code, message, http status). A reconnect of the same session takes over its slot."""
    cfg = st.settings
    others = [c for k, c in st.streams.items() if k != sid]
    if len(others) >= cfg.max_sessions:
        return 4503, (f"the server is at its limit of {cfg.max_sessions} open session streams "
                      f"({len(others)} open, max_sessions); try again later"), 503
    mine = sum(c == client for c in others)
    if mine >= cfg.max_sessions_per_client:
        return 4429, (f"this client ({client}) already has {mine} open session streams, the limit is "
                      f"{cfg.max_sessions_per_client} (max_sessions_per_client); close one first"), 429
    st.streams[sid] = client
    _owners[sid] = me
    return None


def _release(st, sid: str, me: object) -> bool:
    """Give the slot back if this stream still holds it; whether it did."""
    if _owners.get(sid) is not me:
        return False
    del _owners[sid]
    st.streams.pop(sid, None)
    return True


@router.websocket("/{sid}/stream")
async def stream(ws: WebSocket, sid: str, token: str | None = Query(None)):
    st = ws.app.state.glint
    if not (check_host(st.settings, ws.headers) and check_origin(st.settings, ws.headers)):
        await ws.close(code=4403)          # a page from another origin cannot drive a session
        return
    cfg = st.settings
    await ws.accept()
    token, why = await _authenticate(ws, token, cfg)
    row = await run_in_threadpool(lambda: _get(st, sid))
    if row is None or row.closed:
        return await _fail(ws, 4404, f"no open session {sid!r}", 404)
    if not _authorised(row, token):
        return await _fail(ws, 4403, f"wrong or missing session token: {why or 'the token does not match'} "
                                     "(send {\"type\": \"auth\", \"token\": …} first)", 403)
    # viewer sessions need no API token and are made by anyone: they count against the address
    # that streams them (a client could make them from many); editing ones against their owner
    readonly = bool((row.state or {}).get("readonly"))
    client = f"addr:{ws.client.host if ws.client else '?'}" if readonly else row.client
    me = object()
    refused = _reserve(st, sid, client, me)
    if refused is not None:
        return await _fail(ws, *refused)
    try:
        await _serve(ws, st, sid, row, me)
    finally:
        _release(st, sid, me)


async def _serve(ws: WebSocket, st, sid: str, row: Session, me: object) -> None:
    """The stream of an authenticated session that holds its slot (``_reserve``)."""
    cfg = st.settings
    try:
        payload = await run_in_threadpool(st.session_payload, sid)
    except (Conflict, NotFound) as e:
        return await _fail(ws, 4409, str(e), 409)
    try:
        check_frame_size(cfg, (payload.get("state") or {}).get("camera"))
    except HTTPException as e:           # a session stored before the limit, or a scene's camera
        return await _fail(ws, 4413, str(e.detail), 422)
    if _owners.get(sid) is not me:
        return await _fail(ws, 4409, "this session was opened by another stream meanwhile", 409)
    st.pool.close_session(sid)      # one stream per session: a reconnect starts from the stored state
    q = st.pool.open_session(sid, payload)
    state, notes = restore_state(payload["state"], payload["scene"]["spec"])
    await ws.send_text(json.dumps(HelloEvent(
        session=sid, state=state.model_dump(mode="json"), renderer=state.renderer,
        strokes=len([s for s in payload["strokes"] if not s["undone"]]),
        renderers=state.renderers, controls=sorted(_controls(state.renderer, state.readonly))).model_dump()))

    async def pump():
        while True:
            kind, p = await q.get()
            if kind == "frame":
                hdr, img = p
                st.metrics.frame(sid, hdr)
                if q.dropped_frames:
                    hdr = {**hdr, "dropped_frames": q.dropped_frames}
                await ws.send_bytes(encode_frame(hdr, img))
            else:
                try:
                    ev = await run_in_threadpool(on_worker_event, st, sid, p)
                except Exception as e:       # storing it failed: say so, and keep streaming
                    log.exception("session %s: storing a %s event failed", sid, p.get("type"))
                    ev = ErrorEvent(seq=p.get("seq"), message=f"the server could not store the {p.get('type')} "
                                                              f"({type(e).__name__}); try again").model_dump()
                if ev is not None:
                    await ws.send_text(json.dumps(ev))

    # messages are read as fast as they come and stored in batches (persist_batch): the socket
    # never backs up behind the database, and the worker gets them in order
    inbox: asyncio.Queue = asyncio.Queue()

    async def process():
        """Store and forward the inbox in batches until the ``None`` the stream's end puts in it
        (what was received is stored even when the client has gone)."""
        ending = False
        try:
            while not ending:
                # waits at most FLUSH_S: a worker event (a fit) may leave the state unwritten
                # while no message comes
                try:
                    first = await asyncio.wait_for(inbox.get(), FLUSH_S)
                except asyncio.TimeoutError:
                    if has_unsaved(sid):
                        await run_in_threadpool(flush_session, st, sid)
                    continue
                batch = [first]
                while not inbox.empty() and len(batch) < MAX_BATCH:
                    batch.append(inbox.get_nowait())
                ending = batch[-1] is None
                batch = [m for m in batch if m is not None]
                if not batch:
                    continue
                for err, fwd in await run_in_threadpool(persist_batch, st, sid, batch):
                    if ending:
                        continue            # the stream is over: stored, nobody to tell
                    if err is None:
                        st.pool.send(sid, fwd)
                        st.metrics.message(sid, fwd)
                        continue
                    try:
                        await ws.send_text(json.dumps(err))
                    except (WebSocketDisconnect, RuntimeError):
                        pass                # the client left; what it sent is still stored
        except asyncio.CancelledError:
            raise
        except KeyError:            # the pool no longer has it: a newer stream of it took over
            try:
                await _fail(ws, 4409, "this session was opened by another stream (a reconnect or another tab); "
                                      "this one is closed", 409)
            except Exception:
                pass
        except Exception as e:      # the database failed: tell the client, end the stream
            log.exception("session %s: storing messages failed", sid)
            try:
                await _fail(ws, 1011, f"the server could not store your input ({type(e).__name__}); reconnect", 500)
            except Exception:
                pass

    sender = asyncio.create_task(pump())
    processor = asyncio.create_task(process())
    try:
        while True:
            try:
                raw = await receive_json(ws, cfg, cfg.session_idle_seconds)
            except asyncio.TimeoutError:
                await _fail(ws, 4408, f"closed after {cfg.session_idle_seconds:.0f} s without input; reconnect to go on", 408)
                break
            except BadFrame as e:       # nothing of it was applied or stored
                await _fail(ws, e.code, str(e), e.http)
                break
            except json.JSONDecodeError as e:
                await ws.send_text(json.dumps(ErrorEvent(message=f"not JSON: {e.msg}").model_dump()))
                continue
            if isinstance(raw, dict) and raw.get("type") == "auth":
                continue
            try:
                msg = client_msg.validate_python(raw)
                if getattr(msg, "preset", None) is not None:
                    raise StateError("environment: send asset_id (an uploaded map) or index, not preset")
            except StateError as e:
                await ws.send_text(json.dumps(ErrorEvent(seq=msg.seq, message=str(e)).model_dump()))
                continue
            except ValidationError as e:
                err = e.errors()[0]
                seq = raw.get("seq") if isinstance(raw, dict) else None
                await ws.send_text(json.dumps(ErrorEvent(
                    seq=seq if isinstance(seq, int) else None,
                    message=f"{'.'.join(str(x) for x in err['loc'])}: {err['msg']}").model_dump()))
                continue
            if processor.done():
                break
            if inbox.qsize() >= MAX_PENDING:
                await _fail(ws, 4429, f"more than {MAX_PENDING} messages waiting to be stored: the client sends "
                                      "faster than the server can keep up; reconnect", 429)
                break
            inbox.put_nowait(msg)
    except WebSocketDisconnect:
        pass
    except RuntimeError as e:   # sending on a socket the client already closed
        log.info("session %s stream ended: %s", sid, e)
    finally:
        sender.cancel()
        inbox.put_nowait(None)      # store what was received, then stop
        try:
            await asyncio.wait_for(processor, 30.0)
        except (asyncio.TimeoutError, asyncio.CancelledError):
            processor.cancel()
        if _release(st, sid, me):       # a newer stream of this session keeps its worker session
            st.pool.close_session(sid)
        st.metrics.session_ended(sid)
        await run_in_threadpool(forget_session, st, sid)
        await run_in_threadpool(_ended, st, sid)
        # the stream's states, batches and frames were freed on the threadpool's threads:
        # give what malloc holds free back (the server's memory grew ~20 MiB per run of eight
        # sessions without it, issue 9)
        await run_in_threadpool(trim_malloc)


def _controls(kind: str, readonly: bool) -> set[str]:
    from worker.renderers import controls

    c = set(controls(kind))
    return c - {"materials"} if readonly else c


def _ended(st, sid: str) -> None:
    """A stream ended: viewer sessions are over (a shopper gets a new one); editing sessions
    stay open to reconnect to, until closed or expired (``expire_idle``)."""
    with _lock(sid), st.db() as s, s.begin():
        row = _row(s, sid)
        if row is not None:
            row.last_active = now()
            if (row.state or {}).get("readonly"):
                row.closed = True


def expire_idle(st, older_than: dt.timedelta, viewers_older_than: dt.timedelta | None = None) -> int:
    """Close editing sessions without a stream and without activity for ``older_than``; delete
    viewer (read-only) sessions without a stream (never opened, or ended) and without activity
    for ``viewers_older_than`` (default: the ``viewer_session_seconds`` setting), with their
    stroke rows: anyone may make them (publications are public), so they must not pile up.
    Returns the sessions closed or deleted."""
    if viewers_older_than is None:
        viewers_older_than = dt.timedelta(seconds=st.settings.viewer_session_seconds)
    t = now()
    cutoff, viewer_cutoff = t - older_than, t - viewers_older_than
    n = 0

    def idle(row, cut) -> bool:
        last = row.last_active or row.updated or row.created
        if last is not None and last.tzinfo is None:
            last = last.replace(tzinfo=dt.timezone.utc)
        return row.id not in st.streams and last is not None and last < cut

    with st.db() as s, s.begin():
        for row in s.scalars(select(Session).where(Session.closed.is_(False))):
            if not (row.state or {}).get("readonly") and idle(row, cutoff):
                row.closed = True
                n += 1
        # viewer rows, open or closed, without reading their states
        q = select(Session.id, Session.last_active, Session.updated, Session.created).where(
            Session.state["readonly"].as_boolean().is_(True))
        gone = [r.id for r in s.execute(q) if idle(r, viewer_cutoff)]
        if gone:
            s.execute(delete(StrokeRow).where(StrokeRow.session_id.in_(gone)))
            s.execute(delete(SessionSave).where(SessionSave.session_id.in_(gone)))
            s.execute(delete(Session).where(Session.id.in_(gone)))
    return n + len(gone)


def _get(st, sid):
    with st.db() as s:
        return s.get(Session, sid)
