"""Scenes (scene file v1 bodies whose mesh and map fields are uploaded asset ids) and their
precomputations, run as background jobs with progress."""
from __future__ import annotations

import asyncio
import logging

from fastapi import APIRouter, Body, HTTPException, Query
from fastapi.concurrency import run_in_threadpool
from sqlalchemy import select

from worker.scene import SceneFile

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


def scene_out(st, s, sc: Scene) -> SceneOut:
    return SceneOut(id=sc.id, name=sc.name, spec=sc.spec, created=sc.created,
                    precomputation=pre_out(st.latest_precomputation(s, sc.id)))


def validate_scene(s, body) -> dict:
    """Scene file v1 with asset ids: the schema, then every referenced asset and its kind."""
    from worker.scene import SceneError, SceneFile, parse_scene

    if isinstance(body, SceneFile):
        spec = body
    else:
        try:
            spec = parse_scene(body, "scene")
        except SceneError as e:
            raise HTTPException(422, str(e)) from None
    refs = [("environment.map", spec.environment.map, "envmap")]
    refs += [(f"objects[{i}].mesh", o.mesh, "mesh") for i, o in enumerate(spec.objects)]
    for where, ref, kind in refs:
        a = s.get(Asset, ref)
        if a is None:
            raise HTTPException(422, f"{where}: {ref!r} is not an uploaded asset id (upload it to /v1/assets/{kind}s)")
        if a.kind != kind:
            raise HTTPException(422, f"{where}: asset {ref!r} is a {a.kind}, not a {kind}")
    names = [o.name for o in spec.objects]
    if len(set(names)) != len(names):
        raise HTTPException(422, "objects: names must be unique")
    return spec.model_dump(mode="json")


@router.post("/v1/scenes", response_model=SceneOut, status_code=201)
def create_scene(st: State, db: DB, _: Client,
                 body: SceneFile = Body(..., description="scene file v1 (DESIGN.md §3) whose mesh and map fields are asset ids"),
                 name: str = Query("", max_length=200)):
    spec = validate_scene(db, body)
    sc = Scene(name=name, spec=spec)
    db.add(sc)
    db.commit()
    return scene_out(st, db, sc)


@router.get("/v1/scenes", response_model=list[SceneOut])
def list_scenes(st: State, db: DB, _: Client):
    return [scene_out(st, db, sc) for sc in db.scalars(select(Scene).order_by(Scene.created.desc()).limit(200))]


@router.get("/v1/scenes/{scene_id}", response_model=SceneOut)
def get_scene(scene_id: str, st: State, db: DB, _: Client):
    sc = db.get(Scene, scene_id)
    if sc is None:
        raise HTTPException(404, f"no scene {scene_id!r}")
    return scene_out(st, db, sc)


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
        with st.db() as s, s.begin():
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
