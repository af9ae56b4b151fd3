"""What a renderer is, said once in its package's ``__init__`` and read without importing it.

A renderer package (worker/renderers/cuts, gi, paint) starts with a ``DECLARATION``: its kind
(the scene file's ``renderer``), the controls a session on it may change, and where its
``Renderer`` and ``Precomputation`` classes are ("module:Class", imported when first asked
for). The package's ``__init__`` imports nothing numerical: the API process reads the
declaration to check stream messages (``worker.renderers.controls``) and never loads the
renderer's ray tracer, solvers or C kernels. The renderer class takes its ``kind`` and
``controls`` from the declaration, so they are written once.

This module imports the standard library only.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass, field

# everything a session may change; a renderer offers a subset (the studio hides the others
# and says why): "move" is placing movable objects, "ground" the shadow-catcher ground,
# "strokes" painting strokes that a fit turns into a BRDF
ALL_CONTROLS = frozenset({"camera", "light", "materials", "environment", "ground", "move", "strokes"})


@dataclass(frozen=True)
class RendererDeclaration:
    """kind : registry key, the scene file's ``renderer`` (e.g. "cuts").
    controls : the subset of ALL_CONTROLS an interactive session may change.
    renderer, precomputation : "package.module:Class" of the Renderer and Precomputation
        subclasses (imported by ``worker.renderers.get``).
    why_not : control -> why this renderer does not offer it (shown beside the control the
        studio turns off).
    settings : "module:Name" of the type of the renderer's optional scene-file settings, the
        scene file's field named ``kind`` (``worker.scene.scene_model`` adds it): a pydantic model
        validated with the scene file, or "builtins:dict" for a JSON object the renderer
        validates itself at precomputation; None for a renderer without settings. The module
        must be as light as this one's callers (pydantic, no numerical imports).
    bakes_fixed : objects with ``"editable": false`` (scene.SceneObject) have their BRDF baked
        into the precomputation: a session on this renderer cannot edit them."""
    kind: str
    controls: frozenset[str]
    renderer: str
    precomputation: str
    why_not: dict[str, str] = field(default_factory=dict, hash=False, compare=False)
    settings: str | None = None
    bakes_fixed: bool = False

    def __post_init__(self):
        object.__setattr__(self, "controls", frozenset(self.controls))
        unknown = self.controls - ALL_CONTROLS
        if unknown:
            raise ValueError(f"renderer {self.kind!r}: unknown controls {sorted(unknown)} "
                             f"(known: {', '.join(sorted(ALL_CONTROLS))})")
        for what in (self.renderer, self.precomputation, *([self.settings] if self.settings else [])):
            if what.count(":") != 1:
                raise ValueError(f"renderer {self.kind!r}: {what!r} is not 'module:Class'")


def resolve(path: str):
    """The object named by "package.module:Name" (imported now)."""
    module, _, name = path.partition(":")
    return getattr(importlib.import_module(module), name)


def lazy_exports(package: str, exports: dict[str, str]):
    """A module ``__getattr__`` (PEP 562) for a renderer package: ``exports`` maps a public name
    to the submodule (relative, e.g. ".renderer") it comes from, imported on first use, so
    ``from worker.renderers.cuts import CutRenderer`` keeps working while importing the package
    itself (for its DECLARATION) stays light."""
    def __getattr__(name: str):
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(exports[name], package), name)
    return __getattr__
