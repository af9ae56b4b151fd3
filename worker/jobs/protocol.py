"""Client messages of the session stream (DESIGN.md §5), validated at the edge.

Every message is a JSON object with an increasing ``seq`` and a ``type``. The server validates
with these models before anything is persisted or forwarded; the worker applies them.
"""
from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

from ..fit.brush import Stroke
from ..scene import Material, Vec3


class _Msg(BaseModel):
    model_config = ConfigDict(extra="forbid")
    seq: int = Field(ge=0)


class ViewMsg(_Msg):
    """Partial camera: any of eye, target, up, fov_y_deg (width and height are the session's)."""
    type: Literal["view"]
    eye: Vec3 | None = None
    target: Vec3 | None = None
    up: Vec3 | None = None
    fov_y_deg: float | None = Field(None, gt=1.0, lt=170.0)
    drag: bool = False


class LightMsg(_Msg):
    type: Literal["light"]
    rotation_deg: float | None = Field(None, ge=-1e6, le=1e6)
    intensity: float | None = Field(None, ge=0.0, le=1e6)
    drag: bool = False


class MaterialMsg(_Msg):
    type: Literal["material"]
    object: str | None = None          # default: the session's edited object
    material: Material


class StrokeMsg(_Msg):
    type: Literal["stroke"]
    stroke: Stroke


class UndoMsg(_Msg):
    type: Literal["undo"]


class RedoMsg(_Msg):
    type: Literal["redo"]


class FitMsg(_Msg):
    type: Literal["fit"]
    constrained: bool | None = None
    unpainted_weight: float | None = Field(None, ge=0.0, le=1e6)


class SaveMsg(_Msg):
    type: Literal["save"]
    name: str | None = Field(None, max_length=200)
    material_id: str | None = Field(None, max_length=32)   # add a version to this design


class DisplayMsg(_Msg):
    """Display settings: exposure (EV), tone curve, JPEG quality."""
    type: Literal["display"]
    exposure: float | None = Field(None, ge=-20.0, le=20.0)
    tone: Literal["linear", "aces", "neutral"] | None = None
    quality: int | None = Field(None, ge=10, le=100)


class VariantMsg(_Msg):
    """Viewer: show published variant ``index`` (the server supplies its material)."""
    type: Literal["variant"]
    index: int = Field(ge=0, le=1000)


class EnvironmentMsg(_Msg):
    """Viewer: light the object with published environment preset ``index``."""
    type: Literal["environment"]
    index: int = Field(ge=0, le=1000)


ClientMsg = Annotated[Union[ViewMsg, LightMsg, MaterialMsg, StrokeMsg, UndoMsg, RedoMsg, FitMsg, SaveMsg, DisplayMsg,
                            VariantMsg, EnvironmentMsg], Field(discriminator="type")]
client_msg = TypeAdapter(ClientMsg)
READONLY_TYPES = {"view", "light", "display", "variant", "environment"}   # what a shopper may send
