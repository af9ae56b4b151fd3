"""Scenes (scene file v1 bodies whose mesh and map fields are uploaded asset ids) and their
precomputations, run as background jobs with progress."""
from __future__ import annotations

import asyncio
import json

from fastapi import APIRouter, HTTPException, Query, Request, Response
from fastapi.concurrency import run_in_threadpool

from worker.memory import no_collections

from .. import jsonchunks
from ..bodies import capped_chunks
from ..db import Precomputation, Scene
from ..deps import DB, Client, State
from ..schemas import PrecomputationOut, SceneOut, as_utc
from ..services import scenes
from ..services.scenes import run_precompute  # noqa: F401 -- server/demo.py precomputes the demo scene with it
from .errors import http_errors

router = APIRouter(tags=["scenes"])


def pre_out(p: Precomputation | None) -> PrecomputationOut | None:
    if p is None:
        return None
    return PrecomputationOut(id=p.id, scene_id=p.scene_id, kind=p.kind or "cuts", status=p.status, progress=p.progress, message=p.message,
                             stats=p.stats or {}, created=p.created, updated=p.updated)


def scene_dict(st, s, sc: Scene) -> dict:
    """SceneOut's JSON form, built from the stored spec as it is (validated when it was created):
    re-validating a 20 000-object spec through pydantic for every read took seconds."""
    pre = pre_out(st.latest_precomputation(s, sc.id))
    return {"id": sc.id, "name": sc.name, "spec": sc.spec, "created": as_utc(sc.created).isoformat(),
            "precomputation": pre.model_dump(mode="json") if pre is not None else None}


def json_response(obj, status_code: int = 200) -> Response:
    """A JSON response encoded piece by piece (server/jsonchunks.py): run it in a thread."""
    with no_collections():
        return Response(jsonchunks.dumps(obj, depth=3), status_code=status_code, media_type="application/json")


def validate_scene(s, body, max_objects: int | None = None) -> dict:
    """services.scenes.validate with its errors as HTTP answers (server/demo.py registers the
    demo scene through it)."""
    with http_errors():
        return scenes.validate(s, body, max_objects)


async def read_json_body(request: Request, limit: int, setting: str):
    """The request body parsed as JSON, read with a size cap (413 naming the limit and the
    length) and parsed in a thread in pieces, so a large body never stalls the event loop."""
    buf = [chunk async for chunk in capped_chunks(
        request, limit, f"body of {{n}} bytes is over the {limit}-byte limit ({setting})",
        f"body of more than {limit} bytes is over the {limit}-byte limit ({setting})",
        "the request body was cut off before its end")]

    def parse():
        try:
            with no_collections():
                return jsonchunks.loads(b"".join(buf))
        except UnicodeDecodeError:
            raise HTTPException(422, "the body is not UTF-8 JSON") from None
        except json.JSONDecodeError as e:
            raise HTTPException(422, f"the body is not valid JSON (line {e.lineno}, column {e.colno}: {e.msg})") from None
    return await run_in_threadpool(parse)


# The body is read raw (read_json_body) and validated in a thread (services/scenes.py); its schema is
# still the documented one, declared here
SCENE_BODY = {"requestBody": {"required": True, "description": "scene file v1 (docs/design/conventions.md, scene file) whose mesh and map "
                              "fields are asset ids", "content": {"application/json": {
                                  "schema": {"$ref": "#/components/schemas/SceneFile"}}}}}


@router.post("/v1/scenes", response_model=SceneOut, status_code=201, openapi_extra=SCENE_BODY,
             responses={413: {"description": "over max_scene_body_bytes or max_scene_objects"}})
async def create_scene(request: Request, st: State, _: Client, name: str = Query("", max_length=200)):
    cfg = st.settings
    body = await read_json_body(request, cfg.max_scene_body_bytes, "GLINT_MAX_SCENE_BODY_BYTES")

    def create():
        with no_collections(), http_errors(), st.db() as s, s.begin():
            sc = scenes.create(s, name, body, cfg.max_scene_objects)
            return json_response(scene_dict(st, s, sc), 201)
    return await run_in_threadpool(create)


@router.get("/v1/scenes", response_model=list[SceneOut])
def list_scenes(st: State, db: DB, _: Client, limit: int = Query(50, ge=1, le=200, description="scenes per page"),
                offset: int = Query(0, ge=0, le=2**31 - 1, description="scenes skipped (newest first)")):
    """The newest scenes first, a page at a time."""
    return json_response([scene_dict(st, db, sc) for sc in scenes.page(db, limit, offset)])


@router.get("/v1/scenes/{scene_id}", response_model=SceneOut)
def get_scene(scene_id: str, st: State, db: DB, _: Client):
    with http_errors():
        sc = scenes.get(db, scene_id)
    return json_response(scene_dict(st, db, sc))


@router.post("/v1/scenes/{scene_id}/precompute", response_model=PrecomputationOut, status_code=202)
async def start_precompute(scene_id: str, st: State, _: Client):
    def create():
        with no_collections(), http_errors(), st.db() as s, s.begin():
            return scenes.queue_precomputation(s, scene_id, st.precompute_tasks)
    p, new = await run_in_threadpool(create)
    if new:
        st.precompute_tasks[p.id] = asyncio.create_task(scenes.run_precompute(st, p.id))
    return pre_out(p)


@router.get("/v1/precomputations/{pre_id}", response_model=PrecomputationOut)
def get_precompute(pre_id: str, db: DB, _: Client):
    with http_errors():
        return pre_out(scenes.get_precomputation(db, pre_id))


@router.get("/v1/precomputations/{pre_id}/preview", response_class=Response,
            responses={200: {"content": {"image/jpeg": {}}, "description": "the first look (JPEG)"},
                       404: {"description": "no such precomputation, or no preview (yet)"}})
def get_precompute_preview(pre_id: str, st: State, db: DB, _: Client):
    """The scene's first look, drawn at the start of its precomputation (``stats.preview``:
    its size and the seconds it took) from cuts over 256 directions per vertex instead of
    32 768: the object, its material and its self-shadowing, blurrier than the final frames."""
    with http_errors():
        p = scenes.get_precomputation(db, pre_id)
    sha = ((p.stats or {}).get("preview") or {}).get("sha256")
    data = st.blobs.get(sha) if sha and st.blobs.has(sha) else None
    if data is None:
        raise HTTPException(404, f"precomputation {pre_id!r} has no preview "
                                 f"({'not drawn yet' if p.status in ('queued', 'running') else 'none was drawn'})")
    return Response(data, media_type="image/jpeg", headers={"Cache-Control": "private, max-age=3600"})
