"""What every BRDF model is, and the registry that makes a new one a single module.

One place per model, as pbrt keeps one class per BxDF and Mitsuba one plugin per file: a model
module defines a pydantic class (its JSON schema, docs/design/conventions.md, scene file), how it packs into the kernels'
flat form (``pack``), the NumPy reference of what the kernel evaluates, the name of its C kernel
branch (looked up in the library at load time, never copied by hand), its studio controls and
example instances that the generic conformance tests (tests/models) run (reciprocity, energy,
C/NumPy agreement). ``@register`` adds it; nothing else in the package lists models.

A model without a C kernel (``kernel = None``) still renders: the renderer shades its points
with the NumPy reference. That is how a test registers a model from its own file.

Every model is ``f = albedo/π + specular part``; the specular part is evaluated from the
geometry of a pair of local-frame directions (``Geometry``): cosines of ωi, ωo, the half vector
h and ωi·h. Below either horizon f = 0.
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from typing import Annotated, Any, Callable, ClassVar, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter
from pydantic_core import PydanticCustomError, core_schema

INV_PI = 1.0 / np.pi
Vec3 = tuple[float, float, float]
Color = Annotated[tuple[float, float, float], Field(description="linear RGB")]

# the kernels' packed layout (worker/native/src/glintk.c checks the same numbers at load)
N_PARAMS = 132   # 4 + 4·32: the lobes model's MAX_LOBES lobes
# p(h) tables over the upper hemisphere in hemi-octahedral coordinates: N×N samples, ~0.9°
# apart; a lookup costs one division instead of an acos and an atan2
TABLE_N = 160


@dataclass
class Geometry:
    """A batch of local-frame direction pairs (z = normal), float64.

    wi, wo : (…, 3) unit vectors; h : (…, 3) unit half vectors; ci, co, ch : (…,) cosines of
    ωi, ωo, h with the normal; cd : (…,) ωi·h (= ωo·h)."""
    wi: np.ndarray
    wo: np.ndarray
    h: np.ndarray
    ci: np.ndarray
    co: np.ndarray
    ch: np.ndarray
    cd: np.ndarray

    @classmethod
    def of(cls, wi, wo) -> "Geometry":
        wi = np.asarray(wi, np.float64)
        wo = np.asarray(wo, np.float64)
        hv = wi + wo
        h = hv / np.maximum(np.linalg.norm(hv, axis=-1, keepdims=True), 1e-20)
        return cls(wi, wo, h, wi[..., 2], wo[..., 2], h[..., 2], np.einsum("...i,...i->...", wi, h))


class PackedBRDF:
    """A material in the kernels' flat form.

    kernel : name of the C kernel branch (``glk_model_id``), or None for NumPy only.
    params : (N_PARAMS,) float32, params[0:3] the albedo; the rest is the model's.
    table : optional (TABLE_N, TABLE_N, 3) float32 p(h) table (hemi-octahedral).
    specular : the NumPy reference of the kernel branch: Geometry -> (…, 3) float64, the BRDF
        minus albedo/π (1/sr).
    refine_radius, extent : how the cut renderer refines clusters for this material: a cluster
        of radius R (radians) at angle a from the mirror direction is split while
        R > refine_radius and a < R + extent (the specular part is non-zero only within extent
        of the mirror direction). By default ``lobe_width`` w gives (w/2, 2w).
    """

    def __init__(self, kernel: str | None, params, specular: Callable[[Geometry], np.ndarray], table=None,
                 lobe_width: float = np.inf, refine_radius: float | None = None, extent: float | None = None):
        self.kernel = kernel
        self.params = np.zeros(N_PARAMS, np.float32)
        self.params[: len(params)] = params
        self.specular = specular
        self.table = None if table is None else np.ascontiguousarray(table, dtype=np.float32)
        self.refine_radius = float(0.5 * lobe_width if refine_radius is None else refine_radius)
        self.extent = float(2.0 * lobe_width if extent is None else extent)

    @property
    def albedo(self) -> np.ndarray:
        return self.params[0:3].astype(np.float64)

    def eval(self, wi, wo) -> np.ndarray:
        """f(ωi, ωo) (…, 3) float64 1/sr for local-frame unit directions (…, 3)."""
        g = Geometry.of(wi, wo)
        out = self.albedo * INV_PI + self.specular(g)
        return np.where(((g.ci > 0) & (g.co > 0))[..., None], out, 0.0)


class BRDFModel(BaseModel):
    """Base class of every material model (subclass, declare ``model: Literal[name]`` and the
    fields, override ``specular_part`` and, for a C kernel, ``pack``; then ``@register``).

    Class attributes
    ----------------
    kernel : C kernel branch name, or None (NumPy reference only).
    controls : studio controls, e.g. ``{"name": "alpha", "kind": "range", "min": 0.02,
        "max": 1, "step": 0.01}`` or ``{"name": "specular", "kind": "color"}``.
    creatable : whether the studio can start a design from this model's defaults (srbf comes
        from strokes instead).
    label : human name.
    studio_default : the fields a design starts from in the studio (over the field defaults,
        which stay what stored materials mean): a plausible material, not a mirror.
    """
    model_config = ConfigDict(extra="forbid")

    kernel: ClassVar[str | None] = None
    controls: ClassVar[tuple[dict, ...]] = ({"name": "albedo", "kind": "color"},)
    creatable: ClassVar[bool] = True
    label: ClassVar[str] = ""
    studio_default: ClassVar[dict] = {}

    model: str
    albedo: Color = (0.0, 0.0, 0.0)

    # -- what a subclass provides ------------------------------------------------------------
    def specular_part(self, g: Geometry) -> np.ndarray:
        """The BRDF minus albedo/π at local geometry g: (…, 3) float64, 1/sr."""
        return np.zeros(np.shape(g.ci) + (3,))

    def lobe_width(self) -> float:
        """Angular width (radians) of the specular lobe around the mirror direction, for the
        cut renderer's refinement; π or more for wide or unknown lobes."""
        return np.pi

    @classmethod
    def examples(cls) -> list["BRDFModel"]:
        """Instances the conformance tests run (tests/models)."""
        try:
            return [cls()]
        except Exception:
            return []

    # -- derived -----------------------------------------------------------------------------
    def pack(self) -> PackedBRDF:
        """Kernel form; the default is NumPy only (``specular_part`` as the reference)."""
        return PackedBRDF(self.kernel, [*self.albedo], self.specular_part, lobe_width=min(np.pi, self.lobe_width()))

    def evaluate(self, wi, wo) -> np.ndarray:
        """f(ωi, ωo) (…, 3) float64 1/sr, local-frame unit directions (…, 3), as the kernel
        sees it (through pack)."""
        return packed(self).eval(wi, wo)


_PACKS: "OrderedDict[str, PackedBRDF]" = OrderedDict()
_PACKS_LOCK = threading.Lock()
PACKS_KEPT = 16


def packed(m: "BRDFModel") -> PackedBRDF:
    """m.pack(), remembered by content for the process (the last PACKS_KEPT): a session's state
    is copied by every message, so one material arrives as new objects, and packing a fitted
    srbf (its p(h) table over every centre) costs ~20-50 ms; the renderer and the studio's curve
    of the same fit share one pack. Thread-safe (session threads and the background builder)."""
    key = f"{type(m).__name__}:{m.model_dump_json()}"
    with _PACKS_LOCK:
        p = _PACKS.get(key)
        if p is not None:
            _PACKS.move_to_end(key)
            return p
    p = m.pack()
    with _PACKS_LOCK:
        _PACKS[key] = p
        while len(_PACKS) > PACKS_KEPT:
            _PACKS.popitem(last=False)
    return p


_MODELS: dict[str, type[BRDFModel]] = {}


def register(cls: type[BRDFModel]) -> type[BRDFModel]:
    """Class decorator: make ``cls`` a material model (by its ``model`` literal)."""
    name = cls.model_fields["model"].default
    if not isinstance(name, str) or not name:
        raise TypeError(f"{cls.__name__}: declare model: Literal['name'] = 'name'")
    _MODELS[name] = cls
    return cls


def unregister(name: str) -> None:
    _MODELS.pop(name, None)


def models() -> dict[str, type[BRDFModel]]:
    """Registered models by name (registration order)."""
    return dict(_MODELS)


def model_class(name: str) -> type[BRDFModel]:
    if name not in _MODELS:
        raise KeyError(name)
    return _MODELS[name]


def _validate(v: Any) -> BRDFModel:
    if isinstance(v, BRDFModel):
        return v
    if not isinstance(v, dict):
        raise PydanticCustomError("material_type", "a material is a JSON object with a 'model' field")
    name = v.get("model")
    cls = _MODELS.get(name) if isinstance(name, str) else None
    if cls is None:
        raise PydanticCustomError("unknown_model", "unknown material model {model} (models: {known})",
                                  {"model": repr(name), "known": ", ".join(_MODELS)})
    return cls.model_validate(v)


class _MaterialType:
    """Validation dispatches on ``model`` through the registry at call time (so a model
    registered later, even from a test file, validates everywhere); the JSON schema is the
    discriminated union of the models registered when the schema is generated."""

    @classmethod
    def __get_pydantic_core_schema__(cls, source, handler):
        ser = core_schema.plain_serializer_function_ser_schema(
            lambda m, info: m.model_dump(mode=info.mode, by_alias=info.by_alias), info_arg=True)
        return core_schema.no_info_plain_validator_function(_validate, serialization=ser)

    @classmethod
    def __get_pydantic_json_schema__(cls, cs, handler):
        union = Annotated[Union[tuple(_MODELS.values())], Field(discriminator="model")]
        return handler(TypeAdapter(union).core_schema)


Material = Annotated[BRDFModel, _MaterialType]
material_adapter = TypeAdapter(Material)


def parse_material(data) -> BRDFModel:
    """A material from its JSON form (dict), validated by its model's schema."""
    return material_adapter.validate_python(data)


def describe() -> list[dict]:
    """What the studio needs to offer every model: name, label, controls, defaults (when it
    can be created from scratch) and its JSON schema."""
    out = []
    for name, cls in _MODELS.items():
        default = None
        if cls.creatable:
            try:
                default = cls(**cls.studio_default).model_dump(mode="json")
            except Exception:
                default = None
        out.append({"model": name, "label": cls.label or name, "controls": list(cls.controls),
                    "creatable": default is not None, "default": default,
                    "kernel": cls.kernel, "schema": cls.model_json_schema()})
    return out
