"""The stream's events: what the server sends its client (``ServerEvent``), and what a worker
sends the server about a session (``WorkerEvent``: a fit, a paint fit, a rejected stroke, a
save to store).

A worker event that changes what is stored says so on its class, like a client message
(messages.py): ``storage`` (how the server writes the state it leaves) and ``apply`` (the new
state and the effect for the server's store, effects.py); the server applies it with
``apply_event`` to its copy of the stored state, the same way it applies client messages.
"""
from __future__ import annotations

from typing import Annotated, ClassVar, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, model_validator

from ..models import parse_material
from .effects import NO_EFFECT, RejectStroke, StoreEffect, StoreSave
from .messages import Storage
from .state import SessionState, copy_state

class _Event(BaseModel):
    seq: int | None = Field(None, description="the client message this answers, if any")


class _WorkerEvent(_Event):
    """An event a worker sends that the server applies to the stored state (``apply_event``).
    storage : as a client message's; "rows": it changes rows of its own only, never the state
    (its ``apply`` is given None)."""
    storage: ClassVar[Storage] = "state"

    def apply(self, st: SessionState | None) -> StoreEffect | None:
        """Change ``st`` (the caller's copy) and say what else the server stores (None: nothing)."""
        raise NotImplementedError


def _off(kind: str, controls: list[str]) -> dict[str, str]:
    from ..renderers import ALL_CONTROLS, why_not

    return {c: why_not(kind, c) for c in sorted(ALL_CONTROLS - set(controls))}


class HelloEvent(_Event):
    type: Literal["hello"] = "hello"
    session: str
    state: dict
    strokes: int = Field(description="active strokes")
    renderer: str = "cuts"
    renderers: list[str] = Field(default_factory=list, description="renderers the session may switch between")
    controls: list[str] = Field(default_factory=list, description="what this session's renderer lets a client change")
    streams: int = Field(1, description="open streams of this session on this server, this one included (another "
                                        "tab, a reload): they all see each other's changes")
    off: dict[str, str] = Field(default_factory=dict, description="each control this renderer does not offer, "
                                                                  "and why (filled from renderer and controls)")

    @model_validator(mode="after")
    def _fill_off(self):
        if not self.off:
            self.off = _off(self.renderer, self.controls)
        return self


class PeerEvent(_Event):
    """A change another stream of this session made (another tab): the client message as the
    session applied it (``message.seq`` is the session's number for it), so this client's
    controls can follow; its frame comes like any other. ``streams``: open streams now."""
    type: Literal["peer"] = "peer"
    message: dict
    streams: int = 1


class StrokeEvent(_WorkerEvent):
    storage: ClassVar[Storage] = "rows"
    type: Literal["stroke"] = "stroke"
    strokes: int
    notes: list[str] = Field(default_factory=list)
    rejected: bool = False

    def apply(self, st):
        # a rejected stroke's row is never replayed; the state does not change
        return RejectStroke(self.seq) if self.rejected and self.seq is not None else None


class FitStats(BaseModel):
    model_config = ConfigDict(extra="allow")
    strokes: int = 0


class FitEvent(_WorkerEvent):
    # a fit is derived from the stored strokes (a restore replays them and fits again), so it
    # is written like a camera move, at most FLUSH_S later: the stroke's frame, which follows
    # this event, does not wait for a transaction that rewrites the ~30 KB state
    storage: ClassVar[Storage] = "batched"
    type: Literal["fit"] = "fit"
    object: str
    material: dict
    # the material's curve comes as a curve event after the frame (the studio keeps its last one
    # until then); given here only where it costs nothing on the way to the frame
    curve: dict | None = None
    stats: FitStats
    notes: list[str] = Field(default_factory=list)
    # an undone or redone region step (rename, erase, merge, material: not a fit of strokes):
    # the material is what the edited object's next strokes paint over, in a new epoch, with
    # region ``painting`` painted (None: one BRDF), as the region message itself set
    rebase: bool = False
    painting: str | None = None

    def apply(self, st):
        if self.object in st.objects:
            mats = list(st.materials)
            mats[st.objects.index(self.object)] = parse_material(self.material)
            st.materials = mats
            if self.rebase and self.object == st.object:
                st.base_material = st.materials[st.objects.index(self.object)]
                st.region = self.painting
                st.epoch = st.fresh_epoch()
        return None


class GuidanceEvent(_Event):
    """A stroke fit fell short (achieved < 80%), and what would help (fit/guidance.py).

    For a brightening stroke in direct light, the light is measured: luminances over the painted
    pixels of the light around their mirror directions (``mirror``), the brightest above their
    horizon and what was asked; the share of the ask the mirror light covers now (``covered``)
    and at the environment rotation that covers most (``rotate_to_deg``,
    ``covered_at_rotation``); the share of pixels no BRDF can serve (``impossible_share``).
    Otherwise (a darkening or a colour change, or any stroke under GI, where a room's walls light
    the mirror directions as much as the map) those are null, and the event says what one BRDF
    for the whole object did: ``spill``, the RMS change of the object's unpainted pixels relative
    to their radiance. ``region``: the stroke fitted one BRDF for the
    whole object, and a painted region would change only what it covers. ``message``: the same
    in words. Sent after the stroke's frame."""
    type: Literal["guidance"] = "guidance"
    object: str
    achieved: float
    asked: float | None = None
    mirror: float | None = None
    brightest_above: float | None = None
    covered: float | None = None
    rotate_to_deg: float | None = None
    covered_at_rotation: float | None = None
    impossible_share: float | None = None
    spill: float | None = None
    region: bool = False
    message: str


class CurveEvent(_Event):
    type: Literal["curve"] = "curve"
    object: str
    curve: dict


class SavedEvent(_Event):
    type: Literal["saved"] = "saved"
    material_id: str
    version: int
    name: str


class NoteEvent(_Event):
    type: Literal["note"] = "note"
    message: str


class ErrorEvent(_Event):
    type: Literal["error"] = "error"
    message: str
    fatal: bool = False
    code: int | None = None


class PaintEvent(_WorkerEvent):
    """The lobes material fitted to a ``paint`` message's readings (worker/paint/session.py)."""
    type: Literal["paint"] = "paint"
    object: str
    material: dict
    measured: dict = Field(description="the fitted material's readings: what the frame shows")
    requested: dict
    error_l1: float
    error_max: float
    residuals: dict = Field(default_factory=dict, description="signed relative residual (fit − reading)/(|reading| + "
                            "floor) of every reading, same form as the readings")
    unmet: list[str] = Field(default_factory=list, description="readings the fit misses by more than 3%: "
                             "'gloss' or 'ANGLE:channel' (e.g. '-15:r')")
    warning: str | None = Field(None, description="a sentence naming the unmet readings, or null when all are met")
    flop_index: float | None = None
    ms_fit: float
    swatch: str = Field("", max_length=65_536,
                        description="the fitted paint on a sphere under the palette's studio lights, as the worker "
                                    "shades it (worker/paint/swatch.py): a PNG data URL")

    def apply(self, st):
        if self.object in st.objects:
            mat = parse_material(self.material)
            mats = list(st.materials)
            mats[st.objects.index(self.object)] = mat
            st.materials = mats
            if self.object == st.object:
                st.base_material = mat          # strokes now paint over the paint
        return None


class ExposureEvent(_WorkerEvent):
    """The worker chose the display exposure: the median object pixel shown as middle grey
    (an uploaded scene's first frame), or a captured lighting applied in the units of its
    preview (the map's median luminance middle grey, as the preview was exposed)."""
    storage: ClassVar[Storage] = "batched"
    type: Literal["exposure"] = "exposure"
    exposure: float = Field(ge=-20.0, le=20.0)
    reason: str = ""

    def apply(self, st):
        st.exposure = self.exposure
        st.auto_exposure = False
        return None


class RendererEvent(_Event):
    """The session now draws with this renderer; ``controls`` is what a client may change,
    ``off`` each control it does not offer and why."""
    type: Literal["renderer"] = "renderer"
    kind: str
    controls: list[str]
    off: dict[str, str] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _fill_off(self):
        if not self.off:
            self.off = _off(self.kind, self.controls)
        return self


class ObjectEvent(_Event):
    """The session now edits ``object`` (an ``object`` message): its material, the curve of
    it, and its active strokes (its own undo history)."""
    type: Literal["object"] = "object"
    object: str
    material: dict
    curve: dict
    strokes: int = 0


class PickedEvent(_Event):
    """The object under (u, v) of the last frame (a ``pick`` message); None: the background."""
    type: Literal["picked"] = "picked"
    u: float
    v: float
    object: str | None = None


class ConvertedEvent(_WorkerEvent):
    """An object's material converted to another model with the same look (a ``convert``
    message): the fitted material and how close it is (worker/models/convert.py)."""
    type: Literal["converted"] = "converted"
    object: str
    material: dict
    curve: dict
    error: float = Field(description="relative RMS difference of the BRDF over the fit's samples")
    albedo_error: float = Field(description="largest relative change of the mean directional albedo "
                                            "per channel (the mean colour under a smooth light)")

    def apply(self, st):
        if self.object in st.objects:
            mat = parse_material(self.material)
            mats = list(st.materials)
            mats[st.objects.index(self.object)] = mat
            st.materials = mats
            if self.object == st.object:
                st.base_material = mat          # strokes now paint over the converted material
        return None


class SaveRequest(_WorkerEvent):
    """Worker → server only: the material to store for a pending save."""
    type: Literal["save"] = "save"
    object: str
    name: str | None = None
    material_id: str | None = None
    material: dict

    def apply(self, st):
        # no longer pending whatever the store makes of it (stored, or refused with an error)
        st.pending_saves = [p for p in st.pending_saves if p.seq != self.seq]
        return StoreSave(self.seq, self.object, self.name, self.material_id, self.material)


ServerEvent = Annotated[Union[HelloEvent, StrokeEvent, FitEvent, CurveEvent, SavedEvent, NoteEvent, ErrorEvent,
                              PaintEvent, RendererEvent, PeerEvent, ObjectEvent, PickedEvent, ConvertedEvent, ExposureEvent,
                              GuidanceEvent],
                        Field(discriminator="type")]
server_event = TypeAdapter(ServerEvent)


# worker → server events that change what is stored, by type; any other event is passed on
WORKER_EVENTS: dict[str, type[_WorkerEvent]] = {c.model_fields["type"].default: c
                                                for c in (StrokeEvent, FitEvent, PaintEvent, SaveRequest, ConvertedEvent, ExposureEvent)}


def worker_event(ev: dict) -> _WorkerEvent | None:
    """The typed worker event of an event dict, or None for one the server only passes on."""
    cls = WORKER_EVENTS.get(ev.get("type"))
    return None if cls is None else cls.model_validate(ev)


def apply_event(state: SessionState, ev: _WorkerEvent) -> tuple[SessionState, StoreEffect]:
    """The stored state after a worker event and what else the server stores; the input state
    is not modified (copy-on-write, as ``messages.apply``)."""
    st = copy_state(state)
    return st, ev.apply(st) or NO_EFFECT
