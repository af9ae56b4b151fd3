"""Publications: saved designs (variants) and environment presets of one object of a scene, for
the shopper viewer; and the read-only sessions that viewer opens on them."""
from __future__ import annotations

from sqlalchemy import select

from worker.protocol.messages import EnvironmentMsg, VariantMsg, apply
from worker.protocol.state import new_state

from ..db import Asset, MaterialDesign, MaterialVersion, Publication, Scene, Session, latest_version, new_secret, token_hash
from .errors import Conflict, Invalid, NotFound


def publish(s, name: str, scene_id: str, obj: str | None, variants: list[dict], environments: list[dict]) -> Publication:
    """variants: {material_id, version (None: the latest), label}; environments: {asset_id (None:
    the scene's map), label, rotation_deg}. The designs' versions are copied in, so a later save
    does not change what shoppers see. NotFound without the scene; Invalid for a bad object,
    design, version or map, named by its place in the request."""
    sc = s.get(Scene, scene_id)
    if sc is None:
        raise NotFound(f"no scene {scene_id!r}")
    names = [o["name"] for o in sc.spec["objects"]]
    obj = obj or names[0]
    if obj not in names:
        raise Invalid(f"object: no object {obj!r} (objects: {', '.join(names)})")
    out_variants = []
    for i, v in enumerate(variants):
        d = s.get(MaterialDesign, v["material_id"])
        if d is None:
            raise Invalid(f"variants[{i}]: no material {v['material_id']!r}")
        ver = latest_version(s, d.id) if v["version"] is None else s.scalars(
            select(MaterialVersion).where(MaterialVersion.design_id == d.id, MaterialVersion.version == v["version"])).first()
        if ver is None:
            raise Invalid(f"variants[{i}]: material {v['material_id']!r} has no version {v['version']}")
        out_variants.append({"label": v["label"] or d.name, "material_id": d.id, "version": ver.version,
                             "material": ver.body})
    envs = []
    for i, e in enumerate(environments):
        aid = e["asset_id"] or sc.spec["environment"]["map"]
        a = s.get(Asset, aid)
        if a is None or a.kind != "envmap":
            raise Invalid(f"environments[{i}]: {aid!r} is not an uploaded environment map")
        envs.append({"label": e["label"], "asset_id": aid, "rotation_deg": e["rotation_deg"]})
    p = Publication(name=name, scene_id=sc.id, object=obj, variants=out_variants, environments=envs)
    s.add(p)
    return p


def get(s, pub_id: str) -> Publication:
    p = s.get(Publication, pub_id)
    if p is None:
        raise NotFound(f"no publication {pub_id!r}")
    return p


def viewer_scene(st, s, pub_id: str) -> tuple[Publication, Scene]:
    """The publication and its scene, ready to be viewed: NotFound without the publication,
    Conflict while its scene cannot be (its assets or precomputation missing)."""
    p = get(s, pub_id)
    try:
        st.scene_payload(s, p.scene_id)
    except (Conflict, NotFound) as e:
        raise Conflict(str(e)) from None
    return p, s.get(Scene, p.scene_id)


def open_viewer(s, p: Publication, sc: Scene, client: str) -> tuple[Session, str]:
    """A read-only session on variant 0 under environment preset 0: (its row, its token)."""
    envs = []
    for e in p.environments:
        a = s.get(Asset, e["asset_id"])
        envs.append({"label": e["label"], "sha256": a.sha256, "filename": a.filename, "rotation_deg": e["rotation_deg"]})
    variants = [{"label": v["label"], "material": v["material"]} for v in p.variants]
    state = new_state(sc.spec, p.object, readonly=True, publication=p.id, variants=variants, environments=envs,
                      quality=80)
    state, _ = apply(state, VariantMsg(seq=0, index=0))
    state, _ = apply(state, EnvironmentMsg(seq=0, index=0))
    state.last_seq = -1
    token = new_secret()
    row = Session(scene_id=sc.id, token_sha256=token_hash(token), state=state.model_dump(mode="json"), client=client)
    s.add(row)
    return row, token
