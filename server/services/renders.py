"""Renders and fits for automation clients: the worker jobs they are (a scene's payload with the
request), and a fit's result saved as a new material design. The jobs run in the worker pool;
``JobFailed`` from it carries the status of what went wrong."""
from __future__ import annotations

from . import assets, materials
from .errors import Invalid


def render_job(st, scene_id: str, request: dict) -> dict:
    """The render job of a scene: NotFound without the scene or one of its assets, Conflict
    before its precomputation is done. ``request``: the render's fields (camera, materials,
    format, …) as JSON. Blocking (the database): call it from a thread."""
    with st.db() as s:
        scene = st.scene_payload(s, scene_id)
    return {"type": "render", "scene": scene, **request}


def fit_job(st, scene_id: str, obj: str, request: dict, target_asset: str | None, mask_asset: str | None,
            strokes: bool) -> dict:
    """The fit job of one object to strokes or to a target image asset (and its mask): as
    render_job, and Invalid for both or neither of strokes and target, an unknown object, or
    an asset that is no image. ``request``: the fit request as JSON. Blocking."""
    if strokes == bool(target_asset):
        raise Invalid("give exactly one of strokes and target_asset")
    with st.db() as s:
        scene = st.scene_payload(s, scene_id)
    names = [o["name"] for o in scene["spec"]["objects"]]
    if obj not in names:
        raise Invalid(f"object: no object {obj!r} (objects: {', '.join(names)})")
    files = {}
    with st.db() as s:
        for key, ref in (("target", target_asset), ("mask", mask_asset)):
            if ref is not None:
                files[key] = assets.image_file(s, ref, key)
    return {"type": "fit", "scene": scene, "request": request, **files}


def save_fit(st, name: str, scene_id: str, obj: str, material: dict) -> tuple[str, int]:
    """A fit's material as a new design: (its id, version 1). Blocking."""
    with st.db() as s, s.begin():
        d, v = materials.create(s, name, scene_id, obj, material, "fit")
        return d.id, v.version
