"""Lighting captures (issue 15, cyber-worlds §IV): a zip of the capture manifest and its fisheye
brackets (worker/capture) becomes an environment-map asset, as a job with progress.

``POST /v1/captures`` (``Content-Type: application/zip``, within ``max_capture_bytes``) stores the
zip, answers 202 with the capture's id, and runs the job; ``GET /v1/captures/{id}`` shows its
status, progress, the new asset's id and the stats (dynamic range, frame pixels removed, the
camera response); ``GET /v1/captures/{id}/preview`` is the stitched map tone-mapped to PNG.
A session lights its scene with the result by ``{"type": "environment", "asset_id": …}``.
"""
from __future__ import annotations

import asyncio
import datetime as dt
import logging
from pathlib import Path

from fastapi import APIRouter, HTTPException, Request, Response
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel

from ..db import Asset, Capture
from ..deps import DB, Client, State
from ..workers import JobFailed
from .assets import receive_upload

router = APIRouter(prefix="/v1/captures", tags=["captures"])
log = logging.getLogger("glint")

# Both media types the route accepts are declared: generated clients (openapi-python-client)
# upload binary bodies as application/octet-stream only, and skipped the route when it named zip alone
_BYTES = {"schema": {"type": "string", "format": "binary"}}
ZIP_BODY = {"requestBody": {"required": True, "description": "a zip of manifest.json and the photos it names",
                            "content": {"application/zip": _BYTES, "application/octet-stream": _BYTES}}}
PNG = {"content": {"image/png": {"schema": {"type": "string", "format": "binary"}}}}


class CaptureOut(BaseModel):
    id: str
    status: str
    progress: float
    message: str
    asset_id: str | None = None
    stats: dict
    preview: str | None = None
    created: dt.datetime
    updated: dt.datetime


def _out(c: Capture) -> CaptureOut:
    return CaptureOut(id=c.id, status=c.status, progress=c.progress, message=c.message, asset_id=c.asset_id,
                      stats=c.stats or {}, created=c.created, updated=c.updated,
                      preview=f"/v1/captures/{c.id}/preview" if c.preview_sha256 else None)


@router.post("", response_model=CaptureOut, status_code=202, openapi_extra=ZIP_BODY)
async def start_capture(request: Request, st: State, _: Client):
    """Upload a capture (zip) and start processing it."""
    ctype = request.headers.get("content-type", "")
    if ctype.split(";")[0].strip() not in ("application/zip", "application/x-zip-compressed", "application/octet-stream"):
        raise HTTPException(415, "a capture is uploaded as application/zip (manifest.json and the photos)")
    tmp, sha, size = await receive_upload(request, st, st.settings.max_capture_bytes, "captures")
    try:
        sha = st.blobs.put_file(Path(tmp.name), sha)
    finally:
        Path(tmp.name).unlink(missing_ok=True)

    def create():
        with st.db() as s, s.begin():
            c = Capture(zip_sha256=sha, status="queued", stats={"zip_bytes": size})
            s.add(c)
            s.flush()
            return c
    c = await run_in_threadpool(create)
    st.precompute_tasks[f"capture-{c.id}"] = asyncio.create_task(_run(st, c.id))
    return _out(c)


async def _run(st, cid: str) -> None:
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


@router.get("/{cid}", response_model=CaptureOut)
def get_capture(cid: str, db: DB, _: Client):
    c = db.get(Capture, cid)
    if c is None:
        raise HTTPException(404, f"no capture {cid!r}")
    return _out(c)


@router.get("/{cid}/preview", response_class=Response, responses={200: PNG})
def capture_preview(cid: str, st: State, db: DB, _: Client):
    """The stitched map, tone-mapped (PNG)."""
    c = db.get(Capture, cid)
    if c is None or not c.preview_sha256:
        raise HTTPException(404, f"capture {cid!r} has no preview (yet)")
    return Response(st.blobs.get(c.preview_sha256), media_type="image/png")
