"""Renders and fits for automation clients: run in a worker, answered when done."""
from __future__ import annotations

from fastapi import APIRouter, HTTPException, Response
from fastapi.concurrency import run_in_threadpool

from ..deps import Client, State
from ..schemas import FitOut, FitRequest, RenderRequest
from ..services import renders
from ..workers import JobFailed
from .errors import http_errors

router = APIRouter(tags=["renders and fits"])


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
    with http_errors():
        job = await run_in_threadpool(renders.render_job, st, req.scene_id,
                                      req.model_dump(mode="json", exclude={"scene_id"}))
    res = await run(st, job)
    return Response(content=res["bytes"], media_type=res["media_type"])


@router.post("/v1/fits", response_model=FitOut)
async def fit(req: FitRequest, st: State, _: Client):
    """Fit an ``srbf`` material for one object to strokes or to a target image asset."""
    with http_errors():
        job = await run_in_threadpool(renders.fit_job, st, req.scene_id, req.object, req.model_dump(mode="json"),
                                      req.target_asset, req.mask_asset, bool(req.strokes))
    res = await run(st, job)
    out = FitOut(material=res["material"], stats=res["stats"])
    if req.save_as:
        out.material_id, out.version = await run_in_threadpool(renders.save_fit, st, req.save_as, req.scene_id,
                                                               req.object, res["material"])
    return out
