"""Lighting captures: an uploaded zip of a capture manifest and its fisheye brackets, processed
by a worker job (worker/capture) into an environment-map asset, with progress in the database."""
from __future__ import annotations

import asyncio
import logging
from pathlib import Path

from starlette.concurrency import run_in_threadpool  # the thread pool the routes use too

from ..db import Asset, Capture
from ..workers import JobFailed
from .errors import NotFound

log = logging.getLogger("glint")


def store_zip(blobs, tmp_name: str, sha: str) -> str:
    """The uploaded temporary file stored as a blob (its SHA-256); the temporary file is gone."""
    try:
        return blobs.put_file(Path(tmp_name), sha)
    finally:
        Path(tmp_name).unlink(missing_ok=True)


def create(s, zip_sha: str, size: int) -> Capture:
    c = Capture(zip_sha256=zip_sha, status="queued", stats={"zip_bytes": size})
    s.add(c)
    s.flush()
    return c


def get(s, cid: str) -> Capture:
    c = s.get(Capture, cid)
    if c is None:
        raise NotFound(f"no capture {cid!r}")
    return c


def preview(s, blobs, cid: str) -> bytes:
    """The stitched map tone-mapped (PNG bytes); NotFound until the job has made it."""
    c = s.get(Capture, cid)
    if c is None or not c.preview_sha256:
        raise NotFound(f"capture {cid!r} has no preview (yet)")
    return blobs.get(c.preview_sha256)


async def run(st, cid: str) -> None:
    """Background task: the capture job in a worker; when done, the map is a new envmap asset."""
    def update(**kw):
        with st.db() as s, s.begin():
            c = s.get(Capture, cid)
            for k, v in kw.items():
                setattr(c, k, v)

    last = [0.0]

    def progress(f, msg):
        if f - last[0] >= 0.02 or f >= 1.0:
            last[0] = f
            update(progress=float(f), message=str(msg)[:1000], status="running")

    try:
        with st.db() as s:
            zsha = s.get(Capture, cid).zip_sha256
        await run_in_threadpool(update, status="running", message="starting")
        res = await st.pool.run_job({"type": "capture", "zip_sha256": zsha, "max_files": st.settings.max_capture_files,
                                     "max_total_bytes": st.settings.max_capture_unpacked_bytes}, on_progress=progress)

        def done():
            with st.db() as s, s.begin():
                a = Asset(kind="envmap", filename=f"capture-{cid}.exr", sha256=res["exr_sha256"], size=res["exr_bytes"],
                          meta={"source": "capture", "capture_id": cid,
                                "width": res["stats"].get("width"), "height": res["stats"].get("height")})
                s.add(a)
                s.flush()
                c = s.get(Capture, cid)
                c.status, c.progress, c.message = "done", 1.0, "done"
                c.asset_id, c.preview_sha256 = a.id, res["preview_sha256"]
                c.stats = {**(c.stats or {}), **res["stats"]}
        await run_in_threadpool(done)
    except asyncio.CancelledError:
        await run_in_threadpool(update, status="failed", message="cancelled: the server stopped; upload it again")
        raise
    except JobFailed as e:
        await run_in_threadpool(update, status="failed", message=str(e)[:1000], stats={"status": e.status})
    except Exception as e:
        log.exception("capture %s failed", cid)
        await run_in_threadpool(update, status="failed", message=f"internal error ({type(e).__name__})")
    finally:
        st.precompute_tasks.pop(f"capture-{cid}", None)
