"""Scenes (scene file v1 bodies whose mesh and map fields are uploaded asset ids) and their
precomputations, run as background jobs with progress."""
from __future__ import annotations

import asyncio
import json
import logging

from fastapi import APIRouter, HTTPException, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from sqlalchemy import select
from starlette.requests import ClientDisconnect

from worker.memory import no_collections

from .. import jsonchunks
from ..db import Asset, Precomputation, Scene
from ..deps import DB, Client, State
from ..schemas import PrecomputationOut, SceneOut

router = APIRouter(tags=["scenes"])
log = logging.getLogger("glint")


def pre_out(p: Precomputation | None) -> PrecomputationOut | None:
    if p is None:
        return None
    return PrecomputationOut(id=p.id, scene_id=p.scene_id, kind=p.kind or "cuts", status=p.status, progress=p.progress, message=p.message,
                             stats=p.stats or {}, created=p.created, updated=p.updated)


def scene_dict(st, s, sc: Scene) -> dict:
    """SceneOut's JSON form, built from the stored spec as it is (validated when it was created):
    re-validating a 20 000-object spec through pydantic for every read took seconds."""
    pre = pre_out(st.latest_precomputation(s, sc.id))
    return {"id": sc.id, "name": sc.name, "spec": sc.spec, "created": sc.created.isoformat(),
            "precomputation": pre.model_dump(mode="json") if pre is not None else None}


def json_response(obj, status_code: int = 200) -> Response:
    """A JSON response encoded piece by piece (server/jsonchunks.py): run it in a thread."""
    with no_collections():
        return Response(jsonchunks.dumps(obj, depth=3), status_code=status_code, media_type="application/json")


def check_assets(s, refs: list[tuple[str, str, str]]) -> None:
    """refs: (where, asset id, kind). Distinct ids are looked up in bulk (a query per object took
    20 000 queries for a 20 000-object scene); the first bad one is named."""
    ids = list(dict.fromkeys(r for _, r, _ in refs))
    found = {}
    for k in range(0, len(ids), 500):
        found.update({a.id: a for a in s.scalars(select(Asset).where(Asset.id.in_(ids[k:k + 500])))})
    for where, ref, kind in refs:
        a = found.get(ref)
        if a is None:
            raise HTTPException(422, f"{where}: {ref!r} is not an uploaded asset id (upload it to /v1/assets/{kind}s)")
        if a.kind != kind:
            raise HTTPException(422, f"{where}: asset {ref!r} is a {a.kind}, not a {kind}")


def validate_scene(s, body, max_objects: int | None = None) -> dict:
    """Scene file v1 with asset ids: the schema, then every referenced asset and its kind.
    Returns the spec's JSON form. Linear in the number of objects."""
    from worker.scene import SceneError, SceneFile, parse_scene_pieces

    try:
        if isinstance(body, SceneFile):
            spec, out = body, body.model_dump(mode="json")
        else:
            spec, out = parse_scene_pieces(body, "scene", max_objects)
    except SceneError as e:
        raise HTTPException(413 if "over the limit" in str(e) else 422, str(e)) from None
    refs = [("environment.map", spec.environment.map, "envmap")]
    refs += [(f"objects[{i}].mesh", o.mesh, "mesh") for i, o in enumerate(spec.objects)]
    check_assets(s, refs)
    return out


async def read_json_body(request: Request, limit: int, setting: str):
    """The request body parsed as JSON, read with a size cap (413 naming the limit and the
    length) and parsed in a thread in pieces, so a large body never stalls the event loop."""
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > limit:
        raise HTTPException(413, f"body of {int(declared)} bytes is over the {limit}-byte limit ({setting})")
    buf, size = [], 0
    try:
        async for chunk in request.stream():
            size += len(chunk)
            if size > limit:
                raise HTTPException(413, f"body of more than {limit} bytes is over the {limit}-byte limit ({setting})")
            buf.append(chunk)
    except ClientDisconnect:
        raise HTTPException(400, "the request body was cut off before its end") from None

    def parse():
        try:
            with no_collections():
                return jsonchunks.loads(b"".join(buf))
        except UnicodeDecodeError:
            raise HTTPException(422, "the body is not UTF-8 JSON") from None
        except json.JSONDecodeError as e:
            raise HTTPException(422, f"the body is not valid JSON (line {e.lineno}, column {e.colno}: {e.msg})") from None
    return await run_in_threadpool(parse)


# The body is read raw (read_json_body) and validated in a thread (validate_scene); its schema is
# still the documented one, declared here
SCENE_BODY = {"requestBody": {"required": True, "description": "scene file v1 (DESIGN.md §3) whose mesh and map "
                              "fields are asset ids", "content": {"application/json": {
                                  "schema": {"$ref": "#/components/schemas/SceneFile"}}}}}


@router.post("/v1/scenes", response_model=SceneOut, status_code=201, openapi_extra=SCENE_BODY,
             responses={413: {"description": "over max_scene_body_bytes or max_scene_objects"}})
async def create_scene(request: Request, st: State, _: Client, name: str = Query("", max_length=200)):
    cfg = st.settings
    body = await read_json_body(request, cfg.max_scene_body_bytes, "GLINT_MAX_SCENE_BODY_BYTES")

    def create():
        with no_collections(), st.db() as s, s.begin():
            spec = validate_scene(s, body, cfg.max_scene_objects)
            sc = Scene(name=name, spec=spec)
            s.add(sc)
            s.flush()
            return json_response(scene_dict(st, s, sc), 201)
    return await run_in_threadpool(create)


@router.get("/v1/scenes", response_model=list[SceneOut])
def list_scenes(st: State, db: DB, _: Client, limit: int = Query(50, ge=1, le=200, description="scenes per page"),
                offset: int = Query(0, ge=0, le=2**31 - 1, description="scenes skipped (newest first)")):
    """The newest scenes first, a page at a time."""
    rows = db.scalars(select(Scene).order_by(Scene.created.desc(), Scene.id).offset(offset).limit(limit))
    return json_response([scene_dict(st, db, sc) for sc in rows])


@router.get("/v1/scenes/{scene_id}", response_model=SceneOut)
def get_scene(scene_id: str, st: State, db: DB, _: Client):
    sc = db.get(Scene, scene_id)
    if sc is None:
        raise HTTPException(404, f"no scene {scene_id!r}")
    return json_response(scene_dict(st, db, sc))


async def run_precompute(st, pre_id: str, on_progress=None) -> bool:
    """Background task: the precompute job in a worker, progress written to the database.
    Returns whether it finished."""
    def update(**kw):
        with st.db() as s, s.begin():
            p = s.get(Precomputation, pre_id)
            for k, v in kw.items():
                setattr(p, k, v)

    last = [0.0, 0.0]

    def progress(f, msg):
        if on_progress is not None:
            on_progress(f, msg)
        if f - last[0] >= 0.02 or f >= 1.0:
            last[0] = f
            update(progress=float(f), message=msg, status="running")
        if f - last[1] >= 0.1 or f >= 1.0:
            last[1] = f
            log.info("precomputation %s: %3.0f%% (%s)", pre_id, 100 * f, msg)

    try:
        with st.db() as s:
            sid = s.get(Precomputation, pre_id).scene_id
            payload = st.scene_payload(s, sid, need_parts=False)
        await run_in_threadpool(update, status="running", message="starting")
        res = await st.pool.run_job({"type": "precompute", "scene": payload}, on_progress=progress)
        await run_in_threadpool(update, status="done", progress=1.0, message="done", kind=res["kind"],
                                parts=res["parts"], stats=res["stats"])
        log.info("precomputation %s done: %s", pre_id, res["stats"].get("seconds"))
        return True
    except asyncio.CancelledError:
        await run_in_threadpool(update, status="failed", message="cancelled: the server stopped; start it again")
        raise
    except Exception as e:
        log.error("precomputation %s failed: %s", pre_id, e)
        await run_in_threadpool(update, status="failed", message=str(e)[:1000])
        return False
    finally:
        st.precompute_tasks.pop(pre_id, None)


@router.post("/v1/scenes/{scene_id}/precompute", response_model=PrecomputationOut, status_code=202)
async def start_precompute(scene_id: str, st: State, _: Client):
    def create():
        with no_collections(), st.db() as s, s.begin():
            if s.get(Scene, scene_id) is None:
                raise HTTPException(404, f"no scene {scene_id!r}")
            kind = s.get(Scene, scene_id).spec.get("renderer", "cuts")
            cur = st.latest_precomputation(s, scene_id, kind=kind)
            if cur is not None and cur.status in ("queued", "running", "done") and \
                    (cur.status == "done" or cur.id in st.precompute_tasks):
                return cur, False
            p = Precomputation(scene_id=scene_id, status="queued", kind=kind)
            s.add(p)
            s.flush()
            return p, True
    p, new = await run_in_threadpool(create)
    if new:
        st.precompute_tasks[p.id] = asyncio.create_task(run_precompute(st, p.id))
    return pre_out(p)


@router.get("/v1/precomputations/{pre_id}", response_model=PrecomputationOut)
def get_precompute(pre_id: str, db: DB, _: Client):
    p = db.get(Precomputation, pre_id)
    if p is None:
        raise HTTPException(404, f"no precomputation {pre_id!r}")
    return pre_out(p)
