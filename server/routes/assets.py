"""Uploads of meshes, environment maps and images (targets, masks).

The body is the raw file (``Content-Type: application/octet-stream``), with ``?filename=`` giving
its name and type. It is streamed to a temporary file with a size cap, hashed, checked by
actually reading it (type, triangle count, pixel count before decoding, NaN and negative
radiance) in a child process with a time limit (server/inspect.py), and only then stored under
its SHA-256.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Literal

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect

from ..db import Asset
from ..deps import DB, Client, State
from ..inspect import inspect_in_child
from ..schemas import AssetOut

router = APIRouter(prefix="/v1/assets", tags=["assets"])

KINDS = {"meshes": ("mesh", {".obj", ".ply", ".glb", ".stl"}),
         "envmaps": ("envmap", {".exr", ".hdr"}),
         "images": ("image", {".png", ".exr", ".hdr", ".npy"})}


def _out(a: Asset) -> AssetOut:
    return AssetOut(id=a.id, kind=a.kind, filename=a.filename, sha256=a.sha256, size=a.size, meta=a.meta or {},
                    created=a.created)


async def receive_upload(request: Request, st, limit: int, what: str):
    """Stream a request body to a temporary file in the blob store, hashing it, under a size cap
    (the declared length is checked first, the bytes as they come). Returns (temporary file, its
    SHA-256, size); 413 over the cap, 400 for a body cut off, 422 for an empty one."""
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > limit:
        raise HTTPException(413, f"upload of {int(declared)} bytes is over the {limit}-byte limit for {what}")
    h = hashlib.sha256()
    size = 0
    tmp = st.blobs.temp_file()
    try:
        with tmp:
            try:
                async for chunk in request.stream():
                    size += len(chunk)
                    if size > limit:
                        raise HTTPException(413, f"upload is over the {limit}-byte limit for {what}")
                    h.update(chunk)
                    tmp.write(chunk)
            except ClientDisconnect:
                raise HTTPException(400, "the upload was cut off before its end") from None
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
    akind, exts = KINDS[kind]
    ext = Path(filename).suffix.lower()
    if ext not in exts:
        raise HTTPException(415, f"{filename!r}: {kind} must be one of {', '.join(sorted(exts))}")
    limit = {"mesh": st.settings.max_mesh_bytes, "envmap": st.settings.max_envmap_bytes,
             "image": st.settings.max_image_bytes}[akind]
    tmp, sha, size = await receive_upload(request, st, limit, kind)
    try:
        named = Path(tmp.name + ext)
        os.replace(tmp.name, named)
        cfg = st.settings
        limits = {"max_mesh_faces": cfg.max_mesh_faces, "max_envmap_pixels": cfg.max_envmap_pixels,
                  "max_image_pixels": 64_000_000}
        meta = await run_in_threadpool(inspect_in_child, named, akind, limits, cfg.inspect_seconds)
        sha = st.blobs.put_file(named, sha)
    finally:
        for p in (Path(tmp.name), Path(tmp.name + ext)):
            p.unlink(missing_ok=True)

    def save():
        with st.db() as s, s.begin():
            a = Asset(kind=akind, filename=Path(filename).name, sha256=sha, size=size, meta=meta)
            s.add(a)
            s.flush()
            return _out(a)
    return await run_in_threadpool(save)


@router.get("/{asset_id}", response_model=AssetOut)
def get_asset(asset_id: str, db: DB, _: Client):
    a = db.get(Asset, asset_id)
    if a is None:
        raise HTTPException(404, f"no asset {asset_id!r}")
    return _out(a)
