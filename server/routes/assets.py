"""Uploads of meshes, environment maps and images (targets, masks).

The body is the raw file (``Content-Type: application/octet-stream``), with ``?filename=`` giving
its name and type. It is streamed to a temporary file with a size cap, hashed, checked by
actually reading it (type, triangle count, pixel count before decoding, NaN and negative
radiance) in a child process with a time limit (server/inspect.py), and only then stored under
its SHA-256.
"""
from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Literal

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.concurrency import run_in_threadpool

from ..bodies import capped_chunks
from ..db import Asset
from ..deps import DB, Client, State
from ..schemas import AssetOut
from ..services import assets
from .errors import http_errors

router = APIRouter(prefix="/v1/assets", tags=["assets"])


def _out(a: Asset) -> AssetOut:
    return AssetOut(id=a.id, kind=a.kind, filename=a.filename, sha256=a.sha256, size=a.size, meta=a.meta or {},
                    created=a.created)


async def receive_upload(request: Request, st, limit: int, what: str):
    """Stream a request body to a temporary file in the blob store, hashing it, under a size cap
    (the declared length is checked first, the bytes as they come). Returns (temporary file, its
    SHA-256, size); 413 over the cap, 400 for a body cut off, 422 for an empty one."""
    declared = request.headers.get("content-length")
    h = hashlib.sha256()
    size = 0
    tmp = st.blobs.temp_file()
    try:
        with tmp:
            async for chunk in capped_chunks(request, limit, f"upload of {{n}} bytes is over the {limit}-byte limit for {what}",
                                             f"upload is over the {limit}-byte limit for {what}",
                                             "the upload was cut off before its end"):
                size += len(chunk)
                h.update(chunk)
                tmp.write(chunk)
        if declared and declared.isdigit() and int(declared) != size:
            raise HTTPException(400, f"the upload is truncated: {size} of {declared} bytes arrived")
        if size == 0:
            raise HTTPException(422, "the upload is empty")
    except BaseException:
        Path(tmp.name).unlink(missing_ok=True)
        raise
    return tmp, h.hexdigest(), size


BINARY_BODY = {"requestBody": {"required": True, "description": "the file itself, as bytes",
                               "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}}}


@router.post("/{kind}", response_model=AssetOut, status_code=201, openapi_extra=BINARY_BODY,
             summary="Upload a mesh (.obj .ply .glb .stl), an environment map (.exr .hdr) or an image")
async def upload(kind: Literal["meshes", "envmaps", "images"], request: Request, st: State, _: Client,
                 filename: str = Query(..., min_length=1, max_length=255, description="original file name (its extension gives the type)")):
    with http_errors():
        akind, ext = assets.upload_kind(kind, filename)
        tmp, sha, size = await receive_upload(request, st, assets.size_limit(st.settings, akind), kind)
        sha, meta = await run_in_threadpool(assets.check_and_store, st.settings, st.blobs, tmp.name, akind, ext, sha)

    def save():
        with st.db() as s, s.begin():
            return _out(assets.create(s, akind, filename, sha, size, meta))
    return await run_in_threadpool(save)


@router.get("/{asset_id}", response_model=AssetOut)
def get_asset(asset_id: str, db: DB, _: Client):
    with http_errors():
        return _out(assets.get(db, asset_id))
