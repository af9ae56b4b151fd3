"""Publications: a set of saved designs (variants) and environment presets for the shopper
viewer at ``/view/{id}``, and their static bundles: turntables of final frames built as a job
when published, served as immutable content-addressed files (any CDN can cache them) or
downloaded as a zip for any static host. Reading a publication and its bundle is public. Where
the publisher allows it (``live``), the viewer may also open a read-only streaming session: it
can turn the object, switch variants and presets, and nothing else."""
from __future__ import annotations

import asyncio
import re
from typing import Literal

from fastapi import APIRouter, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse
from pydantic import BaseModel, ConfigDict, Field

from .. import ratelimit
from ..db import Publication
from ..deps import DB, Client, State, client_key
from ..schemas import SessionOut
from ..services import publications
from . import bundle_files
from .errors import http_errors
from .sessions import check_frame_size

router = APIRouter(prefix="/v1/publications", tags=["publications"])


class VariantIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    material_id: str
    version: int | None = Field(None, ge=1, description="default: the latest")
    label: str | None = Field(None, max_length=100, description="default: the design's name")


class EnvironmentIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    asset_id: str | None = Field(None, description="an uploaded environment map; default: the scene's")
    label: str | None = Field(None, max_length=100, description="default: the map's name (its file name)")
    rotation_deg: float | None = Field(None, description="degrees about +Y; default: the scene's own rotation for "
                                       "the scene's map (as the studio shows it), 0 for another map")


class EncodeIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    avif_quality: int = Field(60, ge=1, le=100, description="AVIF quality of the 1× frames")
    avif_quality_2x: int = Field(40, ge=1, le=100, description="AVIF quality of the 2× frames (seen at twice the "
                                 "pixel density, where a lower quality does not show)")
    avif_speed: int = Field(10, ge=0, le=10, description="libavif effort: 10 the fastest (~40 ms of CPU a 640×480 "
                            "view for both sizes); lower is a few percent smaller at several times the time")
    jpeg_quality: int = Field(85, ge=1, le=100)


class BundleIn(BaseModel):
    """How the bundle's turntables are made (docs/guides/publishing.md)."""
    model_config = ConfigDict(extra="forbid")
    azimuths: int = Field(72, ge=1, le=360, description="frames per turn, evenly spaced from the scene camera's")
    elevations_deg: list[float] | None = Field(None, min_length=1, max_length=5,
                                               description="default: the scene camera's and 20° above it")
    width: int | None = Field(None, ge=16, le=4096, description="1× frame width; default: the scene camera's")
    height: int | None = Field(None, ge=16, le=4096, description="1× frame height; default: the scene camera's")
    samples: Literal[1, 2, 4, 9, 16] = Field(4, description="samples per pixel of the 2× frame where it "
                                             "anti-aliases (see antialias); the 1× frame averages 2 × 2 of them")
    antialias: Literal["edges", "full"] = Field("edges", description="edges: the samples at pixels next to a "
                                                "silhouette, occlusion or crease, one elsewhere (where more change "
                                                "nothing); full: at every pixel")
    shading: Literal["refined", "vertex", "pixel"] = "refined"
    tone: Literal["neutral", "aces", "linear"] = "neutral"
    exposure: float = Field(0.0, ge=-10, le=10)
    ground_shadow: bool | None = Field(None, description="default: the scene's ground (objects standing on it)")
    encode: EncodeIn = Field(default_factory=EncodeIn)


class PublicationCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str = Field(min_length=1, max_length=200)
    scene_id: str
    object: str | None = None
    variants: list[VariantIn] = Field(min_length=1, max_length=32)
    environments: list[EnvironmentIn] = Field(default_factory=list, max_length=16)
    live: bool = Field(False, description="the viewer may open a live streaming session (a worker per shopper)")
    bundle: BundleIn = Field(default_factory=BundleIn)


class BundleOut(BaseModel):
    status: Literal["none", "queued", "running", "done", "failed"]
    progress: float
    message: str
    stats: dict = Field(description="views, rendered, reused, files, bytes, seconds, … of the latest build")
    manifest: str | None = Field(description="URL of the last finished build's manifest (immutable)")


class PublicationOut(BaseModel):
    id: str
    name: str
    scene_id: str
    object: str
    variants: list[dict]
    environments: list[dict]
    live: bool
    bundle: BundleOut
    viewer: str
    download: str


def _out(p: Publication) -> PublicationOut:
    return PublicationOut(id=p.id, name=p.name, scene_id=p.scene_id, object=p.object, variants=p.variants,
                          environments=p.environments, live=bool(p.live), bundle=publications.bundle_state(p),
                          viewer=f"/view/{p.id}", download=f"/v1/publications/{p.id}/bundle.zip")


def _start_build(st, pub_id: str, bid: str) -> None:
    st.precompute_tasks[f"publication-{pub_id}"] = task = asyncio.create_task(publications.run_build(st, pub_id, bid))
    task.add_done_callback(lambda _t: st.precompute_tasks.pop(f"publication-{pub_id}", None))


def _args(req: PublicationCreate) -> tuple:
    return (req.name, req.scene_id, req.object, [v.model_dump() for v in req.variants],
            [e.model_dump() for e in req.environments], req.live, req.bundle.model_dump())


@router.post("", response_model=PublicationOut, status_code=201)
async def publish(req: PublicationCreate, st: State, _: Client):
    """Publish designs and start building their bundle (``bundle.status`` follows it)."""
    def create():
        with http_errors(), st.db() as s, s.begin():
            p = publications.publish(s, *_args(req))
            return p.id, publications.queue_build(s, p.id)
    pid, bid = await run_in_threadpool(create)
    _start_build(st, pid, bid)
    return await run_in_threadpool(_read, st, pid)


@router.put("/{pub_id}", response_model=PublicationOut, responses={409: {"description": "a build of it is running"}})
async def republish(pub_id: str, req: PublicationCreate, st: State, _: Client):
    """Publish again under the same id (designs at their latest versions unless named) and
    rebuild its bundle: only frames whose inputs changed are rendered; viewers keep the last
    finished bundle until the new one is done."""
    def update():
        with http_errors(), st.db() as s, s.begin():
            publications.republish(s, pub_id, *_args(req))
            return publications.queue_build(s, pub_id)
    bid = await run_in_threadpool(update)
    _start_build(st, pub_id, bid)
    return await run_in_threadpool(_read, st, pub_id)


def _read(st, pub_id: str) -> PublicationOut:
    with http_errors(), st.db() as s:
        return _out(publications.get(s, pub_id))


RATE_LIMITED = {429: {"description": "too many requests from this address in the last 60 s: the message names "
                                     "the limit, Retry-After the seconds to wait"}}


@router.get("/{pub_id}", response_model=PublicationOut, responses=RATE_LIMITED)
def get_publication(pub_id: str, request: Request, st: State, db: DB):
    ratelimit.check(request, "public_reads_per_minute", st.settings.public_reads_per_minute)
    with http_errors():
        return _out(publications.get(db, pub_id))


MANIFEST = {200: {"description": "the bundle manifest (docs/guides/publishing.md); ETag: its digest",
                  "content": {"application/json": {}}},
            304: {"description": "If-None-Match named the current manifest"},
            409: {"description": "no build has finished yet (the message gives its progress)"}}


@router.get("/{pub_id}/manifest", response_class=Response, responses=MANIFEST)
async def get_manifest(pub_id: str, request: Request, st: State):
    """The publication's current bundle manifest: revalidated on every use (``no-cache`` with
    an ETag, answered 304 when unchanged), since a republish replaces it; the files it names
    are immutable."""
    def sha():
        with http_errors(), st.db() as s:
            return publications.manifest_sha(s, pub_id)
    digest = await run_in_threadpool(sha)
    return await bundle_files.serve(st, request, f"{digest}.json", "no-cache")


@router.get("/{pub_id}/bundle.zip", response_class=FileResponse, responses={
    200: {"description": "index.html, player.js, viewer.css, manifest.json and files/ for any static host",
          "content": {"application/zip": {"schema": {"type": "string", "format": "binary"}}}}, **RATE_LIMITED})
async def download_bundle(pub_id: str, request: Request, st: State):
    """The current bundle as a zip to unpack on any static host (open its index.html)."""
    ratelimit.check(request, "public_reads_per_minute", st.settings.public_reads_per_minute)

    def make():
        with http_errors(), st.db() as s:
            p = publications.get(s, pub_id)
            digest = publications.manifest_sha(s, pub_id)
        return p.name, publications.bundle_zip(st, digest)
    name, path = await run_in_threadpool(make)
    safe = re.sub(r"[^\w.-]+", "_", name).strip("_") or "glint"
    return FileResponse(path, media_type="application/zip", filename=f"{safe}-bundle.zip")


@router.post("/{pub_id}/sessions", response_model=SessionOut, status_code=201, responses={
    **RATE_LIMITED, 403: {"description": "the publication does not allow the live mode"}})
def open_viewer(pub_id: str, request: Request, st: State, db: DB):
    """A read-only live session showing variant 0 under environment preset 0, for publications
    published with ``live`` (public, so rate limited per client address; deleted when unused
    for ``viewer_session_seconds``)."""
    ratelimit.check(request, "viewer_sessions_per_minute", st.settings.viewer_sessions_per_minute)
    with http_errors():
        p, sc = publications.viewer_scene(st, db, pub_id)
    check_frame_size(st.settings, sc.spec["camera"])
    row, token = publications.open_viewer(db, p, sc, client_key("anonymous", request))
    db.commit()
    return SessionOut(id=row.id, token=token, scene_id=sc.id, stream=f"/v1/sessions/{row.id}/stream", state=row.state)
