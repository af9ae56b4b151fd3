"""The seam between a scene and the ways of drawing it: ``Renderer`` and ``Precomputation``.

Glint has several renderers, each with a precomputation of its own (docs/architecture/index.md):

==========  ==========================================  ====================================
kind        what it draws                                what it precomputes
==========  ==========================================  ====================================
``cuts``    direct light with visibility cuts            per-vertex cuts (+ cut fields of
            (cyber-worlds §V, inverse-brdf-modeling)     movable objects)
``gi``      interreflections, fixed view and light       multibounce tensors per pixel
            (polynomial-gi)
``paint``   cosine lobes by prefiltered maps (cacad)     prefiltered environment maps per lobe
==========  ==========================================  ====================================

A renderer is built from a loaded scene and its precomputed data, and turns a ``FrameRequest``
(camera, lighting, materials, level of detail) into ``Rendered`` radiance with per-object masks
and timings. Sessions, jobs and the CLI never build a renderer class by name: they ask
``worker.renderers.get(kind)`` for the pair registered under the scene's ``renderer`` field.

A precomputation is a list of ``Part``\\ s, each addressed by a content key of exactly what it
depends on (so a part is computed once and shared: moving an object never invalidates the cut
field keyed by its mesh alone). ``ensure`` computes the missing parts into an ``ArtifactStore``
(a folder for the CLI, the blob store for the service), optionally split into chunks that run
in parallel (vertex ranges for cuts, so a Ray cluster can share the work, byte-identical after
assembly). ``load`` turns the stored parts into the renderer's data.
"""
from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Mapping, Protocol, Sequence

import numpy as np

from ..errors import GlintError


class Unsupported(GlintError):
    """A request this renderer cannot serve (e.g. moving the camera of a fixed-view GI scene)."""

    status = 409


# --- what to draw ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Lighting:
    """The environment's rotation about +Y (degrees, Mitsuba's convention) and its scale."""
    rotation_deg: float = 0.0
    intensity: float = 1.0


class FrameCancelled(Exception):
    """A frame its requester no longer needs (``FrameRequest.cancelled`` said so mid-way)."""


@dataclass
class FrameRequest:
    """One frame.

    camera : scene.Camera (its width and height are the frame's).
    lighting : Lighting.
    materials : one scene material per object, in scene order.
    lod : "full", or "drag" while the user drags (the renderer picks what it coarsens), or
        "quick": a first frame shown at once before the anti-aliased still (full resolution;
        the cut renderer draws one sample with its drag level's cuts and clusters; renderers
        without such a level treat it as "full").
    shading : renderer-specific shading mode (for cuts: "refined", the default, vertex shading
        with per-pixel shading where its interpolation is wrong; "vertex", the interpolation
        alone; "pixel", every pixel shaded). A session asks for "vertex" in its one-sample
        frames while something moves and "refined" in its settled (anti-aliased) frames.
    transforms : object name -> scene.Transform for movable objects (cut renderer).
    samples : primary-visibility samples per pixel (anti-aliasing), ≥ 1.
    antialias : where the samples are taken: "full", at every pixel; "edges", only at pixels
        next to a discontinuity of the surface seen (silhouettes, occlusions, object boundaries,
        creases), one sample elsewhere, where more change nothing but the cost (cut renderer,
        vertex and refined shading; others treat it as "full").
    vertex_radiance : object index -> (vertex ids (K,) int32, radiance (K, 3) float32), radiance
        already known (e.g. from a per-vertex transfer matrix); renderers that shade vertices
        use it instead of shading those vertices.
    ground_shadow : draw the shadow-catcher ground's shadow (None: the scene's ``ground.shadow``,
        off for a scene without ``ground``); renderers without one ignore it.
    ground_intensity : its strength k in [0, 1] (None: the scene's ``ground.intensity``).
    drag_scale : at the drag level of detail, the resolution divisor (2: half, 4: a quarter,
        chosen by the session under load); renderers may ignore it.
    cancelled : a checkpoint for a frame that may give way (a session's frame that answers no
        stroke): renderers may call it between parts of their work. It may block while more
        urgent work runs (a stroke elsewhere on the machine) and returns True when the frame is
        no longer wanted (a new message for it came): the renderer then raises FrameCancelled,
        so the new message is not kept waiting.
    """
    camera: Any
    lighting: Lighting = Lighting()
    materials: Sequence[Any] = ()
    lod: str = "full"
    shading: str = "refined"
    transforms: Mapping[str, Any] | None = None
    samples: int = 1
    antialias: str = "full"
    vertex_radiance: Mapping[int, tuple[np.ndarray, np.ndarray]] | None = None
    ground_shadow: bool | None = None
    ground_intensity: float | None = None
    drag_scale: int = 2
    cancelled: Callable[[], bool] | None = None


@dataclass
class Rendered:
    """radiance : (H, W, 3) float32 linear radiance (W·sr⁻¹·m⁻² up to the map's units).
    object_id : (H, W) int32 object index per pixel, −1 for the background.
    timings : milliseconds per stage (e.g. {"light": 2.1, "shade": 30.5, "interpolate": 1.2}).
    info : what the renderer wants a client to know (level of detail used, cuts τ, …)."""
    radiance: np.ndarray
    object_id: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)


# --- optional capabilities ---------------------------------------------------------------------
# What some renderers can do beyond ``render``: name -> the methods it brings. A renderer lists
# the names it has in ``capabilities``; the session runtime, the fit driver and the fitter ask
# ``renderer.can(name)``. The methods' shapes (as the cut renderer defines them):
#
# "place"        place(transforms: Mapping[str, scene.Transform] | None) -> None
#                    where movable objects stand for the fitter's questions until the next frame.
# "drag_level"   coarse_cuts() -> Any
#                    build the drag-time level of detail now (the session does it at open, so
#                    the first drag does not pay it).
# "view_cache"   has_view(camera, samples: int = 1, antialias: str = "full") -> bool
#                    whether a frame of (camera, samples) costs only shading (its primary hits
#                    are cached); without the capability every view counts as ready.
#                forget_views(min_pixels: int) -> int
#                    drop cached views of cameras of at least min_pixels (width × height);
#                    returns how many went (a closed session's big frame frees its memory).
# "stroke_fit"   surface_samples(camera, object_index: int, pixels: (M,) int64 | None) -> Samples
#                transfer(samples, basis, lighting: Lighting, coarse: bool = False)
#                    -> (T (3, N, J) float32, E (N, 3) float32)   (inverse-brdf-modeling eq. 21)
#                shade_samples(samples, material, object_index: int, lighting: Lighting,
#                              coarse: bool = False) -> (N, 3) float64 radiance
#                    what the stroke fitter (worker/fit/fitter.py) asks of a renderer; Samples
#                    holds pix (N,), positions, normals, wo (N, 3) float32, verts (N, 3) int32,
#                    bary (N, 3) float32 (worker/renderers/cuts/renderer.py).
# "polynomial_transfer"  linearise(samples, basis, lighting, material, object_index: int,
#                              coarse: bool = False) -> (T (3, N, J) float32, E (N, 3) float32,
#                                                        R (N, 3) float64)
#                    for a renderer whose image is not linear in the edited object's coefficients
#                    (interreflections: polynomial-gi eq. 28): radiance ≈ ρ_d E + T c + R around
#                    ``material``; the fitter then re-linearises at each solution (Gauss-Newton)
#                    and judges a fit by ``shade_samples``. With stroke_fit.
#                prepare_basis(basis) -> None
#                    pay a fitting basis's one-time costs now (a session does it at open).
# "live_object"  make_live(object_index: int, materials: Sequence | None = None) -> float
#                    prepare to edit this object's material (the scene's other materials as
#                    given): the GI renderer freezes every other object (polynomial-gi eq. 27),
#                    the mode switch a session pays when the object is picked, not on its first
#                    edit; returns seconds.
# "vertex_transfer"  vertex_samples(camera, object_index: int, samples: int = 1, antialias: str = "full") -> Samples
#                    the object's visible vertices, whose transfer rows give the fitted
#                    material's radiance there (FrameRequest.vertex_radiance); with transfer.
CAPABILITIES: dict[str, tuple[str, ...]] = {
    "place": ("place",),
    "drag_level": ("coarse_cuts",),
    "view_cache": ("has_view", "forget_views"),
    "stroke_fit": ("surface_samples", "transfer", "shade_samples"),
    "vertex_transfer": ("vertex_samples", "transfer"),
    "polynomial_transfer": ("linearise", "prepare_basis"),
    "live_object": ("make_live",),
}


def implemented_capabilities(cls: type) -> frozenset[str]:
    """The capabilities whose methods a renderer class defines (declared or not)."""
    return frozenset(c for c, methods in CAPABILITIES.items()
                     if all(callable(getattr(cls, m, None)) for m in methods))


class Renderer(ABC):
    """Draws one loaded scene from its precomputed data.

    Class attributes
    ----------------
    kind : the registry key (the scene file's ``renderer``), from the package's DECLARATION.
    controls : what an interactive session may change: a subset of
        declaration.ALL_CONTROLS, from the package's DECLARATION (the studio hides the
        others and says why).
    capabilities : the optional capabilities (CAPABILITIES) it has; each one's methods must be
        defined (checked when the class is defined), and callers ask ``renderer.can(name)``.
    """

    kind: ClassVar[str]
    controls: ClassVar[frozenset[str]] = frozenset({"camera", "light", "materials", "environment"})
    capabilities: ClassVar[frozenset[str]] = frozenset()
    # with stroke_fit: the fit resolution of a session's strokes, a fraction of the view's
    # (fit rows cost the cut renderer a transfer each, so it fits at a quarter)
    stroke_fit_scale: ClassVar[float] = 0.25

    def __init_subclass__(cls, **kw):
        super().__init_subclass__(**kw)
        cls.capabilities = frozenset(cls.capabilities)
        unknown = cls.capabilities - set(CAPABILITIES)
        if unknown:
            raise TypeError(f"{cls.__name__} declares unknown capabilities {sorted(unknown)} "
                            f"(known: {', '.join(sorted(CAPABILITIES))})")
        missing = {c: [m for m in CAPABILITIES[c] if not callable(getattr(cls, m, None))]
                   for c in cls.capabilities}
        missing = {c: ms for c, ms in missing.items() if ms}
        if missing:
            raise TypeError(f"{cls.__name__} declares capabilities it does not implement: "
                            + "; ".join(f"{c} needs {', '.join(ms)}" for c, ms in sorted(missing.items())))

    @classmethod
    def can(cls, capability: str) -> bool:
        """Whether this renderer has an optional capability (a key of CAPABILITIES; a name that
        is not one is a KeyError, so a typo cannot read as "no")."""
        if capability not in CAPABILITIES:
            raise KeyError(f"unknown renderer capability {capability!r} (known: {', '.join(sorted(CAPABILITIES))})")
        return capability in cls.capabilities

    def __init__(self, scene, data, kernels=None):
        self.scene = scene
        self.data = data

    @abstractmethod
    def render(self, req: FrameRequest) -> Rendered:
        """Radiance of one frame (see FrameRequest / Rendered)."""

    def set_environment(self, envmap: np.ndarray) -> None:
        """Light the scene with another (H, W, 3) float32 equirectangular map."""
        raise Unsupported(f"the {self.kind} renderer cannot change its environment map")

    def object_mask(self, camera) -> np.ndarray:
        """(H, W) int32 object index per pixel, −1 background."""
        raise Unsupported(f"the {self.kind} renderer has no object mask")

    def edge_mask(self, camera) -> np.ndarray | None:
        """(H, W) bool: the pixels next to a silhouette, an occlusion or a crease, where the
        radiance at the pixel centre is not the mean over the pixel (an image of the scene from
        elsewhere, a photograph or Mitsuba, holds that mean); None when the renderer cannot tell."""
        return None


# --- what to precompute ------------------------------------------------------------------------


@dataclass(frozen=True)
class Part:
    """One stored piece of a precomputation.

    key : content address of everything it depends on (hex); also its name in the store.
    label : what it is, for progress and errors ("static cuts", "cut field of 'chair'", …).
    work : its size in the unit ``progress`` counts (e.g. vertices), for a progress bar.
    meta : whatever ``compute`` needs to know which part this is.
    """
    key: str
    label: str
    work: int = 1
    meta: Mapping[str, Any] = field(default_factory=dict)


class ArtifactStore(Protocol):
    """Where parts live: ``get`` returns the bytes stored under a key, or None."""

    def get(self, key: str) -> bytes | None: ...

    def put(self, key: str, data: bytes) -> None: ...


Progress = Callable[[int], None]      # called with units of work done since the last call


class Precomputation(ABC):
    """What a renderer needs computed before it can draw a scene.

    Subclasses define ``parts`` and ``compute`` (and may split a part into chunks, computed
    independently and assembled); ``load`` builds the renderer's data from stored parts.
    ``options`` is a plain dict of the precomputation's settings (τ, bounces, spp, …), from the
    scene file, the CLI or the REST request; its defaults are the subclass's.
    """

    kind: ClassVar[str]

    def __init__(self, kernels=None):
        self._k = kernels

    @property
    def kernels(self):
        """The kernel backend this precomputation computes with (worker/native/kernels.py): the
        one it was given, else the process's, chosen when first needed (so a precomputation made
        at import time does not load the C library)."""
        if self._k is None:
            from ..native.kernels import kernels
            self._k = kernels()
        return self._k

    @abstractmethod
    def parts(self, scene, options: Mapping[str, Any]) -> list[Part]:
        """The parts this scene needs, each with its content key."""

    def chunks(self, scene, part: Part, options: Mapping[str, Any], n: int) -> list[Any]:
        """Split a part into about n independent chunks (default: one)."""
        return [None]

    @abstractmethod
    def compute(self, scene, part: Part, options: Mapping[str, Any], chunk: Any = None,
                progress: Progress | None = None, threads: int = 2) -> Any:
        """Compute one chunk of a part (the whole part when chunk is None); returns what
        ``assemble`` takes (by default: the part's bytes)."""

    def assemble(self, scene, part: Part, options: Mapping[str, Any], results: list[Any]) -> tuple[bytes, dict]:
        """Join the chunks' results into the part's bytes and its stats."""
        if len(results) != 1 or not isinstance(results[0], (bytes, bytearray)):
            raise NotImplementedError(f"{type(self).__name__} splits parts but does not assemble them")
        return bytes(results[0]), {}

    @abstractmethod
    def load(self, scene, blobs: Mapping[str, bytes], options: Mapping[str, Any]) -> Any:
        """The renderer's data from the stored parts (key -> bytes)."""

    def describe(self, scene, part: Part, blob: bytes) -> dict:
        """Stats of a stored part (sizes, counts), for a precomputation found already done."""
        return {"bytes": len(blob)}


# the share of a part's progress kept for its assembly and storing (encoding, deflate, the
# write): measured on the couch's visibility cuts (12.6K vertices), 160 s tracing and 13 s
# assembling on two loaded cores; before, the bar sat at 100% through those 13 s
ASSEMBLE_SHARE = 0.08


def ensure(pre: Precomputation, scene, store: ArtifactStore, options: Mapping[str, Any] | None = None,
           progress: Progress | None = None, threads: int = 2, stage: Callable[[str], None] | None = None) -> dict:
    """Compute the parts missing from the store, in this process. Returns stats:
    {"parts": {key: {"label", "cached": bool, "seconds", ...part stats}}, "seconds": total,
    "computed": number of parts computed}. progress : units of work done (a part's ``work``
    in all, (1 − ASSEMBLE_SHARE) of it while computing, the rest once it is assembled and
    stored); stage : what is being done now ("tracing visibility cuts", …)."""
    options = dict(options or {})
    say = stage or (lambda text: None)
    t0 = time.perf_counter()
    out: dict[str, Any] = {"parts": {}, "computed": 0}
    for part in pre.parts(scene, options):
        blob = store.get(part.key)
        if blob is not None:
            out["parts"][part.key] = {"label": part.label, "cached": True, **pre.describe(scene, part, blob)}
            if progress:
                progress(part.work)
            continue
        t1 = time.perf_counter()
        say(f"computing {part.label}")
        scaled = None
        if progress:
            k = 1.0 - ASSEMBLE_SHARE
            seen = [0]

            def scaled(n):
                # never more than the computing share, whatever the part's compute reports
                n = min(n, part.work - seen[0])
                seen[0] += n
                progress(n * k)
        results = [pre.compute(scene, part, options, ch, scaled, threads)
                   for ch in pre.chunks(scene, part, options, 1)]
        say(f"assembling and storing {part.label}")
        blob, stats = pre.assemble(scene, part, options, results)
        store.put(part.key, blob)
        if progress:
            progress(part.work - seen[0] * (1.0 - ASSEMBLE_SHARE))
        out["parts"][part.key] = {"label": part.label, "cached": False, "seconds": time.perf_counter() - t1,
                                  "bytes": len(blob), **stats}
        out["computed"] += 1
    out["seconds"] = time.perf_counter() - t0
    return out


def load(pre: Precomputation, scene, store: ArtifactStore, options: Mapping[str, Any] | None = None):
    """The renderer's data from the store; GlintError (409) naming the missing parts."""
    options = dict(options or {})
    parts = pre.parts(scene, options)
    blobs, missing = {}, []
    for p in parts:
        b = store.get(p.key)
        if b is None:
            missing.append(p.label)
        else:
            blobs[p.key] = b
    if missing:
        raise NotPrecomputed(missing)
    return pre.load(scene, blobs, options)


def missing_parts(pre: Precomputation, scene, store: ArtifactStore, options: Mapping[str, Any] | None = None) -> list[str]:
    """The labels of the precomputation's parts for this scene that the store lacks: a scene
    precomputed by an earlier version whose parts' recipe or input changed (e.g. how meshes are
    loaded) has some, though its precomputation row says done."""
    return [p.label for p in pre.parts(scene, dict(options or {})) if store.get(p.key) is None]


class NotPrecomputed(GlintError):
    """The scene lacks precomputed parts (409); ``missing`` their labels. The service answers it
    by precomputing the scene again (server/services/scenes.py)."""

    def __init__(self, missing: list[str]):
        super().__init__(f"not precomputed yet: {', '.join(missing)}", status=409)
        self.missing = list(missing)
