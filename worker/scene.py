"""Scene file version 1 (docs/design/conventions.md, scene file): pydantic models, and loading of meshes and maps.

Paths in a scene file are relative to the file. Errors name the bad field or file.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .envmap import load_envmap
from .errors import GlintError
from .models import (GGX, SRBF, BlinnPhong, BRDFModel, Color, Curve, Lambert, Lobes, Material,  # noqa: F401
                     Vec3, parse_material)


class SceneError(GlintError):
    """A scene that cannot be loaded; the message names the field or file."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Transform(_Strict):
    scale: float | Vec3 = 1.0
    rotate_deg: Vec3 = (0.0, 0.0, 0.0)
    translate: Vec3 = (0.0, 0.0, 0.0)

    def matrix(self) -> np.ndarray:
        """4×4 float64: scale, then rotate X, Y, Z (right-handed, degrees), then translate."""
        s = np.ones(3) * np.asarray(self.scale, dtype=np.float64)
        m = np.diag([*s, 1.0])
        for axis, deg in zip(range(3), self.rotate_deg):
            if deg:
                m = _rot(axis, np.radians(deg)) @ m
        m[:3, 3] += np.asarray(self.translate)
        return m


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    r = np.eye(4)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


class Environment(_Strict):
    map: str
    rotation_deg: float = 0.0
    intensity: float = Field(1.0, ge=0.0)


class Camera(_Strict):
    eye: Vec3
    target: Vec3
    up: Vec3 = (0.0, 1.0, 0.0)
    fov_y_deg: float = Field(40.0, gt=0.0, lt=180.0)
    width: int = Field(640, ge=1, le=8192)
    height: int = Field(480, ge=1, le=8192)

    @model_validator(mode="after")
    def _frame(self):
        # a camera without a direction, or looking along its up vector, has no image plane
        fwd = np.subtract(self.target, self.eye, dtype=np.float64)
        n = np.linalg.norm(fwd)
        if not np.isfinite(n) or n < 1e-12:
            raise ValueError("eye and target must differ")
        if np.linalg.norm(np.cross(fwd / n, np.asarray(self.up, np.float64))) < 1e-9:
            raise ValueError("up must not be parallel to the viewing direction")
        return self


class SceneObject(_Strict):
    name: str = Field(min_length=1)
    mesh: str
    transform: Transform = Field(default_factory=Transform)
    material: Material = Field(default_factory=Lambert)
    # GI renderer (polynomial-gi §5.3): false bakes this material into the precomputation
    editable: bool = True
    # cut renderer (cyber-worlds §V): true precomputes a visibility cut field for the object, so
    # it can be moved without precomputing again
    movable: bool = False


class Ground(_Strict):
    """An invisible shadow-catcher ground plane under the objects: it darkens the
    background where the objects occlude the environment from it, by the ratio of occluded to
    open-sky irradiance (worker/renderers/cuts/ground.py). ``shadow`` is the default a renderer
    option (and the studio and viewer toggle) can override; ``intensity`` k blends the darkening
    (1 − k(1 − ratio), as model-viewer's shadow-intensity); ``height`` is the plane's world y
    (default: the scene's lowest vertex)."""
    shadow: bool = True
    intensity: float = Field(1.0, ge=0.0, le=1.0)
    height: float | None = None

class _SceneHead(_Strict):
    """The fields of every scene file before the renderers' settings (see ``scene_model``)."""
    version: Literal[1] = 1
    renderer: str = Field("cuts", description="how the scene is drawn: cuts (direct light, default), "
                                              "or another registered renderer (worker/renderers)")
    environment: Environment
    camera: Camera
    objects: list[SceneObject] = Field(min_length=1)

    @field_validator("renderer")
    @classmethod
    def _known_renderer(cls, v):
        from .renderers import kinds

        if v not in kinds():
            raise ValueError(f"unknown renderer {v!r} (known: {', '.join(kinds())})")
        return v

    @field_validator("objects")
    @classmethod
    def _unique_names(cls, v):
        return _check_unique(v)


_models: dict[tuple, type[_SceneHead]] = {}


def scene_model() -> type[_SceneHead]:
    """The scene file's model: the common fields, then one optional field per registered renderer
    that declares settings (its DECLARATION's ``settings``, under the field named by its kind:
    ``cuts``, ``gi``, ``paint``), then ``ground`` and ``exposure``. Built from
    ``worker.renderers.declarations()`` once per list of renderer packages, so a renderer's
    settings are registered with the renderer, not written here."""
    from pydantic import create_model

    from .renderers import RENDERER_PACKAGES, declarations
    from .renderers.declaration import resolve

    key = tuple(RENDERER_PACKAGES)
    model = _models.get(key)
    if model is None:
        fields: dict[str, Any] = {}
        for kind, decl in declarations().items():
            if decl.settings is None:
                continue
            if kind in _SceneHead.model_fields or kind in ("ground", "exposure"):
                raise ValueError(f"renderer {kind!r}: its settings field would shadow the scene file's {kind!r}")
            t = resolve(decl.settings)
            fields[kind] = ((dict[str, Any] if t is dict else t) | None, None)
        model = create_model(
            "SceneFile", __base__=_SceneHead, __module__=__name__, **fields,
            ground=(Ground | None, Field(None, description="optional shadow-catcher ground plane (precomputed with the cuts)")),
            exposure=(float | Literal["auto"] | None, Field(
                None, description="the display exposure (stops) a new session starts with; \"auto\": the worker exposes "
                                  "so that the median object pixel is middle grey (uploaded scenes)")))
        # kept per list of packages (never cleared): the built-in list's model must stay the
        # module's SceneFile, which pickling (Ray, worker processes) finds by name
        _models[key] = model
    return model


# the model of the built-in renderers: the API's request body, and what type hints name
SceneFile = scene_model()


def _check_unique(objects: list) -> list:
    # one pass with a set: counting each name in the list was O(n²) (20 000 objects: seconds)
    seen, dup = set(), set()
    for o in objects:
        (dup if o.name in seen else seen).add(o.name)
    if dup:
        shown = sorted(dup)
        raise ValueError(f"object names must be unique, repeated: {shown[:20]}" + (f" and {len(shown) - 20} more" if len(shown) > 20 else ""))
    return objects


def _format_validation(e: ValidationError, source: str) -> str:
    lines = [f"{source}: invalid scene file"]
    for err in e.errors():
        loc = ".".join(str(p) for p in err["loc"])
        lines.append(f"  {loc}: {err['msg']}")
    return "\n".join(lines)


def parse_scene(data: dict | str, source: str = "scene") -> SceneFile:
    try:
        model = scene_model()
        if isinstance(data, str):
            return model.model_validate_json(data)
        return model.model_validate(data)
    except ValidationError as e:
        raise SceneError(_format_validation(e, source)) from None


OBJECT_CHUNK = 256         # objects validated per pydantic call (parse_scene_pieces)


def parse_scene_pieces(data: dict, source: str = "scene", max_objects: int | None = None) -> tuple[SceneFile, dict]:
    """A scene file dict validated as ``parse_scene`` does, in pieces: the objects in runs of
    OBJECT_CHUNK (one pydantic call each, so a thread running this lets others run between them),
    the rest with the first object. Returns (the SceneFile, its JSON form as model_dump(mode="json")).

    max_objects : refuse more objects than this (SceneError naming the limit and the count).
    Linear in the number of objects."""
    if not isinstance(data, dict):
        raise SceneError(f"{source}: invalid scene file\n  : a scene file is a JSON object, not {type(data).__name__}")
    objs = data.get("objects")
    if not isinstance(objs, list) or not objs:
        return (sc := parse_scene(data, source)), sc.model_dump(mode="json")
    if max_objects is not None and len(objs) > max_objects:
        raise SceneError(f"{source}: {len(objs)} objects is over the limit of {max_objects} objects per scene "
                         "(GLINT_MAX_SCENE_OBJECTS)")
    head = parse_scene({**data, "objects": objs[:1]}, source)
    ta = _objects_adapter()
    valid, dumped, errors = [], [], []
    for k in range(0, len(objs), OBJECT_CHUNK):
        try:
            part = ta.validate_python(objs[k:k + OBJECT_CHUNK])
        except ValidationError as e:
            for err in e.errors():
                loc = list(err["loc"])
                if loc and isinstance(loc[0], int):
                    loc[0] += k
                errors.append(f"  objects.{'.'.join(str(x) for x in loc)}: {err['msg']}")
            if len(errors) >= 20:
                break
            continue
        valid.extend(part)
        dumped.extend(ta.dump_python(part, mode="json"))
    if errors:
        raise SceneError("\n".join([f"{source}: invalid scene file", *errors[:20]]))
    try:
        _check_unique(valid)
    except ValueError as e:
        raise SceneError(f"{source}: invalid scene file\n  objects: {e}") from None
    model = type(head)
    spec = model.model_construct(**{k: getattr(head, k) for k in model.model_fields if k != "objects"},
                                     objects=valid)
    spec.__pydantic_fields_set__ = set(head.__pydantic_fields_set__)
    out = head.model_dump(mode="json")
    out["objects"] = dumped
    return spec, out


_ADAPTER = []


def _objects_adapter():
    if not _ADAPTER:
        from pydantic import TypeAdapter

        _ADAPTER.append(TypeAdapter(list[SceneObject]))
    return _ADAPTER[0]


class Mesh:
    """A triangle mesh in world space.

    vertices : (V, 3) float32, faces : (F, 3) int32, normals : (V, 3) float32 unit vertex normals;
    uvs : (V, 2) float32 texture coordinates from the file (origin at the image's bottom left, as
    OBJ and trimesh have them), NaN rows for vertices of parts without any, or None when the file
    has none. Rendering ignores them; the glTF export bakes painted region weights into textures
    through them (worker/export/texture.py).
    """

    def __init__(self, vertices, faces, normals, uvs=None):
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float32)
        self.faces = np.ascontiguousarray(faces, dtype=np.int32)
        self.normals = np.ascontiguousarray(normals, dtype=np.float32)
        self.uvs = None if uvs is None else np.ascontiguousarray(uvs, dtype=np.float32)
        self.repair: dict = {}      # what load_mesh repaired (worker.mesh_repair.repair's report)
        # (V,) int64: the vertex of the repaired file's mesh each vertex copies, when load_mesh
        # split vertices at creases (worker/creases.py), else None
        self.source: np.ndarray | None = None


def area_weighted_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) unit vertex normals: sum of adjacent (unnormalised, so area-weighted) face normals."""
    v = vertices.astype(np.float64)
    fn = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(norm > 0, n / np.maximum(norm, 1e-300), [0.0, 1.0, 0.0])
    return n


def normals_in_file(path: Path) -> bool:
    """Whether a mesh file stores vertex normals: PLY ``property … nx``, OBJ ``vn`` lines, glTF
    ``NORMAL`` attributes. Read from the file itself because trimesh computes normals on demand
    and exposes no public flag for "came from the file"."""
    import json
    import mmap
    import re
    import struct

    suf = path.suffix.lower()
    with open(path, "rb") as f:
        if suf == ".ply":
            head = f.read(65536)
            head = head[: head.find(b"end_header")] if b"end_header" in head else head
            return re.search(rb"^property\s+\S+\s+nx\s*$", head, re.M) is not None
        if suf == ".obj":
            if path.stat().st_size == 0:
                return False
            with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
                return re.search(rb"(?:^|\n)[ \t]*vn[ \t]", mm) is not None
        if suf in (".glb", ".gltf"):
            data = f.read()
            try:
                if suf == ".glb":
                    n = struct.unpack_from("<I", data, 12)[0]
                    doc = json.loads(data[20:20 + n])
                else:
                    doc = json.loads(data)
            except (struct.error, ValueError):
                return False
            return any("NORMAL" in (pr.get("attributes") or {})
                       for m in doc.get("meshes", []) for pr in m.get("primitives", []))
    return False


def _unit_or(n: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Normalise rows of n (V, 3); rows of zero or non-finite length take the fallback's."""
    n = np.array(n, dtype=np.float64)            # a writable copy: trimesh's arrays are read-only
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    ok = np.isfinite(ln) & (ln > 1e-12)
    return np.where(ok, n / np.where(ok, ln, 1.0), fallback)


def load_mesh(path: str | Path, transform: Transform | None = None) -> Mesh:
    """Load OBJ (all groups), PLY, GLB/GLTF or STL through trimesh, apply the transform.

    Vertex normals come from the file when present (OBJ `vn`, PLY nx/ny/nz, glTF NORMAL),
    otherwise they are area-weighted face normals of each vertex's smooth wedge, the vertex split
    along sharp edges (worker/creases.py; docs/design/conventions.md). A glTF scene's node
    transforms apply to positions and (inverse-transposed) to its normals. The mesh is repaired
    (worker.mesh_repair.repair; its report is ``Mesh.repair``): a mesh without normals in the file
    also has its winding made coherent and its pieces turned outward before its vertices are
    split at creases; SceneError when nothing survives.
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: mesh file not found")
    try:
        loaded = trimesh.load(str(path), process=False, skip_materials=True)
        has_n = normals_in_file(path)
    except Exception as e:
        raise SceneError(f"{path}: not a readable mesh ({type(e).__name__}: {e})") from None
    if isinstance(loaded, trimesh.Scene):
        # walk the graph rather than Scene.dump(): dump copies geometry without the file's normals
        placed = [(loaded.geometry[name], np.asarray(T, np.float64))
                  for T, name in (loaded.graph[node] for node in loaded.graph.nodes_geometry)]
    else:
        placed = [(loaded, np.eye(4))]
    placed = [(g, T) for g, T in placed if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    if not placed:
        raise SceneError(f"{path}: contains no triangles")
    verts, faces, normals, uvs, base = [], [], [], [], 0
    from_faces = True                      # every normal computed here, none read from the file
    for g, T in placed:
        v = np.asarray(g.vertices, dtype=np.float64)
        f = np.asarray(g.faces, dtype=np.int64)
        # texture coordinates where the part has them (trimesh splits vertices at UV seams, so
        # each vertex has one); NaN for a part without, so parts stay aligned
        uv = getattr(g.visual, "uv", None)
        uvs.append(np.asarray(uv, np.float64)[:, :2] if uv is not None and len(uv) == len(v)
                   else np.full((len(v), 2), np.nan))
        if len(f) and (f.min() < 0 or f.max() >= len(v)):
            raise SceneError(f"{path}: face indices out of range")
        aw = area_weighted_normals(v, f)
        own = has_n and len(g.vertex_normals) == len(v)
        from_faces &= not own
        n = _unit_or(g.vertex_normals, aw) if own else aw
        if not np.allclose(T, np.eye(4)):
            v = v @ T[:3, :3].T + T[:3, 3]
            n = _unit_or(n @ np.linalg.inv(T[:3, :3]), area_weighted_normals(v, f))
        verts.append(v); faces.append(f + base); normals.append(n); base += len(v)
    v = np.concatenate(verts); f = np.concatenate(faces); n = np.concatenate(normals)
    uv = np.concatenate(uvs)
    from .mesh_repair import MeshRejected, repair_carrying

    try:
        v, f, carried, report = repair_carrying(v, f, normals=n, normals_from_faces=from_faces, uvs=uv)
    except MeshRejected as e:
        raise SceneError(f"{path}: {e}") from None
    n, uv = carried["normals"], carried["uvs"]
    if from_faces:
        # no normals in the file: one per smooth wedge around each vertex, not one averaged
        # across a sharp edge (worker/creases.py), on the repaired (coherently wound) faces
        from .creases import split_creases

        v, f, n, source, crease = split_creases(v, f)
        uv = uv[source]                     # a copy keeps its vertex's texture coordinates
        report = {**report, "creases": crease, "vertices_out": int(len(v))}
    else:
        source = None
    if transform is not None:
        m = transform.matrix()
        v = v @ m[:3, :3].T + m[:3, 3]
        n = _unit_or(n @ np.linalg.inv(m[:3, :3]), area_weighted_normals(v, f))  # inverse transpose
    mesh = Mesh(v, f, n, uvs=None if np.isnan(uv).all() else uv)
    mesh.repair = report
    if source is not None and crease["vertices_split"]:
        mesh.source = source
    return mesh


class LoadedScene:
    """A scene with meshes loaded in world space and concatenated.

    Attributes: spec (SceneFile), mesh (Mesh, all objects), object_of_vertex (V,) int32,
    object_of_face (F,) int32, envmap (H, W, 3) float32, root (Path of the scene folder).
    """

    def __init__(self, spec: SceneFile, root: Path, envmap: np.ndarray | None = None, resolver=None):
        self.spec = spec
        self.root = root
        self._resolver = resolver          # ref -> Path, for scenes whose files are stored blobs
        meshes = []
        for i, o in enumerate(spec.objects):
            try:
                meshes.append(load_mesh(self.resolve(o.mesh), o.transform))
            except SceneError as e:
                raise SceneError(f"objects[{i}] ({o.name!r}).mesh: {e}") from None
        vs, fs, ns, ov, of, base = [], [], [], [], [], 0
        for i, m in enumerate(meshes):
            vs.append(m.vertices); fs.append(m.faces + base); ns.append(m.normals)
            ov.append(np.full(len(m.vertices), i, np.int32)); of.append(np.full(len(m.faces), i, np.int32))
            base += len(m.vertices)
        uvs = None
        if any(m.uvs is not None for m in meshes):
            uvs = np.concatenate([m.uvs if m.uvs is not None else np.full((len(m.vertices), 2), np.nan, np.float32)
                                  for m in meshes])
        self.mesh = Mesh(np.concatenate(vs), np.concatenate(fs), np.concatenate(ns), uvs=uvs)
        self.object_of_vertex = np.concatenate(ov)
        self.object_of_face = np.concatenate(of)
        self._sources = [m.source for m in meshes]
        if envmap is None:
            try:
                envmap = load_envmap(self.resolve(spec.environment.map))
            except ValueError as e:
                raise SceneError(f"environment.map: {e}") from None
        self.envmap = envmap

    def resolve(self, rel: str) -> Path:
        if self._resolver is not None:
            return self._resolver(rel)
        p = Path(rel)
        return p if p.is_absolute() else (self.root / p)

    @property
    def materials(self):
        return [o.material for o in self.spec.objects]

    def vertex_source(self, index: int) -> np.ndarray | None:
        """(n_o,) int64: for each vertex of object ``index``, the object-local vertex of its mesh
        file it copies when loading split vertices at creases (a regions material painted on the
        mesh as loaded before that is remapped through it, models.regions.fit_mesh), else None."""
        src = getattr(self, "_sources", None)
        return None if src is None else src[index]


def load_scene(path: str | Path) -> LoadedScene:
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: scene file not found")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise SceneError(f"{path}: not valid JSON (line {e.lineno}, column {e.colno}: {e.msg})") from None
    return LoadedScene(parse_scene(data, str(path)), path.parent.resolve())
