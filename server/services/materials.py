"""Material designs with versions: every save is a new version, nothing is overwritten;
archiving a design keeps its versions readable. Functions return (design, version) rows."""
from __future__ import annotations

from sqlalchemy import select, update

from ..db import MaterialDesign, MaterialVersion, latest_version
from .errors import Conflict, NotFound


def design(db, material_id: str) -> MaterialDesign:
    d = db.get(MaterialDesign, material_id)
    if d is None:
        raise NotFound(f"no material {material_id!r}")
    return d


def add_version(db, d: MaterialDesign, body: dict, note: str = "", name: str = "",
                thumbnail_sha256: str | None = None) -> MaterialVersion:
    """The design's next version. name : the version's label; thumbnail_sha256 : a JPEG in the
    blob store (the frame it was saved from)."""
    # lock the design until commit, so that concurrent saves (sessions, REST) number their versions
    # one after the other: a no-op UPDATE takes the row lock on PostgreSQL and the write lock on
    # SQLite, whose driver runs the reads before a transaction's first write outside it
    db.execute(update(MaterialDesign).where(MaterialDesign.id == d.id).values(archived=MaterialDesign.archived)
               .execution_options(synchronize_session=False))
    cur = latest_version(db, d.id)
    v = MaterialVersion(design_id=d.id, version=(cur.version + 1) if cur else 1, body=body, note=note,
                        name=name, thumbnail_sha256=thumbnail_sha256)
    db.add(v)
    return v


def create(db, name: str, scene_id: str | None, object: str | None, body: dict, note: str = ""):
    """A new design whose first version is ``body`` (a material's JSON form)."""
    d = MaterialDesign(name=name, scene_id=scene_id, object=object)
    db.add(d)
    db.flush()
    return d, add_version(db, d, body, note)


def list_designs(db, include_archived: bool = False):
    """The newest 500 designs first, each with its latest version."""
    q = select(MaterialDesign).order_by(MaterialDesign.created.desc()).limit(500)
    if not include_archived:
        q = q.where(MaterialDesign.archived.is_(False))
    return [(d, latest_version(db, d.id)) for d in db.scalars(q)]


def get(db, material_id: str):
    d = design(db, material_id)
    return d, latest_version(db, d.id)


def save(db, material_id: str, body: dict, note: str = ""):
    """A new version of a design; an archived one takes none (Conflict)."""
    d = design(db, material_id)
    if d.archived:
        raise Conflict(f"material {material_id!r} is archived")
    return d, add_version(db, d, body, note)


def versions(db, material_id: str) -> list[MaterialVersion]:
    design(db, material_id)
    return list(db.scalars(select(MaterialVersion).where(MaterialVersion.design_id == material_id)
                           .order_by(MaterialVersion.version)))


def version(db, material_id: str, number: int) -> MaterialVersion:
    v = db.scalars(select(MaterialVersion).where(MaterialVersion.design_id == material_id,
                                                 MaterialVersion.version == number)).first()
    if v is None:
        raise NotFound(f"material {material_id!r} has no version {number}")
    return v


def thumbnail(db, blobs, material_id: str, number: int) -> bytes:
    """A version's thumbnail JPEG (NotFound: the version has none: saved over REST)."""
    v = version(db, material_id, number)
    if v.thumbnail_sha256 is None:
        raise NotFound(f"material {material_id!r} version {number} has no thumbnail (it was not saved from a session)")
    return blobs.get(v.thumbnail_sha256)


def archive(db, material_id: str):
    d = design(db, material_id)
    d.archived = True
    return d, latest_version(db, d.id)
