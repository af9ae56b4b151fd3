"""Exports: a scene, its materials and design variants as a glTF 2.0 binary, a MaterialX
document or a Mitsuba 3 scene folder (zipped), made by a worker and answered when done.

The fitted materials' approximation errors are in the file (the glb's ``asset.extras.glint``,
the MaterialX shaders' doc strings, the zip's ``report.json``) and, in short, in the
``X-Glint-Export-Report`` header (JSON).
"""
from __future__ import annotations

import json
from typing import Literal

from fastapi import APIRouter, Response
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, ConfigDict, Field

from ..deps import Client, State
from ..services import exports
from .errors import http_errors
from .renders import run

router = APIRouter(tags=["exports"])
MAX_VARIANTS = 16          # worker/export/common.py MAX_VARIANTS: a fit each


class ExportVariant(BaseModel):
    model_config = ConfigDict(extra="forbid")
    material_id: str = Field(max_length=64)
    version: int | None = Field(None, ge=1, le=2**31 - 1, description="None: the latest")
    label: str | None = Field(None, max_length=200, description="None: the design's name")


class ExportRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    scene_id: str | None = Field(None, max_length=64, description="the scene (or give publication_id)")
    publication_id: str | None = Field(None, max_length=64,
                                       description="a publication: its scene, object and variants")
    format: Literal["gltf", "mtlx", "mitsuba"]
    object: str | None = Field(None, max_length=255, description="the object the variants dress (default: the first)")
    variants: list[ExportVariant] = Field(default_factory=list, max_length=MAX_VARIANTS)
    render_check: bool = Field(False, description="also render the exported materials with Glint against the "
                                                  "originals (needs the scene's precomputation)")


_BIN = {"schema": {"type": "string", "format": "binary"}}


def short_report(rep: dict) -> str:
    """The header's JSON: per material its label, model, extensions and errors; the render check."""
    mats = [{"label": m["label"][:80], "model": m["model"], "rel_rmse": round(m["rel_rmse"], 5),
             "albedo_rel_rmse": round(m["albedo_rel_rmse"], 5), "extensions": m.get("extensions", [])}
            for m in rep["materials"]]
    out = {"materials": mats, "faces": rep["faces"], "bytes": rep["bytes"]}
    if rep.get("render"):
        out["render"] = [{"variant": r["variant"], "rel_rmse": round(r["rel_rmse"], 5)} for r in rep["render"]]
    return json.dumps(out, ensure_ascii=True)


@router.post("/v1/exports", response_class=Response,
             responses={200: {"description": "the export: a .glb (model/gltf-binary), a .mtlx (application/xml) or a "
                                             "zip of the Mitsuba 3 folder (application/zip); header "
                                             "X-Glint-Export-Report: the approximation errors (JSON)",
                              "content": {"model/gltf-binary": _BIN, "application/xml": _BIN, "application/zip": _BIN}}})
async def export(req: ExportRequest, st: State, _: Client):
    """Export a scene (or a publication) with its design variants as glTF, MaterialX or Mitsuba 3."""
    with http_errors():
        job = await run_in_threadpool(exports.export_job, st, req.scene_id, req.format, req.object,
                                      [v.model_dump() for v in req.variants], req.publication_id, req.render_check)
    res = await run(st, job)
    media, ext = exports.MEDIA[req.format]
    return Response(content=res["bytes"], media_type=media,
                    headers={"Content-Disposition": f'attachment; filename="{res["name"]}.{ext}"',
                             "X-Glint-Export-Report": short_report(res["report"])})
