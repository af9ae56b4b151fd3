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
    200: {"description": "a frame (image/avif, image/jpeg), a manifest (application/json) or the published "
                         "object's glTF model (model/gltf-binary); Cache-Control: public, max-age=31536000, "
                         "immutable; ETag: its digest",
          "content": {"image/avif": {"schema": {"type": "string", "format": "binary"}},
                      "image/jpeg": {"schema": {"type": "string", "format": "binary"}},
                      "model/gltf-binary": {"schema": {"type": "string", "format": "binary"}},
                      "application/json": {}}},
    304: {"description": "If-None-Match named this file"}, 404: {"description": "no such published file"}})
async def get_bundle_file(name: str, request: Request, st: State):
    """One file of a published bundle, by the name its manifest gives it (``<sha256>.<ext>``)."""
    return await serve(st, request, name)


class _Route:
    path = "/v1/bundle-files/{name}"


_ROUTE = _Route()


class CachedBundleFiles:
    """ASGI layer in front of the app's routing: a GET of a bundle file already in the memory
    cache is answered here (200, or 304 for a matching If-None-Match), without the routing, the
    dependency injection and the request-guard layers behind it, which cost several times the
    answer itself; a file not cached yet goes on to the route (``get_bundle_file``), which
    loads it. The files are public and immutable, so the Host and Origin checks those layers
    make (against DNS rebinding of private answers) have nothing to protect here. Placed inside
    the request-context layer, so such answers still get a request id, an access line and
    their metrics."""

    PREFIX = "/v1/bundle-files/"

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        path = scope.get("path", "")
        if scope["type"] != "http" or scope.get("method") != "GET" or not path.startswith(self.PREFIX):
            return await self.app(scope, receive, send)
        name = path[len(self.PREFIX):]
        data = bundle_files.CACHE.get(name)
        if data is None:
            return await self.app(scope, receive, send)
        scope["route"] = _ROUTE          # the metrics and access line name the route template
        digest = name.split(".")[0]
        etag = f'"{digest}"'.encode()
        inm = next((v for k, v in scope.get("headers") or () if k == b"if-none-match"), None)
        hit = inm is not None and any(t.strip() in (etag, b"W/" + etag, b"*") for t in inm.split(b","))
        headers = [(b"etag", etag), (b"cache-control", IMMUTABLE.encode()), (b"x-content-type-options", b"nosniff")]
        if hit:
            await send({"type": "http.response.start", "status": 304, "headers": headers})
            await send({"type": "http.response.body", "body": b""})
            return
        headers += [(b"content-type", bundle_files.MEDIA[name.rsplit(".", 1)[1]].encode()),
                    (b"content-length", str(len(data)).encode())]
        await send({"type": "http.response.start", "status": 200, "headers": headers})
        await send({"type": "http.response.body", "body": data})
