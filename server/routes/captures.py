"""Lighting captures (cyber-worlds §IV): a zip of the capture manifest and its fisheye
brackets (worker/capture) becomes an environment-map asset, as a job with progress.

``POST /v1/captures`` (``Content-Type: application/zip``, within ``max_capture_bytes``) stores the
zip, answers 202 with the capture's id, and runs the job; ``GET /v1/captures/{id}`` shows its
status, progress, the new asset's id and the stats (dynamic range, frame pixels removed, the
camera response); ``GET /v1/captures/{id}/preview`` is the stitched map tone-mapped to PNG.
A session lights its scene with the result by ``{"type": "environment", "asset_id": …}``.
"""
from __future__ import annotations

import asyncio

from fastapi import APIRouter, HTTPException, Request, Response
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel

from ..db import Capture
from ..deps import DB, Client, State
from ..schemas import UtcDateTime
from ..services import captures
from .assets import receive_upload
from .errors import http_errors

router = APIRouter(prefix="/v1/captures", tags=["captures"])

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
    created: UtcDateTime
    updated: UtcDateTime


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
    sha = await run_in_threadpool(captures.store_zip, st.blobs, tmp.name, sha)

    def create():
        with st.db() as s, s.begin():
            return captures.create(s, sha, size)
    c = await run_in_threadpool(create)
    st.precompute_tasks[f"capture-{c.id}"] = asyncio.create_task(captures.run(st, c.id))
    return _out(c)


@router.get("/{cid}", response_model=CaptureOut)
def get_capture(cid: str, db: DB, _: Client):
    with http_errors():
        return _out(captures.get(db, cid))


@router.get("/{cid}/preview", response_class=Response, responses={200: PNG})
def capture_preview(cid: str, st: State, db: DB, _: Client):
    """The stitched map, tone-mapped (PNG)."""
    with http_errors():
        return Response(captures.preview(db, st.blobs, cid), media_type="image/png")
