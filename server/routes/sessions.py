"""Interactive sessions: created over REST (id and secret token), streamed over a WebSocket
(docs/design/conventions.md, streaming protocol). Every client message is validated (worker/protocol) and applied to the stored
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
import collections
import datetime as dt
import hmac
import json
import logging
import time

from fastapi import APIRouter, Header, HTTPException, Query, Request, WebSocket, WebSocketDisconnect
from fastapi.concurrency import run_in_threadpool
from pydantic import ValidationError
from sqlalchemy import delete, select

from worker.memory import trim_malloc
from worker.protocol import (BadMessage as BadFrame, ErrorEvent, HelloEvent, PeerEvent, StateError,  # noqa: F401
                             client_msg, encode_frame, json_depth, new_state, parse_message_text, restore_state)

from ..db import (RegionStepRow, Scene, Session, SessionLogRow, SessionSave, SessionServer, StrokeRow, new_secret, now,
                  token_hash)
from ..deps import DB, Client, State, check_host, check_origin, client_key
from ..schemas import SessionCreate, SessionOut
from ..services.scenes import precompute_again
from ..sessions_store import FLUSH_S, POLL_S, StreamRefused
from ..state import Conflict, NotFound

router = APIRouter(prefix="/v1/sessions", tags=["sessions"])
log = logging.getLogger("glint")
AUTH_SECONDS = 10.0      # a stream must authenticate within this
MAX_BATCH = 256          # client messages stored in one transaction at most
MAX_PENDING = 4096       # client messages waiting to be stored before the stream is refused
# how long a session's worker session outlives its last stream to store the saves still pending
# (a save is a fraction of a second; one not stored by then is run when the session reopens)
SAVE_WAIT_S = 15.0
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


def _region_steps(db, row: Session) -> list[dict]:
    """The session's region steps, without their materials (the state holds the current one)."""
    rows = db.scalars(select(RegionStepRow).where(RegionStepRow.session_id == row.id).order_by(RegionStepRow.id))
    return [{"seq": r.seq, "object": r.object, "region_before": r.region_before, "region_after": r.region_after,
             "undone": r.undone, "dropped": r.dropped} for r in rows]


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
        state = new_state(sc.spec, req.object, camera, max_frame_pixels=st.settings.max_frame_pixels)
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
    # what a stream holds but has not written yet, written before the row is read: read first,
    # a stream ending meanwhile (its last write, then its copy dropped) left this row stale with
    # nothing unsaved to refresh it from. Writing early is harmless (the state is written within
    # FLUSH_S anyway); a stream ending meanwhile holds the lock, so this waits for its write.
    if st.sessions.has_unsaved(sid):
        st.sessions.flush(sid)
    row = db.get(Session, sid)
    if row is None:
        raise HTTPException(404, f"no session {sid!r}")
    if not _authorised(row, x_session_token):
        raise HTTPException(403, "wrong or missing session token (X-Session-Token header)")
    return SessionOut(id=row.id, scene_id=row.scene_id, stream=_stream_url(sid), state=row.state,
                      strokes=_strokes(db, row), region_steps=_region_steps(db, row), closed=row.closed,
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


class _Conn:
    """One stream of a session: its socket, what waits to be sent on it, and how its own
    message numbers map to the session's.

    Frames and events go out in the order they were put, from a task of its own, so a slow
    client never holds up the session's other streams; a frame still waiting when a newer one
    comes is dropped (the newest is what matters). A client numbers its messages on from the
    hello's ``state.last_seq``; when another stream used those numbers the store gives the
    message the session's next one (``persist_batch(renumber=True)``), and the frames' ``ack``
    and the errors this client gets are translated back to its own numbers."""

    def __init__(self, ws: WebSocket, client: str):
        self.ws, self.client = ws, client
        self.out: collections.deque = collections.deque()
        self.wake = asyncio.Event()
        self.dropped = 0
        self.last_client = -1            # the client's last accepted seq
        self.base = -1                   # the session's last_seq when this stream's hello was sent
        # (session seq, client seq) of its messages not yet acknowledged by a frame sent on it
        self.mine: collections.deque = collections.deque(maxlen=MAX_PENDING)
        self.acked = -1                  # the client seq of the last frame's ack
        self.sender: asyncio.Task | None = None
        self.readonly = False            # a shopper's viewer session (never shared across processes)

    def start(self, base: int) -> None:
        self.base = self.last_client = self.acked = base
        self.sender = asyncio.create_task(self._send_loop())

    def event(self, ev: dict) -> None:
        self.out.append(("text", json.dumps(ev)))
        self.wake.set()

    def frame(self, hdr: dict, img: bytes) -> None:
        for k, item in enumerate(self.out):
            if item[0] == "frame":             # one undelivered frame at most: the newest
                del self.out[k]
                self.dropped += 1
                break
        self.out.append(("frame", (hdr, img)))
        self.wake.set()

    def sent_as(self, session_seq: int, client_seq: int) -> None:
        self.mine.append((session_seq, client_seq))

    def client_ack(self, ack: int) -> int:
        """The client's number for the last of its messages that a frame acknowledging session
        seq ``ack`` includes (for a stream alone on its session, ``ack`` itself)."""
        while self.mine and self.mine[0][0] <= ack:
            self.acked = self.mine.popleft()[1]
        return self.acked

    async def _send_loop(self) -> None:
        try:
            while True:
                await self.wake.wait()
                self.wake.clear()
                while self.out:
                    kind, p = self.out.popleft()
                    if kind == "text":
                        await self.ws.send_text(p)
                        continue
                    hdr, img = p
                    hdr = {**hdr, "ack": self.client_ack(hdr.get("ack", -1))}
                    if self.dropped:
                        hdr["dropped_frames"] = hdr.get("dropped_frames", 0) + self.dropped
                    await self.ws.send_bytes(encode_frame(hdr, img))
        except (WebSocketDisconnect, RuntimeError, OSError):
            pass                         # the client left: its receive loop ends the stream

    async def close(self) -> None:
        """Send what is queued (a second at most), then stop."""
        if self.sender is None:
            return
        self.wake.set()
        for _ in range(20):
            if not self.out or self.sender.done():
                break
            await asyncio.sleep(0.05)
        self.sender.cancel()
        self.sender = None

    async def fail(self, code: int, message: str, http: int) -> None:
        """A fatal error event after what is queued, then the close code."""
        await self.close()
        await _fail(self.ws, code, message, http)


@router.websocket("/{sid}/stream")
async def stream(ws: WebSocket, sid: str, token: str | None = Query(None)):
    """A session's stream: any number of them per session (a reload, another tab); they share
    its worker session and each gets every frame and event (``_pump``) and the others' changes
    (``PeerEvent``)."""
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
    conn = _Conn(ws, client)
    conn.readonly = readonly
    try:
        streams, first = st.sessions.attach(sid, conn, client, cfg.max_sessions, cfg.max_sessions_per_client)
    except StreamRefused as e:
        return await _fail(ws, e.code, e.message, e.http)
    try:
        if await _join(st, sid, conn, streams, first):
            await _serve(st, sid, conn)
    except WebSocketDisconnect:
        pass
    except Exception as e:
        # a client told why, not a dropped connection (uvicorn closes the socket without a close
        # frame when a handler raises); the traceback goes to the log
        log.exception("session %s: the stream failed", sid)
        await conn.fail(1011, f"the server failed on this stream ({type(e).__name__}); reconnect", 500)
    finally:
        await conn.close()
        if st.sessions.detach(sid, conn):
            # a stream that opens the session again meanwhile (a reload) waits for this (_join)
            ended = st.sessions.ending[sid] = asyncio.Event()
            try:
                await _session_ended(st, sid, streams)
            finally:
                ended.set()
                if st.sessions.ending.get(sid) is ended:
                    del st.sessions.ending[sid]


async def _join(st, sid: str, conn: _Conn, streams, first: bool) -> bool:
    """Start a stream: the first of the session in this process opens its worker session from
    the stored state and starts ``_pump``; every one gets a hello with the current state, and
    one that joins the newest frame. False (the stream was failed): the session cannot be
    drawn."""
    ws, cfg = conn.ws, st.settings
    if first:
        streams.ready = asyncio.Event()
        streams.order = asyncio.Lock()
        prev = st.sessions.ending.get(sid)
        if prev is not None:
            # the session's last stream here is still ending it (a reload, a reconnect): its
            # write-back of the cached state and its end of the worker session must not land on
            # the ones this stream starts from
            try:
                await asyncio.wait_for(prev.wait(), SAVE_WAIT_S + 30.0)
            except asyncio.TimeoutError:
                log.warning("session %s: the previous stream's end took over %.0f s", sid, SAVE_WAIT_S + 30.0)
    try:
        if first and not conn.readonly:
            # other processes serving it too log what they store from now on (shared sessions)
            await run_in_threadpool(st.sessions.announce, sid)
        payload = await run_in_threadpool(st.session_payload, sid)
        check_frame_size(cfg, (payload.get("state") or {}).get("camera"))
    except (Conflict, NotFound) as e:
        streams.failed = str(e)
        streams.ready.set()
        await _fail(ws, 4409, str(e), 409)
        return False
    except HTTPException as e:           # a session stored before the limit, or a scene's camera
        streams.failed = str(e.detail)
        streams.ready.set()
        await _fail(ws, 4413, str(e.detail), 422)
        return False
    if first:
        st.sessions.started_at(sid, int((payload.get("state") or {}).get("last_seq", -1)))
        st.pool.close_session(sid)       # a worker may still hold it from a stream that ended: start afresh
        q = st.pool.open_session(sid, payload)
        streams.pump = asyncio.create_task(_pump(st, sid, q, streams))
        streams.ready.set()
    else:
        try:
            await asyncio.wait_for(streams.ready.wait(), 60.0)
        except asyncio.TimeoutError:
            await _fail(ws, 4503, "the session's first stream is still opening it; reconnect", 503)
            return False
        if streams.failed:
            await _fail(ws, 4409, streams.failed, 409)
            return False
    state, _ = restore_state(payload["state"], payload["scene"]["spec"])
    conn.start(state.last_seq)
    conn.event(HelloEvent(
        session=sid, state=state.model_dump(mode="json"), renderer=state.renderer,
        strokes=len([s for s in payload["strokes"] if not s["undone"]]), streams=len(streams.conns),
        renderers=state.renderers, controls=sorted(_controls(state.renderer, state.readonly))).model_dump())
    if not first and streams.last_frame is not None:
        conn.frame(*streams.last_frame)
    return True


async def _pump(st, sid: str, q, streams) -> None:
    """The worker session's output to every stream of the session: frames (the newest kept for
    streams that join and for saved versions' thumbnails) and events (stored first when they
    change what is stored: ``apply_worker_event``)."""
    while True:
        kind, p = await q.get()
        if kind == "frame":
            hdr, img = p
            st.metrics.frame(sid, hdr)
            if q.dropped_frames:
                hdr = {**hdr, "dropped_frames": q.dropped_frames}
            streams.last_frame = (hdr, img)
            for c in list(streams.conns):
                c.frame(hdr, img)
            continue
        try:
            ev = await run_in_threadpool(st.sessions.apply_worker_event, sid, p)
        except Exception as e:       # storing it failed: say so, and keep streaming
            log.exception("session %s: storing a %s event failed", sid, p.get("type"))
            ev = ErrorEvent(seq=p.get("seq"), message=f"the server could not store the {p.get('type')} "
                                                      f"({type(e).__name__}); try again").model_dump()
        if ev is not None and ev.get("type") == "error" and ev.get("fatal") and ev.get("code") == 409:
            # the scene's precomputed data lacks parts (made by an earlier version): precompute it
            # again, and say so rather than leave the designer with a scene that never opens
            try:
                scene_id = await run_in_threadpool(_scene_of, st, sid)
                pid = await precompute_again(st, scene_id, ev.get("message", ""))
                ev = {**ev, "message": f"{ev['message']}. This scene's precomputed data comes from an earlier "
                                       f"version of Glint: it is being precomputed again (precomputation {pid}, "
                                       "its progress in the Scene panel); open the scene again when it is done"}
            except Exception:
                log.exception("session %s: could not start precomputing its scene again", sid)
        if ev is not None:
            for c in list(streams.conns):
                c.event(ev)


def _scene_of(st, sid: str) -> str:
    row = _get(st, sid)
    if row is None:
        raise KeyError(sid)
    return row.scene_id


async def _serve(st, sid: str, conn: _Conn) -> None:
    """Read the stream's messages until it ends; ``_store_and_forward`` stores them in batches
    (the socket never backs up behind the database, and the worker gets them in order)."""
    ws, cfg = conn.ws, st.settings
    inbox: asyncio.Queue = asyncio.Queue()
    processor = asyncio.create_task(_store_and_forward(st, sid, conn, inbox))
    try:
        while True:
            try:
                raw = await receive_json(ws, cfg, cfg.session_idle_seconds)
            except asyncio.TimeoutError:
                await conn.fail(4408, f"closed after {cfg.session_idle_seconds:.0f} s without input; reconnect to go on", 408)
                break
            except BadFrame as e:       # nothing of it was applied or stored
                await conn.fail(e.code, str(e), e.http)
                break
            except json.JSONDecodeError as e:
                conn.event(ErrorEvent(message=f"not JSON: {e.msg}").model_dump())
                continue
            if isinstance(raw, dict) and raw.get("type") == "auth":
                continue
            msg, err = _validate(raw, conn)
            if err is not None:
                conn.event(err)
                continue
            if processor.done():
                break
            if inbox.qsize() >= MAX_PENDING:
                await conn.fail(4429, f"more than {MAX_PENDING} messages waiting to be stored: the client sends "
                                      "faster than the server can keep up; reconnect", 429)
                break
            conn.last_client = msg.seq
            inbox.put_nowait(msg)
    except WebSocketDisconnect:
        pass
    except RuntimeError as e:   # sending on a socket the client already closed
        log.info("session %s stream ended: %s", sid, e)
    finally:
        inbox.put_nowait(None)      # store what was received, then stop
        try:
            await asyncio.wait_for(processor, 30.0)
        except (asyncio.TimeoutError, asyncio.CancelledError):
            processor.cancel()


def _validate(raw, conn: _Conn):
    """(the client message, None) or (None, the error event for it): a valid message whose seq
    is above this stream's last one."""
    try:
        msg = client_msg.validate_python(raw)
        if getattr(msg, "preset", None) is not None:
            raise StateError("environment: send asset_id (an uploaded map) or index, not preset")
    except StateError as e:
        return None, ErrorEvent(seq=msg.seq, message=str(e)).model_dump()
    except ValidationError as e:
        err = e.errors()[0]
        seq = raw.get("seq") if isinstance(raw, dict) else None
        return None, ErrorEvent(seq=seq if isinstance(seq, int) else None,
                                message=f"{'.'.join(str(x) for x in err['loc'])}: {err['msg']}").model_dump()
    if msg.seq <= conn.last_client:
        # the worker would skip it (it treats such a seq as already applied)
        return None, ErrorEvent(seq=msg.seq, message=f"seq {msg.seq} is not above the last one, {conn.last_client}: "
                                                     "number messages on from the hello event's state.last_seq"
                                ).model_dump()
    return msg, None


async def _store_and_forward(st, sid: str, conn: _Conn, inbox: asyncio.Queue) -> None:
    """Store and forward the inbox in batches until the ``None`` the stream's end puts in it
    (what was received is stored, and reaches the worker, even when the client has gone): each
    stored message goes to the worker, and to the session's other streams as a PeerEvent."""
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
            streams = st.sessions.streams(sid)
            async with (streams.order if streams is not None and streams.order is not None else _NO_LOCK):
                done = await run_in_threadpool(st.sessions.persist_batch, sid, batch, True)
                # a session other processes serve too: their messages numbered before these first
                _forward_peers(st, sid, streams, st.sessions.take_peers(sid, read=False))
                peers = [c for c in (streams.conns if streams else ()) if c is not conn]
                for msg, (err, fwd) in zip(batch, done):
                    if err is None:
                        conn.sent_as(fwd["seq"], msg.seq)
                        st.pool.send(sid, fwd)
                        st.metrics.message(sid, fwd)
                        if peers:
                            peer = PeerEvent(message=fwd, streams=len(peers) + 1).model_dump()
                            for c in peers:
                                c.event(peer)
                    elif not ending:            # the stream is over: nobody to tell
                        conn.event({**err, "seq": msg.seq})
    except asyncio.CancelledError:
        raise
    except KeyError:            # the pool no longer has it: the session was closed meanwhile
        try:
            await conn.fail(4409, "this session's worker session was closed (DELETE, or the server is stopping); "
                                  "this stream is closed", 409)
        except Exception:
            pass
    except Exception as e:      # the database failed: tell the client, end the stream
        log.exception("session %s: storing messages failed", sid)
        try:
            await conn.fail(1011, f"the server could not store your input ({type(e).__name__}); reconnect", 500)
        except Exception:
            pass


class _NoLock:
    async def __aenter__(self):
        return None

    async def __aexit__(self, *a):
        return False


_NO_LOCK = _NoLock()


def _forward_peers(st, sid: str, streams, msgs: list[dict]) -> None:
    """Other processes' messages of a shared session (stored by them, in seq order): to this
    process's worker session, and to every stream here as a PeerEvent (a change another tab
    made), as a message of another stream here is."""
    if not msgs:
        return
    conns = list(streams.conns) if streams is not None else []
    for m in msgs:
        try:
            st.pool.send(sid, m)
        except KeyError:         # the worker session was closed meanwhile
            return
        peer = PeerEvent(message=m, streams=len(conns) + 1).model_dump()
        for c in conns:
            c.event(peer)


async def share_loop(st) -> None:
    """Every POLL_S: the sessions streamed here that other API processes serve too get the
    messages those stored (server/sessions_store.py, shared sessions), in seq order."""
    while True:
        await asyncio.sleep(POLL_S)
        try:
            shared = await run_in_threadpool(st.sessions.poll)
            for sid in shared:
                streams = st.sessions.streams(sid)
                if streams is None or streams.order is None:
                    continue
                async with streams.order:
                    _forward_peers(st, sid, streams, await run_in_threadpool(st.sessions.take_peers, sid))
        except asyncio.CancelledError:
            raise
        except Exception as e:       # the database is away for a moment: try again next time
            log.warning("shared sessions: %s", e)


async def _session_ended(st, sid: str, streams) -> None:
    """The session's last stream here ended: let its worker store the saves still pending (a
    tab that saves as it closes is not kept waiting for the answer; at most SAVE_WAIT_S), then
    stop its worker session, write and drop its cached state, note when it was last used."""
    t0 = time.monotonic()
    while streams.pump is not None and not streams.pump.done() and time.monotonic() - t0 < SAVE_WAIT_S:
        cached = st.sessions.cached_state(sid)
        if cached is None or not cached.pending_saves:
            break
        await asyncio.sleep(0.05)
    if streams.pump is not None:
        streams.pump.cancel()
    if st.sessions.is_streamed(sid):
        return      # a stream opened it again meanwhile, with a worker session of its own
    st.pool.close_session(sid)
    st.metrics.session_ended(sid)
    await run_in_threadpool(st.sessions.forget, sid)
    await run_in_threadpool(_ended, st, sid)
    # the stream's states, batches and frames were freed on the threadpool's threads: give
    # what malloc holds free back (the server's memory grew ~20 MiB per run of eight sessions
    # without it)
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
        return not st.sessions.is_streamed(row.id) and last is not None and last < cut

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
            s.execute(delete(RegionStepRow).where(RegionStepRow.session_id.in_(gone)))
            s.execute(delete(SessionLogRow).where(SessionLogRow.session_id.in_(gone)))
            s.execute(delete(SessionServer).where(SessionServer.session_id.in_(gone)))
            s.execute(delete(SessionSave).where(SessionSave.session_id.in_(gone)))
            s.execute(delete(Session).where(Session.id.in_(gone)))
    return n + len(gone)


def _get(st, sid):
    with st.db() as s:
        return s.get(Session, sid)
