"""Paint-to-BRDF for one object of a scene: saved views, strokes, fits (inverse-brdf-modeling §3-4).

A ``Fitter`` holds, per saved view, the object's pixels at a reduced fit resolution (default a
quarter of the view: 160×120 for 640×480), their transfer matrix for the SRBF basis under the
view's lighting, and the base rendering B' those pixels show with the material the design started
from. The fit target is a pure function of (bases, stroke history): undo and redo re-fit
exactly, and a session can be rebuilt from its stored strokes.

Under global illumination (a renderer with ``polynomial_transfer``, renderers/gi) the image is
polynomial, not linear, in the edited object's coefficients (polynomial-gi eq. 28): a view's
rows are then the expansion ρ_d E + T c + R around a material, and ``fit`` is Gauss-Newton: the
constrained least squares (eq. 17-19) on the expansion, re-linearised at its solution until the
expansion and the renderer's exact radiance agree (GN_TOL), at most GN_STEPS solves.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..errors import GlintError
from ..renderers.base import Lighting, Unsupported
from ..scene import SRBF, Camera, Material
from .basis import DEFAULT_NL, SRBFBasis, default_basis, equivalent_roughness, static_alpha_for
from .brush import (DEFAULT_UNPAINTED_WEIGHT, Stroke, StrokeHistory, achromatic, apply_stroke, stroke_effect,
                    stroke_notes, stroke_weights)
from .solve import FitRows, SolveResult, gram, solve

MAX_FIT_ROWS = 4000     # the paper's largest N; see Fitter.row_stride
# a quick view (Fitter.build_view with ``select``): the painted pixels plus about this many
# unpainted ones spread over the object, so a stroke in a view not yet built reaches its frame
# in a fraction of the full view's cost; the rest comes later (extend_view)
QUICK_ROWS = 400
DEFAULT_FIT_ALBEDO = False
# Gauss-Newton under GI: stop when the expansion's prediction at the solution is within GN_TOL
# (relative RMS over the fit rows) of the exact radiance, or after GN_STEPS solves
GN_TOL = 2e-3
GN_STEPS = 4
# samples over a pixel whose mean is a target fit's row where the pixel's area matters
# (Fitter.antialias_rows). Fewer than the settled frame's (jobs/lod.py STILL_SAMPLES): each costs
# a transfer row, and a fit averaged over 4 and shown at 16 was as close to Mitsuba as its GGX
# there (the dragon under stinson-beach's sun at α 0.1: 5.2% against 4.4%; BENCHMARKS.md)
AREA_SAMPLES = 4


def _take(smp, idx):
    """Rows idx of a renderer's Samples (a dataclass of per-point arrays; an optional one may be None)."""
    def rows(x):
        return None if x is None else x[idx]
    return dataclasses.replace(smp, **{f.name: rows(getattr(smp, f.name)) for f in dataclasses.fields(smp)})


def _cat(a, b):
    """Samples a followed by Samples b."""
    def cat(x, y):
        return None if x is None or y is None else np.concatenate([x, y])
    return dataclasses.replace(a, **{f.name: cat(getattr(a, f.name), getattr(b, f.name))
                                     for f in dataclasses.fields(a)})


def painted_select(stroke: Stroke):
    """A ``build_view``/``extend_view`` selection: the pixels a stroke paints."""
    return lambda xy, footprint: stroke_weights(stroke, xy, footprint) > 0


def quick_select(stroke: Stroke | None = None, rows: int = QUICK_ROWS):
    """A quick view's selection: every s-th object pixel in scan order (about ``rows`` of
    them) and every pixel the stroke paints."""
    def select(xy, footprint):
        keep = np.zeros(len(xy), bool)
        keep[::max(1, -(-len(xy) // rows))] = True
        if stroke is not None:
            keep |= stroke_weights(stroke, xy, footprint) > 0
        return keep
    return select


def albedo_of(material) -> tuple[float, float, float]:
    """The diffuse albedo ρ_d of any scene material."""
    return tuple(material.albedo)


class FitError(GlintError):
    """A fit request that cannot be served (no object pixels, unknown view, bad target)."""


@dataclass
class FitView:
    """One saved view of the edited object at fit resolution.

    camera : the view camera (full resolution, as the designer sees it).
    size : (w, h) fit resolution. pix : (N,) flat fit-pixel indices of object pixels.
    xy : (N, 2) their centres in view-image pixels. T : (3, N, J) float32, E : (N, 3) float32
    (transfer.py). base : (N, 3) float64 radiance B' with the base material. gram : (3, J, J).
    samples : the renderer's Samples of those pixels (to re-shade the base when it changes).
    """
    camera: Camera
    rotation_deg: float
    intensity: float
    size: tuple[int, int]
    pix: np.ndarray
    xy: np.ndarray
    T: np.ndarray
    E: np.ndarray
    base: np.ndarray
    gram: np.ndarray
    seconds_transfer: float
    samples: object = field(repr=False, default=None)
    cache: dict = field(repr=False, default_factory=dict)
    # a partial view (built with ``select``): every object pixel of the fit grid as candidates
    # (their samples and xy), and the candidates not built yet (indices into them)
    cand_samples: object = field(repr=False, default=None)
    cand_xy: np.ndarray | None = field(repr=False, default=None)
    unbuilt: np.ndarray | None = field(repr=False, default=None)
    # rows on the renderer's drag-level (coarser) cuts: a quick view's, at about half the
    # transfer's cost, replaced by a full build like a partial view (``provisional``)
    coarse: bool = False
    # polynomial renderers (GI): the rows are the expansion around ``lin_material``, with the
    # offset R (N, 3) (radiance ≈ ρ_d E + T c + R); None for linear ones
    offset: np.ndarray | None = None
    lin_material: object = field(repr=False, default=None)
    # (N,) bool: rows made the mean over their pixel's area (``Fitter.antialias_rows``), and
    # those whose area is partly another surface's (left out of a target image's fit)
    averaged: np.ndarray | None = field(repr=False, default=None)
    mixed: np.ndarray | None = field(repr=False, default=None)

    @property
    def partial(self) -> bool:
        return self.unbuilt is not None and len(self.unbuilt) > 0

    @property
    def provisional(self) -> bool:
        """A quick view, partial or on coarse cuts: the session builds it in full later."""
        return self.partial or self.coarse

    @property
    def n_object(self) -> int:
        """Object pixels of the view at fit resolution, built or not."""
        return self.n + (len(self.unbuilt) if self.unbuilt is not None else 0)

    @property
    def lighting(self) -> Lighting:
        return Lighting(self.rotation_deg, self.intensity)

    @property
    def n(self) -> int:
        return len(self.pix)

    @property
    def footprint(self) -> float:
        """Half a fit pixel, in view-image pixels."""
        return 0.5 * max(self.camera.width / self.size[0], self.camera.height / self.size[1])


@dataclass
class FitOutcome:
    """A fit's result. For stroke fits, ``achieved`` and ``spill`` say how far the single BRDF
    of the object could follow the strokes (brush.stroke_effect): the share of the requested
    change delivered on the painted pixels, and the relative change of the unpainted ones.
    ``energy`` (3,) is each channel's largest specular albedo, against ``energy_bound`` (3,) =
    1 − ρ_d of the same channel. ``steps`` counts the solves (Gauss-Newton steps under GI) and
    ``gap`` the last step's relative gap between the expansion and the exact radiance (None for
    a linear renderer, where they are the same)."""
    material: SRBF
    solve: SolveResult
    pixels: int
    painted: int
    notes: list[str]
    seconds_transfer: float
    achieved: float | None = None
    spill: float | None = None
    steps: int = 1
    gap: float | None = None

    @property
    def energy(self) -> list[float]:
        return [float(x) for x in self.solve.energy]

    @property
    def energy_per_channel(self) -> list[float]:
        """``energy`` under the name the session's fit event gives it."""
        return self.energy

    @property
    def energy_bound(self) -> list[float]:
        return [float(x) for x in self.solve.energy_bound]


class Fitter:
    """Fits an ``srbf`` material for one object of a scene, through a renderer that answers the
    fitter's questions (renderers/cuts ``CutRenderer``: ``surface_samples``, ``transfer``,
    ``shade_samples``, ``object_mask``).

    Parameters
    ----------
    renderer : the scene's renderer.
    object_name : the edited object.
    base_material : what strokes paint over (default: the object's material in the scene file).
    basis : SRBF basis (default: basis.default_basis, the paper's 147 centres of σ = π/40 plus
        finer levels near the normal, the smith static with the base material's roughness
        (basis.static_alpha_for), F0 from ``fresnel_f0``).
    fit_scale : fit resolution as a fraction of the view resolution (0.25: 640×480 → 160×120).
    albedo : diffuse albedo ρ_d (3,); default: the base material's.
    max_rows : the most unpainted rows a fit holds over all its views (``row_stride``).
    """

    def __init__(self, renderer, object_name: str, base_material: Material | None = None,
                 basis: SRBFBasis | None = None, fit_scale: float = 0.25, albedo=None, fresnel_f0: float = 1.0,
                 max_rows: int = MAX_FIT_ROWS, transfer_rows: bool = True):
        scene = renderer.scene
        names = [o.name for o in scene.spec.objects]
        if object_name not in names:
            raise FitError(f"no object named {object_name!r} (objects: {', '.join(names)})")
        if not 0.0 < fit_scale <= 1.0:
            raise FitError(f"fit_scale must be in (0, 1], got {fit_scale}")
        if not renderer.can("stroke_fit"):
            raise FitError(f"the {renderer.kind} renderer cannot fit materials to strokes")
        self.renderer = renderer
        self.object_name = object_name
        self.obj = names.index(object_name)
        self.base_material: Material = base_material or scene.materials[self.obj]
        # the smith static's roughness follows the material the design starts from
        self.basis = basis or default_basis(fresnel_f0=fresnel_f0, static_alpha=static_alpha_for(self.base_material))
        self.basis.energy_rows()        # once per basis, not on the first fit
        self.fit_scale = fit_scale
        self.max_rows = int(max_rows)
        self.albedo = np.asarray(albedo_of(self.base_material) if albedo is None else albedo, np.float64)
        if self.albedo.shape != (3,) or np.any(self.albedo < 0) or np.any(self.albedo > 1):
            raise FitError(f"diffuse albedo must be 3 values in [0, 1], got {self.albedo.tolist()}")
        self.views: list[FitView] = []
        # False: views hold their samples and base rendering only (a painted region's fit builds
        # its own rows over the region, fit/regions.py): ``fit`` is refused
        self.transfer_rows = bool(transfer_rows)
        self.history = StrokeHistory()
        self._last: np.ndarray | None = None
        # GI: rows are expansions around a material (new views: the latest fit's)
        self.polynomial = renderer.can("polynomial_transfer")
        self._lin_material = self.base_material

    # -- views ----------------------------------------------------------------------------------
    def fit_size(self, camera: Camera) -> tuple[int, int]:
        return (max(1, round(camera.width * self.fit_scale)), max(1, round(camera.height * self.fit_scale)))

    def add_view(self, camera: Camera | None = None, rotation_deg: float | None = None,
                 intensity: float | None = None) -> int:
        """Save a view (default: the scene's camera and lighting); returns its index."""
        self.views.append(self.build_view(camera, rotation_deg, intensity))
        return len(self.views) - 1

    def build_view(self, camera: Camera | None = None, rotation_deg: float | None = None,
                   intensity: float | None = None, select=None, coarse: bool = False) -> FitView:
        """A view's fit rows (transfer, Gram, base rendering) without saving it: safe to run
        on a background thread while the fitter is in use.

        select : None (every object pixel of the fit grid) or a function (xy (M, 2) view-image
            pixel centres, footprint) -> (M,) bool choosing the rows to build now: a partial
            view, completed later by ``extend_view`` (its unpainted rows weigh for the unbuilt
            ones meanwhile, see ``fit``).
        coarse : build the rows (these and any added by ``extend_view``) on the renderer's
            drag-level cuts (renderers.cuts.renderer.DRAG_TAU): the transfer at about half the
            cost and 3% from the full cuts' (BENCHMARKS.md), for a stroke's first frame while the
            full view is built later."""
        spec = self.renderer.scene.spec
        camera = camera or spec.camera
        rot = spec.environment.rotation_deg if rotation_deg is None else float(rotation_deg)
        inten = spec.environment.intensity if intensity is None else float(intensity)
        t0 = time.perf_counter()
        fw, fh = self.fit_size(camera)
        # fit pixels sit on view-pixel centres (every 1/fit_scale-th view pixel), so a target
        # image at the view's resolution is read without interpolation: a highlight a few
        # pixels wide is not blurred in the target while the transfer samples it at a point
        cols = np.minimum(((np.arange(fw) + 0.5) * camera.width / fw).astype(np.int64), camera.width - 1)
        rows = np.minimum(((np.arange(fh) + 0.5) * camera.height / fh).astype(np.int64), camera.height - 1)
        sel = (rows[:, None] * camera.width + cols[None, :]).reshape(-1)
        smp = self.renderer.surface_samples(camera, self.obj, pixels=sel)     # smp.pix: fit-grid indices
        if len(smp) == 0:
            raise FitError(f"object {self.object_name!r} covers no pixel of this view at the fit "
                           f"resolution {fw}×{fh}; move the camera closer or raise fit_scale")
        pix = smp.pix
        xy = np.stack([cols[pix % fw] + 0.5, rows[pix // fw] + 0.5], axis=1).astype(np.float64)
        J = self.basis.J
        view = FitView(camera, rot, inten, (fw, fh), pix[:0], xy[:0], np.zeros((3, 0, J), np.float32),
                       np.zeros((0, 3), np.float32), np.zeros((0, 3)), np.zeros((3, J, J)), 0.0,
                       _take(smp, np.zeros(0, np.int64)), coarse=coarse)
        if self.polynomial:
            view.offset, view.lin_material = np.zeros((0, 3)), self._lin_material
        first = np.arange(len(pix))
        if select is not None:
            keep = np.asarray(select(xy, view.footprint), bool)
            if not keep.all():
                view.cand_samples, view.cand_xy = smp, xy
                view.unbuilt = np.nonzero(~keep)[0]
                first = np.nonzero(keep)[0]
        if len(first) == 0:                  # a selection that picks nothing: one row to start
            first, view.unbuilt = view.unbuilt[:1], view.unbuilt[1:]
        self._add_rows(view, _take(smp, first), xy[first])
        view.seconds_transfer = time.perf_counter() - t0
        return view

    def extend_view(self, view: FitView, select=None) -> int:
        """Build more of a partial view: the unbuilt candidates ``select`` (as in build_view)
        picks, or all of them. Returns the number of rows added. Not thread-safe against a fit
        of the same view: the session calls it on its own thread."""
        if not view.partial:
            return 0
        t0 = time.perf_counter()
        idx = view.unbuilt
        if select is not None:
            idx = idx[np.asarray(select(view.cand_xy[idx], view.footprint), bool)]
        if len(idx) == 0:
            return 0
        self._add_rows(view, _take(view.cand_samples, idx), view.cand_xy[idx])
        view.unbuilt = np.setdiff1d(view.unbuilt, idx, assume_unique=True)
        if not view.partial:
            view.cand_samples = view.cand_xy = view.unbuilt = None
        view.seconds_transfer += time.perf_counter() - t0
        return len(idx)

    def _add_rows(self, view: FitView, smp, xy: np.ndarray) -> None:
        """Transfer, Gram and base rendering of more pixels of a view, appended to its rows."""
        # a coarse view's base rendering is on the same cuts as its transfer: the fit then sees
        # no difference between the two where nothing is painted
        kw = {"coarse": True} if view.coarse else {}
        if not self.transfer_rows:
            # zero rows, never read (calloc'd pages stay untouched)
            T, E = np.zeros((3, len(smp), self.basis.J), np.float32), np.zeros((len(smp), 3), np.float32)
            if self.polynomial:
                view.offset = np.concatenate([view.offset, np.zeros((len(smp), 3))])
        elif self.polynomial:
            T, E, R = self.renderer.linearise(smp, self.basis, view.lighting, view.lin_material, self.obj, **kw)
            view.offset = np.concatenate([view.offset, R])
        else:
            T, E = self.renderer.transfer(smp, self.basis, view.lighting, **kw)
        base = self.renderer.shade_samples(smp, self.base_material, self.obj, view.lighting, **kw)
        view.pix = np.concatenate([view.pix, smp.pix])
        view.xy = np.concatenate([view.xy, xy])
        view.T = np.concatenate([view.T, T], axis=1) if view.T.shape[1] else T
        view.E = np.concatenate([view.E, E])
        view.base = np.concatenate([view.base, base])
        # Σ_i T_iᵀT_i: additive over rows; a polynomial renderer's rows are re-expanded at
        # every Gauss-Newton step, so theirs is built when a fit needs it (``_gram``)
        view.gram = None if self.polynomial else (view.gram + gram(T) if self.transfer_rows else view.gram)
        view.samples = _cat(view.samples, smp)
        view.cache.clear()

    def _relinearise(self, view: FitView, material, rows: np.ndarray | None = None) -> None:
        """A polynomial renderer's rows of a view (all, or ``rows``: the ones a fit uses),
        expanded around another material. Rows left out keep their expansion around an earlier
        material: still an expansion of the same image, which a later fit's Gauss-Newton steps
        refine when it uses them."""
        kw = {"coarse": True} if view.coarse else {}
        smp = view.samples if rows is None else _take(view.samples, rows)
        T, E, R = self.renderer.linearise(smp, self.basis, view.lighting, material, self.obj, **kw)
        if rows is None:
            view.T, view.E, view.offset = T, E, R
        else:
            view.T[:, rows], view.E[rows], view.offset[rows] = T, E, R
        view.lin_material = material
        view.gram = None
        view.cache.clear()

    def _used_rows(self, targets) -> list[np.ndarray | None]:
        """Per view, the rows a fit reads (``_rows``): every stride-th one and the painted ones,
        or None for all of them."""
        stride = self.row_stride()
        if stride == 1:
            return [None] * len(self.views)
        return [np.union1d(np.arange(0, v.n, stride), np.nonzero(p)[0]) for v, (_, p) in zip(self.views, targets)]

    def _shade(self, view: FitView, material, rows: np.ndarray | None = None) -> np.ndarray:
        """The renderer's radiance (N, 3) of a view's rows (or ``rows`` of them) under a material."""
        smp = view.samples if rows is None else _take(view.samples, rows)
        return self.renderer.shade_samples(smp, material, self.obj, view.lighting,
                                           **({"coarse": True} if view.coarse else {}))

    def _shade_base(self, view: FitView) -> np.ndarray:
        """B' (N, 3): the base material at the view's fit pixels, shaded like the renderer's
        pixel mode (each corner's cut with the pixel's normal, blended by barycentric weight)."""
        kw = {"coarse": True} if view.coarse else {}
        return self.renderer.shade_samples(view.samples, self.base_material, self.obj, view.lighting, **kw)

    def set_base_material(self, material: Material, albedo=None) -> None:
        """Strokes now paint over this material's appearance (bases are re-shaded)."""
        self.base_material = material
        self.albedo = np.asarray(albedo_of(material) if albedo is None else albedo, np.float64)
        for v in self.views:
            v.base = self._shade_base(v)

    # -- strokes --------------------------------------------------------------------------------
    def add_stroke(self, stroke: Stroke | dict) -> list[str]:
        """Record a stroke; returns notes (e.g. a stroke that touches no pixel of the object)."""
        stroke = stroke if isinstance(stroke, Stroke) else Stroke.model_validate(stroke)
        if stroke.view >= len(self.views):
            raise FitError(f"stroke refers to view {stroke.view} but {len(self.views)} view(s) are saved")
        self.history.push(stroke)
        return self._stroke_notes(len(self.history) - 1, stroke)

    def _stroke_notes(self, i: int, stroke: Stroke) -> list[str]:
        v = self.views[stroke.view]
        if not np.any(stroke_weights(stroke, v.xy, v.footprint) > 0):
            return [f"stroke {i + 1} touches no pixel of object {self.object_name!r} in view {stroke.view}; "
                    "it is ignored"]
        return []

    def undo(self) -> Stroke | None:
        return self.history.undo()

    def redo(self) -> Stroke | None:
        return self.history.redo()

    def targets(self):
        """Per view: (target (N, 3) float64, painted (N,) bool), and notes for ignored strokes."""
        out = [(v.base.copy(), np.zeros(v.n, bool)) for v in self.views]
        notes = []
        for i, s in enumerate(self.history.strokes):
            v = self.views[s.view]
            w = stroke_weights(s, v.xy, v.footprint)
            if not np.any(w > 0):
                notes += self._stroke_notes(i, s)
                continue
            apply_stroke(out[s.view][0], s, w)
            out[s.view][1][w > 0] = True
        return out, notes

    # -- fitting --------------------------------------------------------------------------------
    def fit(self, constrained: bool = True, unpainted_weight: float = DEFAULT_UNPAINTED_WEIGHT,
            n_l: int = DEFAULT_NL, targets=None, fit_albedo: bool = DEFAULT_FIT_ALBEDO,
            neutral: bool | None = None) -> FitOutcome:
        """Solve for the SRBF coefficients matching the strokes (or given per-view targets:
        a list of (target (N, 3), painted/valid (N,) bool) as from ``targets()``); with
        ``fit_albedo`` the diffuse albedo too (solve.solve). neutral : one specular part for the
        three channels (solve.solve); None: when the strokes ask for no colour (brush.achromatic),
        never for given targets."""
        if not self.views:
            raise FitError("no view saved: add_view() first")
        if unpainted_weight < 0:
            raise FitError("unpainted_weight must be ≥ 0")
        if not self.transfer_rows:
            raise FitError("this fitter's views hold no transfer rows (made for a painted region's fit)")
        notes = []
        strokes = targets is None
        if neutral is None:
            neutral = strokes and achromatic(self.history.strokes)
        if strokes:
            targets, notes = self.targets()
        painted = sum(int(p.sum()) for _, p in targets)
        prior = self._prior()
        steps, gap, exact = 0, None, None
        used = self._used_rows(targets) if self.polynomial else None
        while True:
            rows = self._rows(targets, unpainted_weight)
            if not any(np.any(r.weight > 0) for r in rows):
                raise FitError("nothing to fit: no painted pixel and unpainted_weight is 0")
            res = solve(rows, self.basis, self.albedo, constrained=constrained, n_l=n_l, prior=prior,
                        warm=self._last if constrained else None, fit_albedo=fit_albedo, neutral=neutral)
            steps += 1
            if constrained:
                self._last = res.coefficients
            mat = SRBF.model_validate(self.basis.to_material(res.coefficients, res.albedo))
            if not self.polynomial:
                break
            # the expansion against the exact radiance at its solution (polynomial-gi eq. 28), on
            # the rows the fit reads: a step costs those rows, not the view's (max_rows)
            at = [slice(None) if u is None else u for u in used]
            exact = [self._shade(v, mat, None if u is None else u) for v, u in zip(self.views, used)]
            lin = [self.predicted(res.coefficients, i, res.albedo)[a] for i, a in enumerate(at)]
            num = sum(float(((e - p) ** 2).sum()) for e, p in zip(exact, lin))
            den = sum(float((t[a] ** 2).sum()) for (t, _), a in zip(targets, at))
            gap = float(np.sqrt(num / max(den, 1e-300)))
            self._lin_material = mat
            if gap <= GN_TOL or steps >= GN_STEPS:
                break
            for v, u in zip(self.views, used):
                self._relinearise(v, mat, u)
        if exact is not None and any(u is not None for u in used):
            exact = [self._shade(v, mat) for v in self.views]    # the fit's figures: every row
        achieved = spill = None
        if self.polynomial and gap is not None and gap > GN_TOL:
            notes = notes + [f"the fit under global illumination stopped after {steps} Gauss-Newton steps with its "
                             f"expansion {100 * gap:.1f}% from the exact radiance"]
        if strokes and painted:
            pred = exact if exact is not None else \
                [self.predicted(res.coefficients, i, res.albedo) for i in range(len(self.views))]
            achieved, spill = stroke_effect([v.base for v in self.views], [t for t, _ in targets],
                                            [p for _, p in targets], pred)
            notes = notes + stroke_notes(achieved, res, res.albedo)
        return FitOutcome(mat, res, sum(v.n for v in self.views), painted, notes,
                          sum(v.seconds_transfer for v in self.views), achieved, spill, steps, gap)

    def _rows(self, targets, unpainted_weight: float) -> list[FitRows]:
        """The solver's rows of every view for per-view (target, painted) (see ``fit``); a
        polynomial renderer's offset R moves into the target."""
        rows = []
        stride = self.row_stride()
        for v, (tgt, pmask) in zip(self.views, targets):
            if v.offset is not None:
                tgt = tgt - v.offset
            npaint = int(pmask.sum())
            # a partial view's unpainted rows stand for its unbuilt pixels too (every painted
            # pixel is built: the session extends a view under each stroke)
            uw = unpainted_weight * (v.n_object - npaint) / max(1, v.n - npaint) if v.partial else unpainted_weight
            if stride == 1:
                if v.gram is None:
                    v.gram = gram(v.T)
                rows.append(FitRows(v.T, v.E, tgt, np.where(pmask, 1.0, uw), v.gram))
                continue
            # every stride-th row stands for the unpainted rows around it; painted rows count once
            sub = np.arange(0, v.n, stride)
            w = np.where(pmask[sub], 1.0, uw * stride)
            rows.append(FitRows(v.T[:, sub], v.E[sub], tgt[sub], w, self._sub_gram(v, stride)))
            extra = np.nonzero(pmask & (np.arange(v.n) % stride != 0))[0]
            if len(extra):
                rows.append(FitRows(v.T[:, extra], v.E[extra], tgt[extra], np.ones(len(extra))))
        return rows

    def row_stride(self) -> int:
        """The bound on a fit's size: a fit holds at most ``max_rows`` unpainted rows
        over all its views, plus the painted ones. Beyond that, every view keeps every s-th row
        (s the same for all views), weighted s times, so each view still pulls with the weight of
        all its pixels and the solve's cost stays that of ``max_rows`` rows."""
        total = sum(v.n for v in self.views)
        return max(1, -(-total // self.max_rows))

    def _sub_gram(self, v: FitView, stride: int) -> np.ndarray:
        key = ("gram", stride)
        if key not in v.cache:
            v.cache.clear()
            v.cache[key] = gram(v.T[:, ::stride])
        return v.cache[key]

    def _prior(self) -> np.ndarray | None:
        """c₀ of the proximal term: the base material's coefficients when it is an SRBF over
        this basis (unseen directions keep their look), else zero."""
        m = self.base_material
        if isinstance(m, SRBF) and self.basis.matches(m):
            return np.asarray(m.coefficients, np.float64)
        return None

    def _target_image(self, view: int, image) -> np.ndarray:
        """A target image for a view, checked: (h, w, 3) float32, finite, the view's aspect."""
        v = self.views[view]
        img = np.asarray(image, np.float32)
        if img.ndim != 3 or img.shape[2] < 3:
            raise FitError(f"target must be an (H, W, 3) image, got shape {img.shape}")
        img = np.ascontiguousarray(img[:, :, :3])
        if not np.all(np.isfinite(img)):
            raise FitError("target contains NaN or infinite values")
        th, tw = img.shape[:2]
        if abs(tw / th - v.camera.width / v.camera.height) > 0.02 * v.camera.width / v.camera.height:
            raise FitError(f"target is {tw}×{th} but the view is {v.camera.width}×{v.camera.height}: "
                           "the aspect ratios differ")
        return img

    def target_rows(self, view: int, image: np.ndarray, mask: np.ndarray | None = None):
        """Per-pixel target (N, 3) and validity (N,) for a view from an image of linear radiance
        (h, w, 3) at any resolution with the view's aspect ratio, sampled bilinearly at the fit
        pixels' centres. A fit pixel is valid where all four bilinear taps lie on the object (in
        a render of the object mask at the image's resolution), is not a pixel whose area shows
        something else too (``antialias_rows``: ``mixed``) and, if given, mask (h, w) > 0."""
        v = self.views[view]
        img = self._target_image(view, image)
        th, tw = img.shape[:2]
        cam = v.camera.model_copy(update={"width": tw, "height": th})
        objmask = (self.renderer.object_mask(cam) == self.obj).astype(np.float32)
        if mask is not None:
            m = np.asarray(mask)
            if m.shape[:2] != (th, tw):
                raise FitError(f"mask is {m.shape[1]}×{m.shape[0]} but the target is {tw}×{th}")
            objmask *= (m.reshape(th, tw, -1)[:, :, 0] > 0)
        mx = (v.xy[:, 0] * tw / v.camera.width - 0.5).astype(np.float32)
        my = (v.xy[:, 1] * th / v.camera.height - 0.5).astype(np.float32)
        tgt = cv2.remap(img, mx[None, :], my[None, :], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0]
        x0, y0 = np.floor(mx).astype(np.int64), np.floor(my).astype(np.int64)
        valid = np.ones(v.n, bool)
        for dx in (0, 1):
            for dy in (0, 1):
                xi, yi = np.clip(x0 + dx, 0, tw - 1), np.clip(y0 + dy, 0, th - 1)
                valid &= objmask[yi, xi] > 0
        if v.mixed is not None:
            valid &= ~v.mixed
        return tgt.astype(np.float64), valid

    def antialias_rows(self, view: int, extra: np.ndarray | None = None, samples: int | None = None) -> int:
        """Make a view's rows at edge pixels (and the rows ``extra`` (N,) bool) the mean over
        the pixel's area, for a fit to an image made elsewhere; returns how many rows changed
        (rows done before are not done again; 0 when the renderer or the fit cannot: a
        polynomial renderer re-expands its rows from one point).

        A target pixel (a photograph's, Mitsuba's) is the mean radiance over its area, a fit row
        the radiance at its centre. Inside a smooth piece of surface the two agree to first order;
        next to a silhouette, an occlusion or a crease (the renderer's ``edge_mask``, where the
        studio's settled frame takes its samples) they do not, nor where the image is curved at
        the pixel scale (``steep_rows``), and a fit that matched centre rows to area targets would
        bend its lobes to make up for it: the sofa2's piping, 2-3 pixels tall, took the settled
        frame of a fit to Mitsuba's GGX α 0.1 8.8% from it where the GGX itself is 7.3% (7.1%
        with these rows). Those rows become the mean of ``samples`` (default AREA_SAMPLES)
        transfer rows over the pixel
        (render.sample_offsets); a pixel whose samples are not all on the object is marked
        ``mixed``. Not thread-safe against a fit of the same view."""
        v = self.views[view]
        if not self._averages_rows(view):
            return 0
        area = self.renderer.area_samples
        S = int(samples or AREA_SAMPLES)
        t0 = time.perf_counter()
        cam = v.camera
        edges = self.renderer.edge_mask(cam)
        if edges is None:
            return 0
        if v.averaged is None:
            v.averaged, v.mixed = np.zeros(v.n, bool), np.zeros(v.n, bool)
        px = (np.floor(v.xy[:, 1]).astype(np.int64) * cam.width + np.floor(v.xy[:, 0]).astype(np.int64))
        want = edges.reshape(-1)[px]
        if extra is not None:
            want |= np.asarray(extra, bool)
        rows = np.nonzero(want & ~v.averaged)[0]
        v.averaged[rows] = True
        if not len(rows):
            return 0
        kw = {"coarse": True} if v.coarse else {}
        try:
            smp = area(cam, self.obj, px[rows], S)              # smp.pix: i·S + s of rows[i]
        except Unsupported:
            return 0
        owner = smp.pix // S
        whole = np.bincount(owner, minlength=len(rows)) == S
        v.mixed[rows[~whole]] = True
        if not whole.any():
            return 0
        keep = whole[owner]
        smp = _take(smp, np.nonzero(keep)[0])
        T, E = self.renderer.transfer(smp, self.basis, v.lighting, **kw)
        base = self.renderer.shade_samples(smp, self.base_material, self.obj, v.lighting, **kw)
        done = rows[whole]
        # rows i·S + s of each whole pixel, in order: the mean over s
        T = T.reshape(3, len(done), S, -1).mean(axis=2, dtype=np.float64).astype(np.float32)
        E = E.reshape(len(done), S, 3).mean(axis=1, dtype=np.float64).astype(np.float32)
        base = base.reshape(len(done), S, 3).mean(axis=1)
        if v.gram is not None:
            v.gram = v.gram - gram(v.T[:, done]) + gram(T)
        # new arrays, not writes into the old ones (a copied view may share them)
        v.T, v.E, v.base = v.T.copy(), v.E.copy(), v.base.copy()
        v.T[:, done], v.E[done], v.base[done] = T, E, base
        v.cache = {}
        v.seconds_transfer += time.perf_counter() - t0
        return len(done)

    def _averages_rows(self, view: int) -> bool:
        """Whether ``antialias_rows`` can average a view's rows: a renderer with ``area_samples``,
        a linear one (a polynomial renderer re-expands its rows from one point), a whole view."""
        return (not self.polynomial and self.transfer_rows and hasattr(self.renderer, "area_samples")
                and not self.views[view].partial)

    def steep_rows(self, view: int, image: np.ndarray) -> np.ndarray:
        """(N,) bool: the view's rows whose pixel in a target image (any resolution with the
        view's aspect) is curved at the pixel scale, judged as the settled frame judges its own
        (edges.steep_pixels: the largest channel departs from the mean of its two neighbours
        along a row or a column by more than STEEP × the object's mean largest channel in the
        image): a glint narrower than a pixel, whose mean over the pixel one sample misses. A
        sun on a detailed mesh: the dragon under stinson-beach, GGX α 0.15, its fit's settled
        frame 9.6% from Mitsuba with the edge rows averaged, 7.0% with these too (the GGX
        itself 7.3%)."""
        from ..renderers.cuts.edges import steep_pixels

        v = self.views[view]
        img = self._target_image(view, image)
        th, tw = img.shape[:2]
        om = self.renderer.object_mask(v.camera.model_copy(update={"width": tw, "height": th}))
        on = np.nonzero(om.reshape(-1) == self.obj)[0]
        out = np.zeros(v.n, bool)
        if not len(on):
            return out
        rgb = img.reshape(-1, 3)
        scale = np.zeros(max(int(om.max()), self.obj) + 1, np.float32)
        scale[self.obj] = float(rgb[on].max(1).mean())
        hit = np.zeros(th * tw, bool)
        hit[steep_pixels(rgb, on, np.zeros(0, np.int64), om, scale, th, tw)] = True
        hit &= om.reshape(-1) == self.obj
        # a row's pixel in the image: the one holding its centre
        x = np.clip(np.floor(v.xy[:, 0] * tw / v.camera.width).astype(np.int64), 0, tw - 1)
        y = np.clip(np.floor(v.xy[:, 1] * th / v.camera.height).astype(np.int64), 0, th - 1)
        return hit[y * tw + x]

    def set_basis(self, basis: SRBFBasis) -> None:
        """Fit over another basis from now on: every saved view's transfer is rebuilt."""
        self.basis = basis
        self.basis.energy_rows()
        self._last = None
        old, self.views = self.views, []
        for v in old:
            self.add_view(v.camera, v.rotation_deg, v.intensity)

    def fit_targets(self, images: list, masks: list | None = None, constrained: bool = True,
                    n_l: int = DEFAULT_NL, auto_static: bool = False) -> FitOutcome:
        """Fit to one target image per saved view (automation: ``glint fit --target``).

        auto_static : when the basis uses the smith static, fit once, set its roughness to the
            fitted distribution's (``equivalent_roughness``), rebuild the transfer and fit again
            (costs a second transfer)."""
        out = self._fit_targets(images, masks, constrained, n_l)
        if auto_static and self.basis.static == "smith":
            a = equivalent_roughness(self.basis, out.solve.coefficients)
            if abs(np.log(a / self.basis.static_alpha)) > np.log(1.15):
                b = self.basis
                self.set_basis(SRBFBasis(b.centers, b.bandwidths, b.fresnel_f0, b.static, a))
                out = self._fit_targets(images, masks, constrained, n_l)
        return out

    def _fit_targets(self, images, masks, constrained, n_l) -> FitOutcome:
        if len(images) != len(self.views):
            raise FitError(f"{len(images)} target image(s) for {len(self.views)} view(s)")
        masks = masks or [None] * len(images)
        images = [self._target_image(i, img) for i, img in enumerate(images)]     # refused before any work
        for i, img in enumerate(images):
            if self._averages_rows(i):
                self.antialias_rows(i, extra=self.steep_rows(i, img))
        targets = []
        for i, (img, m) in enumerate(zip(images, masks)):
            tgt, valid = self.target_rows(i, img, m)
            if not valid.any():
                raise FitError(f"target {i} covers no pixel of object {self.object_name!r}")
            targets.append((tgt, valid))
        # only valid pixels count: weight 1 inside, 0 elsewhere
        return self.fit(constrained=constrained, unpainted_weight=0.0, n_l=n_l, targets=targets)

    def predicted(self, coefficients: np.ndarray, view: int = 0, albedo=None) -> np.ndarray:
        """Radiance (N, 3) the fit predicts at a view's fit pixels for coefficients (J, 3) and
        diffuse albedo (3,) (default: the fitter's)."""
        v = self.views[view]
        rho = self.albedo if albedo is None else np.asarray(albedo)
        out = rho * v.E + np.stack([v.T[c] @ coefficients[:, c] for c in range(3)], axis=1)
        return out + v.offset if v.offset is not None else out
