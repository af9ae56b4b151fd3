"""Material overrides: objects' materials replaced by object name, as ``glint render --material
OBJECT=MATERIAL.json`` and the REST render's ``materials`` (a material per object name) ask.

One function, so that every caller agrees on which names are valid, what a material is (any
registered model, validated by its schema) and in which order several overrides apply. The
callers only say where a material comes from (a file, a request body) and word the errors for
their users.
"""
from __future__ import annotations

from typing import Any, Callable, Iterable

from .errors import GlintError


class UnknownObject(GlintError):
    """An override names no object of the scene."""

    def __init__(self, name: str, names: list[str]):
        super().__init__(f"no object {name!r} in the scene (objects: {', '.join(names)})")
        self.object, self.names = name, names


class InvalidMaterial(GlintError):
    """An override's material is not a valid material; ``reason`` is the validator's first line."""

    def __init__(self, name: str, reason: str):
        super().__init__(f"{name}: not a valid material ({reason})")
        self.object, self.reason = name, reason


def apply_material_overrides(scene, overrides: Iterable[tuple[str, Any | Callable[[], Any]]], materials=None) -> list:
    """The scene's materials (or ``materials``, one per object) with each ``(object name,
    material)`` of ``overrides`` in place, in order (a later one for the same object wins).

    A material is its JSON form (a dict), a parsed model, or a function returning the JSON form:
    a function is called only once its object name is known to be valid, so that a bad name is
    reported before a missing file. Raises UnknownObject or InvalidMaterial."""
    from .models import BRDFModel, parse_material
    from .models.regions import RegionsError, has_regions, layer_weights

    names = [o.name for o in scene.spec.objects]
    mats = list(scene.materials if materials is None else materials)
    for name, value in overrides:
        if name not in names:
            raise UnknownObject(name, names)
        data = value() if callable(value) else value
        if not isinstance(data, BRDFModel):
            try:
                data = parse_material(data)
            except ValueError as e:          # pydantic's ValidationError is a ValueError
                raise InvalidMaterial(name, str(e).splitlines()[0]) from e
        o = names.index(name)
        if has_regions(data):
            # region weights index the object's own vertices: a material painted on another mesh
            # is refused here, before a renderer would blend the wrong vertices
            try:
                layer_weights(data, object_vertex_count(scene, o), scene.vertex_source(o))
            except RegionsError as e:
                raise InvalidMaterial(name, str(e)) from e
        mats[o] = data
    return mats


def object_vertex_count(scene, index: int) -> int:
    """Vertices of object ``index`` of a loaded scene (its mesh as loaded)."""
    import numpy as np

    return int(np.count_nonzero(scene.object_of_vertex == index))
