"""``regions``: a spatially varying material, a base material with painted regions over it.

A region is a per-vertex weight map w(v) ∈ [0, 1] over the object's mesh (sparse: the vertices
it covers and their weights; soft-edged by the brush falloff, worker/fit/regions.py) with a
material of its own. Regions are layers, each painted over what is below it, in order:

    L_0(v) = L_base(v),   L_k(v) = (1 − w_k(v)) L_{k−1}(v) + w_k(v) L_{region k}(v)

so a vertex's radiance is Σ_l a_l(v) L_l(v) with the effective weights (``layer_weights``)

    a_base = Π_k (1 − w_k),   a_k = w_k Π_{j>k} (1 − w_j),   Σ_l a_l = 1.

Each L_l is linear in its material's BRDF coefficients (inverse-brdf-modeling eq. 21), so a fit
of a region's material stays the paper's linear least squares with the region's weights
multiplying its transfer rows.

This is the interface other parts use: ``layer_weights(material, n_vertices)`` gives the layer
materials and their per-vertex weights (any material: a plain one is one layer of weight 1).
Renderers that blend layers per vertex or per pixel draw the regions (the cut renderer's modes,
the paint renderer, the GI renderer at its camera hits: renderers/layers.py); everything that only asks a material for one BRDF (``pack``, ``evaluate``) gets
the base's, so a renderer that does not know regions draws the base alone.

Vertex ids are the object's own (0 … vertex_count − 1, in the order its mesh file loads, see
scene.load_mesh); ``vertex_count`` is checked against the object where the material is applied
(worker/overrides.py, the cut renderer), so weights never land on another mesh's vertices.
"""
from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, TypeAdapter, field_validator, model_validator

from .base import BRDFModel, Color, Geometry, PackedBRDF, _MaterialType, models, register

MAX_REGIONS = 32                 # regions per material (a designer's layers, not a texture)
MAX_REGION_VERTICES = 2_000_000  # vertices per region (the largest scene meshes are ~1M)
MAX_VERTEX_COUNT = 50_000_000


class _LayerMaterialType(_MaterialType):
    """A layer's material: validated as any material (then refused if it has regions itself);
    its JSON schema is the union of the other models, so the schema of ``regions`` is not
    recursive."""

    @classmethod
    def __get_pydantic_json_schema__(cls, cs, handler):
        union = Annotated[Union[tuple(m for n, m in models().items() if n != "regions")], Field(discriminator="model")]
        return handler(TypeAdapter(union).core_schema)


LayerMaterial = Annotated[BRDFModel, _LayerMaterialType]


class RegionsError(ValueError):
    """Regions that do not fit the object they are applied to (message says why)."""


class Region(BaseModel):
    """One painted region: name, material, and its sparse weight map (vertices (K,) sorted,
    unique object-local vertex ids; weights (K,) in [0, 1])."""
    model_config = ConfigDict(extra="forbid")

    name: str = Field(min_length=1, max_length=100)
    material: LayerMaterial
    vertices: list[Annotated[int, Field(ge=0, lt=MAX_VERTEX_COUNT)]] = Field(max_length=MAX_REGION_VERTICES)
    weights: list[Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]] = Field(max_length=MAX_REGION_VERTICES)

    @field_validator("material")
    @classmethod
    def _not_nested(cls, v):
        if isinstance(v, Regions):
            raise ValueError("a region's material cannot itself have regions")
        return v

    @model_validator(mode="after")
    def _sizes(self):
        if len(self.vertices) != len(self.weights):
            raise ValueError(f"region {self.name!r}: {len(self.weights)} weights for {len(self.vertices)} vertices")
        v = np.asarray(self.vertices, np.int64)
        if len(v) > 1 and np.any(np.diff(v) <= 0):
            raise ValueError(f"region {self.name!r}: vertex ids must be sorted and unique")
        return self

    def dense(self, n_vertices: int) -> np.ndarray:
        """w (n_vertices,) float32 over the object's vertices."""
        w = np.zeros(n_vertices, np.float32)
        if self.vertices:
            w[np.asarray(self.vertices, np.int64)] = np.asarray(self.weights, np.float32)
        return w


class _Cache:
    """A value computed from a model's fields, kept beside them: equal to any other _Cache, so
    it never makes two equal materials compare unequal; ``key`` holds the fields it came from
    (a ``model_copy(update=...)`` that replaces them is recomputed, not misread)."""

    def __init__(self):
        self.key = self.value = None

    def __eq__(self, other):
        return isinstance(other, _Cache)

    __hash__ = None


def _albedo_of(base: Any):
    if isinstance(base, BRDFModel):
        return tuple(base.albedo)
    if isinstance(base, dict) and isinstance(base.get("albedo"), (list, tuple)):
        return tuple(base["albedo"])
    return None


@register
class Regions(BRDFModel):
    """A base material with painted regions (see the module doc). ``albedo`` is the base's (the
    object's mean diffuse colour for whatever asks a material for one)."""
    kernel: ClassVar[str | None] = None
    label: ClassVar[str] = "Painted regions"
    creatable: ClassVar[bool] = False
    controls: ClassVar[tuple[dict, ...]] = ()
    model: Literal["regions"] = "regions"
    albedo: Color = (0.0, 0.0, 0.0)
    base: LayerMaterial
    vertex_count: int = Field(ge=1, le=MAX_VERTEX_COUNT, description="vertices of the object the weights index")
    regions: list[Region] = Field(min_length=1, max_length=MAX_REGIONS)
    _dense: _Cache = PrivateAttr(default_factory=_Cache)
    _resplit: _Cache = PrivateAttr(default_factory=_Cache)     # fit_mesh's remapped copy

    @model_validator(mode="before")
    @classmethod
    def _albedo_from_base(cls, data):
        if isinstance(data, dict) and "albedo" not in data:
            a = _albedo_of(data.get("base"))
            if a is not None:
                data = {**data, "albedo": a}
        return data

    @field_validator("base")
    @classmethod
    def _flat_base(cls, v):
        if isinstance(v, Regions):
            raise ValueError("the base of a regions material cannot itself have regions")
        return v

    @model_validator(mode="after")
    def _check(self):
        if tuple(self.albedo) != tuple(self.base.albedo):
            raise ValueError("a regions material's albedo is its base's: leave it out or give the base's")
        names = [r.name for r in self.regions]
        if len(set(names)) != len(names):
            raise ValueError(f"region names must be unique, got {names}")
        for r in self.regions:
            if r.vertices and r.vertices[-1] >= self.vertex_count:
                raise ValueError(f"region {r.name!r}: vertex {r.vertices[-1]} is beyond vertex_count "
                                 f"{self.vertex_count}")
        return self

    # -- as one BRDF: the base's --------------------------------------------------------------
    def specular_part(self, g: Geometry) -> np.ndarray:
        return self.base.pack().specular(g)

    def lobe_width(self) -> float:
        return self.base.lobe_width()

    def pack(self) -> PackedBRDF:
        return self.base.pack()

    # -- layers -------------------------------------------------------------------------------
    def layers(self) -> tuple[list[BRDFModel], np.ndarray]:
        """(materials (L,), a (L, vertex_count) float32): the base, then each region, with the
        effective per-vertex weights of the module doc (Σ_l a_l = 1). Cached on the instance."""
        key = (self.base, self.regions, self.vertex_count)
        c = self._dense
        if c.key is None or c.key[0] is not key[0] or c.key[1] is not key[1] or c.key[2] != key[2]:
            n = self.vertex_count
            a = np.empty((len(self.regions) + 1, n), np.float32)
            above = np.ones(n, np.float32)          # Π_{j>k} (1 − w_j), built from the top layer down
            for k in range(len(self.regions), 0, -1):
                w = self.regions[k - 1].dense(n)
                a[k] = w * above
                above *= 1.0 - w
            a[0] = above
            c.key, c.value = key, ([self.base] + [r.material for r in self.regions], a)
        return c.value

    def with_region(self, region: Region) -> "Regions":
        """A copy with ``region`` added on top (or replacing the region of the same name)."""
        rest = [r for r in self.regions if r.name != region.name]
        return Regions(base=self.base, vertex_count=self.vertex_count, regions=[*rest, region])

    @classmethod
    def examples(cls):
        from .ggx import GGX
        from .lambert import Lambert

        return [cls(base=Lambert(albedo=(0.4, 0.3, 0.2)), vertex_count=4,
                    regions=[Region(name="seat", material=GGX(alpha=0.2, albedo=(0.1, 0.1, 0.1)),
                                    vertices=[1, 2], weights=[1.0, 0.5])])]


def fit_mesh(material, n_vertices: int, source: np.ndarray | None = None):
    """``material`` with region weights over an object of ``n_vertices`` vertices: itself, or,
    for a regions material painted on the object's mesh before loading split its vertices at
    creases (source (n_vertices,) int64: the vertex each one copies, scene.LoadedScene.
    vertex_source), the same regions with every copy taking its vertex's weight. Remapped copies
    are kept on the material (the state hands the same object to every frame). RegionsError when
    the regions were painted on a mesh of another size."""
    if not isinstance(material, Regions) or material.vertex_count == n_vertices:
        return material
    if source is not None and len(source) == n_vertices and len(source) \
            and material.vertex_count == int(source.max()) + 1:
        c = material._resplit
        if c.key is None or c.key[0] is not source or c.key[1] is not material.regions:
            regions = []
            for r in material.regions:
                w = r.dense(material.vertex_count)[source]
                ids = np.nonzero(w > 0)[0]
                regions.append(Region(name=r.name, material=r.material, vertices=ids.tolist(),
                                      weights=w[ids].astype(np.float64).tolist()))
            c.key, c.value = (source, material.regions), Regions(base=material.base, vertex_count=n_vertices,
                                                                  regions=regions)
        return c.value
    raise RegionsError(f"the material's regions were painted on a mesh of {material.vertex_count} "
                       f"vertices, but the object has {n_vertices}")


def layer_weights(material, n_vertices: int, source: np.ndarray | None = None) -> tuple[list[BRDFModel], np.ndarray]:
    """The layers of any material over an object of ``n_vertices`` vertices: (materials (L,),
    effective weights (L, n_vertices) float32 summing to 1 per vertex). A material without
    regions is one layer of weight 1. source : the object's vertex_source (``fit_mesh``).
    RegionsError when a regions material was painted on a mesh of another size."""
    if isinstance(material, Regions):
        return fit_mesh(material, n_vertices, source).layers()
    return [material], np.ones((1, n_vertices), np.float32)


def has_regions(material) -> bool:
    return isinstance(material, Regions)


def region_names(material) -> list[str]:
    """The painted regions of a material, bottom first (a region fitted in parts once)."""
    if not has_regions(material):
        return []
    return list(dict.fromkeys(r.name.split("/")[0] for r in material.regions))


def in_group(region_name: str, name: str) -> bool:
    """Whether a region belongs to the painted region ``name``: itself or one of its parts
    (``name/1``, ``name/2``, … of a region fitted in parts)."""
    return region_name == name or region_name.startswith(name + "/")


def rename_region(material: Regions, name: str, new_name: str) -> Regions:
    """The material with region ``name`` (and its parts) called ``new_name``."""
    regions = [r.model_copy(update={"name": new_name + r.name[len(name):]}) if in_group(r.name, name) else r
               for r in material.regions]
    return Regions(base=material.base, vertex_count=material.vertex_count, regions=regions)


def without_region(material: Regions, name: str):
    """The material without region ``name`` (and its parts): its base when none is left."""
    rest = [r for r in material.regions if not in_group(r.name, name)]
    if not rest:
        return material.base
    return Regions(base=material.base, vertex_count=material.vertex_count, regions=rest)


def merge_regions(material: Regions, name: str, into: str) -> Regions:
    """The material with region ``name`` merged into region ``into``: one region named ``into``,
    at the place of ``into``'s first part, with its first part's material and the union of the two
    footprints (w = 1 − Π(1 − w_i) over every part of both: painted by either, as much as the
    layers blended them)."""
    n = material.vertex_count
    grp = [r for r in material.regions if in_group(r.name, name) or in_group(r.name, into)]
    keep = np.ones(n)
    for r in grp:
        keep *= 1.0 - r.dense(n)
    w = 1.0 - keep
    ids = np.nonzero(w > 0)[0]
    first = next(r for r in material.regions if in_group(r.name, into))
    merged = Region(name=into, material=first.material, vertices=ids.tolist(),
                    weights=np.round(w[ids], 6).tolist())
    out = []
    for r in material.regions:
        if r is first:
            out.append(merged)
        elif not (in_group(r.name, name) or in_group(r.name, into)):
            out.append(r)
    return Regions(base=material.base, vertex_count=n, regions=out)


def with_region_material(material: Regions, name: str, layer) -> Regions:
    """The material with region ``name`` (every part of it) given the material ``layer``."""
    regions = [r.model_copy(update={"material": layer}) if in_group(r.name, name) else r for r in material.regions]
    return Regions(base=material.base, vertex_count=material.vertex_count, regions=regions)
