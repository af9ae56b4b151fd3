"""Material designs with versions: every save is a new version, nothing is overwritten;
deleting archives the design (its versions stay readable)."""
from __future__ import annotations

from fastapi import APIRouter, Path, Query, Response

from ..db import MaterialDesign, MaterialVersion
from ..deps import DB, Client, State
from ..schemas import MaterialCreate, MaterialOut, MaterialUpdate, VersionOut
from ..services import materials
from ..services.materials import add_version  # noqa: F401 -- routes/sessions.py saves versions through it
from .errors import http_errors

router = APIRouter(prefix="/v1/materials", tags=["materials"])
# integers from clients are bounded in the schema: a larger one overflowed the database
# driver's 64-bit integer (a 500) instead of being refused
MAX_INT = 2**31 - 1


def _thumb_url(v: MaterialVersion) -> str | None:
    return f"/v1/materials/{v.design_id}/versions/{v.version}/thumbnail" if v.thumbnail_sha256 else None


def _out(d: MaterialDesign, v: MaterialVersion) -> MaterialOut:
    return MaterialOut(id=d.id, name=d.name, version=v.version, material=v.body, scene_id=d.scene_id,
                       object=d.object, archived=d.archived, created=v.created, version_name=v.name or "",
                       thumbnail=_thumb_url(v))


def _version_out(v: MaterialVersion) -> VersionOut:
    return VersionOut(version=v.version, material=v.body, note=v.note, created=v.created, name=v.name or "",
                      thumbnail=_thumb_url(v))


@router.post("", response_model=MaterialOut, status_code=201)
def create_material(req: MaterialCreate, db: DB, _: Client):
    d, v = materials.create(db, req.name, req.scene_id, req.object, req.material.model_dump(mode="json"), req.note)
    db.commit()
    return _out(d, v)


@router.get("", response_model=list[MaterialOut])
def list_materials(db: DB, _: Client, include_archived: bool = Query(False)):
    return [_out(d, v) for d, v in materials.list_designs(db, include_archived)]


@router.get("/{material_id}", response_model=MaterialOut)
def get_material(material_id: str, db: DB, _: Client):
    with http_errors():
        return _out(*materials.get(db, material_id))


@router.put("/{material_id}", response_model=MaterialOut)
def update_material(material_id: str, req: MaterialUpdate, db: DB, _: Client):
    with http_errors():
        d, v = materials.save(db, material_id, req.material.model_dump(mode="json"), req.note)
    db.commit()
    return _out(d, v)


@router.get("/{material_id}/versions", response_model=list[VersionOut])
def list_versions(material_id: str, db: DB, _: Client):
    with http_errors():
        return [_version_out(v) for v in materials.versions(db, material_id)]


@router.get("/{material_id}/versions/{version}", response_model=VersionOut)
def get_version(material_id: str, db: DB, _: Client,
                version: int = Path(ge=1, le=MAX_INT, description="1, 2, … (the first save is 1)")):
    with http_errors():
        return _version_out(materials.version(db, material_id, version))


@router.get("/{material_id}/versions/{version}/thumbnail", response_class=Response,
            responses={200: {"content": {"image/jpeg": {}}, "description": "a JPEG of at most 192×144 pixels"},
                       404: {"description": "no such version, or it has no thumbnail"}})
def get_thumbnail(material_id: str, db: DB, st: State, _: Client,
                  version: int = Path(ge=1, le=MAX_INT, description="1, 2, … (the first save is 1)")):
    """The small JPEG of the frame a version was saved from (versions saved from a session)."""
    with http_errors():
        data = materials.thumbnail(db, st.blobs, material_id, version)
    # a version never changes, nor its thumbnail
    return Response(data, media_type="image/jpeg", headers={"Cache-Control": "private, max-age=31536000, immutable"})


@router.delete("/{material_id}", response_model=MaterialOut)
def archive_material(material_id: str, db: DB, _: Client):
    with http_errors():
        d, v = materials.archive(db, material_id)
    db.commit()
    return _out(d, v)
