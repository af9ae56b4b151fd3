"""Publications: a set of saved designs (variants) and environment presets for the shopper
viewer at ``/view/{id}``. Reading a publication and opening a viewer session are public; a
viewer session is read-only: it can turn the object, switch variants and presets, and nothing
else, so a shopper cannot change a saved design."""
from __future__ import annotations

from fastapi import APIRouter, Request
from pydantic import BaseModel, ConfigDict, Field

from .. import ratelimit
from ..db import Publication
from ..deps import DB, Client, State, client_key
from ..schemas import SessionOut
from ..services import publications
from .errors import http_errors
from .sessions import check_frame_size

router = APIRouter(prefix="/v1/publications", tags=["publications"])


class VariantIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    material_id: str
    version: int | None = Field(None, ge=1, description="default: the latest")
    label: str | None = Field(None, max_length=100)


class EnvironmentIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    asset_id: str | None = Field(None, description="an uploaded environment map; default: the scene's")
    label: str = Field("studio", max_length=100)
    rotation_deg: float = 0.0


class PublicationCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str = Field(min_length=1, max_length=200)
    scene_id: str
    object: str | None = None
    variants: list[VariantIn] = Field(min_length=1, max_length=32)
    environments: list[EnvironmentIn] = Field(default_factory=list, max_length=16)


class PublicationOut(BaseModel):
    id: str
    name: str
    scene_id: str
    object: str
    variants: list[dict]
    environments: list[dict]
    viewer: str


def _out(p: Publication) -> PublicationOut:
    return PublicationOut(id=p.id, name=p.name, scene_id=p.scene_id, object=p.object, variants=p.variants,
                          environments=p.environments, viewer=f"/view/{p.id}")


@router.post("", response_model=PublicationOut, status_code=201)
def publish(req: PublicationCreate, db: DB, _: Client):
    with http_errors():
        p = publications.publish(db, req.name, req.scene_id, req.object, [v.model_dump() for v in req.variants],
                                 [e.model_dump() for e in req.environments or [EnvironmentIn()]])
    db.commit()
    return _out(p)


RATE_LIMITED = {429: {"description": "too many requests from this address in the last 60 s: the message names "
                                     "the limit, Retry-After the seconds to wait"}}


@router.get("/{pub_id}", response_model=PublicationOut, responses=RATE_LIMITED)
def get_publication(pub_id: str, request: Request, st: State, db: DB):
    ratelimit.check(request, "public_reads_per_minute", st.settings.public_reads_per_minute)
    with http_errors():
        return _out(publications.get(db, pub_id))


@router.post("/{pub_id}/sessions", response_model=SessionOut, status_code=201, responses=RATE_LIMITED)
def open_viewer(pub_id: str, request: Request, st: State, db: DB):
    """A read-only session showing variant 0 under environment preset 0 (public, so rate limited
    per client address; deleted when unused for ``viewer_session_seconds``)."""
    ratelimit.check(request, "viewer_sessions_per_minute", st.settings.viewer_sessions_per_minute)
    with http_errors():
        p, sc = publications.viewer_scene(st, db, pub_id)
    check_frame_size(st.settings, sc.spec["camera"])
    row, token = publications.open_viewer(db, p, sc, client_key("anonymous", request))
    db.commit()
    return SessionOut(id=row.id, token=token, scene_id=sc.id, stream=f"/v1/sessions/{row.id}/stream", state=row.state)
