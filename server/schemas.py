"""Request and response bodies of the REST API (pydantic v2)."""
from __future__ import annotations

import datetime as dt
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

from worker.fit.brush import Stroke
from worker.fit.files import ViewSpec
from worker.scene import Camera, Color, Material, SceneFile, Transform

MAX_FIT_POINTS = 200_000          # stroke points of one POST /v1/fits, in all
MAX_OBJECTS = 20_000              # per-object maps of a request: Settings.max_scene_objects' default


def as_utc(t: dt.datetime) -> dt.datetime:
    """A stored time as an aware UTC datetime. The database keeps UTC, but SQLite hands it back
    without its offset, and a browser reads an ISO time without one as its own local time: a
    version saved at 10:35 UTC showed as 10:35 in New York too."""
    return t.replace(tzinfo=dt.timezone.utc) if t.tzinfo is None else t.astimezone(dt.timezone.utc)


# a time in a response: always with its offset (+00:00)
UtcDateTime = Annotated[dt.datetime, AfterValidator(as_utc)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class AssetOut(BaseModel):
    id: str
    kind: str
    filename: str
    sha256: str
    size: int
    meta: dict
    created: UtcDateTime


class PrecomputationOut(BaseModel):
    id: str
    scene_id: str
    kind: str = "cuts"
    status: Literal["queued", "running", "done", "failed"]
    progress: float
    message: str
    stats: dict
    created: UtcDateTime
    updated: UtcDateTime


class SceneOut(BaseModel):
    id: str
    name: str
    spec: SceneFile
    created: UtcDateTime
    precomputation: PrecomputationOut | None = None


class RenderRequest(Strict):
    scene_id: str
    camera: Camera | None = None
    rotation_deg: float | None = None
    intensity: float | None = Field(None, ge=0.0)
    materials: dict[str, Material] = Field(default_factory=dict, max_length=MAX_OBJECTS, description="per object name")
    transforms: dict[str, Transform] = Field(default_factory=dict, max_length=MAX_OBJECTS, description="per object name: where the scene's "
                                             "movable objects stand (\"movable\": true; nothing is precomputed again)")
    mode: Literal["refined", "vertex", "pixel"] = Field(
        "refined", description="cut renderer shading: refined (the default: vertex shading, per pixel where its "
                               "interpolation is wrong), vertex (the interpolation alone) or pixel (every pixel)")
    format: Literal["png", "exr"] = "png"
    exposure: float = Field(0.0, ge=-20, le=20)
    tone: Literal["linear", "aces", "neutral"] = "neutral"


class FitRequest(Strict):
    scene_id: str
    object: str
    strokes: list[Stroke] = Field(default_factory=list, max_length=10_000)
    views: list[ViewSpec] = Field(default_factory=list, max_length=64)
    target_asset: str | None = Field(None, description="an uploaded image asset (linear .npy/.exr/.hdr, sRGB .png)")
    mask_asset: str | None = None
    constrained: bool = True
    unpainted_weight: float = Field(0.25, ge=0.0, description="weight of unpainted pixels (painted: 1); the default is worker/fit/brush.py DEFAULT_UNPAINTED_WEIGHT")
    albedo: Color | None = None
    fresnel_f0: float | None = Field(None, ge=0.0, le=1.0)
    fit_scale: float | None = Field(None, gt=0.0, le=1.0)
    save_as: str | None = Field(None, max_length=200, description="save the result as a new material design")


    @model_validator(mode="after")
    def _points(self):
        # each stroke may have 10 000 points: bounded in total too (the fit's time grows with them)
        n = sum(len(s.points) for s in self.strokes)
        if n > MAX_FIT_POINTS:
            raise ValueError(f"strokes: {n} points in all is over the limit of {MAX_FIT_POINTS}")
        return self


class FitOut(BaseModel):
    material: dict
    stats: dict
    material_id: str | None = None
    version: int | None = None


class MaterialCreate(Strict):
    name: str = Field(min_length=1, max_length=200)
    material: Material
    scene_id: str | None = None
    object: str | None = None
    note: str = Field("", max_length=1000)


class MaterialUpdate(Strict):
    material: Material
    note: str = Field("", max_length=1000)


class MaterialOut(BaseModel):
    id: str
    name: str
    version: int
    material: dict
    scene_id: str | None
    object: str | None
    archived: bool
    created: UtcDateTime
    version_name: str = Field("", description="the latest version's name")
    thumbnail: str | None = Field(None, description="URL of the latest version's thumbnail JPEG, if it has one")


class VersionOut(BaseModel):
    version: int
    material: dict
    note: str
    created: UtcDateTime
    name: str = Field("", description="the designer's label for this version")
    thumbnail: str | None = Field(None, description="URL of a small JPEG of the frame this version was saved "
                                                    "from (none for versions saved over REST)")


class SessionCreate(Strict):
    scene_id: str
    object: str | None = None
    camera: Camera | None = None


class SessionOut(BaseModel):
    id: str
    token: str | None = None
    scene_id: str
    stream: str
    state: dict[str, Any]
    strokes: list[dict] = Field(default_factory=list)
    region_steps: list[dict] = Field(default_factory=list, description=(
        "the steps on painted regions (rename, erase, merge, a region's material) that undo and redo cover, in "
        "order: seq, object, region_before, region_after (the region painted before and after), undone, dropped "
        "(left on the redo stack when a new edit came)"))
    worker_pid: int | None = None
    closed: bool = False
