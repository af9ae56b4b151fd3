"""Interactive sessions: created over REST (id and secret token), streamed over a WebSocket
(DESIGN.md §5). Every client message is validated, persisted, then forwarded to the worker
holding the session, so a worker crash loses nothing: the pool re-opens the session from here.
"""
from __future__ import annotations

import asyncio
import hmac
import json
import logging

from fastapi import APIRouter, Header, HTTPException, Query, WebSocket, WebSocketDisconnect
from fastapi.concurrency import run_in_threadpool
from pydantic import ValidationError
from sqlalchemy import select

from worker.jobs.protocol import READONLY_TYPES, client_msg
from worker.jobs.session import encode_frame
from worker.scene import Camera

from ..db import MaterialDesign, Publication, Scene, Session, StrokeRow, new_secret, token_hash
from ..deps import DB, Client, State
from ..schemas import SessionCreate, SessionOut
from ..state import Conflict, NotFound
from .materials import add_version

router = APIRouter(prefix="/v1/sessions", tags=["sessions"])
log = logging.getLogger("glint")


def _stream_url(sid: str) -> str:
    return f"/v1/sessions/{sid}/stream"


def _strokes(db, row: Session) -> list[dict]:
    rows = db.scalars(select(StrokeRow).where(StrokeRow.session_id == row.id).order_by(StrokeRow.id))
    return [{"seq": r.seq, "epoch": r.epoch, "undone": r.undone, "dropped": r.dropped, **r.body} for r in rows]


@router.post("", response_model=SessionOut, status_code=201)
def create_session(req: SessionCreate, st: State, db: DB, _: Client):
    sc = db.get(Scene, req.scene_id)
    if sc is None:
        raise HTTPException(404, f"no scene {req.scene_id!r}")
    try:
        st.scene_payload(db, sc.id)
    except Conflict as e:
        raise HTTPException(409, str(e)) from None
    except NotFound as e:
        raise HTTPException(404, str(e)) from None
    names = [o["name"] for o in sc.spec["objects"]]
    obj = req.object or names[0]
    if obj not in names:
        raise HTTPException(422, f"object: no object {obj!r} (objects: {', '.join(names)})")
    cam = (req.camera.model_dump(mode="json") if req.camera else sc.spec["camera"])
    token = new_secret()
    row = Session(scene_id=sc.id, token_sha256=token_hash(token), state={
        "object": obj, "camera": cam, "rotation_deg": sc.spec["environment"]["rotation_deg"],
        "intensity": sc.spec["environment"]["intensity"], "materials": [o["material"] for o in sc.spec["objects"]],
        "base_material": sc.spec["objects"][names.index(obj)]["material"], "epoch": 0, "last_seq": -1})
    db.add(row)
    db.commit()
    return SessionOut(id=row.id, token=token, scene_id=sc.id, stream=_stream_url(row.id), state=row.state)


def _object_names(s, row: Session) -> list[str]:
    """Object names of the session's scene, in the order of state["materials"]."""
    return [o["name"] for o in s.get(Scene, row.scene_id).spec["objects"]]


def _authorised(row: Session | None, token: str | None) -> bool:
    return row is not None and token is not None and hmac.compare_digest(row.token_sha256, token_hash(token))


@router.get("/{sid}", response_model=SessionOut)
def get_session(sid: str, st: State, db: DB, x_session_token: str | None = Header(None), token: str | None = Query(None)):
    row = db.get(Session, sid)
    if row is None:
        raise HTTPException(404, f"no session {sid!r}")
    if not _authorised(row, x_session_token or token):
        raise HTTPException(403, "wrong or missing session token (X-Session-Token header or ?token=)")
    return SessionOut(id=row.id, scene_id=row.scene_id, stream=_stream_url(sid), state=row.state,
                      strokes=_strokes(db, row), worker_pid=st.pool.worker_of(sid) if hasattr(st.pool, "worker_of") else None)


@router.delete("/{sid}", status_code=204)
def close_session(sid: str, st: State, db: DB, x_session_token: str | None = Header(None)):
    row = db.get(Session, sid)
    if not _authorised(row, x_session_token):
        raise HTTPException(404 if row is None else 403, "no such session or wrong token")
    row.closed = True
    db.commit()
    st.pool.close_session(sid)


# -- persistence of client messages ---------------------------------------------------------------
def persist(st, sid: str, msg) -> tuple[dict | None, dict | None]:
    """Record a validated message before the worker sees it. Returns (error event, None) when
    the message cannot apply (nothing is stored or forwarded), else (None, message to forward)."""
    with st.db() as s, s.begin():
        row = s.get(Session, sid)
        state = dict(row.state)
        epoch = state.get("epoch", 0)
        t = msg.type
        fwd = msg.model_dump(mode="json")
        if state.get("readonly") and t not in READONLY_TYPES:
            return {"type": "error", "seq": msg.seq, "message": f"{t}: this is a read-only viewer session"}, None
        if t in ("variant", "environment") and not state.get("readonly"):
            return {"type": "error", "seq": msg.seq, "message": f"{t}: only viewer sessions have published {t}s"}, None
        if t == "variant":
            pub = s.get(Publication, state["publication"])
            if not msg.index < len(pub.variants):
                return {"type": "error", "seq": msg.seq, "message": f"variant: no variant {msg.index}"}, None
            names = _object_names(s, row)
            mats = list(state["materials"])
            mats[names.index(state["object"])] = pub.variants[msg.index]["material"]
            state.update(materials=mats, variant=msg.index)
            # the worker gets the published material, never one from the client
            fwd = {"seq": msg.seq, "type": "material", "material": pub.variants[msg.index]["material"]}
        elif t == "environment":
            if not msg.index < len(state.get("environments", [])):
                return {"type": "error", "seq": msg.seq, "message": f"environment: no preset {msg.index}"}, None
            state["environment_index"] = msg.index
            state["rotation_deg"] = state["environments"][msg.index]["rotation_deg"]
        elif t == "view":
            upd = {k: v for k, v in msg.model_dump(mode="json").items()
                   if k in ("eye", "target", "up", "fov_y_deg") and v is not None}
            try:
                state["camera"] = Camera.model_validate({**state["camera"], **upd}).model_dump(mode="json")
            except ValidationError as e:
                return {"type": "error", "seq": msg.seq, "message": f"view: {e.errors()[0]['msg']}"}, None
        elif t == "light":
            if msg.rotation_deg is not None:
                state["rotation_deg"] = msg.rotation_deg
            if msg.intensity is not None:
                state["intensity"] = msg.intensity
        elif t == "material":
            names = _object_names(s, row)
            name = msg.object or state["object"]
            if name not in names:
                return {"type": "error", "seq": msg.seq, "message": f"material: no object {name!r}"}, None
            mats = list(state["materials"])
            mats[names.index(name)] = msg.material.model_dump(mode="json")
            state["materials"] = mats
            if name == state["object"]:
                state["base_material"] = mats[names.index(name)]
                state["epoch"] = epoch + 1
        elif t == "stroke":
            for r in s.scalars(select(StrokeRow).where(StrokeRow.session_id == sid, StrokeRow.epoch == epoch,
                                                       StrokeRow.undone.is_(True), StrokeRow.dropped.is_(False))):
                r.dropped = True
            s.add(StrokeRow(session_id=sid, epoch=epoch, seq=msg.seq, body={
                "stroke": msg.stroke.model_dump(mode="json"), "camera": state["camera"],
                "rotation_deg": state["rotation_deg"], "intensity": state["intensity"]}))
        elif t in ("undo", "redo"):
            q = select(StrokeRow).where(StrokeRow.session_id == sid, StrokeRow.epoch == epoch,
                                        StrokeRow.dropped.is_(False), StrokeRow.undone.is_(t == "redo"))
            q = q.order_by(StrokeRow.seq.desc() if t == "undo" else StrokeRow.seq.asc())
            r = s.scalars(q.limit(1)).first()
            if r is not None:
                r.undone = t == "undo"
        elif t == "fit":
            if msg.constrained is not None:
                state["constrained"] = msg.constrained
            if msg.unpainted_weight is not None:
                state["unpainted_weight"] = msg.unpainted_weight
        elif t == "display":
            for k in ("exposure", "tone", "quality"):
                if getattr(msg, k) is not None:
                    state[k] = getattr(msg, k)
        state["last_seq"] = max(int(state.get("last_seq", -1)), msg.seq)
        row.state = state
    return None, fwd


def on_worker_event(st, sid: str, ev: dict) -> dict:
    """Events that change what is stored: a fit result updates the session's material, a save
    creates a material version. Returns the event to send to the client."""
    if ev.get("type") == "fit" and "material" in ev:
        with st.db() as s, s.begin():
            row = s.get(Session, sid)
            state = dict(row.state)
            names = _object_names(s, row)
            mats = list(state["materials"])
            mats[names.index(ev["object"])] = ev["material"]
            state["materials"] = mats
            row.state = state
        return ev
    if ev.get("type") == "save":
        with st.db() as s, s.begin():
            row = s.get(Session, sid)
            d = s.get(MaterialDesign, ev["material_id"]) if ev.get("material_id") else None
            if ev.get("material_id") and d is None:
                return {"type": "error", "seq": ev.get("seq"), "message": f"save: no material {ev['material_id']!r}"}
            if d is None:
                d = MaterialDesign(name=ev.get("name") or f"{ev['object']} design", scene_id=row.scene_id, object=ev["object"])
                s.add(d)
                s.flush()
            v = add_version(s, d, ev["material"], note=f"saved from session {sid}")
            s.flush()
            return {"type": "saved", "seq": ev.get("seq"), "material_id": d.id, "version": v.version, "name": d.name}
    return ev


# -- the stream ---------------------------------------------------------------------------------
@router.websocket("/{sid}/stream")
async def stream(ws: WebSocket, sid: str, token: str | None = Query(None)):
    st = ws.app.state.glint
    await ws.accept()
    row = await run_in_threadpool(lambda: _get(st, sid))
    if row is None or row.closed:
        await ws.send_text(json.dumps({"type": "error", "fatal": True, "code": 404, "message": f"no open session {sid!r}"}))
        await ws.close(code=4404)
        return
    if not _authorised(row, token):
        await ws.send_text(json.dumps({"type": "error", "fatal": True, "code": 403, "message": "wrong or missing session token"}))
        await ws.close(code=4403)
        return
    try:
        payload = await run_in_threadpool(st.session_payload, sid)
    except (Conflict, NotFound) as e:
        await ws.send_text(json.dumps({"type": "error", "fatal": True, "code": 409, "message": str(e)}))
        await ws.close(code=4409)
        return
    st.pool.close_session(sid)      # one stream per session: a reconnect starts from the stored state
    q = st.pool.open_session(sid, payload)
    await ws.send_text(json.dumps({"type": "hello", "session": sid, "state": payload["state"],
                                   "strokes": len([s for s in payload["strokes"] if not s["undone"]])}))

    async def pump():
        while True:
            kind, p = await q.get()
            if kind == "frame":
                await ws.send_bytes(encode_frame(*p))
            else:
                ev = await run_in_threadpool(on_worker_event, st, sid, p)
                await ws.send_text(json.dumps(ev))

    sender = asyncio.create_task(pump())
    try:
        while True:
            text = await ws.receive_text()
            try:
                raw = json.loads(text)
            except json.JSONDecodeError as e:
                await ws.send_text(json.dumps({"type": "error", "message": f"not JSON: {e.msg}"}))
                continue
            try:
                msg = client_msg.validate_python(raw)
            except ValidationError as e:
                err = e.errors()[0]
                seq = raw.get("seq") if isinstance(raw, dict) else None
                await ws.send_text(json.dumps({"type": "error", "seq": seq,
                                               "message": f"{'.'.join(str(x) for x in err['loc'])}: {err['msg']}"}))
                continue
            err, fwd = await run_in_threadpool(persist, st, sid, msg)
            if err is not None:
                await ws.send_text(json.dumps(err))
                continue
            st.pool.send(sid, fwd)
    except WebSocketDisconnect:
        pass
    except RuntimeError as e:   # sending on a socket the client already closed
        log.info("session %s stream ended: %s", sid, e)
    finally:
        sender.cancel()
        st.pool.close_session(sid)


def _get(st, sid):
    with st.db() as s:
        return s.get(Session, sid)
