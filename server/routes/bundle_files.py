"""The files of published bundles: content-addressed (named by the SHA-256 of their bytes), so
they never change and are served ``immutable`` for a year with a strong ETag (a conditional GET
is answered 304). A CDN in front of the service can keep them forever; the service serves
cached ones from memory without a thread hop (services/bundle_files.py)."""
from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request, Response
from fastapi.concurrency import run_in_threadpool

from ..deps import State
from ..services import bundle_files

router = APIRouter(tags=["publications"])
IMMUTABLE = "public, max-age=31536000, immutable"


def _matches(request: Request, etag: str) -> bool:
    inm = request.headers.get("if-none-match")
    if not inm:
        return False
    tags = [t.strip() for t in inm.split(",")]
    return "*" in tags or etag in tags or f"W/{etag}" in tags


async def serve(st, request: Request, name: str, cache_control: str = IMMUTABLE) -> Response:
    """A bundle file (404 for any name that is not one), or 304 when If-None-Match names it."""
    etag = f'"{name.split(".")[0]}"'
    headers = {"ETag": etag, "Cache-Control": cache_control}
    data = bundle_files.CACHE.get(name)
    if data is None:
        data = await run_in_threadpool(bundle_files.load, st, name)
    if data is None:
        raise HTTPException(404, f"no published file {name!r}")
    if _matches(request, etag):
        return Response(status_code=304, headers=headers)
    return Response(data, media_type=bundle_files.MEDIA[name.rsplit(".", 1)[1]], headers=headers)


@router.get("/v1/bundle-files/{name}", response_class=Response, responses={
    200: {"description": "a frame (image/webp, image/jpeg) or a manifest (application/json); Cache-Control: "
                         "public, max-age=31536000, immutable; ETag: its digest",
          "content": {"image/webp": {"schema": {"type": "string", "format": "binary"}},
                      "image/jpeg": {"schema": {"type": "string", "format": "binary"}},
                      "application/json": {}}},
    304: {"description": "If-None-Match named this file"}, 404: {"description": "no such published file"}})
async def get_bundle_file(name: str, request: Request, st: State):
    """One file of a published bundle, by the name its manifest gives it (``<sha256>.<ext>``)."""
    return await serve(st, request, name)
