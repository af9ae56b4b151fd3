"""Scenes (scene file v1 bodies whose mesh and map fields are uploaded asset ids) and their
precomputations, which run as background jobs in a worker with their progress in the database."""
from __future__ import annotations

import asyncio
import logging

from starlette.concurrency import run_in_threadpool  # the thread pool the routes use too
from sqlalchemy import select

from ..db import Asset, Precomputation, Scene
from ..state import AppState
from .errors import Invalid, NotFound

log = logging.getLogger("glint")


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
            raise Invalid(f"{where}: {ref!r} is not an uploaded asset id (upload it to /v1/assets/{kind}s)")
        if a.kind != kind:
            raise Invalid(f"{where}: asset {ref!r} is a {a.kind}, not a {kind}")


def validate(s, body, max_objects: int | None = None) -> dict:
    """Scene file v1 with asset ids: the schema, then every referenced asset and its kind.
    Returns the spec's JSON form; Invalid (413 over the limits, else 422). Linear in the number
    of objects."""
    from worker.scene import SceneError, SceneFile, parse_scene_pieces

    try:
        if isinstance(body, SceneFile):
            spec, out = body, body.model_dump(mode="json")
        else:
            spec, out = parse_scene_pieces(body, "scene", max_objects)
    except SceneError as e:
        raise Invalid(str(e), 413 if "over the limit" in str(e) else 422) from None
    refs = [("environment.map", spec.environment.map, "envmap")]
    refs += [(f"objects[{i}].mesh", o.mesh, "mesh") for i, o in enumerate(spec.objects)]
    check_assets(s, refs)
    return out


def create(s, name: str, body, max_objects: int | None = None) -> Scene:
    sc = Scene(name=name, spec=validate(s, body, max_objects))
    s.add(sc)
    s.flush()
    return sc


def page(s, limit: int, offset: int) -> list[Scene]:
    """The newest scenes first."""
    return list(s.scalars(select(Scene).order_by(Scene.created.desc(), Scene.id).offset(offset).limit(limit)))


def get(s, scene_id: str) -> Scene:
    sc = s.get(Scene, scene_id)
    if sc is None:
        raise NotFound(f"no scene {scene_id!r}")
    return sc


def queue_precomputation(s, scene_id: str, running, stale: bool = False) -> tuple[Precomputation, bool]:
    """(precomputation, whether it is new) for the scene's renderer: the one done or under way
    (its id in ``running``, the tasks of this process) if there is one, else a new queued one.
    stale : the one done lacks parts this version of Glint needs (``precompute_again``): only one
    under way is reused."""
    sc = get(s, scene_id)
    kind = sc.spec.get("renderer", "cuts")
    cur = AppState.latest_precomputation(s, scene_id, kind=kind)
    if cur is not None and cur.status in ("queued", "running", "done") and \
            ((cur.status == "done" and not stale) or cur.id in running):
        return cur, False
    p = Precomputation(scene_id=scene_id, status="queued", kind=kind)
    s.add(p)
    s.flush()
    return p, True


def get_precomputation(s, pre_id: str) -> Precomputation:
    p = s.get(Precomputation, pre_id)
    if p is None:
        raise NotFound(f"no precomputation {pre_id!r}")
    return p


async def run_precompute(st, pre_id: str, on_progress=None) -> bool:
    """Background task: the precompute job in a worker, progress written to the database.
    Returns whether it finished."""
    def update(**kw):
        with st.db() as s, s.begin():
            p = s.get(Precomputation, pre_id)
            for k, v in kw.items():
                setattr(p, k, v)

    last = [0.0, 0.0, ""]

    def progress(f, msg, extra=None):
        if extra and "preview" in extra:
            # the job's first look (worker/renderers/cuts/preview.py): shown while it runs
            update(stats={"preview": extra["preview"]})
        if on_progress is not None:
            if extra:
                on_progress(f, msg, extra)
            else:
                on_progress(f, msg)
        # a new stage ("assembling and storing …") is written at once, whatever the fraction
        stage = msg.rsplit(": ", 1)[0] if ": " in msg else ""
        if f - last[0] >= 0.02 or f >= 1.0 or stage != last[2]:
            last[0], last[2] = f, stage
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


async def precompute_again(st, scene_id: str, missing: str = "") -> str:
    """Start precomputing a scene whose finished precomputation lacks parts this version of Glint
    needs (a session could not open: worker NotPrecomputed; or the demo's check at start): parts
    already stored are reused, the others computed, with progress like any precomputation.
    Returns its id (a run already under way is reused)."""
    import asyncio

    from fastapi.concurrency import run_in_threadpool

    def queue():
        with st.db() as s, s.begin():
            p, new = queue_precomputation(s, scene_id, st.precompute_tasks, stale=True)
            return p.id, new
    pid, new = await run_in_threadpool(queue)
    if new:
        log.info("scene %s: its precomputed data lacks %s (made by an earlier version?): precomputing it again "
                 "as precomputation %s", scene_id, missing or "parts", pid)
        st.precompute_tasks[pid] = asyncio.get_running_loop().create_task(run_precompute(st, pid))
    return pid
