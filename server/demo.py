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
    path = demo_scene(st.settings.data_dir / "assets")
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
    """Create the demo scene if missing and precompute it unless done (progress in the log)."""
    from .routes.scenes import run_precompute

    try:
        sid = await run_in_threadpool(_create_demo, st)

        def pending():
            with st.db() as s, s.begin():
                if st.latest_precomputation(s, sid, done=True) is not None:
                    return None
                p = Precomputation(scene_id=sid, status="queued")
                s.add(p)
                s.flush()
                return p.id
        pid = await run_in_threadpool(pending)
        if pid is None:
            log.info("demo scene %s is ready: open http://%s:%d/", sid, st.settings.host, st.settings.port)
            return
        log.info("precomputing the demo scene %s (first start only; progress follows)", sid)
        await run_precompute(st, pid)
        log.info("demo scene %s is ready: open http://%s:%d/", sid, st.settings.host, st.settings.port)
    except Exception as e:   # the service stays up without its demo
        log.error("could not prepare the demo scene: %s", e)
