"""Material designs with versions: every save is a new version, nothing is overwritten;
deleting archives the design (its versions stay readable)."""
from __future__ import annotations

from fastapi import APIRouter, HTTPException, Path, Query
from sqlalchemy import select, update

from ..db import MaterialDesign, MaterialVersion, latest_version
from ..deps import DB, Client
from ..schemas import MaterialCreate, MaterialOut, MaterialUpdate, VersionOut

router = APIRouter(prefix="/v1/materials", tags=["materials"])
# integers from clients are bounded in the schema: a larger one overflowed the database
# driver's 64-bit integer (a 500) instead of being refused
MAX_INT = 2**31 - 1


def _out(d: MaterialDesign, v: MaterialVersion) -> MaterialOut:
    return MaterialOut(id=d.id, name=d.name, version=v.version, material=v.body, scene_id=d.scene_id,
                       object=d.object, archived=d.archived, created=v.created)


def _design(db, material_id: str) -> MaterialDesign:
    d = db.get(MaterialDesign, material_id)
    if d is None:
        raise HTTPException(404, f"no material {material_id!r}")
    return d


def add_version(db, d: MaterialDesign, body: dict, note: str = "") -> MaterialVersion:
    # lock the design until commit, so that concurrent saves (sessions, REST) number their versions
    # one after the other: a no-op UPDATE takes the row lock on PostgreSQL and the write lock on
    # SQLite, whose driver runs the reads before a transaction's first write outside it
    db.execute(update(MaterialDesign).where(MaterialDesign.id == d.id).values(archived=MaterialDesign.archived)
               .execution_options(synchronize_session=False))
    cur = latest_version(db, d.id)
    v = MaterialVersion(design_id=d.id, version=(cur.version + 1) if cur else 1, body=body, note=note)
    db.add(v)
    return v


@router.post("", response_model=MaterialOut, status_code=201)
def create_material(req: MaterialCreate, db: DB, _: Client):
    d = MaterialDesign(name=req.name, scene_id=req.scene_id, object=req.object)
    db.add(d)
    db.flush()
    v = add_version(db, d, req.material.model_dump(mode="json"), req.note)
    db.commit()
    return _out(d, v)


@router.get("", response_model=list[MaterialOut])
def list_materials(db: DB, _: Client, include_archived: bool = Query(False)):
    q = select(MaterialDesign).order_by(MaterialDesign.created.desc()).limit(500)
    if not include_archived:
        q = q.where(MaterialDesign.archived.is_(False))
    return [_out(d, latest_version(db, d.id)) for d in db.scalars(q)]


@router.get("/{material_id}", response_model=MaterialOut)
def get_material(material_id: str, db: DB, _: Client):
    d = _design(db, material_id)
    return _out(d, latest_version(db, d.id))


@router.put("/{material_id}", response_model=MaterialOut)
def update_material(material_id: str, req: MaterialUpdate, db: DB, _: Client):
    d = _design(db, material_id)
    if d.archived:
        raise HTTPException(409, f"material {material_id!r} is archived")
    v = add_version(db, d, req.material.model_dump(mode="json"), req.note)
    db.commit()
    return _out(d, v)


@router.get("/{material_id}/versions", response_model=list[VersionOut])
def list_versions(material_id: str, db: DB, _: Client):
    _design(db, material_id)
    rows = db.scalars(select(MaterialVersion).where(MaterialVersion.design_id == material_id)
                      .order_by(MaterialVersion.version))
    return [VersionOut(version=v.version, material=v.body, note=v.note, created=v.created) for v in rows]


@router.get("/{material_id}/versions/{version}", response_model=VersionOut)
def get_version(material_id: str, db: DB, _: Client,
                version: int = Path(ge=1, le=MAX_INT, description="1, 2, … (the first save is 1)")):
    v = db.scalars(select(MaterialVersion).where(MaterialVersion.design_id == material_id,
                                                 MaterialVersion.version == version)).first()
    if v is None:
        raise HTTPException(404, f"material {material_id!r} has no version {version}")
    return VersionOut(version=v.version, material=v.body, note=v.note, created=v.created)


@router.delete("/{material_id}", response_model=MaterialOut)
def archive_material(material_id: str, db: DB, _: Client):
    d = _design(db, material_id)
    d.archived = True
    db.commit()
    return _out(d, latest_version(db, d.id))
