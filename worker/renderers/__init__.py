"""Renderers by kind (see base.py). ``get(kind)`` returns the registered (Renderer class,
Precomputation instance); ``controls(kind)`` what a session on it may change.

A renderer is a package under worker/renderers/ whose ``__init__`` holds its ``DECLARATION``
(declaration.py: kind, controls, and where its classes are) and imports nothing numerical, so
the API process reads the declarations without the renderers' numerical imports; the classes
are imported when ``get`` first asks for them.

Adding a renderer: the package (its DECLARATION, a Renderer subclass taking ``kind`` and
``controls`` from it and listing its ``capabilities``, a Precomputation subclass), plus one
line in RENDERER_PACKAGES.
"""
from __future__ import annotations

import importlib

from ..errors import GlintError
from .base import (CAPABILITIES, ArtifactStore, FrameRequest, Lighting, Part, Precomputation,  # noqa: F401
                   Rendered, Renderer, Unsupported, ensure, implemented_capabilities, load)
from .declaration import ALL_CONTROLS, RendererDeclaration, resolve  # noqa: F401

# one line per renderer: the package whose DECLARATION says what it is
RENDERER_PACKAGES: list[str] = [
    "worker.renderers.cuts",
    "worker.renderers.gi",
    "worker.renderers.paint",
]

_declared: dict[tuple[str, ...], dict[str, RendererDeclaration]] = {}
_registry: dict[str, tuple[type[Renderer], Precomputation]] = {}


def declarations() -> dict[str, RendererDeclaration]:
    """kind -> the declaration of every renderer in RENDERER_PACKAGES (light: imports only the
    packages' ``__init__``)."""
    packages = tuple(RENDERER_PACKAGES)
    out = _declared.get(packages)
    if out is None:
        out = {}
        for name in packages:
            decl = getattr(importlib.import_module(name), "DECLARATION", None)
            if not isinstance(decl, RendererDeclaration):
                raise TypeError(f"renderer package {name!r} has no DECLARATION (worker/renderers/declaration.py)")
            if decl.kind in out:
                raise ValueError(f"renderer {decl.kind!r} declared by two packages")
            out[decl.kind] = decl
        _declared.clear()
        _declared[packages] = out
    return out


def controls(kind: str) -> frozenset[str]:
    """What a session on this renderer may change (camera, light, materials, environment, ground,
    move); nothing for a kind no package declares."""
    decl = declarations().get(kind)
    return decl.controls if decl is not None else frozenset()


def bakes_fixed(kind: str) -> bool:
    """Whether the ``kind`` renderer bakes objects marked ``"editable": false`` into its
    precomputation (RendererDeclaration.bakes_fixed)."""
    decl = declarations().get(kind)
    return bool(decl is not None and decl.bakes_fixed)


def why_not(kind: str, control: str) -> str:
    """Why the ``kind`` renderer does not offer ``control`` (a sentence for the designer, from
    its declaration's ``why_not``)."""
    decl = declarations().get(kind)
    reason = decl.why_not.get(control) if decl is not None else None
    return reason or f"the {kind} renderer does not offer {control}"


def kinds() -> list[str]:
    return sorted(declarations())


def get(kind: str) -> tuple[type[Renderer], Precomputation]:
    decl = declarations().get(kind)
    if decl is None:
        raise GlintError(f"unknown renderer {kind!r} (known: {', '.join(kinds())})")
    hit = _registry.get(kind)
    if hit is None or hit[0].__module__ + ":" + hit[0].__qualname__ != decl.renderer:
        hit = _registry[kind] = _build(decl)
    return hit


def _build(decl: RendererDeclaration) -> tuple[type[Renderer], Precomputation]:
    cls, pre_cls = resolve(decl.renderer), resolve(decl.precomputation)
    if not (isinstance(cls, type) and issubclass(cls, Renderer)):
        raise TypeError(f"renderer {decl.kind!r}: {decl.renderer} is not a Renderer")
    if not (isinstance(pre_cls, type) and issubclass(pre_cls, Precomputation)):
        raise TypeError(f"renderer {decl.kind!r}: {decl.precomputation} is not a Precomputation")
    # the classes take kind and controls from the declaration; one written by hand must agree
    for what, have in (("kind", cls.kind), ("controls", frozenset(cls.controls)), ("precomputation kind", pre_cls.kind)):
        want = decl.controls if what == "controls" else decl.kind
        if have != want:
            raise ValueError(f"renderer {decl.kind!r}: {what} {have!r} of the class differs from its DECLARATION {want!r}")
    return cls, pre_cls()


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
