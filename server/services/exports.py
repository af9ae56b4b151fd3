"""Exports of a scene (glTF, MaterialX, Mitsuba 3): the worker job they are, with the design
variants resolved from saved materials (pinned versions) or from a publication."""
from __future__ import annotations

from sqlalchemy import select

from ..db import MaterialDesign, MaterialVersion, Publication, latest_version
from .errors import Invalid, NotFound

MEDIA = {"gltf": ("model/gltf-binary", "glb"), "mtlx": ("application/xml", "mtlx"), "mitsuba": ("application/zip", "zip")}


def _version(s, i: int, material_id: str, version: int | None) -> MaterialVersion:
    d = s.get(MaterialDesign, material_id)
    if d is None:
        raise Invalid(f"variants[{i}]: no material {material_id!r}")
    v = latest_version(s, d.id) if version is None else s.scalars(
        select(MaterialVersion).where(MaterialVersion.design_id == d.id, MaterialVersion.version == version)).first()
    if v is None:
        raise Invalid(f"variants[{i}]: material {material_id!r} has no version {version}")
    return v, d


def export_job(st, scene_id: str | None, fmt: str, obj: str | None, variants: list[dict],
               publication_id: str | None, render_check: bool) -> dict:
    """The export job: the scene's payload (its precomputation only for the render check), and
    the variants as {"label", "materials": {object: material JSON}}. With ``publication_id``,
    the publication's scene, object and variants. NotFound without the scene or publication;
    Invalid for an unknown object, design or version, or both or neither of scene and
    publication. Blocking (the database): call it from a thread."""
    if (scene_id is None) == (publication_id is None):
        raise Invalid("give exactly one of scene_id and publication_id")
    with st.db() as s:
        if publication_id is not None:
            p = s.get(Publication, publication_id)
            if p is None:
                raise NotFound(f"no publication {publication_id!r}")
            scene_id, obj = p.scene_id, p.object
            out = [{"label": v["label"], "materials": {obj: v["material"]}} for v in p.variants]
        else:
            out = []
        scene = st.scene_payload(s, scene_id, need_parts=render_check)
        names = [o["name"] for o in scene["spec"]["objects"]]
        obj = obj or names[0]
        if obj not in names:
            raise Invalid(f"object: no object {obj!r} (objects: {', '.join(names)})")
        for i, v in enumerate(variants):
            ver, d = _version(s, i, v["material_id"], v.get("version"))
            out.append({"label": v.get("label") or d.name, "materials": {obj: ver.body}})
    return {"type": "export", "scene": scene, "format": fmt, "variants": out, "render_check": render_check}
