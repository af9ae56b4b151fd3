"""Settings of a GI precomputation and the editable "units" of a scene (polynomial-gi §3-5).

A scene file may carry an optional ``gi`` object (scene.SceneFile.gi, validated here):

.. code-block:: json

    "gi": {"series": [64, 1, 1, 1], "spp": 256, "fresnel": false, "seed": 0,
           "regions": [{"name": "rug", "object": "floor", "weights": "rug.png", "axis": "y",
                        "material": {"model": "lambert", "albedo": [0.6, 0.1, 0.1]}}],
           "anisotropic": [{"object": "vase", "exponent": 225, "tangent": [0, 1, 0],
                            "material": {"model": "ashikhmin-shirley", "exponent_u": 225,
                                         "exponent_v": 225, "specular": [0.9, 0.9, 0.9]}}]}

* ``series`` (J_N, J_{N-1}, …) from the eye, one entry per bounce (polynomial-gi eq. 17-20):
  J half-angle bands at the bounce nearest the eye; the second entry is 1 (diffuse equivalent)
  or J2 > 1 bands (the slower-decaying series of §4.3, J2 must divide J); further entries are 1.
  The number of bounces N is the series' length (``bounces`` pads with 1 or truncates).
* ``fresnel``: also precompute the Fresnel layer of Appendix A (eq. 31-32) for every editable
  object: a second band set with quotient (1 − cos θd)^5; doubles the first-bounce storage.
* ``quotient``: the quotient ρ_q of the half-angle bands (Appendix A, fixed at precomputation
  like the paper's per-material-family ρ_q): "distribution" 1/(cos θi + cos θo − cos θi cos θo)
  (Glint's curve and srbf form) or "microfacet" 1/(4 cos θi cos θo) (GGX); one for all objects,
  or per object name. By default each object takes the one suiting its scene material
  (microfacet for ggx, distribution otherwise); any model can still be edited on either.
* ``regions``: spatial weight maps H(x) (eq. 5-6, §5.3): a greyscale image projected along
  ``axis`` over the object's bounding box; the region's material applies with weight H(x), the
  object's own with 1 − ΣH. Each region is an editable unit named like an object.
* ``painted``: objects' painted regions traced into the tensors (``{"object": "sofa", "material":
  <a "regions" material>}``, models/regions.py): each region is a unit named by the region, its
  weight at a path vertex its layer weight interpolated over the face hit (eq. 5-6 with per-vertex
  maps), so the light it reflects on to other surfaces is its own material's. Without this the
  renderer draws painted regions at the camera's hits only (renderer.py ``_n_units``).
* ``denoise``: denoise every basis image of the tensors once, at precomputation, with Intel
  Open Image Denoise (denoise.py): frames stay linear in the first-vertex coefficients; the
  indirect bounces carry the first vertex on hat functions over the bands.
* ``anisotropic``: objects whose first-bounce bands are over the Ashikhmin-Shirley anisotropy
  factor γ = cos θh^(n_u sin² φh) of Appendix A (eq. 33-35) instead of θh, with a fixed n_u
  and a brushing direction ``tangent`` (world axis, projected onto the tangent plane).

Objects with ``"editable": false`` (scene.SceneObject, §5.3) are baked with their material.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, Mapping

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, model_validator

from ...errors import GlintError
from ...keys import content_key
from ...scene import Material
from . import denoise
from .anisotropy import AshikhminShirley

DEFAULT_SERIES = (64, 1, 1, 1)
MAX_BOUNCES = 4


class GIOptionsError(GlintError):
    """Bad GI settings; the message names the field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class GIRegion(_Strict):
    name: str = Field(min_length=1)
    object: str
    weights: str = Field(description="greyscale image (PNG/EXR/NPY), values in [0, 1]")
    axis: Literal["x", "y", "z"] = "y"
    material: Material


class GIPainted(_Strict):
    object: str
    material: Material = Field(description="a material with painted regions (model \"regions\")")


class GIAnisotropy(_Strict):
    object: str
    exponent: float = Field(225.0, gt=0.0, le=1e5, description="n_u, fixed at precomputation")
    tangent: tuple[float, float, float] = (1.0, 0.0, 0.0)
    material: AshikhminShirley | None = None

    @model_validator(mode="after")
    def _check(self):
        if np.linalg.norm(self.tangent) < 1e-9:
            raise ValueError("tangent must not be zero")
        if self.material is not None and abs(self.material.exponent_u - self.exponent) > 1e-9:
            raise ValueError(f"material.exponent_u must equal exponent ({self.exponent})")
        return self


class GIOptions(_Strict):
    series: tuple[int, ...] = DEFAULT_SERIES
    bounces: int | None = Field(None, ge=1, le=MAX_BOUNCES)
    spp: int = Field(64, ge=1, le=1 << 20)
    fresnel: bool = False
    quotient: Literal["distribution", "microfacet"] | dict[str, Literal["distribution", "microfacet"]] | None = None
    seed: int = Field(0, ge=0)
    denoise: bool = Field(False, description="denoise every basis image of the tensors once (denoise.py)")
    regions: list[GIRegion] = []
    painted: list[GIPainted] = []
    anisotropic: list[GIAnisotropy] = []

    @model_validator(mode="after")
    def _series(self):
        s = list(self.series)
        if not s:
            raise ValueError("series must not be empty")
        if self.bounces is not None:
            s = (s + [1] * MAX_BOUNCES)[: self.bounces]
        if len(s) > MAX_BOUNCES:
            raise ValueError(f"at most {MAX_BOUNCES} bounces (series {self.series})")
        if not (2 <= s[0] <= 256):
            raise ValueError(f"series[0] (J, bands at the bounce nearest the eye) must be in 2..256, got {s[0]}")
        if len(s) > 1 and s[1] != 1 and (s[1] < 2 or s[1] > 32 or s[0] % s[1] != 0):
            raise ValueError(f"series[1] must be 1 (diffuse equivalent) or a divisor of J={s[0]} in 2..32, got {s[1]}")
        if any(x != 1 for x in s[2:]):
            raise ValueError(f"series entries after the second must be 1 (diffuse equivalents), got {s}")
        object.__setattr__(self, "series", tuple(s))
        object.__setattr__(self, "bounces", len(s))
        return self

    @property
    def J(self) -> int:
        return self.series[0]

    @property
    def J2(self) -> int:
        """Bands at the second bounce from the eye; 1 means the diffuse equivalent."""
        return self.series[1] if len(self.series) > 1 else 1


def parse_options(scene, overrides: Mapping[str, Any] | None = None) -> GIOptions:
    """The scene file's ``gi`` object, updated with ``overrides`` (CLI/REST), validated."""
    raw = dict(getattr(scene.spec, "gi", None) or {})
    ov = {k: v for k, v in (overrides or {}).items() if v is not None}
    if "series" in ov and "bounces" not in ov:
        raw.pop("bounces", None)  # an explicit series sets the bounces
    raw.update(ov)
    try:
        return GIOptions.model_validate(raw)
    except ValidationError as e:
        msgs = [f"gi.{'.'.join(str(p) for p in err['loc'])}: {err['msg']}" for err in e.errors()]
        raise GIOptionsError("invalid GI settings\n  " + "\n  ".join(msgs)) from None


def parse_series(text: str) -> tuple[int, ...]:
    try:
        s = tuple(int(x) for x in text.replace(" ", "").split(",") if x)
    except ValueError:
        raise GIOptionsError(f"--series {text!r}: expected comma-separated integers such as 64,1,1,1") from None
    if not s:
        raise GIOptionsError("--series must not be empty")
    return s


# --- units: the editable BRDF slots ------------------------------------------------------------


@dataclass
class Unit:
    """An editable BRDF: an object's own material, or a region's. ``object`` is the object
    index; ``region`` the index into options.regions (None for the object's own material);
    ``anisotropic`` the GIAnisotropy of the object (None for half-angle bands); ``painted``
    (index into options.painted, the region's index in its material) for a traced painted
    region."""
    name: str
    object: int
    region: int | None
    material: Any
    anisotropic: GIAnisotropy | None = None
    painted: tuple[int, int] | None = None


@dataclass
class UnitLayout:
    """Units in order (objects' own materials in scene order, then regions), and per object the
    units that cover it. ``fixed`` is a boolean per object (``"editable": false``)."""
    units: list[Unit]
    of_object: list[list[int]]
    fixed: np.ndarray
    aniso_of_object: list[GIAnisotropy | None] = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        return [u.name for u in self.units]

    def quotients(self, scene, opts: "GIOptions") -> list[str]:
        """The quotient of each object's half-angle bands (see GIOptions.quotient)."""
        objs = scene.spec.objects
        names = [o.name for o in objs]
        q = opts.quotient
        if isinstance(q, dict):
            for n in q:
                if n not in names:
                    raise GIOptionsError(f"gi.quotient: no object named {n!r}")
        out = []
        for o in objs:
            if isinstance(q, str):
                out.append(q)
            elif isinstance(q, dict) and o.name in q:
                out.append(q[o.name])
            else:
                # srbf with the smith static is a microfacet form too (F·G1·G1/(4 cosθi cosθo))
                micro = getattr(o.material, "model", None) == "ggx" or getattr(o.material, "static", None) == "smith"
                out.append("microfacet" if micro else "distribution")
        return out

    def index(self, name: str) -> int:
        for i, u in enumerate(self.units):
            if u.name == name:
                return i
        raise GIOptionsError(f"no editable object or region named {name!r} (editable: {', '.join(self.names) or 'none'})")


def unit_layout(scene, opts: GIOptions) -> UnitLayout:
    objs = scene.spec.objects
    names = [o.name for o in objs]
    fixed = np.array([not getattr(o, "editable", True) for o in objs], bool)
    aniso: list[GIAnisotropy | None] = [None] * len(objs)
    for k, a in enumerate(opts.anisotropic):
        if a.object not in names:
            raise GIOptionsError(f"gi.anisotropic[{k}].object: no object named {a.object!r}")
        i = names.index(a.object)
        if fixed[i]:
            raise GIOptionsError(f"gi.anisotropic[{k}]: object {a.object!r} is not editable")
        aniso[i] = a
    units: list[Unit] = []
    of_object: list[list[int]] = [[] for _ in objs]
    for i, o in enumerate(objs):
        if fixed[i]:
            continue
        mat = o.material
        if aniso[i] is not None:
            mat = aniso[i].material or AshikhminShirley(exponent_u=aniso[i].exponent, exponent_v=aniso[i].exponent)
        of_object[i].append(len(units))
        units.append(Unit(o.name, i, None, mat, aniso[i]))
    for k, r in enumerate(opts.regions):
        if r.object not in names:
            raise GIOptionsError(f"gi.regions[{k}].object: no object named {r.object!r}")
        i = names.index(r.object)
        if fixed[i]:
            raise GIOptionsError(f"gi.regions[{k}]: object {r.object!r} is not editable (regions need an editable object)")
        if aniso[i] is not None:
            raise GIOptionsError(f"gi.regions[{k}]: object {r.object!r} is anisotropic; regions on it are not supported")
        if r.name in names or r.name in [u.name for u in units]:
            raise GIOptionsError(f"gi.regions[{k}].name: {r.name!r} is already an object or region name")
        of_object[i].append(len(units))
        units.append(Unit(r.name, i, k, r.material))
    from ...models.regions import RegionsError, fit_mesh, has_regions
    seen = set()
    for k, p in enumerate(opts.painted):
        if p.object not in names:
            raise GIOptionsError(f"gi.painted[{k}].object: no object named {p.object!r}")
        i = names.index(p.object)
        if i in seen:
            raise GIOptionsError(f"gi.painted[{k}]: object {p.object!r} is listed twice")
        seen.add(i)
        if fixed[i] or aniso[i] is not None:
            raise GIOptionsError(f"gi.painted[{k}]: object {p.object!r} is "
                                 f"{'not editable' if fixed[i] else 'anisotropic'}; painted regions need an isotropic editable object")
        if not has_regions(p.material):
            raise GIOptionsError(f"gi.painted[{k}].material: not a material with painted regions (model \"regions\")")
        try:
            fit_mesh(p.material, int((scene.object_of_vertex == i).sum()), scene.vertex_source(i))
        except RegionsError as e:
            raise GIOptionsError(f"gi.painted[{k}]: {e}") from None
        for j, r in enumerate(p.material.regions):
            if r.name in names or r.name in [u.name for u in units]:
                raise GIOptionsError(f"gi.painted[{k}]: region {r.name!r} is already an object or region name")
            of_object[i].append(len(units))
            units.append(Unit(r.name, i, None, r.material, painted=(k, j)))
    return UnitLayout(units, of_object, fixed, aniso)


# --- content keys ------------------------------------------------------------------------------


FORMAT_VERSION = 5      # 5: shading normals turned to the geometric side, outline points shaded at grazing


def tensor_key(scene, opts: GIOptions, region_images: list[np.ndarray]) -> str:
    """Content key of a scene's tensors: geometry, camera, lighting, the materials of fixed
    objects, editability, regions' weight maps, anisotropy settings, series, bounces, spp,
    fresnel, seed and the format version. Editable materials are not in it: they are what the
    tensors leave free."""
    spec = scene.spec
    m = scene.mesh
    fixed_mats = [o.material.model_dump(mode="json") if not getattr(o, "editable", True) else None
                  for o in spec.objects]
    return content_key(
        "gi", FORMAT_VERSION, vertices=m.vertices, faces=m.faces, normals=m.normals,
        object_of_face=scene.object_of_face, camera=spec.camera.model_dump(mode="json"), envmap=scene.envmap,
        lighting={"rotation_deg": spec.environment.rotation_deg, "intensity": spec.environment.intensity},
        fixed_materials=fixed_mats,
        regions=[dict(r.model_dump(mode="json", exclude={"material", "weights"})) for r in opts.regions],
        painted=[{"object": p.object, "vertex_count": p.material.vertex_count,
                  "regions": [{"name": r.name, "vertices": r.vertices, "weights": r.weights}
                              for r in p.material.regions]} for p in opts.painted],
        **{f"region_image_{i}": np.asarray(img) for i, img in enumerate(region_images)},
        anisotropic=[a.model_dump(mode="json", exclude={"material"}) for a in opts.anisotropic],
        series=list(opts.series), spp=opts.spp, fresnel=opts.fresnel,
        quotients=unit_layout(scene, opts).quotients(scene, opts), seed=opts.seed,
        **({"denoise": [denoise.HATS, denoise.ENERGY_SHARE, denoise.QUALITY, "tails-together", denoise.SHARE_WIDTH,
                       "weighted", denoise.PROBE_ALPHAS]}
           if opts.denoise else {}))


_MATERIAL = TypeAdapter(Material)


def parse_material(data: Any, source: str = "material"):
    """A scene material (any model) or a GI-only ``ashikhmin-shirley`` from JSON data."""
    try:
        if isinstance(data, dict) and data.get("model") == "ashikhmin-shirley":
            return AshikhminShirley.model_validate(data)
        return _MATERIAL.validate_python(data)
    except ValidationError as e:
        raise GIOptionsError(f"{source}: not a valid material ({str(e).splitlines()[0]}: "
                             f"{e.errors()[0]['msg']})") from None
