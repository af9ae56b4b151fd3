"""One interactive session's state, the stream's messages and events, and the one function that
applies a message to the state (DESIGN.md §5).

The same ``apply(state, msg)`` runs where the server persists a message (server/routes/
sessions.py) and where the worker renders it (jobs/session.py), so the two can never disagree
about what a message means. It is pure: it returns the new state and an ``Effect`` saying what
else the message asks for (a stroke to record, an undo, a save), which each side carries out
in its own way (rows in the database; the fitter in the worker).

Adding a stream message: a ``ClientMsg`` subclass with ``type: Literal[...]`` and an ``apply``
method, decorated with ``@message``. Events the server sends are the ``*Event`` models below;
``stream-schema.json`` (``glint schema``) publishes both for clients and tests.

Every message carries an increasing ``seq``. A message whose ``seq`` is not above the state's
``last_seq`` is already part of the state: a worker that re-opens a session from what the server
stored skips it, so a message persisted while a session is being restored is applied once.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Annotated, Any, ClassVar, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError
from pydantic_core import PydanticCustomError, core_schema

from ..fit.brush import DEFAULT_UNPAINTED_WEIGHT, Stroke
from ..models import Material, Vec3, parse_material
from ..scene import Camera, Transform

Tone = Literal["linear", "aces", "neutral"]


class StateError(ValueError):
    """A message that cannot apply to this state; the message says why (sent as an error
    event; nothing is stored or forwarded)."""


# --- state ---------------------------------------------------------------------------------------


class EnvPreset(BaseModel):
    """An environment map a session can switch to: a stored blob and its rotation."""
    label: str = ""
    sha256: str
    filename: str
    rotation_deg: float = 0.0


class Variant(BaseModel):
    """A published design a viewer session can show."""
    label: str = ""
    material: Material


class PendingSave(BaseModel):
    """A save the client asked for that is not stored yet (re-run after a worker restart)."""
    seq: int
    name: str | None = None
    material_id: str | None = None


class SessionState(BaseModel):
    """What the server stores per session and the worker renders from."""
    model_config = ConfigDict(extra="ignore")

    objects: list[str]
    object: str
    camera: Camera
    rotation_deg: float = 0.0
    intensity: float = 1.0
    materials: list[Material]
    base_material: Material
    epoch: int = 0
    last_seq: int = -1
    exposure: float = 0.0
    tone: Tone = "neutral"
    quality: int = 85
    shadow: bool | None = None              # ground shadow on/off; None: the scene's default
    constrained: bool = True
    unpainted_weight: float = DEFAULT_UNPAINTED_WEIGHT
    readonly: bool = False
    publication: str | None = None
    variants: list[Variant] = Field(default_factory=list)
    variant: int | None = None
    environments: list[EnvPreset] = Field(default_factory=list)
    environment_index: int | None = None
    pending_saves: list[PendingSave] = Field(default_factory=list)
    # the renderer drawing the session, and the ones it may switch between (a GI scene's path
    # back to direct light): the scene's own, and the cut renderer
    renderer: str = "cuts"
    renderers: list[str] = Field(default_factory=lambda: ["cuts"])
    # the paint designer's last readings per object (what the paint panel shows)
    paint: dict[str, dict] = Field(default_factory=dict)
    # where movable objects are now (scene objects with "movable": true), by name
    transforms: dict[str, Transform] = Field(default_factory=dict)
    movable: list[str] = Field(default_factory=list)

    def allows(self, control: str) -> bool:
        from ..renderers import controls

        return control in controls(self.renderer)

    @property
    def object_index(self) -> int:
        return self.objects.index(self.object)

    def material_of(self, name: str):
        return self.materials[self.objects.index(name)]


def new_state(spec, object_name: str | None = None, camera=None, **fields) -> SessionState:
    """The state of a new session on a scene file (``worker.scene.SceneFile`` or its dict)."""
    spec = spec if isinstance(spec, dict) else spec.model_dump(mode="json")
    names = [o["name"] for o in spec["objects"]]
    obj = object_name or names[0]
    if obj not in names:
        raise StateError(f"object: no object {obj!r} (objects: {', '.join(names)})")
    mats = [o.get("material") or {"model": "lambert"} for o in spec["objects"]]
    env = spec["environment"]
    kind = spec.get("renderer") or "cuts"
    movable = [o["name"] for o in spec["objects"] if o.get("movable")]
    return SessionState.model_validate({
        "objects": names, "object": obj, "camera": camera or spec["camera"],
        "rotation_deg": env.get("rotation_deg", 0.0), "intensity": env.get("intensity", 1.0),
        "materials": mats, "base_material": mats[names.index(obj)], "renderer": kind,
        "renderers": [kind] + (["cuts"] if kind != "cuts" else []), "movable": movable,
        "transforms": {o["name"]: o.get("transform") or {} for o in spec["objects"] if o.get("movable")}, **fields})


def restore_state(raw: dict, spec) -> tuple[SessionState, list[str]]:
    """A stored state read back, never failing: fields a newer or older release cannot use fall
    back to the scene's values, with a note each (a stored material over today's limits must
    not make every restore fail)."""
    spec = spec if isinstance(spec, dict) else spec.model_dump(mode="json")
    raw = dict(raw or {})
    notes: list[str] = []
    base = new_state(spec, raw.get("object") if raw.get("object") in [o["name"] for o in spec["objects"]] else None)
    good = base.model_dump(mode="json")
    raw.setdefault("objects", good["objects"])
    mats = raw.get("materials")
    if not isinstance(mats, list) or len(mats) != len(good["materials"]):
        raw["materials"] = good["materials"]
    else:
        fixed = []
        for i, m in enumerate(mats):
            try:
                parse_material(m)
                fixed.append(m)
            except (ValidationError, ValueError, TypeError) as e:
                notes.append(f"the stored material of {good['objects'][i]!r} is not valid any more "
                             f"({_first_error(e)}); the scene's material is used")
                fixed.append(good["materials"][i])
        raw["materials"] = fixed
    try:
        parse_material(raw.get("base_material"))
    except (ValidationError, ValueError, TypeError):
        raw["base_material"] = raw["materials"][good["objects"].index(raw.get("object") or good["object"])]
    for k, v in good.items():
        raw.setdefault(k, v)
    try:
        return SessionState.model_validate(raw), notes
    except ValidationError as e:
        # any other stored field that no longer validates: keep what does, one field at a time
        for err in e.errors():
            k = err["loc"][0] if err["loc"] else None
            if k in good:
                notes.append(f"stored session field {k!r} is not valid any more ({err['msg']}); reset")
                raw[k] = good[k]
        return SessionState.model_validate(raw), notes


def _first_error(e: Exception) -> str:
    if isinstance(e, ValidationError):
        err = e.errors()[0]
        return f"{'.'.join(str(x) for x in err['loc'])}: {err['msg']}"
    return str(e)


# --- effects -----------------------------------------------------------------------------------


@dataclass
class Effect:
    """What a message asks for beyond the new state.

    kind : None, "stroke" (record ``stroke``, painted in the state's current view), "undo",
        "redo", "save" (``save``), "refit" (fit options changed), "rebase" (the edited object's
        base material changed: strokes of earlier epochs no longer apply).
    drag : the message is part of a drag (the worker renders at the drag level of detail).
    """
    kind: str | None = None
    stroke: dict | None = None
    save: PendingSave | None = None
    drag: bool = False
    data: dict = field(default_factory=dict)


# --- client messages --------------------------------------------------------------------------

_MESSAGES: dict[str, type["ClientMsg"]] = {}


def message(cls):
    """Class decorator: register a client message type (by its ``type`` literal)."""
    _MESSAGES[cls.model_fields["type"].default] = cls
    return cls


class ClientMsg(BaseModel):
    """A client → server message. ``readonly_ok``: a shopper's read-only viewer may send it."""
    model_config = ConfigDict(extra="forbid")
    readonly_ok: ClassVar[bool] = False
    # strict: "7" is not a seq (lax mode turned it into 7, and the server stored what the
    # client may not have meant); the server refuses one not above the state's last_seq
    seq: int = Field(ge=0, le=2**53, strict=True)
    type: str

    def apply(self, st: SessionState) -> Effect | None:
        raise NotImplementedError


@message
class ViewMsg(ClientMsg):
    """Partial camera: any of eye, target, up, fov_y_deg (width and height are the session's)."""
    readonly_ok: ClassVar[bool] = True
    type: Literal["view"] = "view"
    eye: Vec3 | None = None
    target: Vec3 | None = None
    up: Vec3 | None = None
    fov_y_deg: float | None = Field(None, gt=1.0, lt=170.0)
    drag: bool = False

    def apply(self, st):
        if not st.allows("camera"):
            raise StateError(f"view: the {st.renderer} renderer draws from a fixed camera "
                             "(switch to the cuts renderer to orbit)")
        upd = {k: getattr(self, k) for k in ("eye", "target", "up", "fov_y_deg") if getattr(self, k) is not None}
        try:
            st.camera = Camera.model_validate({**st.camera.model_dump(), **upd})
        except ValidationError as e:
            raise StateError(f"view: {e.errors()[0]['msg']}") from None
        return Effect(drag=self.drag)


@message
class LightMsg(ClientMsg):
    readonly_ok: ClassVar[bool] = True
    type: Literal["light"] = "light"
    rotation_deg: float | None = Field(None, ge=-1e6, le=1e6)
    intensity: float | None = Field(None, ge=0.0, le=1e6)
    drag: bool = False

    def apply(self, st):
        if self.rotation_deg is not None and not st.allows("light"):
            raise StateError(f"light: the {st.renderer} renderer's lighting is fixed by its precomputation "
                             "(switch to the cuts renderer to turn it)")
        if self.rotation_deg is not None:
            st.rotation_deg = float(self.rotation_deg)
        if self.intensity is not None:
            st.intensity = float(self.intensity)
        return Effect(drag=self.drag)


@message
class MaterialMsg(ClientMsg):
    """Set an object's material (default: the edited object). For the edited object it is also
    the new base that strokes paint over: earlier strokes do not carry over (a new epoch)."""
    type: Literal["material"] = "material"
    object: str | None = None
    material: Material

    def apply(self, st):
        name = self.object or st.object
        if name not in st.objects:
            raise StateError(f"material: no object {name!r} (objects: {', '.join(st.objects)})")
        mats = list(st.materials)
        mats[st.objects.index(name)] = self.material
        st.materials = mats
        if name == st.object:
            st.base_material = self.material
            st.epoch += 1
            return Effect("rebase")
        return None


@message
class StrokeMsg(ClientMsg):
    type: Literal["stroke"] = "stroke"
    stroke: Stroke

    def apply(self, st):
        a = st.base_material.albedo
        if min(a) < 0 or max(a) > 1:
            raise StateError(f"stroke: strokes paint over the edited object's material, whose diffuse albedo "
                             f"{list(a)} is outside [0, 1]; choose a physical material first")
        return Effect("stroke", stroke={"stroke": self.stroke.model_dump(mode="json"),
                                        "camera": st.camera.model_dump(mode="json"),
                                        "rotation_deg": st.rotation_deg, "intensity": st.intensity})


@message
class UndoMsg(ClientMsg):
    type: Literal["undo"] = "undo"

    def apply(self, st):
        return Effect("undo")


@message
class RedoMsg(ClientMsg):
    type: Literal["redo"] = "redo"

    def apply(self, st):
        return Effect("redo")


@message
class FitMsg(ClientMsg):
    type: Literal["fit"] = "fit"
    constrained: bool | None = None
    unpainted_weight: float | None = Field(None, ge=0.0, le=1e6)

    def apply(self, st):
        if self.constrained is not None:
            st.constrained = self.constrained
        if self.unpainted_weight is not None:
            st.unpainted_weight = self.unpainted_weight
        return Effect("refit")


@message
class SaveMsg(ClientMsg):
    """Store the edited object's material as a new design (``name``) or a new version of one
    (``material_id``). Pending until stored, so a worker crash does not lose it."""
    type: Literal["save"] = "save"
    name: str | None = Field(None, max_length=200)
    material_id: str | None = Field(None, max_length=32)

    def apply(self, st):
        p = PendingSave(seq=self.seq, name=self.name, material_id=self.material_id)
        st.pending_saves = [*st.pending_saves, p]
        return Effect("save", save=p)


@message
class DisplayMsg(ClientMsg):
    """Display settings: exposure (EV), tone curve, JPEG quality, and the ground shadow under the
    objects (scenes with a ``ground``; the frame header's ``shadow`` says whether it is drawn)."""
    readonly_ok: ClassVar[bool] = True
    type: Literal["display"] = "display"
    exposure: float | None = Field(None, ge=-20.0, le=20.0)
    tone: Tone | None = None
    quality: int | None = Field(None, ge=10, le=100)
    shadow: bool | None = None

    def apply(self, st):
        for k in ("exposure", "tone", "quality", "shadow"):
            if getattr(self, k) is not None:
                setattr(st, k, getattr(self, k))
        return None


@message
class VariantMsg(ClientMsg):
    """Viewer: show published variant ``index`` (a material the publication holds, never one
    from the client)."""
    readonly_ok: ClassVar[bool] = True
    type: Literal["variant"] = "variant"
    index: int = Field(ge=0, le=1000)

    def apply(self, st):
        if not st.readonly:
            raise StateError("variant: only viewer sessions have published variants")
        if self.index >= len(st.variants):
            raise StateError(f"variant: no variant {self.index} (there are {len(st.variants)})")
        mats = list(st.materials)
        mats[st.object_index] = st.variants[self.index].material
        st.materials = mats
        st.variant = self.index
        return None


@message
class EnvironmentMsg(ClientMsg):
    """Light the scene with environment preset ``index`` (viewer sessions: the published
    presets), or, in an editing session, with an uploaded environment map ``asset_id`` (e.g. a
    captured one). The server turns ``asset_id`` into ``preset`` (the stored file) before it
    applies and forwards the message; a client cannot send ``preset`` itself."""
    readonly_ok: ClassVar[bool] = True
    type: Literal["environment"] = "environment"
    index: int | None = Field(None, ge=0, le=1000)
    asset_id: str | None = Field(None, max_length=32)
    preset: EnvPreset | None = None

    def apply(self, st):
        if not st.allows("environment"):
            raise StateError(f"environment: the {st.renderer} renderer's lighting is fixed by its precomputation")
        if self.preset is not None:
            if st.readonly:
                raise StateError("environment: a viewer session shows the published presets only")
            found = [i for i, e in enumerate(st.environments) if e.sha256 == self.preset.sha256]
            if found:
                i = found[0]
            else:
                st.environments = [*st.environments, self.preset]
                i = len(st.environments) - 1
        elif self.asset_id is not None:
            raise StateError("environment: asset_id must be resolved by the server")
        elif self.index is not None:
            i = self.index
        else:
            raise StateError("environment: give index or asset_id")
        if i >= len(st.environments):
            raise StateError(f"environment: no preset {i} (there are {len(st.environments)})")
        st.environment_index = i
        st.rotation_deg = st.environments[i].rotation_deg
        return None


def _scale3(s) -> tuple[float, float, float]:
    return tuple(float(x) for x in s) if isinstance(s, (tuple, list)) else (float(s),) * 3


@message
class MoveMsg(ClientMsg):
    """Place a movable object (cyber-worlds §V: visibility cut fields): its transform as in the
    scene file (scale, rotate, translate), replacing the one it had. ``drag`` while the user
    drags it (the drag level of detail)."""
    readonly_ok: ClassVar[bool] = True
    type: Literal["move"] = "move"
    object: str = Field(min_length=1, max_length=255)
    transform: Transform
    drag: bool = False

    def apply(self, st):
        if not st.allows("move"):
            raise StateError(f"move: the {st.renderer} renderer cannot move objects")
        if self.object not in st.objects:
            raise StateError(f"move: no object {self.object!r} (objects: {', '.join(st.objects)})")
        if self.object not in st.movable:
            raise StateError(f"move: {self.object!r} is not movable (mark it \"movable\": true in the scene file)")
        old = st.transforms.get(self.object)
        a, b = (_scale3(x.scale) for x in (old or self.transform, self.transform))
        if a != b and (len(set(a)) > 1 or len(set(b)) > 1):
            # a non-uniform scale is part of a movable object's shape (its precomputed field)
            raise StateError(f"move: {self.object!r} cannot change a non-uniform scale (it is part of the shape)")
        st.transforms = {**st.transforms, self.object: self.transform}
        return Effect("move", drag=self.drag, data={"object": self.object})


@message
class RendererMsg(ClientMsg):
    """Draw the session with another of its renderers (a GI scene's path back to direct light
    and the free camera, and forth)."""
    readonly_ok: ClassVar[bool] = True
    type: Literal["renderer"] = "renderer"
    kind: str = Field(max_length=32)

    def apply(self, st):
        if self.kind not in st.renderers:
            raise StateError(f"renderer: {self.kind!r} is not available here (available: {', '.join(st.renderers)})")
        st.renderer = self.kind
        return Effect("renderer")


@message
class PaintMsg(ClientMsg):
    """The paint designer's readings (cacad §4): a 20° gloss value and reflectance factors at
    aspecular angles (worker/paint/geometry.py). The worker fits a lobes material to them; the
    fit comes back as a ``paint`` event, and the object's material follows it."""
    type: Literal["paint"] = "paint"
    object: str | None = None
    gloss: float = Field(0.0, ge=0.0, le=1000.0)
    aspecular: dict[str, tuple[float, float, float]] = Field(min_length=1, max_length=16)

    def apply(self, st):
        name = self.object or st.object
        if name not in st.objects:
            raise StateError(f"paint: no object {name!r} (objects: {', '.join(st.objects)})")
        st.paint = {**st.paint, name: {"gloss": self.gloss, "aspecular": {k: list(v) for k, v in self.aspecular.items()}}}
        if name == st.object:
            st.epoch += 1          # like a new material: strokes painted before do not carry over
        return Effect("paint", data={"object": name})


def _validate_msg(v: Any) -> ClientMsg:
    if isinstance(v, ClientMsg):
        return v
    if not isinstance(v, dict):
        raise PydanticCustomError("message_type", "a message is a JSON object with 'seq' and 'type'")
    cls = _MESSAGES.get(v.get("type")) if isinstance(v.get("type"), str) else None
    if cls is None:
        raise PydanticCustomError("unknown_message", "unknown message type {type} (types: {known})",
                                  {"type": repr(v.get("type")), "known": ", ".join(_MESSAGES)})
    return cls.model_validate(v)


class _MsgType:
    @classmethod
    def __get_pydantic_core_schema__(cls, source, handler):
        ser = core_schema.plain_serializer_function_ser_schema(lambda m, info: m.model_dump(mode=info.mode),
                                                               info_arg=True)
        return core_schema.no_info_plain_validator_function(_validate_msg, serialization=ser)

    @classmethod
    def __get_pydantic_json_schema__(cls, cs, handler):
        union = Annotated[Union[tuple(_MESSAGES.values())], Field(discriminator="type")]
        return handler(TypeAdapter(union).core_schema)


AnyClientMsg = Annotated[ClientMsg, _MsgType]
client_msg = TypeAdapter(AnyClientMsg)


def apply(state: SessionState, msg: ClientMsg) -> tuple[SessionState, Effect]:
    """The state after ``msg`` and what else it asks for (StateError: it cannot apply, and
    nothing changes). The input state is not modified."""
    if state.readonly and not msg.readonly_ok:
        raise StateError(f"{msg.type}: this is a read-only viewer session")
    # copy-on-write: every message replaces the fields it changes (a new Camera, a new list of
    # materials), never edits a nested value in place, so a shallow copy with its own top-level
    # containers keeps ``state`` intact; a deep copy of a fitted srbf state was 12% of a
    # worker's time under load (issue 9)
    st = state.model_copy()
    for k, v in st.__dict__.items():
        if isinstance(v, (list, dict)):
            st.__dict__[k] = type(v)(v)
    eff = msg.apply(st) or Effect()
    st.last_seq = max(st.last_seq, msg.seq)
    return st, eff


# --- events (server → client) ---------------------------------------------------------------


class _Event(BaseModel):
    seq: int | None = Field(None, description="the client message this answers, if any")


class HelloEvent(_Event):
    type: Literal["hello"] = "hello"
    session: str
    state: dict
    strokes: int = Field(description="active strokes")
    renderer: str = "cuts"
    renderers: list[str] = Field(default_factory=list, description="renderers the session may switch between")
    controls: list[str] = Field(default_factory=list, description="what this session's renderer lets a client change")


class FrameHeader(BaseModel):
    """The JSON header of a binary frame: 4-byte big-endian length | header | image."""
    frame: int
    ack: int = Field(description="the highest client seq whose effect the frame shows")
    width: int
    height: int
    format: Literal["jpeg"] = "jpeg"
    lod: bool = Field(description="drawn at the drag level of detail (coarser cuts, half resolution): chosen "
                                  "while the user drags only when full frames do not fit the frame budget")
    samples: int = Field(1, description="primary-visibility samples per pixel (anti-aliasing of still frames)")
    quick: bool = Field(False, description="a first frame shown at once (after a new fit, or when the user lets go "
                                           "of the camera): one sample, highlights slightly blurred; the anti-aliased "
                                           "still of the same state follows when the session is idle")
    shadow: bool | None = Field(None, description="the ground shadow is drawn; null: the scene has no ground")
    ms_render: float = Field(description="rendering, not counting ms_paused")
    ms_encode: float
    ms_paused: float = Field(0.0, description="how long the rendering stood aside for strokes being handled "
                                               "elsewhere on the machine (strokes go before frames)")
    ms_wait: float = Field(0.0, description="how long the message this frame answers waited in the worker before it "
                                             "was handled (other sessions' work, this session's previous frame): its "
                                             "oldest stroke, undo, redo or fit if it has one, else its oldest message")
    ms_apply: float = Field(0.0, description="applying the messages (a stroke's fit view is built here)")
    ms_fit: float = Field(0.0, description="the BRDF fit the messages asked for (0: none)")
    skipped: int = Field(0, description="client messages folded into this frame without a frame of their own")


class StrokeEvent(_Event):
    type: Literal["stroke"] = "stroke"
    strokes: int
    notes: list[str] = Field(default_factory=list)
    rejected: bool = False


class FitStats(BaseModel):
    model_config = ConfigDict(extra="allow")
    strokes: int = 0


class FitEvent(_Event):
    type: Literal["fit"] = "fit"
    object: str
    material: dict
    curve: dict
    stats: FitStats
    notes: list[str] = Field(default_factory=list)


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


class PaintEvent(_Event):
    """The lobes material fitted to a ``paint`` message's readings (worker/paint/session.py)."""
    type: Literal["paint"] = "paint"
    object: str
    material: dict
    measured: dict = Field(description="the fitted material's readings: what the frame shows")
    requested: dict
    error_l1: float
    error_max: float
    flop_index: float | None = None
    ms_fit: float


class RendererEvent(_Event):
    """The session now draws with this renderer; ``controls`` is what a client may change."""
    type: Literal["renderer"] = "renderer"
    kind: str
    controls: list[str]


class SaveRequest(_Event):
    """Worker → server only: the material to store for a pending save."""
    type: Literal["save"] = "save"
    object: str
    name: str | None = None
    material_id: str | None = None
    material: dict


ServerEvent = Annotated[Union[HelloEvent, StrokeEvent, FitEvent, CurveEvent, SavedEvent, NoteEvent, ErrorEvent,
                              PaintEvent, RendererEvent],
                        Field(discriminator="type")]
server_event = TypeAdapter(ServerEvent)


def stream_schema() -> dict:
    """JSON Schema of the stream (DESIGN.md §5): client messages, server events, frame header."""
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": "Glint session stream",
            "description": "WebSocket /v1/sessions/{id}/stream: JSON client messages with increasing seq; "
                           "JSON server events; binary frames of 4-byte big-endian header length | JSON "
                           "header | JPEG.",
            "client_message": client_msg.json_schema(), "server_event": server_event.json_schema(),
            "frame_header": FrameHeader.model_json_schema()}


def encode_frame(header: dict, image: bytes) -> bytes:
    """Binary WebSocket frame: 4-byte big-endian header length | UTF-8 JSON header | image."""
    h = json.dumps(header, separators=(",", ":")).encode()
    return len(h).to_bytes(4, "big") + h + image


def decode_frame(data: bytes) -> tuple[dict, bytes]:
    n = int.from_bytes(data[:4], "big")
    return json.loads(data[4:4 + n]), data[4 + n:]
