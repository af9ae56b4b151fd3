"""Renders and fits for automation clients: run in a worker, answered when done."""
from __future__ import annotations

from fastapi import APIRouter, HTTPException, Response
from fastapi.concurrency import run_in_threadpool

from ..db import Asset, MaterialDesign, MaterialVersion
from ..deps import Client, State
from ..schemas import FitOut, FitRequest, RenderRequest
from ..state import Conflict, NotFound
from ..workers import JobFailed

router = APIRouter(tags=["renders and fits"])


def payload_or_http(st, scene_id: str) -> dict:
    with st.db() as s:
        try:
            return st.scene_payload(s, scene_id)
        except NotFound as e:
            raise HTTPException(404, str(e)) from None
        except Conflict as e:
            raise HTTPException(409, str(e)) from None


async def run(st, job: dict) -> dict:
    try:
        return await st.pool.run_job(job)
    except JobFailed as e:
        raise HTTPException(e.status if 400 <= e.status < 600 else 500, str(e)) from None


BINARY = {"schema": {"type": "string", "format": "binary"}}


@router.post("/v1/renders", response_class=Response,
             responses={200: {"description": "the image: PNG (tone-mapped sRGB), or with format exr an OpenEXR "
                                             "file of linear radiance (Content-Type image/x-exr)",
                              "content": {"image/png": BINARY, "image/x-exr": BINARY}}})
async def render(req: RenderRequest, st: State, _: Client):
    """Render the scene (PNG, tone-mapped; or linear EXR with ``format: exr``)."""
    scene = await run_in_threadpool(payload_or_http, st, req.scene_id)
    job = {"type": "render", "scene": scene, **req.model_dump(mode="json", exclude={"scene_id"})}
    res = await run(st, job)
    return Response(content=res["bytes"], media_type=res["media_type"])


@router.post("/v1/fits", response_model=FitOut)
async def fit(req: FitRequest, st: State, _: Client):
    """Fit an ``srbf`` material for one object to strokes or to a target image asset."""
    if bool(req.strokes) == bool(req.target_asset):
        raise HTTPException(422, "give exactly one of strokes and target_asset")

    def prepare():
        scene = payload_or_http(st, req.scene_id)
        names = [o["name"] for o in scene["spec"]["objects"]]
        if req.object not in names:
            raise HTTPException(422, f"object: no object {req.object!r} (objects: {', '.join(names)})")
        files = {}
        with st.db() as s:
            for key, ref in (("target", req.target_asset), ("mask", req.mask_asset)):
                if ref is None:
                    continue
                a = s.get(Asset, ref)
                if a is None or a.kind != "image":
                    raise HTTPException(422, f"{key}_asset: {ref!r} is not an uploaded image asset")
                files[key] = {"sha256": a.sha256, "filename": a.filename}
        return scene, files
    scene, files = await run_in_threadpool(prepare)
    job = {"type": "fit", "scene": scene, "request": req.model_dump(mode="json"), **files}
    res = await run(st, job)
    out = FitOut(material=res["material"], stats=res["stats"])
    if req.save_as:
        def save():
            with st.db() as s, s.begin():
                d = MaterialDesign(name=req.save_as, scene_id=req.scene_id, object=req.object)
                s.add(d)
                s.flush()
                s.add(MaterialVersion(design_id=d.id, version=1, body=res["material"], note="fit"))
                return d.id
        out.material_id, out.version = await run_in_threadpool(save), 1
    return out
