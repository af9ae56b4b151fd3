"""What a message asks for beyond its new state: a closed set of small frozen dataclasses, one
per kind. ``apply`` returns one of them; the server (server/sessions_store.py: rows of its own)
and the worker (worker/jobs/runtime.py: the fitter, the renderer) each have one handler per
class in a dict keyed by the class, so a kind nobody handles is a KeyError at the first test,
never a silent no-op.

Adding an effect: a dataclass here, added to ``Effect``, and a handler on each side that acts
on it (tests/server/test_protocol.py checks every member of ``Effect`` has a worker handler).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Union

from .state import PendingSave


@dataclass(frozen=True, slots=True)
class NoEffect:
    """Nothing beyond the new state (a camera, light or display change)."""


@dataclass(frozen=True, slots=True)
class RecordStroke:
    """Record a stroke, painted in the state's view before the message. stroke : {"stroke":
    Stroke dict, "camera": Camera dict, "rotation_deg": float, "intensity": float} (a stroke
    row's body)."""
    stroke: dict


@dataclass(frozen=True, slots=True)
class Undo:
    """Undo the last active stroke of the current epoch."""


@dataclass(frozen=True, slots=True)
class Redo:
    """Redo the last undone stroke of the current epoch."""


@dataclass(frozen=True, slots=True)
class Refit:
    """The fit options changed: fit again."""


@dataclass(frozen=True, slots=True)
class Save:
    """Store the edited object's material (pending in the state until stored)."""
    save: PendingSave


@dataclass(frozen=True, slots=True)
class NewMaterial:
    """An object's material was set; ``rebase``: it was the edited object's, so strokes of
    earlier epochs no longer apply."""
    object: str
    rebase: bool


# region steps (RegionsChanged with ``before``) kept for undo and redo per session, the most recent:
# the worker's stacks (jobs/runtime.py) and the server's rows (server/sessions_store.py) alike
MAX_REGION_STEPS = 16


@dataclass(frozen=True, slots=True)
class RegionsChanged:
    """The edited object's painted regions changed (``RegionMsg``): its material is the state's,
    and strokes of earlier epochs no longer apply (they are part of it). ``before``: the
    object's material before, when the message changed it (rename, erase, merge, material: an
    undoable step), else None; ``region_before``: the region painted before."""
    object: str
    before: Any = None
    region_before: str | None = None


@dataclass(frozen=True, slots=True)
class Moved:
    """A movable object was placed anew (fit views of the old placement are stale)."""
    object: str


@dataclass(frozen=True, slots=True)
class SwitchRenderer:
    """The session draws with another of its renderers (``state.renderer``)."""


@dataclass(frozen=True, slots=True)
class Relight:
    """The environment map changed (``state.environment_index``)."""


@dataclass(frozen=True, slots=True)
class FitPaint:
    """Fit a lobes material to the paint readings stored for ``object``."""
    object: str


@dataclass(frozen=True, slots=True)
class SelectObject:
    """The edited object changed to ``object``; the worker replays its epoch's strokes (the
    message's ``strokes``, filled by the server)."""
    object: str


@dataclass(frozen=True, slots=True)
class Pick:
    """Say which object is at (u, v) of the last frame (fractions of its width and height)."""
    u: float
    v: float


@dataclass(frozen=True, slots=True)
class Convert:
    """Fit a ``model`` material to ``object``'s look and make it the object's material."""
    object: str
    model: str


@dataclass(frozen=True, slots=True)
class RejectStroke:
    """Worker event: the stroke of message ``seq`` cannot apply; it is never replayed."""
    seq: int


@dataclass(frozen=True, slots=True)
class StoreSave:
    """Worker event: store ``material`` (a Material dict) as a design version for the pending
    save of message ``seq``."""
    seq: int | None
    object: str
    name: str | None
    material_id: str | None
    material: dict


# what a client message's apply returns
Effect = Union[NoEffect, RecordStroke, Undo, Redo, Refit, Save, NewMaterial, RegionsChanged, Moved, SwitchRenderer, Relight, FitPaint,
               SelectObject, Pick, Convert]
# what a worker event's apply returns (on the server)
StoreEffect = Union[NoEffect, RejectStroke, StoreSave]
NO_EFFECT = NoEffect()
