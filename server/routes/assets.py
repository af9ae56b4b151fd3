"""Uploads of meshes, environment maps and images (targets, masks).

The body is the raw file (``Content-Type: application/octet-stream``), with ``?filename=`` giving
its name and type. It is streamed to a temporary file with a size cap, hashed, checked by
actually reading it (type, triangle count, pixel count before decoding, NaN and negative
radiance), and only then stored under its SHA-256.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Literal

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect

from ..db import Asset
from ..deps import DB, Client, State
from ..schemas import AssetOut

router = APIRouter(prefix="/v1/assets", tags=["assets"])

KINDS = {"meshes": ("mesh", {".obj", ".ply", ".glb", ".stl"}),
         "envmaps": ("envmap", {".exr", ".hdr"}),
         "images": ("image", {".png", ".exr", ".hdr", ".npy"})}


def _out(a: Asset) -> AssetOut:
    return AssetOut(id=a.id, kind=a.kind, filename=a.filename, sha256=a.sha256, size=a.size, meta=a.meta or {},
                    created=a.created)


def _check_mesh(path: Path, st) -> dict:
    from worker.scene import SceneError, load_mesh

    try:
        m = load_mesh(path)
    except SceneError as e:
        raise HTTPException(422, str(e).replace(str(path), "the upload")) from None
    if len(m.faces) > st.settings.max_mesh_faces:
        raise HTTPException(413, f"{len(m.faces)} triangles is more than the limit of {st.settings.max_mesh_faces}")
    lo, hi = m.vertices.min(0), m.vertices.max(0)
    return {"vertices": int(len(m.vertices)), "faces": int(len(m.faces)), "bounds": [lo.tolist(), hi.tolist()]}


def _image_size(path: Path) -> tuple[int, int]:
    """(width, height) read from the header alone, before any decoding (decompression bombs)."""
    suf = path.suffix.lower()
    if suf == ".exr":
        import OpenEXR

        try:
            dw = OpenEXR.File(str(path), header_only=True).header()["dataWindow"]
        except Exception as e:
            raise HTTPException(422, f"not a readable OpenEXR file ({e})") from None
        (x0, y0), (x1, y1) = dw
        return int(x1 - x0 + 1), int(y1 - y0 + 1)
    if suf == ".hdr":
        with open(path, "rb") as f:
            head = f.read(4096)
        if not (head.startswith(b"#?RADIANCE") or head.startswith(b"#?RGBE")):
            raise HTTPException(422, "not a Radiance .hdr file")
        for line in head.split(b"\n"):
            parts = line.split()
            if len(parts) == 4 and parts[0] in (b"-Y", b"+Y") and parts[2] in (b"+X", b"-X"):
                return int(parts[3]), int(parts[1])
        raise HTTPException(422, "Radiance .hdr header has no resolution line")
    if suf == ".npy":
        try:
            arr = np.load(path, mmap_mode="r", allow_pickle=False)
        except Exception as e:
            raise HTTPException(422, f"not a readable .npy array ({e})") from None
        if arr.ndim != 3:
            raise HTTPException(422, f"an image array must be H×W×3, got shape {arr.shape}")
        return int(arr.shape[1]), int(arr.shape[0])
    from PIL import Image

    try:
        with Image.open(path) as im:
            return im.size
    except Exception as e:
        raise HTTPException(422, f"not a readable image ({e})") from None


def _check_envmap(path: Path, st) -> dict:
    from worker.envmap import EnvMapError, load_envmap

    w, h = _image_size(path)
    if w * h > st.settings.max_envmap_pixels:
        raise HTTPException(413, f"{w}×{h} pixels is more than the limit of {st.settings.max_envmap_pixels}")
    try:
        img = load_envmap(path)
    except EnvMapError as e:
        raise HTTPException(422, str(e).replace(str(path), "the upload")) from None
    return {"width": int(img.shape[1]), "height": int(img.shape[0]), "mean_radiance": float(img.mean())}


def _check_image(path: Path, st) -> dict:
    from worker.fit.files import load_target
    from worker.scene import SceneError

    w, h = _image_size(path)
    if w * h > 64_000_000:
        raise HTTPException(413, f"{w}×{h} pixels is too large for a target image")
    try:
        img = load_target(path)
    except SceneError as e:
        raise HTTPException(422, str(e).replace(str(path), "the upload")) from None
    return {"width": int(img.shape[1]), "height": int(img.shape[0])}


@router.post("/{kind}", response_model=AssetOut, status_code=201)
async def upload(kind: Literal["meshes", "envmaps", "images"], request: Request, st: State, _: Client,
                 filename: str = Query(..., min_length=1, max_length=255, description="original file name (its extension gives the type)")):
    akind, exts = KINDS[kind]
    ext = Path(filename).suffix.lower()
    if ext not in exts:
        raise HTTPException(415, f"{filename!r}: {kind} must be one of {', '.join(sorted(exts))}")
    limit = {"mesh": st.settings.max_mesh_bytes, "envmap": st.settings.max_envmap_bytes,
             "image": st.settings.max_image_bytes}[akind]
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > limit:
        raise HTTPException(413, f"upload of {int(declared)} bytes is over the {limit}-byte limit for {kind}")
    h = hashlib.sha256()
    size = 0
    tmp = st.blobs.temp_file()
    try:
        with tmp:
            try:
                async for chunk in request.stream():
                    size += len(chunk)
                    if size > limit:
                        raise HTTPException(413, f"upload is over the {limit}-byte limit for {kind}")
                    h.update(chunk)
                    tmp.write(chunk)
            except ClientDisconnect:
                raise HTTPException(400, "the upload was cut off before its end") from None
        if declared and declared.isdigit() and int(declared) != size:
            raise HTTPException(400, f"the upload is truncated: {size} of {declared} bytes arrived")
        if size == 0:
            raise HTTPException(422, "the upload is empty")
        named = Path(tmp.name + ext)
        os.replace(tmp.name, named)
        check = {"mesh": _check_mesh, "envmap": _check_envmap, "image": _check_image}[akind]
        meta = await run_in_threadpool(check, named, st)
        sha = st.blobs.put_file(named, h.hexdigest())
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
