"""Renderers by kind (see base.py). ``get(kind)`` returns the registered (Renderer class,
Precomputation instance); each renderer module registers itself when imported.

Adding a renderer: a module (or package) under worker/renderers/ that subclasses Renderer and
Precomputation and calls ``register``, plus one line in RENDERER_MODULES.
"""
from __future__ import annotations

import importlib

from ..errors import GlintError
from .base import (ArtifactStore, FrameRequest, Lighting, Part, Precomputation, Rendered, Renderer,  # noqa: F401
                   Unsupported, ensure, load)

# one line per renderer: importing the module registers it
RENDERER_MODULES: dict[str, str] = {
    "cuts": "worker.renderers.cuts",
    "gi": "worker.renderers.gi",
    "paint": "worker.renderers.paint",
}
# what a session on each renderer may change, known without importing it (the API process
# checks messages against it and stays free of the renderers' numerical imports); a renderer's
# class attribute ``controls`` must say the same (checked when it registers)
RENDERER_CONTROLS: dict[str, frozenset[str]] = {
    "cuts": frozenset({"camera", "light", "materials", "environment", "ground", "move"}),
    "gi": frozenset({"materials"}),
    "paint": frozenset({"camera", "light", "materials", "environment"}),
}

_registry: dict[str, tuple[type[Renderer], Precomputation]] = {}


def register(renderer: type[Renderer], precomputation: Precomputation) -> None:
    if renderer.kind != precomputation.kind:
        raise ValueError(f"renderer {renderer.kind!r} registered with precomputation {precomputation.kind!r}")
    declared = RENDERER_CONTROLS.setdefault(renderer.kind, frozenset(renderer.controls))
    if frozenset(renderer.controls) != declared:
        raise ValueError(f"renderer {renderer.kind!r}: controls {sorted(renderer.controls)} differ from "
                         f"RENDERER_CONTROLS {sorted(declared)}")
    _registry[renderer.kind] = (renderer, precomputation)


def controls(kind: str) -> frozenset[str]:
    """What a session on this renderer may change (camera, light, materials, environment, move)."""
    return RENDERER_CONTROLS.get(kind, frozenset())


def kinds() -> list[str]:
    return sorted(set(RENDERER_MODULES) | set(_registry))


def prepare(scene, store: ArtifactStore, kind: str | None = None, options: dict | None = None,
            progress=None, threads: int = 2, kernels=None, compute: bool = True):
    """A renderer for a loaded scene: its precomputation ensured in the store (computed here
    when missing and ``compute``), loaded, and the renderer built. ``kind`` defaults to the
    scene file's ``renderer``. Returns (renderer, ensure stats or None)."""
    kind = kind or getattr(scene.spec, "renderer", "cuts")
    cls, pre = get(kind)
    stats = ensure(pre, scene, store, options, progress, threads) if compute else None
    data = load(pre, scene, store, options)
    return cls(scene, data, kernels=kernels), stats


def get(kind: str) -> tuple[type[Renderer], Precomputation]:
    if kind not in _registry and kind in RENDERER_MODULES:
        importlib.import_module(RENDERER_MODULES[kind])
    if kind not in _registry:
        raise GlintError(f"unknown renderer {kind!r} (known: {', '.join(kinds())})")
    return _registry[kind]
