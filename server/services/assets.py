"""Uploaded files (meshes, environment maps, images): what a name's type may be, the size
limits, the check of the bytes (in a child process with a time limit, server/inspect.py), the
blob under its SHA-256 and the asset row."""
from __future__ import annotations

import os
from pathlib import Path

from ..db import Asset
from .errors import Invalid, NotFound

# the upload path's segment -> (asset kind, accepted file name extensions)
KINDS = {"meshes": ("mesh", {".obj", ".ply", ".glb", ".stl"}),
         "envmaps": ("envmap", {".exr", ".hdr"}),
         "images": ("image", {".png", ".exr", ".hdr", ".npy"})}


def upload_kind(kind: str, filename: str) -> tuple[str, str]:
    """(asset kind, extension) of an upload to ``/v1/assets/{kind}`` named ``filename``;
    Invalid (415) for an extension the kind does not take."""
    akind, exts = KINDS[kind]
    ext = Path(filename).suffix.lower()
    if ext not in exts:
        raise Invalid(f"{filename!r}: {kind} must be one of {', '.join(sorted(exts))}", 415)
    return akind, ext


def size_limit(settings, akind: str) -> int:
    return {"mesh": settings.max_mesh_bytes, "envmap": settings.max_envmap_bytes,
            "image": settings.max_image_bytes}[akind]


def check_and_store(settings, blobs, tmp_name: str, akind: str, ext: str, sha: str) -> tuple[str, dict]:
    """Read the uploaded temporary file in a child process (type, triangle or pixel counts, NaN
    and negative radiance) and store it as a blob: (SHA-256, what the check found). The
    temporary file is gone afterwards, stored or not. Blocking: call it from a thread."""
    from fastapi import HTTPException

    from ..inspect import inspect_in_child

    named = Path(tmp_name + ext)       # the readers go by the extension
    try:
        os.replace(tmp_name, named)
        limits = {"max_mesh_faces": settings.max_mesh_faces, "max_envmap_pixels": settings.max_envmap_pixels,
                  "max_image_pixels": 64_000_000}
        try:
            meta = inspect_in_child(named, akind, limits, settings.inspect_seconds)
        except HTTPException as e:     # the inspector answers in HTTP terms: a bad upload, explained
            raise Invalid(e.detail, e.status_code) from None
        return blobs.put_file(named, sha), meta
    finally:
        for p in (Path(tmp_name), named):
            p.unlink(missing_ok=True)


def create(s, akind: str, filename: str, sha: str, size: int, meta: dict) -> Asset:
    a = Asset(kind=akind, filename=Path(filename).name, sha256=sha, size=size, meta=meta)
    s.add(a)
    s.flush()
    return a


def get(s, asset_id: str) -> Asset:
    a = s.get(Asset, asset_id)
    if a is None:
        raise NotFound(f"no asset {asset_id!r}")
    return a


def image_file(s, ref: str, key: str) -> dict:
    """The blob reference of an uploaded image asset (a fit's target or mask): Invalid when
    ``ref`` is no image asset; ``key`` names the request's field."""
    a = s.get(Asset, ref)
    if a is None or a.kind != "image":
        raise Invalid(f"{key}_asset: {ref!r} is not an uploaded image asset")
    return {"sha256": a.sha256, "filename": a.filename}
