"""Fit orchestration of a session: the paint-to-BRDF fitter of the edited object, its fit views
(quick ones built on the frame path for a live stroke, completed in full in the background),
the background builds while the user orbits (``prefetch``), the per-vertex transfer of the edited
object, and the fit itself (``fit_if_needed``).

Cost per message is bounded: a fit holds at most Fitter.max_rows rows (fit/fitter.py), and what a
stroke in a new view needs (the view's transfer rows, the per-vertex transfer of the edited
object) is built in the background while the user is still orbiting (``prefetch``), so the
first stroke after a camera or light change does not pay for it on the frame path.

``FitDriver`` is a part of SessionRuntime (worker/jobs/runtime.py), which owns the state it
reads: ``state``, ``renderer``, ``_drag``, ``closed`` and ``wake``.
"""
from __future__ import annotations

import copy
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from ..errors import GlintError
from ..fit.brush import Stroke
from ..fit.fitter import QUICK_ROWS, FitError, Fitter, painted_select, quick_select
from ..fit.guidance import SHORT
from ..protocol import CurveEvent, FitEvent, NoteEvent, StrokeEvent
from ..renderers.base import Lighting
from ..scene import SRBF, Camera
from .curves import _dump, brdf_curve
from .lod import STILL_ANTIALIAS, STILL_SAMPLES, busy_sessions
from .reporting import _msg

QUICK_ROWS_MIN = 100        # a quick view's unpainted rows under load (QUICK_ROWS / busy sessions)
# what a stroke in the current view will need is built once the view (camera and light) has
# stayed this long: views that change every frame (an orbit without the drag flag) built none
# of it, but each build took a core from the frames (orbit at full quality: ~9 fps on 2 cores)
# while the next message made it useless; below the still frame's wait (session_thread
# STILL_DELAY_S), so the build starts with the settled frame
VIEW_SETTLE_S = 0.1
# a quick view's full build is tried this many times (a failure may be passing: the renderer
# replaced mid-build); then the quick view stays and the session settles on it
BUILD_TRIES = 2
# the per-vertex transfer of a view is built once this many active strokes were painted in it
VT_AFTER_STROKES = 2
# how much lower the background builder's threads run than the session threads (nice levels)
BUILDER_NICE = 10
# a region stroke is fitted in one part on the path to its frame; when that reaches less than
# SHORT of the change, the same strokes are fitted in parts (fit/regions.py, "auto") in the
# background after the frame, and a fit that gains PARTS_GAIN replaces it with a frame of its own
PARTS_GAIN = 0.02


def _lower_priority() -> None:
    """The background builder's thread runs BUILDER_NICE levels below the process (Linux: a
    thread's own nice value; the OpenMP threads its kernels start inherit it), so a per-vertex
    transfer being built (about a second of a core) takes the cores only when strokes and frames
    leave them: before, the strokes painted while it was built waited behind it (stroke → frame
    p95 147 ms on an idle machine against ~50 ms once it was there)."""
    import os

    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, min(19, os.getpriority(os.PRIO_PROCESS, tid) + BUILDER_NICE))
    except (AttributeError, OSError):        # not Linux, or not allowed: it runs as before
        pass


# one background builder per worker process: views are prepared one at a time, at low priority
_builder = ThreadPoolExecutor(max_workers=1, thread_name_prefix="glint-prefetch", initializer=_lower_priority)


class FitDriver:
    """The fit of one session's edited object (a mixin of SessionRuntime)."""

    def _init_fit(self) -> None:
        self.fitter: Fitter | None = None
        self._needs_fit = False
        self._fitted = None       # the material the fitter produced last (identity)
        self._curve_pending = None  # (object, material) whose curve event follows the next frame
        self._quick_next = False  # the next frame shows a new fit: one sample first
        self._vt = None           # per-vertex transfer of the edited object: (key, ids, T, E)
        self._pending: dict = {}  # prefetch futures by what they build
        self._completions: dict = {}   # view index -> (fitter, moves, future of its full build)
        self.quick_rows = QUICK_ROWS
        # movable objects (cut fields): the renderer answers the fitter where they now stand;
        # fit views are valid for the placement they were built in (counted by moves)
        self._moves = 0
        self._view_moves: dict[int, int] = {}
        # (view index, moves) -> failed full builds; after BUILD_TRIES the quick view is kept
        self._build_failures: dict[tuple[int, int], int] = {}
        self._view_changed_at = -1e9    # time.monotonic() of the last camera or light change
        self._fit_serial = 0            # counts fits: a background result of an older one is dropped
        self._parts_pending = None      # (key, fit, kwargs, one-part outcome) to refit in parts
        self._parts_future = None       # (key, one-part achieved, future of the parts fit)

    def _drop_fit_work(self) -> None:
        """Queued and finished background builds no longer apply (a new placement, epoch or renderer)."""
        self._pending.clear()
        self._completions.clear()
        self._parts_pending = self._parts_future = None

    def _ensure_fitter(self) -> Fitter:
        if self.fitter is None:
            self._view_moves = {}
            self._build_failures = {}
            try:
                # a region's strokes fit over the region's own rows (fit/regions.py): the views
                # need no transfer rows of the whole object
                self.fitter = Fitter(self.renderer, self.state.object, base_material=self.state.base_material,
                                     fit_scale=self.renderer.stroke_fit_scale,
                                     transfer_rows=self.state.region is None)
            except FitError as e:
                raise FitError(f"strokes cannot apply: {e}") from None
        return self.fitter

    def _view_key(self, camera, rot, inten):
        return (camera.model_dump_json(), float(rot), float(inten))

    def _view_index(self, camera: Camera, rot: float, inten: float, stroke: dict | None = None) -> int:
        """The saved fit view of a camera and light, built if needed. For a live stroke
        (``stroke`` given) a view not built yet is a quick one (fit/fitter.py QUICK_ROWS): the
        stroke's pixels and a sparse grid of the rest, on the drag level's cuts (half the
        transfer's cost), built in full in the background once the user stops dragging
        (``_complete``); a partial view is extended under each new stroke, so painted pixels
        are always fitted. Replayed strokes get full views."""
        fx = self._ensure_fitter()
        sel = None if stroke is None else Stroke.model_validate({**stroke, "view": 0})
        for i, v in enumerate(fx.views):
            if v.camera == camera and v.rotation_deg == rot and v.intensity == inten and \
                    self._view_moves.get(i, 0) == self._moves:
                if v.partial and sel is not None:
                    fx.extend_view(v, painted_select(sel))
                if sel is not None:                # a new stroke tries a failed full build again
                    self._build_failures.pop((i, self._moves), None)
                return i
        key = ("view", self.state.epoch, self._moves, self._view_key(camera, rot, inten))
        fut = self._pending.pop(key, None)
        if fut is not None and not fut.cancelled() and (fut.done() or sel is None):
            view = fut.result()           # prepared while the user orbited
            if isinstance(view, Exception):
                raise view
            fut = None
        elif sel is not None:
            # under load the quick view shares the worker too: fewer rows, the rest comes with
            # the completion (tests/fit: a few % from the full fit at 300 rows on the bunny)
            rows = max(min(self.quick_rows, QUICK_ROWS_MIN), self.quick_rows // busy_sessions(time.monotonic()))
            view = fx.build_view(camera, rot, inten, select=quick_select(sel, rows), coarse=True)
        else:
            view = fx.build_view(camera, rot, inten)
        fx.views.append(view)
        i = len(fx.views) - 1
        self._view_moves[i] = self._moves
        if view.provisional:
            if fut is not None and not fut.cancelled():
                self._adopt(i, fut)       # the full view already on its way completes it
            elif not self._drag:
                self._complete(i)
        return i

    def _complete(self, i: int) -> None:
        """Build view i in full on the background builder; it replaces the provisional (partial
        or coarse) view when it is ready (``absorb``)."""
        fx, moves, _ = self._completions.get(i, (None, None, None))
        if fx is self.fitter and moves == self._moves:
            return                          # on its way
        v = self.fitter.views[i]
        self._adopt(i, self._submit(self._build_view, self.fitter, v.camera, v.rotation_deg, v.intensity))

    def fit_pending(self) -> bool:
        """Whether a refit of the current strokes is still to come: a quick view whose full build
        (``_complete``) replaces it and re-runs the fit, so the material and the frame will change
        without a message (a frame before it is not the settled one)."""
        fx = self.fitter
        if fx is None or len(fx.history) == 0 or self.state.readonly:
            return False
        return self._needs_fit or any(self._to_complete(i, v) for i, v in enumerate(fx.views))

    def _to_complete(self, i: int, v) -> bool:
        """Whether view i (v) is a quick one whose full build is still to come: of this placement,
        and not given up (its full build failed BUILD_TRIES times; the quick view stays)."""
        return (v.provisional and self._view_moves.get(i, 0) == self._moves
                and self._build_failures.get((i, self._moves), 0) < BUILD_TRIES)

    def _adopt(self, i: int, fut: Future) -> None:
        self._completions[i] = (self.fitter, self._moves, fut)
        fut.add_done_callback(lambda _f: self.wake())

    def absorb(self) -> bool:
        """Background results the session can take now: completed views replace their
        provisional ones (the fit is re-run). Returns whether anything changed. Runs on the session's thread."""
        changed = False
        for i, (fx, moves, fut) in list(self._completions.items()):
            if not fut.done():
                continue
            del self._completions[i]
            view = None if fut.cancelled() else fut.result()
            if fx is not self.fitter or moves != self._moves:
                continue
            if isinstance(view, Exception) or view is None:
                # tried again by the next prefetch; after BUILD_TRIES the quick view stays, said
                # once, and the session settles on it (it waited for the build before, every
                # frame unsettled, and rebuilt the failing view whenever it was idle)
                n = self._build_failures[(i, moves)] = self._build_failures.get((i, moves), 0) + 1
                if n == BUILD_TRIES:
                    why = "cancelled" if view is None else _msg(view)
                    self.events.append(NoteEvent(message=(
                        f"the full fit view could not be built ({why}): the strokes stay fitted on their "
                        "quick view (fewer pixels) until the next stroke in this view")).model_dump())
                    changed = True        # the next frame is the settled one
                continue
            if i < len(fx.views) and fx.views[i].provisional:
                fx.views[i] = view
                self._needs_fit = bool(len(fx.history))
                changed = True
        return self._absorb_parts() or changed

    def _parts_key(self) -> tuple:
        """What a region fit in parts answers: the fit it refines, its region, base and fitter."""
        return (self._fit_serial, self.state.region, id(self.state.base_material), id(self.fitter), self.state.epoch)

    def _start_parts(self) -> None:
        """After a region stroke's frame: fit the same strokes in parts in the background (a copy
        of the fitter's strokes and views, so strokes arriving meanwhile do not change what it
        reads), once no view of theirs is still being completed (that refits in one part) and
        the user is not dragging (the builder would take a core from the drag's frames)."""
        pend = self._parts_pending
        if pend is None or self.fit_pending() or self.closed or self._drag:
            return
        self._parts_pending = None
        key, fit, kwargs, one = pend
        if key != self._parts_key():
            return
        fx = copy.copy(self.fitter)
        fx.views = list(self.fitter.views)
        fx.history = type(self.fitter.history)(self.fitter.history.strokes)

        def run():
            try:
                return fit(fx, parts="auto", **kwargs)
            except Exception as e:             # the one-part fit stays
                return e
        fut = self._submit(run)
        self._parts_future = (key, one.achieved, fut)
        fut.add_done_callback(lambda _f: self.wake())

    def _absorb_parts(self) -> bool:
        """A finished region fit in parts replaces the one-part fit it refines when that is still
        the session's latest and the parts reach PARTS_GAIN more of the change: the material
        is set and a fit event says so (its frame follows); otherwise a note says what became of
        the fit the studio was told would follow. Returns whether there is an event to send."""
        pf = self._parts_future
        if pf is None or not pf[2].done():
            return False
        self._parts_future = None
        key, before, fut = pf
        out = None if fut.cancelled() else fut.result()
        if key != self._parts_key():
            return False                   # a newer fit's event has replaced the studio's status
        if not hasattr(out, "achieved") or out.achieved is None or out.parts < 2 or \
                out.achieved < (before or 0.0) + PARTS_GAIN:
            # the studio said a fit in parts would follow: say what became of it
            if isinstance(out, Exception):
                why = f"the fit in parts failed ({_msg(out)})"
            elif out is None or getattr(out, "achieved", None) is None:
                why = "the fit in parts did not finish"
            elif out.parts < 2:
                why = f"more parts reach no more of the change than one BRDF ({(before or 0.0) * 100:.0f}%)"
            else:
                why = (f"in {out.parts} parts the region reaches {out.achieved * 100:.0f}% of the change, "
                       f"with one BRDF {(before or 0.0) * 100:.0f}%")
            self.events.append(NoteEvent(message=f"{why}: the region stays in one part").model_dump())
            return True                    # a step sends it (its frame is the settled one again)
        st = self.state
        self._set_material(st.object_index, out.material)
        self._fitted = out.material
        self._quick_next = False
        self._curve_later(st.object, out.material)
        self.events.append(FitEvent(object=st.object, material=_dump(out.material),
                                    stats=self._region_stats(out, refined=True),
                                    notes=out.notes).model_dump(exclude_none=True))
        return True

    def _add_stroke(self, rec: dict, live: bool = False) -> StrokeEvent:
        """Add a stored or new (``live``) stroke record; a stroke that cannot apply is rejected
        (reported, not raised: the session goes on, and the server stops replaying it)."""
        seq = rec.get("seq")
        try:
            cam = Camera.model_validate(rec["camera"])
            i = self._view_index(cam, float(rec["rotation_deg"]), float(rec["intensity"]),
                                 rec["stroke"] if live else None)
            st = Stroke.model_validate({**rec["stroke"], "view": i})
            notes = self.fitter.add_stroke(st)
            return StrokeEvent(seq=seq, strokes=len(self.fitter.history), notes=notes)
        except (GlintError, ValueError, KeyError, TypeError) as e:
            n = len(self.fitter.history) if self.fitter is not None else 0
            return StrokeEvent(seq=seq, strokes=n, rejected=True, notes=[f"stroke rejected: {_msg(e)}"])

    def fit_if_needed(self) -> list[dict]:
        self.replay_stored()
        if not self._needs_fit:
            return []
        self._needs_fit = False
        self._fit_serial += 1
        self._parts_pending = self._parts_future = None
        fx = self.fitter
        i = self.state.object_index
        if fx is None or len(fx.history) == 0:
            self._set_material(i, self.state.base_material)
            self._curve_later(self.state.object, self.state.base_material)
            return [FitEvent(object=self.state.object, material=_dump(self.state.base_material),
                             stats={"strokes": 0}).model_dump(exclude_none=True)]
        if self.state.region is not None:
            return self._fit_region()
        out = fx.fit(constrained=self.state.constrained, unpainted_weight=self.state.unpainted_weight)
        self._set_material(i, out.material)
        self._fitted = out.material
        self._quick_next = True
        s = out.solve
        bound = np.asarray(s.energy_bound, np.float64)
        stats = {"strokes": len(fx.history), "pixels": out.pixels, "painted": out.painted,
                 "views": len(fx.views), "rows_stride": fx.row_stride(),
                 "ms_solve": s.seconds * 1e3, "ms_transfer": out.seconds_transfer * 1e3,
                 "residual_rel": s.residual_rel, "energy_max": s.energy_max,
                 "energy_bound": float(bound.min()), "constrained": s.constrained, "steps": out.steps}
        if out.gap is not None:
            stats["gap"] = out.gap           # GI: the expansion's last gap to the exact radiance
        for k in ("achieved", "spill", "energy_per_channel"):
            if getattr(out, k, None) is not None:
                stats[k] = getattr(out, k)
        stats.setdefault("energy_bound_per_channel", bound.tolist())
        self._curve_later(self.state.object, out.material)
        self._guidance_later(out.achieved, spill=out.spill)
        return [FitEvent(object=self.state.object, material=_dump(out.material), stats=stats,
                         notes=out.notes).model_dump(exclude_none=True)]

    def _curve_later(self, name: str, material) -> None:
        """The studio's curve of a fitted material comes as a curve event after the fit's frame
        (``after_frame``): evaluating it (the srbf's p(h) over the plot's directions and its lobe)
        cost about as much as the fit itself, on the path from stroke to frame."""
        self._curve_pending = (name, material)

    def _guidance_later(self, achieved: float | None, guidance: dict | None = None, measure: bool = True,
                        spill: float | None = None) -> None:
        """A stroke fit that fell short gets a guidance event after its frame (fit/guidance.py):
        for a highlight, what the light around the mirror directions can give and the rotation
        that gives most, measured there, off the path from stroke to frame (``measure``: the
        one-BRDF fit), or given (``guidance``: the region fit's, measured with its notes); for
        any other one-BRDF stroke, and under GI, what the one BRDF reached and spread
        (``spill``) and a painted region on offer."""
        short = achieved is not None and achieved < SHORT and (measure or guidance is not None)
        self._guidance_pending = ((self.state.object, achieved, guidance, self.state.region is None, spill)
                                  if short else None)

    def after_frame(self) -> list[dict]:
        """Events that wait for the frame they follow (a fit's curve event; its guidance event),
        and a region fit in parts started (``_start_parts``)."""
        self._start_parts()
        out = []
        if getattr(self, "_curve_pending", None) is not None:
            name, m = self._curve_pending
            self._curve_pending = None
            out.append(CurveEvent(object=name, curve=brdf_curve(m)).model_dump())
        if getattr(self, "_guidance_pending", None) is not None:
            from ..fit.guidance import guidance_event, stroke_guidance

            obj, achieved, g, one_brdf, spill = self._guidance_pending
            self._guidance_pending = None
            fx = self.fitter
            if g is None and fx is not None and obj == self.state.object:
                targets, _ = fx.targets()
                g = stroke_guidance(fx, [(v.base, t, p) for v, (t, p) in zip(fx.views, targets)])
            ev = guidance_event(obj, g, achieved, one_brdf, rotate=self.state.allows("light"), spill=spill)
            if ev is not None:
                out.append(ev)
        return out

    def _fit_region(self) -> list[dict]:
        """The strokes make or extend the state's region (fit/regions.py): one part, so a stroke's
        frame does not wait for a stacked solve; the rest of the object keeps its material. A fit
        short of the change is fitted again in parts after the frame (``_start_parts``)."""
        from ..fit.regions import fit_region, fit_region_gi

        fx, st = self.fitter, self.state
        fit = fit_region_gi if self.renderer.can("polynomial_transfer") else fit_region
        kwargs = {"name": st.region, "unpainted_weight": st.unpainted_weight, "constrained": st.constrained}
        out = fit(fx, **kwargs)
        self._set_material(st.object_index, out.material)
        self._fitted = out.material
        self._quick_next = True
        self._curve_later(st.object, out.material)
        self._guidance_later(out.achieved, out.guidance, measure=False)
        traced = getattr(self.renderer, "region_traced", None)
        if out.achieved is not None and out.achieved < SHORT and not (traced and traced(st.object_index, st.region)):
            self._parts_pending = (self._parts_key(), fit, kwargs, out)
        return [FitEvent(object=st.object, material=_dump(out.material), stats=self._region_stats(out),
                         notes=out.notes).model_dump(exclude_none=True)]

    def _region_stats(self, out, refined: bool = False) -> dict:
        """A region fit's stats for its fit event (``parts_later``: a fit in parts will follow;
        ``refined``: this is that fit)."""
        from ..models.regions import region_names

        fx, st, s = self.fitter, self.state, out.solve
        return {"strokes": len(fx.history), "pixels": out.pixels, "painted": out.painted, "views": len(fx.views),
                "ms_solve": s.seconds * 1e3, "ms_transfer": out.seconds_transfer * 1e3,
                "residual_rel": s.residual_rel, "energy_max": s.energy_max, "constrained": s.constrained,
                "achieved": out.achieved, "spill": out.spill, "spill_far": out.spill_far,
                "regions": region_names(out.material), "painting": st.region, "region": out.report(),
                "parts": out.parts, "parts_later": self._parts_pending is not None and not refined,
                "refined_in_parts": refined}

    # -- background work ----------------------------------------------------------------------------
    def prefetch(self) -> float:
        """When the session is idle and the user is not dragging: build the quick fit
        views in full (strokes painted mid-drag got them), and prepare what a stroke in the
        current view and light will need (its fit view; the per-vertex transfer of the edited
        object once the user paints a second time in one view), on the process's background
        builder. Only for sessions that paint (a fitter exists in this epoch); the current view's
        builds only once it has stayed VIEW_SETTLE_S. Returns the seconds until it will have
        (0.0: nothing put off), after which the session calls this again if still idle."""
        if not self._drag and not self.state.readonly:
            self.replay_stored()          # an idle session's stored strokes, if no message came
        if self.fitter is None or self._drag or self.state.readonly:
            return 0.0
        cam, rot, inten = self.state.camera, self.state.rotation_deg, self.state.intensity
        fx = self.fitter
        for i, v in enumerate(fx.views):
            if self._to_complete(i, v):
                self._complete(i)
        wait = VIEW_SETTLE_S - (time.monotonic() - self._view_changed_at)
        if wait > 0:
            return wait
        if not any(v.camera == cam and v.rotation_deg == rot and v.intensity == inten and
                   self._view_moves.get(i, 0) == self._moves for i, v in enumerate(fx.views)):
            key = ("view", self.state.epoch, self._moves, self._view_key(cam, rot, inten))
            if key not in self._pending:
                for k in [k for k in self._pending if k[0] == "view"]:
                    self._pending[k].cancel()           # only the latest view is worth building
                    del self._pending[k]
                self._pending[key] = self._submit(self._build_view, fx, cam, rot, inten)
        vkey = ("vt", self._view_key(cam, rot, inten))
        if self._vt_wanted() and (self._vt is None or self._vt[0] != vkey[1]) and vkey not in self._pending:
            for k in [k for k in self._pending if k[0] == "vt"]:
                self._pending[k].cancel()
                del self._pending[k]
            self._pending[vkey] = self._submit(self._build_vertex_transfer, cam, rot, inten)
            self._pending[vkey].add_done_callback(lambda _f: self.wake())
        return 0.0

    def _submit(self, fn, *args) -> Future:
        """Queue background work on the process's builder; work of a session closed before it
        starts is not done (``close``)."""
        def run():
            if self.closed:
                return RuntimeError("the session was closed")
            return fn(*args)
        return _builder.submit(run)

    def _vt_wanted(self) -> bool:
        """Whether the per-vertex transfer of this view is worth its cost (about a second of
        one core, ~50 ms saved per stroke frame): once VT_AFTER_STROKES active strokes were
        painted in it."""
        st, fx = self.state, self.fitter
        n = 0
        for s in fx.history.strokes:
            v = fx.views[s.view]
            n += v.camera == st.camera and v.rotation_deg == st.rotation_deg and v.intensity == st.intensity
        return n >= VT_AFTER_STROKES

    @staticmethod
    def _build_view(fx: Fitter, cam, rot, inten):
        try:
            return fx.build_view(cam, rot, inten)
        except Exception as e:               # reported when a stroke needs the view
            return e

    def _build_vertex_transfer(self, cam, rot, inten):
        """Per-vertex transfer of the edited object's visible vertices for a view and light
        (inverse-brdf-modeling eq. 22 with the basis): while only the fitted coefficients change
        (strokes, undo, redo), a frame's shading of that object is one mat-vec."""
        r = self.renderer
        smp = r.vertex_samples(cam, self.state.object_index, samples=STILL_SAMPLES,     # stroke frames are still
                               antialias=STILL_ANTIALIAS)
        T, E = r.transfer(smp, self.fitter.basis, Lighting(rot, inten))
        return (self._view_key(cam, rot, inten), smp.pix, T, E)

    def _vertex_transfer(self):
        """The per-vertex transfer of the current view and light if it is ready, else None:
        a frame never waits for it (it is built in the background, ``prefetch``)."""
        key = self._view_key(self.state.camera, self.state.rotation_deg, self.state.intensity)
        if self._vt is not None and self._vt[0] == key:
            return self._vt
        fut = self._pending.get(("vt", key))
        if fut is not None and fut.done():
            del self._pending[("vt", key)]
            if not fut.cancelled() and fut.exception() is None:
                self._vt = fut.result()
                return self._vt
        return None

    def _override(self):
        """Known radiance of the edited object's vertices when its material is the current fit:
        {object index: (ids, radiance)} for the renderer, or None."""
        i = self.state.object_index
        if self._fitted is None or self.materials[i] is not self._fitted or not self.renderer.can("vertex_transfer"):
            return None
        if not isinstance(self._fitted, SRBF):      # a material with regions: the renderer blends its layers
            return None
        vt = self._vertex_transfer()
        if vt is None:
            return None
        _, ids, T, E = vt
        c = np.asarray(self._fitted.coefficients, np.float32)
        rad = np.asarray(self._fitted.albedo, np.float32) * E + np.stack([T[k] @ c[:, k] for k in range(3)], axis=1)
        return {i: (ids, rad.astype(np.float32))}
