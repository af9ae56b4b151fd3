"""One interactive design session inside a worker process: its state (jobs/state.py), the
scene's renderer, and the paint-to-BRDF fitter of the edited object.

The runtime is rebuilt exactly from what the server stored (state + stroke rows), so a worker
that dies loses nothing: ``SessionRuntime(...)`` on a new worker gives the same frames. It never
fails to open because of what was stored: a stroke that cannot apply is reported as rejected
(the server stops replaying it), a stored value that no longer validates falls back with a note.

Messages go through ``state.apply`` (the same function the server persisted them with); the
runtime then carries out the effect. A message whose seq the restored state already covers is
skipped (it was persisted before the restore read the state).

Cost per message is bounded: a fit holds at most Fitter.max_rows rows (fit/fitter.py), and what a
stroke in a new view needs (the view's transfer rows, the per-vertex transfer of the edited
object) is built in the background while the user is still orbiting (``prefetch``), so the
first stroke after a camera or light change does not pay for it on the frame path.
"""
from __future__ import annotations

import io
import json
import statistics
import threading
import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np
from PIL import Image

from ..core.tonemap import tonemap
from ..memory import trim_malloc
from ..errors import GlintError
from ..fit.brush import Stroke
from ..fit.fitter import QUICK_ROWS, FitError, Fitter, painted_select, quick_select
from ..models import SRBF
from ..renderers.base import FrameRequest, Lighting
from ..scene import Camera
from .state import (ErrorEvent, FitEvent, NoteEvent, RendererEvent, SaveRequest, StateError, StrokeEvent, apply,
                    client_msg, restore_state)

CURVE_SAMPLES = 91
FRAME_BUDGET_MS = 33.0     # a frame while the user drags: 30 fps
STILL_SAMPLES = 4          # anti-aliasing samples per pixel of a still frame
REPROBE_S = 2.0            # while at the drag level of detail, try a full frame this often
# a frame of at least this many pixels gives its transient memory back at once (trim_malloc),
# and a closed session's cached primary hits of such a camera are dropped (``close``): at
# ~410 bytes a pixel (server/routes/sessions.py FRAME_BYTES_PER_PIXEL) that is ~400 MB and up
BIG_FRAME_PIXELS = 1024 * 1024
# one background builder per worker process: views are prepared one at a time, at low priority
_builder = ThreadPoolExecutor(max_workers=1, thread_name_prefix="glint-prefetch")


def brdf_curve(material, n: int = CURVE_SAMPLES) -> dict:
    """The 1D half-angle distribution to plot: p(θh) averaged over φh for srbf, the curve's
    values for curve, and f(θh) in the plane of incidence at normal viewing otherwise.
    Returns {"theta_deg": [...], "values": [[r, g, b], ...], "quantity": str}."""
    from ..core.brdf import evaluate, srbf_material_p

    th = np.linspace(0.0, 90.0, n)
    t = np.radians(th)
    if isinstance(material, SRBF):
        ph = np.linspace(0, 2 * np.pi, 48, endpoint=False)
        T, P = np.meshgrid(t, ph, indexing="ij")
        h = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
        vals = srbf_material_p(material, h).mean(axis=1)       # every centre with its own λ
        q = "p(θh), mean over φh"
    else:
        # ωo = normal, ωi at 2θh in the x-z plane, so θh is the half angle
        wo = np.broadcast_to([0.0, 0.0, 1.0], (n, 3))
        wi = np.stack([np.sin(2 * t), np.zeros(n), np.cos(2 * t)], -1)
        vals = evaluate(material, wi, wo)       # zero past θh = 45°, where ωi is below the horizon
        q = "f(ωi, ωo = n), θh = θi / 2"
    return {"theta_deg": th.round(3).tolist(), "values": np.asarray(vals, np.float64).round(6).tolist(), "quantity": q}


def _dump(m) -> dict:
    return json.loads(m.model_dump_json())


QUICK_ROWS_MIN = 100        # a quick view's unpainted rows under load (QUICK_ROWS / busy sessions)
DRAG_SCALES = (2, 4)        # drag level of detail: half the resolution, a quarter under load
ACTIVE_S = 1.0              # a session that moved something this recently shares the worker
_active: dict[int, float] = {}          # id(runtime) -> time.monotonic() of its last move (this process)
_active_lock = threading.Lock()


def busy_sessions(now: float) -> int:
    """Sessions of this worker process that moved a camera, light or object in the last
    ACTIVE_S (at least 1): they share its core."""
    with _active_lock:
        for k in [k for k, t in _active.items() if now - t > ACTIVE_S]:
            del _active[k]
        return max(1, len(_active))


def _reprobe(est: float, budget: float) -> float:
    """Seconds between tries of a level that cost ``est`` ms against a ``budget``: REPROBE_S,
    longer the further over budget it was (a full frame at 12× a loaded worker's share is tried
    every 24 s, not every 2 s: each try costs the other sessions their frames)."""
    return REPROBE_S * max(1.0, est / max(budget, 1e-9))


def _estimate(hist) -> float:
    # the latest measurement can lower the estimate at once (a probe on a quieter machine),
    # one slow frame among fast ones cannot raise it
    return min(statistics.median(hist), hist[-1])


class SessionRuntime:
    """scene : LoadedScene; renderer : its Renderer; stored : {"state": dict, "strokes": [{"seq",
    "stroke", "camera", "rotation_deg", "intensity", "undone"}, …]} in painting order, rejected
    strokes left out (server/state.py session_payload); env_loader : EnvPreset -> (H, W, 3) map."""

    def __init__(self, scene, renderer, stored: dict, env_loader=None, renderer_for=None):
        self.scene = scene
        self.env_loader = env_loader
        self.renderer_for = renderer_for          # kind -> a renderer of this scene (another kind)
        self.state, notes = restore_state(stored.get("state") or {}, scene.spec)
        self.renderers = {renderer.kind: renderer}
        self.renderer = renderer
        self.events: list[dict] = [NoteEvent(message=n).model_dump() for n in notes]
        # re-opened on a new worker after one died (server/workers.py _restore): the refit of
        # the stored strokes is sent (a fit event) before the first frame, so the server stores
        # the material the strokes give, not the one it had before the crash
        self._restored = bool(stored.get("restored"))
        self.closed = False
        self.frame_no = 0
        self.fitter: Fitter | None = None
        self._needs_fit = False
        self._drag = False
        self._skipped = 0
        self._fitted = None       # the material the fitter produced last (identity)
        self._quick_next = False  # the next frame shows a new fit: one sample first
        self._vt = None           # per-vertex transfer of the edited object: (key, ids, T, E)
        self._pending: dict = {}  # prefetch futures by what they build
        self._completions: dict = {}   # view index -> (fitter, moves, future of its full build)
        self.wake = lambda: None  # called from the builder when a result is ready (SessionThread)
        self.quick_rows = QUICK_ROWS
        self._env_key = None
        # frame cost history for the level of detail: ms of full one-sample frames by what
        # changed since the frame before ("view": camera, "light": lighting, "other")
        self.frame_budget_ms = FRAME_BUDGET_MS
        self._full_ms = {k: deque(maxlen=3) for k in ("view", "light", "other")}
        self._last = None                      # (camera, rotation, intensity, dragging, samples) of the last frame
        self._last_full = 0.0                  # time.monotonic() of the last full frame
        self._drag_ms = {k: deque(maxlen=3) for k in DRAG_SCALES}   # ms of drag frames by scale
        self._last_half = 0.0                  # time.monotonic() of the last half-resolution drag frame
        self.drag_scale = DRAG_SCALES[0]
        # movable objects (cut fields): the renderer answers the fitter where they now stand;
        # fit views are valid for the placement they were built in (counted by moves)
        self._moves = 0
        self._view_moves: dict[int, int] = {}
        if hasattr(renderer, "place"):
            renderer.place(self.state.transforms or None)
        if self.state.renderer != renderer.kind:
            self._switch_renderer(self.state.renderer)
        self._apply_environment()
        # pay the basis's one-time costs (energy rows, solver import, the fitted material's
        # srbf table: ~190 ms the first time in a process, on issue 9's cold first strokes) at
        # open, not on the first stroke
        if not self.state.readonly:
            from ..fit import solve  # noqa: F401
            from ..fit.basis import default_basis, static_alpha_for
            b = default_basis(static_alpha=static_alpha_for(self.state.base_material))
            b.energy_rows()
            SRBF.model_validate(b.to_material(np.zeros((b.J, 3)), (0.0, 0.0, 0.0))).pack()
        if hasattr(renderer, "coarse_cuts"):
            renderer.coarse_cuts()           # the drag-time level of detail
        # replay the stored strokes (undone ones form the redo stack, most recent undone last)
        strokes = stored.get("strokes") or []
        active = [s for s in strokes if not s.get("undone")]
        undone = [s for s in strokes if s.get("undone")]
        kept_undone = 0
        for s in active + undone:
            ev = self._add_stroke(s)
            if ev.rejected:
                self.events.append(ev.model_dump())
            elif s.get("undone"):
                kept_undone += 1
        for _ in range(kept_undone):
            self.fitter.undo()
        self._needs_fit = bool(self.fitter is not None and len(self.fitter.history))
        # saves the server has not stored yet (the worker died before they were): run again
        self._resave = list(self.state.pending_saves)

    # -- the edited object ----------------------------------------------------------------------
    @property
    def names(self) -> list[str]:
        return self.state.objects

    @property
    def materials(self) -> list:
        return self.state.materials

    def _set_material(self, i: int, m) -> None:
        mats = list(self.state.materials)
        mats[i] = m
        self.state.materials = mats

    def _ensure_fitter(self) -> Fitter:
        if self.fitter is None:
            self._view_moves = {}
            try:
                self.fitter = Fitter(self.renderer, self.state.object, base_material=self.state.base_material,
                                     fit_scale=0.25)
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
            if fx is not self.fitter or moves != self._moves or isinstance(view, Exception) or view is None:
                continue
            if i < len(fx.views) and fx.views[i].provisional:
                fx.views[i] = view
                self._needs_fit = bool(len(fx.history))
                changed = True
        return changed

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

    def _switch_renderer(self, kind: str) -> None:
        if kind not in self.renderers:
            if self.renderer_for is None:
                raise FitError(f"this worker cannot switch to the {kind} renderer")
            self.renderers[kind] = self.renderer_for(kind)
        self.renderer = self.renderers[kind]
        if hasattr(self.renderer, "place"):       # movable objects where the session has them
            self.renderer.place(self.state.transforms or None)
        self.fitter = None                         # fit rows belong to a renderer
        self._vt = None
        self._pending.clear()
        self._completions.clear()
        self._env_key = ("switched",)            # the new renderer gets the session's map

    def _paint(self, name: str, seq) -> list[dict]:
        """The lobes material for the stored readings of an object (worker/paint/session.py)."""
        from ..paint.session import apply_paint

        mat, ev = apply_paint({**self.state.paint[name], "object": name, "seq": seq})
        i = self.state.objects.index(name)
        self._set_material(i, mat)
        if name == self.state.object:
            self.state.base_material = mat
            self.fitter = None
        return [ev]

    def _apply_environment(self) -> None:
        i = self.state.environment_index
        key = None if i is None else (i, self.state.environments[i].sha256)
        if key == self._env_key:
            return
        if not self.state.allows("environment"):
            self._env_key = key                   # a fixed-light renderer keeps its precomputed map
            return
        if i is not None:
            if self.env_loader is None:
                raise FitError("environment presets need a worker that can load them")
            self.renderer.set_environment(self.env_loader(self.state.environments[i]))
        else:
            self.renderer.set_environment(self.scene.envmap)
        self._env_key = key
        self._vt = None

    # -- messages -----------------------------------------------------------------------------------
    def handle(self, raw: dict) -> list[dict]:
        """Apply one client message (a dict as the client sent it); returns events."""
        msg = client_msg.validate_python(raw)
        if msg.seq <= self.state.last_seq:
            return []                      # already in the restored state
        before = self.state
        self.state, eff = apply(before, msg)
        ev: list[dict] = []
        if msg.type in ("view", "light", "move"):
            self._drag = eff.drag
            with _active_lock:
                _active[id(self)] = time.monotonic()
        if eff.kind == "move":             # views and the vertex transfer were of the old placement
            if hasattr(self.renderer, "place"):
                self.renderer.place(self.state.transforms or None)
            self._moves += 1
            self._vt = None
            self._pending.clear()
            self._completions.clear()
        if eff.kind == "rebase":
            self.fitter = None             # strokes painted over the old material do not carry over
            self._needs_fit = False
            self._pending.clear()
            self._completions.clear()
        if msg.type == "material":
            name = msg.object or self.state.object
            ev.append({"type": "curve", "seq": msg.seq, "object": name, "curve": brdf_curve(msg.material)})
        elif eff.kind == "stroke":
            se = self._add_stroke({**eff.stroke, "seq": msg.seq}, live=True)
            if not se.rejected:
                self._needs_fit = True
            ev.append(se.model_dump())
        elif eff.kind in ("undo", "redo"):
            fx = self.fitter
            if fx is not None and (fx.undo() if eff.kind == "undo" else fx.redo()) is not None:
                self._needs_fit = True
            else:
                ev.append(NoteEvent(seq=msg.seq, message=f"nothing to {eff.kind}").model_dump())
        elif eff.kind == "refit":
            self._needs_fit = True
        elif eff.kind == "save":
            ev += self.fit_if_needed()
            ev.append(self._save_request(eff.save))
        elif eff.kind == "renderer":
            from ..renderers import controls

            self._switch_renderer(self.state.renderer)
            self._apply_environment()
            ev.append(RendererEvent(seq=msg.seq, kind=self.state.renderer,
                                    controls=sorted(controls(self.state.renderer))).model_dump())
        elif eff.kind == "paint":
            ev += self._paint(eff.data["object"], msg.seq)
        if self.state.environment_index != before.environment_index:
            self._apply_environment()
        return ev

    def _save_request(self, p) -> dict:
        mat = self.state.material_of(self.state.object)
        return SaveRequest(seq=p.seq, object=self.state.object, name=p.name, material_id=p.material_id,
                           material=_dump(mat)).model_dump()

    def take_events(self) -> list[dict]:
        """Events produced outside a message (restore notes, rejected replays, re-run saves)."""
        ev, self.events = self.events, []
        if self._restored:
            self._restored = False
            ev += self.fit_if_needed()
        if self._resave:
            ev += self.fit_if_needed()
            ev += [self._save_request(p) for p in self._resave]
            self._resave = []
        return ev

    def fit_if_needed(self) -> list[dict]:
        if not self._needs_fit:
            return []
        self._needs_fit = False
        fx = self.fitter
        i = self.state.object_index
        if fx is None or len(fx.history) == 0:
            self._set_material(i, self.state.base_material)
            return [FitEvent(object=self.state.object, material=_dump(self.state.base_material),
                             curve=brdf_curve(self.state.base_material), stats={"strokes": 0}).model_dump()]
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
                 "energy_bound": float(bound.min()), "constrained": s.constrained}
        for k in ("achieved", "spill", "energy_per_channel"):
            if getattr(out, k, None) is not None:
                stats[k] = getattr(out, k)
        stats.setdefault("energy_bound_per_channel", bound.tolist())
        return [FitEvent(object=self.state.object, material=_dump(out.material), curve=brdf_curve(out.material),
                         stats=stats, notes=out.notes).model_dump()]

    # -- background work ----------------------------------------------------------------------------
    def prefetch(self) -> None:
        """When the session is idle and the user is not dragging: build the quick fit
        views in full (strokes painted mid-drag got them), and prepare what a stroke in the
        current view and light will need (its fit view; the per-vertex transfer of the edited
        object once the user paints a second time in one view), on the process's background
        builder. Only for sessions that paint (a fitter exists in this epoch)."""
        if self.fitter is None or self._drag or self.state.readonly:
            return
        cam, rot, inten = self.state.camera, self.state.rotation_deg, self.state.intensity
        fx = self.fitter
        for i, v in enumerate(fx.views):
            if v.provisional and self._view_moves.get(i, 0) == self._moves:
                self._complete(i)
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

    def _submit(self, fn, *args) -> Future:
        """Queue background work on the process's builder; work of a session closed before it
        starts is not done (``close``)."""
        def run():
            if self.closed:
                return RuntimeError("the session was closed")
            return fn(*args)
        return _builder.submit(run)

    def close(self) -> None:
        """The session ended: its queued background builds are cancelled (a running one ends
        with its current view; none starts after), and the renderer's cached primary hits of a
        big camera are dropped (a build under way holds the fitter, so the renderer, until it
        ends), so the worker goes back to resting memory (the caller then releases memory,
        worker.memory.release_memory). Before, after an 8192×8192 stream closed its prefetch
        kept both cores busy ~60 s and the worker stayed at 7 GB."""
        self.closed = True
        for fut in list(self._pending.values()) + [c[2] for c in self._completions.values()]:
            fut.cancel()
        self._pending.clear()
        self._completions.clear()
        self._vt = None
        self.fitter = None
        cam = self.state.camera
        if cam.width * cam.height >= BIG_FRAME_PIXELS:
            for r in self.renderers.values():
                if hasattr(r, "forget_views"):
                    r.forget_views(BIG_FRAME_PIXELS)

    def _vt_wanted(self) -> bool:
        """Whether the per-vertex transfer of this view is worth its cost (about a second of
        one core, ~50 ms saved per stroke frame): once two active strokes were painted in it."""
        st, fx = self.state, self.fitter
        n = 0
        for s in fx.history.strokes:
            v = fx.views[s.view]
            n += v.camera == st.camera and v.rotation_deg == st.rotation_deg and v.intensity == st.intensity
        return n >= 2

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
        smp = r.vertex_samples(cam, self.state.object_index, samples=STILL_SAMPLES)   # stroke frames are still
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
        if self._fitted is None or self.materials[i] is not self._fitted or not hasattr(self.renderer, "vertex_samples"):
            return None
        vt = self._vertex_transfer()
        if vt is None:
            return None
        _, ids, T, E = vt
        c = np.asarray(self._fitted.coefficients, np.float32)
        rad = np.asarray(self._fitted.albedo, np.float32) * E + np.stack([T[k] @ c[:, k] for k in range(3)], axis=1)
        return {i: (ids, rad.astype(np.float32))}

    # -- frames -----------------------------------------------------------------------------------
    def _change(self) -> str:
        """What changed since the last frame: "view" (the camera), "light", or "other"."""
        st, last = self.state, self._last
        if last is None or last[0] != st.camera:
            return "view"
        if (last[1], last[2]) != (st.rotation_deg, st.intensity):
            return "light"
        return "other"

    def level_of_detail(self) -> tuple[str, int]:
        """(lod, samples) of the next frame (issue 16). Outside a drag (the client did not flag its
        last view or light message ``drag``) frames are full quality, and anti-aliased with
        STILL_SAMPLES per pixel once the view has settled: the camera is where the last frame
        had it, or that frame was drawn during a drag (its end); a camera moving without drag
        flags gets one sample per frame (``needs_still_frame`` asks for the settled one after).
        While the user drags, frames are full quality (one sample) whenever the measured cost of
        recent full frames of the same kind of change (camera, light, other) fits the frame
        budget, and at the drag level of detail otherwise, with a full frame tried again every
        REPROBE_S (the machine's load changes).

        The budget is this session's share of its worker (issue 9): FRAME_BUDGET_MS divided by
        the sessions of this process that moved a camera, light or object in the last second.
        When even the drag level's half-resolution frames do not fit it, they are drawn at a
        quarter of the resolution (``drag_scale`` 4), tried at half again every REPROBE_S: under
        load every designer keeps a fluid, coarser image rather than a few sharp frames."""
        change = self._change()
        self.drag_scale = DRAG_SCALES[0]
        if not self._drag:
            settled = change != "view" or self._last is None or self._last[3]
            return "full", STILL_SAMPLES if settled else 1
        hist = self._full_ms[change] or self._full_ms["view"]
        if not hist:
            return "full", 1                                     # no measurement yet: measure one
        now = time.monotonic()
        budget = self.frame_budget_ms / busy_sessions(now)
        est = _estimate(hist)
        if est <= budget or now - self._last_full >= _reprobe(est, budget):
            return "full", 1
        half = self._drag_ms[DRAG_SCALES[0]]
        if half and _estimate(half) > budget and now - self._last_half < _reprobe(_estimate(half), budget):
            self.drag_scale = DRAG_SCALES[1]
        return "drag", 1

    def _still_view_ready(self, camera, samples: int) -> bool:
        has = getattr(self.renderer, "has_view", None)
        return has is None or has(camera, samples)

    def needs_still_frame(self) -> bool:
        """Whether the last frame was a moving one (one sample, or the drag level of detail) and
        the session is not dragging: when no message is waiting, one more frame (``frame``) is
        the settled, anti-aliased image of the same state."""
        return self._last is not None and not self._drag and self._last[4] < STILL_SAMPLES

    def frame(self, ack: int, skipped: int = 0, cancelled=None) -> tuple[dict, bytes]:
        """The current frame: (header (FrameHeader fields), JPEG bytes). cancelled : for a frame
        that may give way (renderers.base.FrameRequest.cancelled), a checkpoint that may block
        while strokes elsewhere go first (the header's ``ms_paused``, not counted in the frame's
        own times, which set the level of detail) and says when the frame is no longer wanted;
        the renderer may then raise renderers.base.FrameCancelled (nothing changes)."""
        t0 = time.perf_counter()
        paused = 0.0
        if cancelled is not None:
            checkpoint = cancelled

            def cancelled():
                nonlocal paused
                c0 = time.perf_counter()
                try:
                    return checkpoint()
                finally:
                    paused += time.perf_counter() - c0
        st = self.state
        change = self._change()
        lod, samples = self.level_of_detail()
        camera, lighting = st.camera, Lighting(st.rotation_deg, st.intensity)
        if not st.allows("camera"):          # a fixed-view renderer draws its own camera and light
            camera = self.scene.spec.camera
            lighting = Lighting(self.scene.spec.environment.rotation_deg, st.intensity)
        # progressive: a new fit, or a camera whose anti-aliased primary hits are not traced yet
        # (the user just let go), is shown at once with one sample; the anti-aliased frame
        # follows when the session is idle (needs_still_frame, the worker's loop), and that one
        # is not put off again
        follow_up = self._last is not None and self._last[0] == st.camera and not self._last[3] and \
            self._last[4] < STILL_SAMPLES
        if samples > 1 and (self._quick_next or (not follow_up and not self._still_view_ready(camera, samples))):
            lod, samples = "quick", 1
        self._quick_next = False
        req = FrameRequest(camera=camera, lighting=lighting, materials=st.materials, lod=lod, samples=samples,
                           drag_scale=self.drag_scale, cancelled=cancelled,
                           ground_shadow=st.shadow, transforms=st.transforms or None,
                           # the per-vertex transfer is per view: built for still views, not per drag frame
                           vertex_radiance=None if self._drag else self._override())
        out = self.renderer.render(req)
        rgb = tonemap(out.radiance, st.exposure, st.tone)
        t1 = time.perf_counter() - paused
        buf = io.BytesIO()
        # lower quality while the user drags (DESIGN.md §5), full quality when still
        Image.fromarray(rgb).save(buf, format="JPEG", quality=min(st.quality, 60) if self._drag else st.quality)
        t2 = time.perf_counter() - paused
        if lod == "drag":
            self._drag_ms[self.drag_scale].append((t2 - t0) * 1e3)
            if self.drag_scale == DRAG_SCALES[0]:
                self._last_half = time.monotonic()
        if lod == "full":
            self._last_full = time.monotonic()
            if samples == 1:
                self._full_ms[change].append((t2 - t0) * 1e3)
        # the samples asked for: a renderer without anti-aliasing (gi, paint, movable objects)
        # draws one, and must not be asked again and again for a still frame
        self._last = (st.camera, st.rotation_deg, st.intensity, self._drag, samples)
        self.frame_no += 1
        h, w = rgb.shape[:2]
        if w * h >= BIG_FRAME_PIXELS:
            # the frame's scratch (shading, tone mapping, JPEG) was freed into malloc's arenas
            trim_malloc()
        hdr = {"frame": self.frame_no, "ack": ack, "width": w, "height": h, "format": "jpeg",
               "ms_render": round((t1 - t0) * 1e3, 2), "lod": lod == "drag", "quick": lod == "quick", "samples": int(out.info.get("samples", 1)),
               "shadow": out.info.get("ground_shadow"), "ms_encode": round((t2 - t1) * 1e3, 2), "ms_paused": round(paused * 1e3, 2), "skipped": skipped}
        return hdr, buf.getvalue()


def _msg(e: Exception) -> str:
    from pydantic import ValidationError

    if isinstance(e, ValidationError):
        err = e.errors()[0]
        return f"{'.'.join(str(x) for x in err['loc'])}: {err['msg']}"
    return str(e)


def error_event(e: Exception, seq=None) -> dict:
    """An error event for an exception while handling a message: user errors say what was
    wrong; anything else is a bug, reported as such without a trace."""
    if isinstance(e, (GlintError, StateError, ValueError)):
        return ErrorEvent(seq=seq, message=_msg(e)).model_dump()
    return ErrorEvent(seq=seq, message=f"internal error ({type(e).__name__}): {e}").model_dump()
