"""The stream's client messages, each with its meaning and its policy on its class, and ``apply``:
the one function that applies a message to a session's state (docs/design/conventions.md, streaming protocol).

The same ``apply(state, msg)`` runs where the server persists a message
(server/sessions_store.py) and where the worker renders it (worker/jobs/runtime.py), so the
two can never disagree about what a message means. It is pure: it returns the new state and an
``Effect`` (effects.py) saying what else the message asks for, which each side carries out in
its own way (rows in the database; the fitter in the worker).

A message class declares how it is handled, so no table elsewhere has to agree with it:

storage : ClassVar, how the server stores it: "batched" (its state is written at most
    FLUSH_S later: camera, light, object moves, display), "rows" (rows of its own are written
    before it is forwarded, its state batched: strokes, undo, redo) or "state" (the state is
    written, with everything before it, before it is forwarded: anything else).
urgent : ClassVar, strokes before frames: the worker handles it ahead of other sessions'
    frames (worker/jobs/scheduling.py Priority).
drags : ClassVar, it moves the view, the light or an object: its ``drag`` field sets the
    session's drag state, and it marks the session busy (worker/jobs/lod.py).
readonly_ok : ClassVar, a shopper's read-only viewer may send it.

Adding a stream message: a ``ClientMsg`` subclass with ``type: Literal[...]``, its policy and
an ``apply`` method, decorated with ``@message``; if its apply returns a new kind of effect,
that effect's class (effects.py) and its handlers.

Every message carries an increasing ``seq``. A message whose ``seq`` is not above the state's
``last_seq`` is already part of the state: a worker that re-opens a session from what the server
stored skips it, so a message persisted while a session is being restored is applied once.
"""
from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError
from pydantic_core import PydanticCustomError, core_schema

from ..fit.brush import Stroke, rescale_stroke
from ..models import Material, Vec3
from ..scene import Camera, Transform
from .effects import (NO_EFFECT, Convert, Effect, FitPaint, Moved, NewMaterial, Pick, RecordStroke, Redo, Refit,
                      RegionsChanged, Relight, Save, SelectObject, SwitchRenderer, Undo)
from .state import EnvPreset, ObjectEdit, PendingSave, SessionState, StateError, Tone, copy_state

Storage = Literal["batched", "rows", "state"]
# a frame's pixels at most when the session does not say (server Settings.max_frame_pixels's default)
DEFAULT_MAX_FRAME_PIXELS = 2560 * 1600

_MESSAGES: dict[str, type["ClientMsg"]] = {}


def message(cls):
    """Class decorator: register a client message type (by its ``type`` literal)."""
    _MESSAGES[cls.model_fields["type"].default] = cls
    return cls


class ClientMsg(BaseModel):
    """A client → server message. ``readonly_ok``: a shopper's read-only viewer may send it."""
    model_config = ConfigDict(extra="forbid")
    # the policy (module docstring); a subclass sets what differs
    storage: ClassVar[Storage] = "state"
    urgent: ClassVar[bool] = False
    drags: ClassVar[bool] = False
    readonly_ok: ClassVar[bool] = False
    # strict: "7" is not a seq (lax mode turned it into 7, and the server stored what the
    # client may not have meant); the server refuses one not above the state's last_seq
    seq: int = Field(ge=0, le=2**53, strict=True)
    type: str

    def apply(self, st: SessionState) -> Effect | None:
        """Change ``st`` (a copy the caller owns: replace fields, never edit a nested value in
        place) and say what else is asked for (None: nothing)."""
        raise NotImplementedError


@message
class ViewMsg(ClientMsg):
    """Partial camera: any of eye, target, up, fov_y_deg, and the frame's ``width`` and ``height``
    in pixels (the studio's canvas size times its device pixel ratio), scaled down, keeping
    their aspect, to the session's ``max_frame_pixels``."""
    storage: ClassVar[Storage] = "batched"
    drags: ClassVar[bool] = True
    readonly_ok: ClassVar[bool] = True
    type: Literal["view"] = "view"
    eye: Vec3 | None = None
    target: Vec3 | None = None
    up: Vec3 | None = None
    fov_y_deg: float | None = Field(None, gt=1.0, lt=170.0)
    width: int | None = Field(None, ge=16, le=8192)
    height: int | None = Field(None, ge=16, le=8192)
    drag: bool = False

    def apply(self, st):
        if not st.allows("camera"):
            raise StateError(f"view: the {st.renderer} renderer draws from a fixed camera "
                             "(switch to the cuts renderer to orbit)")
        upd = {k: getattr(self, k) for k in ("eye", "target", "up", "fov_y_deg") if getattr(self, k) is not None}
        if self.width is not None or self.height is not None:
            w, h = self.width or st.camera.width, self.height or st.camera.height
            cap = st.max_frame_pixels or DEFAULT_MAX_FRAME_PIXELS
            if w * h > cap:
                k = (cap / (w * h)) ** 0.5
                w, h = max(16, int(w * k)), max(16, int(h * k))
            upd.update(width=w, height=h)
        try:
            st.camera = Camera.model_validate({**st.camera.model_dump(), **upd})
        except ValidationError as e:
            raise StateError(f"view: {e.errors()[0]['msg']}") from None
        return None


@message
class LightMsg(ClientMsg):
    storage: ClassVar[Storage] = "batched"
    drags: ClassVar[bool] = True
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
        return None


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
        st.refuse_fixed("material", name)
        mats = list(st.materials)
        mats[st.objects.index(name)] = self.material
        st.materials = mats
        rebase = name == st.object
        if rebase:
            st.base_material = self.material
            st.epoch = st.fresh_epoch()
        return NewMaterial(name, rebase)


@message
class StrokeMsg(ClientMsg):
    storage: ClassVar[Storage] = "rows"
    urgent: ClassVar[bool] = True
    type: Literal["stroke"] = "stroke"
    stroke: Stroke
    frame: tuple[Annotated[int, Field(ge=1, le=65536)], Annotated[int, Field(ge=1, le=65536)]] | None = Field(
        None, description="(width, height) of the frame whose pixels the stroke's points, diameter and κ are "
        "in, when it may differ from the session camera's (a client that has asked for a new frame size "
        "and not yet received a frame of it); the stroke is rescaled to the camera's size. Default: the "
        "camera's size.")

    def apply(self, st):
        if not st.allows("strokes"):
            from ..renderers import why_not
            raise StateError(f"stroke: {why_not(st.renderer, 'strokes')}")
        st.refuse_fixed("stroke", st.object)
        a = st.base_material.albedo
        if min(a) < 0 or max(a) > 1:
            raise StateError(f"stroke: strokes paint over the edited object's material, whose diffuse albedo "
                             f"{list(a)} is outside [0, 1]; choose a physical material first")
        stroke = self.stroke if self.frame is None else rescale_stroke(self.stroke, self.frame, st.camera)
        return RecordStroke({"stroke": stroke.model_dump(mode="json"),
                             "camera": st.camera.model_dump(mode="json"),
                             "rotation_deg": st.rotation_deg, "intensity": st.intensity})


@message
class RegionMsg(ClientMsg):
    """The edited object's painted regions (docs/guides/regions.md). ``paint``: the strokes that
    follow make the region ``name``, or extend it when the object's material has it, painted over
    the look so far (the strokes before become part of the material: a new epoch, as a material
    change); undo and redo then cover the region's strokes, and a save stores the material with
    its regions as a design version. ``stop``: strokes fit one BRDF for the object again.
    ``rename``: region ``name`` (with its parts ``name/1`` …) becomes ``new_name``. ``erase``:
    region ``name`` is removed (the object shows what was under it). ``merge``: region ``name``
    is merged into region ``new_name`` (one region with ``new_name``'s material over both
    footprints). ``material``: region ``name`` takes ``material`` (e.g. a design from the
    library). Rename, erase, merge and material are steps undo and redo cover, once the strokes
    painted after them are undone."""
    type: Literal["region"] = "region"
    action: Literal["paint", "stop", "rename", "erase", "merge", "material"]
    name: str | None = Field(None, min_length=1, max_length=100, pattern=r"^[^/]+$")
    new_name: str | None = Field(None, min_length=1, max_length=100, pattern=r"^[^/]+$")
    material: Material | None = None

    def apply(self, st):
        from ..models.regions import (has_regions, in_group as _in_group, merge_regions, rename_region,
                                      with_region_material, without_region)

        if self.action != "stop" and self.name is None:
            raise StateError(f"region: {self.action} needs the region's name")
        if self.action == "paint" and not st.allows("strokes"):
            from ..renderers import why_not
            raise StateError(f"region: {why_not(st.renderer, 'strokes')}")
        i = st.object_index
        cur = before = st.materials[i]
        region_before = st.region
        if self.action in ("rename", "erase", "merge", "material"):
            st.refuse_fixed("region", st.object)
            if not has_regions(cur) or not any(_in_group(r.name, self.name) for r in cur.regions):
                raise StateError(f"region: object {st.object!r} has no region {self.name!r}")
            if self.action in ("rename", "merge"):
                if self.new_name is None:
                    raise StateError(f"region: {self.action} needs new_name")
                there = any(_in_group(r.name, self.new_name) for r in cur.regions)
                if self.action == "rename" and there:
                    raise StateError(f"region: object {st.object!r} has a region {self.new_name!r} already")
                if self.action == "merge" and (not there or self.new_name == self.name):
                    raise StateError(f"region: merge needs another region of object {st.object!r} to merge "
                                     f"{self.name!r} into (no region {self.new_name!r})")
            if self.action == "rename":
                cur = rename_region(cur, self.name, self.new_name)
            elif self.action == "merge":
                cur = merge_regions(cur, self.name, self.new_name)
            elif self.action == "material":
                if self.material is None:
                    raise StateError("region: material needs the material")
                if has_regions(self.material):
                    raise StateError("region: a region's material cannot itself have regions (give its base)")
                cur = with_region_material(cur, self.name, self.material)
            else:
                cur = without_region(cur, self.name)
            mats = list(st.materials)
            mats[i] = cur
            st.materials = mats
            if st.region == self.name:
                st.region = self.new_name if self.action in ("rename", "merge") else \
                    (None if self.action == "erase" else st.region)
        else:
            st.region = self.name if self.action == "paint" else None
        # what the strokes so far made is now what the next ones paint over
        st.base_material = cur
        st.epoch = st.fresh_epoch()
        return RegionsChanged(st.object, before if cur is not before else None, region_before)


@message
class UndoMsg(ClientMsg):
    storage: ClassVar[Storage] = "rows"
    urgent: ClassVar[bool] = True
    type: Literal["undo"] = "undo"

    def apply(self, st):
        return Undo()


@message
class RedoMsg(ClientMsg):
    storage: ClassVar[Storage] = "rows"
    urgent: ClassVar[bool] = True
    type: Literal["redo"] = "redo"

    def apply(self, st):
        return Redo()


@message
class FitMsg(ClientMsg):
    urgent: ClassVar[bool] = True
    type: Literal["fit"] = "fit"
    constrained: bool | None = None
    unpainted_weight: float | None = Field(None, ge=0.0, le=1e6)

    def apply(self, st):
        if self.constrained is not None:
            st.constrained = self.constrained
        if self.unpainted_weight is not None:
            st.unpainted_weight = self.unpainted_weight
        return Refit()


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
        return Save(p)


@message
class DisplayMsg(ClientMsg):
    """Display settings: exposure (EV), tone curve, JPEG quality, and the ground shadow under the
    objects (scenes with a ``ground``; the frame header's ``shadow`` says whether it is drawn)."""
    storage: ClassVar[Storage] = "batched"
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
        return Relight()


def _scale3(s) -> tuple[float, float, float]:
    return tuple(float(x) for x in s) if isinstance(s, (tuple, list)) else (float(s),) * 3


@message
class MoveMsg(ClientMsg):
    """Place a movable object (cyber-worlds §V: visibility cut fields): its transform as in the
    scene file (scale, rotate, translate), replacing the one it had. ``drag`` while the user
    drags it (the drag level of detail)."""
    storage: ClassVar[Storage] = "batched"
    drags: ClassVar[bool] = True
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
        return Moved(self.object)


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
        from ..renderers import bakes_fixed
        if st.object in st.baked and bakes_fixed(self.kind):
            raise StateError(f"renderer: the edited object {st.object!r} is fixed (\"editable\": false) in the "
                             f"{self.kind} precomputation; pick an editable object first")
        st.renderer = self.kind
        return SwitchRenderer()


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
            st.epoch = st.fresh_epoch()     # like a new material: strokes painted before do not carry over
        return FitPaint(name)


@message
class ObjectMsg(ClientMsg):
    """Edit another object: from now on the brush, the fit, the material panel and saves act on
    ``object``. Each object keeps its own strokes and undo history: the one left is remembered
    (its epoch and base material, ``state.edits``) and comes back when it is picked again.
    ``strokes`` is filled by the server (the stroke rows of the object's epoch, for the worker to
    replay); a client's is ignored."""
    type: Literal["object"] = "object"
    object: str = Field(min_length=1, max_length=255)
    strokes: list[dict] | None = Field(None, max_length=100_000)

    def apply(self, st):
        if st.readonly:
            raise StateError("object: a viewer session shows the published object only")
        if self.object not in st.objects:
            raise StateError(f"object: no object {self.object!r} (objects: {', '.join(st.objects)})")
        st.refuse_fixed("object", self.object)
        if self.object != st.object:
            st.edits = {**st.edits, st.object: ObjectEdit(epoch=st.epoch, base_material=st.base_material)}
            back = st.edits.get(self.object)
            if back is not None:
                st.epoch, st.base_material = back.epoch, back.base_material
            else:
                st.epoch, st.base_material = st.fresh_epoch(), st.material_of(self.object)
            st.object = self.object
        return SelectObject(self.object)


@message
class PickMsg(ClientMsg):
    """Which object is under a point of the image (``u``, ``v``: fractions of the frame's width
    and height from its top left): the worker answers with a ``picked`` event from the last
    frame's object ids. Changes nothing."""
    storage: ClassVar[Storage] = "batched"
    readonly_ok: ClassVar[bool] = True
    type: Literal["pick"] = "pick"
    u: float = Field(ge=0.0, le=1.0)
    v: float = Field(ge=0.0, le=1.0)

    def apply(self, st):
        return Pick(self.u, self.v)


@message
class ConvertMsg(ClientMsg):
    """Give an object's material another model with the same look: the worker fits the new
    model to the old material's appearance (worker/models/convert.py) and sends a
    ``converted`` event, which the object's stored material follows. For the edited object it
    is a new base, as a material message (strokes start a new epoch)."""
    type: Literal["convert"] = "convert"
    object: str | None = None
    model: str = Field(max_length=64)

    def apply(self, st):
        from ..models.convert import TARGETS

        name = self.object or st.object
        if name not in st.objects:
            raise StateError(f"convert: no object {name!r} (objects: {', '.join(st.objects)})")
        if self.model not in TARGETS:
            raise StateError(f"convert: cannot convert to {self.model!r} (models: {', '.join(TARGETS)})")
        if name == st.object:
            st.epoch = st.fresh_epoch()
        return Convert(name, self.model)


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
    st = copy_state(state)
    eff = msg.apply(st) or NO_EFFECT
    st.last_seq = max(st.last_seq, msg.seq)
    return st, eff
