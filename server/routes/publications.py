"""Publications: a set of saved designs (variants) and environment presets for the shopper
viewer at ``/view/{id}``. Reading a publication and opening a viewer session are public; a
viewer session is read-only: it can turn the object, switch variants and presets, and nothing
else, so a shopper cannot change a saved design."""
from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request
from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy import select

from ..db import Asset, MaterialDesign, MaterialVersion, Publication, Scene, Session, latest_version, new_secret, token_hash
from worker.jobs.state import EnvironmentMsg, VariantMsg, apply, new_state

from .. import ratelimit
from ..deps import DB, Client, State, client_key
from ..schemas import SessionOut
from ..state import Conflict, NotFound
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
    sc = db.get(Scene, req.scene_id)
    if sc is None:
        raise HTTPException(404, f"no scene {req.scene_id!r}")
    names = [o["name"] for o in sc.spec["objects"]]
    obj = req.object or names[0]
    if obj not in names:
        raise HTTPException(422, f"object: no object {obj!r} (objects: {', '.join(names)})")
    variants = []
    for i, v in enumerate(req.variants):
        d = db.get(MaterialDesign, v.material_id)
        if d is None:
            raise HTTPException(422, f"variants[{i}]: no material {v.material_id!r}")
        ver = latest_version(db, d.id) if v.version is None else db.scalars(
            select(MaterialVersion).where(MaterialVersion.design_id == d.id, MaterialVersion.version == v.version)).first()
        if ver is None:
            raise HTTPException(422, f"variants[{i}]: material {v.material_id!r} has no version {v.version}")
        variants.append({"label": v.label or d.name, "material_id": d.id, "version": ver.version, "material": ver.body})
    envs = []
    for i, e in enumerate(req.environments or [EnvironmentIn()]):
        aid = e.asset_id or sc.spec["environment"]["map"]
        a = db.get(Asset, aid)
        if a is None or a.kind != "envmap":
            raise HTTPException(422, f"environments[{i}]: {aid!r} is not an uploaded environment map")
        envs.append({"label": e.label, "asset_id": aid, "rotation_deg": e.rotation_deg})
    p = Publication(name=req.name, scene_id=sc.id, object=obj, variants=variants, environments=envs)
    db.add(p)
    db.commit()
    return _out(p)


RATE_LIMITED = {429: {"description": "too many requests from this address in the last 60 s: the message names "
                                     "the limit, Retry-After the seconds to wait"}}


@router.get("/{pub_id}", response_model=PublicationOut, responses=RATE_LIMITED)
def get_publication(pub_id: str, request: Request, st: State, db: DB):
    ratelimit.check(request, "public_reads_per_minute", st.settings.public_reads_per_minute)
    p = db.get(Publication, pub_id)
    if p is None:
        raise HTTPException(404, f"no publication {pub_id!r}")
    return _out(p)


@router.post("/{pub_id}/sessions", response_model=SessionOut, status_code=201, responses=RATE_LIMITED)
def open_viewer(pub_id: str, request: Request, st: State, db: DB):
    """A read-only session showing variant 0 under environment preset 0 (public, so rate limited
    per client address; deleted when unused for ``viewer_session_seconds``)."""
    ratelimit.check(request, "viewer_sessions_per_minute", st.settings.viewer_sessions_per_minute)
    p = db.get(Publication, pub_id)
    if p is None:
        raise HTTPException(404, f"no publication {pub_id!r}")
    try:
        st.scene_payload(db, p.scene_id)
    except (Conflict, NotFound) as e:
        raise HTTPException(409, str(e)) from None
    sc = db.get(Scene, p.scene_id)
    check_frame_size(st.settings, sc.spec["camera"])
    envs = []
    for e in p.environments:
        a = db.get(Asset, e["asset_id"])
        envs.append({"label": e["label"], "sha256": a.sha256, "filename": a.filename, "rotation_deg": e["rotation_deg"]})
    variants = [{"label": v["label"], "material": v["material"]} for v in p.variants]
    state = new_state(sc.spec, p.object, readonly=True, publication=p.id, variants=variants, environments=envs,
                      quality=80)
    state, _ = apply(state, VariantMsg(seq=0, index=0))
    state, _ = apply(state, EnvironmentMsg(seq=0, index=0))
    state.last_seq = -1
    token = new_secret()
    row = Session(scene_id=sc.id, token_sha256=token_hash(token), state=state.model_dump(mode="json"),
                  client=client_key("anonymous", request))
    db.add(row)
    db.commit()
    return SessionOut(id=row.id, token=token, scene_id=sc.id, stream=f"/v1/sessions/{row.id}/stream", state=row.state)
