"""The demo scene of ``glint serve``: the CC0 oak chair under a real HDRI (``glint assets fetch``),
or the procedural fallback offline, registered as assets and precomputed on first start."""
from __future__ import annotations

import json
import logging
from pathlib import Path

from fastapi.concurrency import run_in_threadpool
from sqlalchemy import select

from .db import Asset, Precomputation, Scene

log = logging.getLogger("glint")
DEMO_NAME = "demo"


def _register(st, path: Path, kind: str) -> str:
    data = path.read_bytes()
    sha = st.blobs.put(data)
    with st.db() as s, s.begin():
        a = s.scalars(select(Asset).where(Asset.sha256 == sha, Asset.kind == kind)).first()
        if a is None:
            a = Asset(kind=kind, filename=path.name, sha256=sha, size=len(data), meta={"source": "demo"})
            s.add(a)
            s.flush()
        return a.id


def _create_demo(st) -> str:
    from worker.assets import demo_scene

    with st.db() as s:
        sc = s.scalars(select(Scene).where(Scene.name == DEMO_NAME).order_by(Scene.created.desc())).first()
        if sc is not None:
            return sc.id
    path = Path(st.settings.demo_scene) if st.settings.demo_scene else demo_scene(st.settings.data_dir / "assets")
    spec = json.loads(path.read_text())
    root = path.parent
    spec["environment"]["map"] = _register(st, root / spec["environment"]["map"], "envmap")
    for o in spec["objects"]:
        o["mesh"] = _register(st, root / o["mesh"], "mesh")
    from .routes.scenes import validate_scene

    with st.db() as s:
        spec = validate_scene(s, spec)
        sc = Scene(name=DEMO_NAME, spec=spec)
        s.add(sc)
        s.commit()
        return sc.id


async def ensure_demo(st) -> None:
    """Create the demo scene if missing and precompute it unless done. Progress goes to the log
    and to ``st.demo`` (``GET /v1/status``), which the studio polls until the scene is ready."""
    from .routes.scenes import run_precompute

    st.demo = {"state": "fetching", "scene_id": None, "progress": 0.0,
               "message": "fetching the demo assets (first start only)"}
    try:
        sid = await run_in_threadpool(_create_demo, st)
        st.demo.update(scene_id=sid)

        def pending():
            with st.db() as s, s.begin():
                if st.latest_precomputation(s, sid, done=True) is not None:
                    return None
                p = Precomputation(scene_id=sid, status="queued")
                s.add(p)
                s.flush()
                return p.id
        pid = await run_in_threadpool(pending)
        why = "first start only"
        if pid is None:
            # done before: by this version of Glint? (a change in how meshes load or a part's
            # recipe leaves the stored parts under other keys: the demo would not open)
            def payload_of():
                with st.db() as s:
                    return st.scene_payload(s, sid, need_parts=False)
            payload = await run_in_threadpool(payload_of)
            missing = (await st.pool.run_job({"type": "missing_parts", "scene": payload}))["missing"]
            if missing:
                log.info("the demo scene's precomputed data lacks %s (made by an earlier version): "
                         "precomputing it again", ", ".join(missing))

                def again():
                    from .services.scenes import queue_precomputation

                    with st.db() as s, s.begin():
                        return queue_precomputation(s, sid, st.precompute_tasks, stale=True)[0].id
                pid = await run_in_threadpool(again)
                why = "once more: this version of Glint computes it differently"
        if pid is not None:
            log.info("precomputing the demo scene %s (%s; progress follows)", sid, why)
            st.demo.update(state="precomputing", message=f"precomputing the demo scene's visibility ({why})")

            def progress(f, msg, extra=None):
                st.demo.update(progress=float(f), message=f"precomputing the demo scene: {msg}")
                if extra and "preview" in extra:
                    st.demo.update(preview=f"/v1/precomputations/{pid}/preview")
            if not await run_precompute(st, pid, on_progress=progress):
                raise RuntimeError("its precomputation failed (see the log)")
        st.demo.update(state="ready", progress=1.0, message="ready")
        log.info("demo scene %s is ready: open http://%s:%d/", sid, st.settings.host, st.settings.port)
    except Exception as e:   # the service stays up without its demo
        st.demo.update(state="failed", message=f"could not prepare the demo scene: {e}")
        log.error("could not prepare the demo scene: %s", e)
