"""Interactive sessions: created over REST (id and secret token), streamed over a WebSocket
(DESIGN.md §5). Every client message is validated (worker/protocol) and applied to the stored
state by the same ``apply`` the worker renders with, stored as its class declares by the
session store (``st.sessions``, server/sessions_store.py: camera, light and object moves at
most 0.5 s later, anything else before it is forwarded; a fit's material, derived from the
stored strokes, also at most 0.5 s later), then forwarded to the worker holding the session, so
a worker crash loses nothing: the pool re-opens the session from here. Worker events that
change what is stored go through the same store (``apply_worker_event``).

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

from fastapi import APIRouter, Header, HTTPException, Query, Request, WebSocket, WebSocketDisconnect
from fastapi.concurrency import run_in_threadpool
from pydantic import ValidationError
from sqlalchemy import delete, select

from worker.memory import trim_malloc
from worker.protocol import (BadMessage as BadFrame, ErrorEvent, HelloEvent, StateError, client_msg,  # noqa: F401
                             encode_frame, json_depth, new_state, parse_message_text, restore_state)

from ..db import Scene, Session, SessionSave, StrokeRow, new_secret, now, token_hash
from ..deps import DB, Client, State, check_host, check_origin, client_key
from ..schemas import SessionCreate, SessionOut
from ..sessions_store import FLUSH_S
from ..state import Conflict, NotFound

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
    if st.sessions.has_unsaved(sid):
        st.sessions.flush(sid)
        db.refresh(row)
    return SessionOut(id=row.id, scene_id=row.scene_id, stream=_stream_url(sid), state=row.state,
                      strokes=_strokes(db, row), closed=row.closed,
                      worker_pid=st.pool.worker_of(sid))


@router.delete("/{sid}", status_code=204)
def close_session(sid: str, st: State, db: DB, x_session_token: str | None = Header(None)):
    row = db.get(Session, sid)
    if not _authorised(row, x_session_token):
        raise HTTPException(404 if row is None else 403, "no such session or wrong token")
    row.closed = True
    db.commit()
    st.pool.close_session(sid)


# -- the stream ---------------------------------------------------------------------------------
async def _fail(ws: WebSocket, code: int, message: str, http: int) -> None:
    """A fatal error event, then the close code; a client that already left is not an error."""
    try:
        await ws.send_text(json.dumps(ErrorEvent(message=message, fatal=True, code=http).model_dump()))
        await ws.close(code=code)
    except (WebSocketDisconnect, RuntimeError, OSError):
        pass


async def receive_json(ws: WebSocket, cfg, timeout: float):
    """The next stream message, parsed: binary frames (1003), text over
    ``max_stream_message_bytes`` (1009) and JSON nested deeper than ``max_stream_message_depth``
    (4400) raise BadFrame (protocol/wire.py BadMessage); text that is not JSON raises
    json.JSONDecodeError (the stream can go on); the client leaving raises WebSocketDisconnect; asyncio.TimeoutError after ``timeout`` s."""
    m = await asyncio.wait_for(ws.receive(), timeout)
    if m["type"] == "websocket.disconnect":
        raise WebSocketDisconnect(m.get("code", 1000))
    return parse_message_text(m.get("text"), len(m.get("bytes") or b""), cfg.max_stream_message_bytes,
                              cfg.max_stream_message_depth)


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
                    ev = await run_in_threadpool(st.sessions.apply_worker_event, sid, p)
                except Exception as e:       # storing it failed: say so, and keep streaming
                    log.exception("session %s: storing a %s event failed", sid, p.get("type"))
                    ev = ErrorEvent(seq=p.get("seq"), message=f"the server could not store the {p.get('type')} "
                                                              f"({type(e).__name__}); try again").model_dump()
                if ev is not None:
                    await ws.send_text(json.dumps(ev))

    # messages are read as fast as they come and stored in batches (SessionStore.persist_batch):
    # the socket never backs up behind the database, and the worker gets them in order
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
                    if st.sessions.has_unsaved(sid):
                        await run_in_threadpool(st.sessions.flush, sid)
                    continue
                batch = [first]
                while not inbox.empty() and len(batch) < MAX_BATCH:
                    batch.append(inbox.get_nowait())
                ending = batch[-1] is None
                batch = [m for m in batch if m is not None]
                if not batch:
                    continue
                for err, fwd in await run_in_threadpool(st.sessions.persist_batch, sid, batch):
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
        await run_in_threadpool(st.sessions.forget, sid)
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
    with st.sessions.lock(sid), st.db() as s, s.begin():
        row = s.get(Session, sid, with_for_update=True)
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
