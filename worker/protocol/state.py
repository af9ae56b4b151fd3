"""One interactive session's stored state (what the server stores per session and the worker
renders from): ``SessionState``, ``new_state`` for a new session on a scene, ``restore_state``
for a stored one read back (never failing).
"""
from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from ..fit.brush import DEFAULT_UNPAINTED_WEIGHT
from ..models import Material, parse_material
from ..scene import Camera, Transform

Tone = Literal["linear", "aces", "neutral"]


class StateError(ValueError):
    """A message that cannot apply to this state; the message says why (sent as an error
    event; nothing is stored or forwarded)."""


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


class ObjectEdit(BaseModel):
    """Where an object's editing stood when the session moved to another object: its epoch
    (its stroke rows, with their undo state, are the rows of that epoch) and the material its
    strokes paint over."""
    epoch: int
    base_material: Material


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
    # expose the first frame automatically (a scene file's "exposure": "auto"): the worker sets
    # ``exposure`` from it and sends an exposure event
    auto_exposure: bool = False
    # the most pixels a frame may have (the server's max_frame_pixels; None: the camera's bounds)
    max_frame_pixels: int | None = None
    # objects edited before the current one, by name (``ObjectMsg``): each keeps its strokes
    edits: dict[str, ObjectEdit] = Field(default_factory=dict)
    # the painted region the edited object's strokes make or extend (``RegionMsg``; None: the
    # strokes fit one BRDF for the whole object)
    region: str | None = None
    # objects marked "editable": false in the scene file: a renderer that bakes them into its
    # precomputation (the GI one) keeps their BRDF (``fixed``)
    baked: list[str] = Field(default_factory=list)

    def fresh_epoch(self) -> int:
        """An epoch no object has used: the stroke rows of every object's epoch stay its own."""
        return max([self.epoch, *(e.epoch for e in self.edits.values())]) + 1

    def fixed(self, name: str) -> bool:
        """Whether object ``name`` keeps its BRDF under the current renderer."""
        from ..renderers import bakes_fixed

        return name in self.baked and bakes_fixed(self.renderer)

    def refuse_fixed(self, what: str, name: str) -> None:
        if self.fixed(name):
            raise StateError(f"{what}: object {name!r} is fixed (\"editable\": false): its BRDF is baked into "
                             f"the {self.renderer} precomputation and cannot change (pick another object)")

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
    kind = spec.get("renderer") or "cuts"
    baked = [o["name"] for o in spec["objects"] if o.get("editable") is False]
    from ..renderers import bakes_fixed
    editable = [n for n in names if n not in baked] if bakes_fixed(kind) else names
    obj = object_name or (editable or names)[0]
    if obj not in names:
        raise StateError(f"object: no object {obj!r} (objects: {', '.join(names)})")
    mats = [o.get("material") or {"model": "lambert"} for o in spec["objects"]]
    env = spec["environment"]
    movable = [o["name"] for o in spec["objects"] if o.get("movable")]
    ex = spec.get("exposure")
    if ex is not None and "exposure" not in fields and "auto_exposure" not in fields:
        fields = {**fields, **({"auto_exposure": True} if ex == "auto" else {"exposure": float(ex)})}
    return SessionState.model_validate({
        "objects": names, "object": obj, "camera": camera or spec["camera"],
        "rotation_deg": env.get("rotation_deg", 0.0), "intensity": env.get("intensity", 1.0),
        "materials": mats, "base_material": mats[names.index(obj)], "renderer": kind,
        "renderers": [kind] + (["cuts"] if kind != "cuts" else []), "movable": movable, "baked": baked,
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


def copy_state(state: SessionState) -> SessionState:
    """A copy to apply a change to. Copy-on-write: every change replaces the fields it changes
    (a new Camera, a new list of materials), never edits a nested value in place, so a shallow
    copy with its own top-level containers keeps ``state`` intact; a deep copy of a fitted srbf
    state was 12% of a worker's time under load."""
    st = state.model_copy()
    for k, v in st.__dict__.items():
        if isinstance(v, (list, dict)):
            st.__dict__[k] = type(v)(v)
    return st


def _first_error(e: Exception) -> str:
    if isinstance(e, ValidationError):
        err = e.errors()[0]
        return f"{'.'.join(str(x) for x in err['loc'])}: {err['msg']}"
    return str(e)
