"""One interactive design session inside a worker process: its state (worker/protocol), the
scene's renderer, the fit of the edited object (fit_driver.py), and the level of detail of its
frames (lod.py). ``SessionRuntime.handle`` applies a client message and carries out its effect
through ``EFFECTS``, one handler per effect class (worker/protocol/effects.py).

The runtime is rebuilt exactly from what the server stored (state + stroke rows), so a worker
that dies loses nothing: ``SessionRuntime(...)`` on a new worker gives the same frames. It never
fails to open because of what was stored: a stroke that cannot apply is reported as rejected
(the server stops replaying it), a stored value that no longer validates falls back with a note.

Messages go through ``protocol.apply`` (the same function the server persisted them with); the
runtime then carries out the effect. A message whose seq the restored state already covers is
skipped (it was persisted before the restore read the state).
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np

from ..fit.fitter import FitError
from ..models import SRBF
from ..models.base import parse_material
from ..models.regions import region_names
from ..protocol import (MAX_REGION_STEPS, ClientMsg, Convert, ConvertedEvent, CurveEvent, ExposureEvent, FitEvent,
                        FitPaint, Moved, NewMaterial, NoEffect, NoteEvent, ObjectEvent, Pick, PickedEvent, RecordStroke,
                        Redo, Refit, RegionsChanged, Relight, RendererEvent, Save, SaveRequest, SelectObject,
                        SwitchRenderer, Undo, apply, client_msg, restore_state)
from ..renderers.base import FrameRequest, Lighting
from . import compose
from .compose import BIG_FRAME_PIXELS
from .curves import _dump, brdf_curve
from .fit_driver import FitDriver
from .lod import STILL_ANTIALIAS, LevelOfDetail, mark_busy

MEASURE_WIDTH = 200     # pixels across of the frames a model conversion measures the object's colour in
# effect class -> handler(runtime, message, effect) -> events; filled by ``handles`` below
EFFECTS: dict[type, Callable[["SessionRuntime", ClientMsg, object], list[dict]]] = {}


def handles(effect_cls):
    """Decorator: the worker's handler of one effect class."""
    def register(fn):
        EFFECTS[effect_cls] = fn
        return fn
    return register


class SessionRuntime(FitDriver):
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
        self._settled = None             # (image key, header, JPEG) of the last settled frame
        self._drag = False
        self.wake = lambda: None  # called from the builder when a result is ready (SessionThread)
        self._env_key = None
        # region steps (_region_step): (object, material before, after, region before, after);
        # the server stores them as rows (sessions_store.py), so a reopened session has them
        self._region_undo: list[tuple] = []
        self._region_redo: list[tuple] = []
        self._restore_region_steps(stored.get("region_steps") or [])
        self.lod = LevelOfDetail()
        self._init_fit()
        if renderer.can("place"):
            renderer.place(self.state.transforms or None)
        if self.state.renderer != renderer.kind:
            self._switch_renderer(self.state.renderer)
        self._apply_environment()
        # pay the basis's one-time costs (energy rows, solver import, the fitted material's
        # srbf table: ~190 ms the first time in a process, on cold first strokes) at
        # open, not on the first stroke
        if not self.state.readonly:
            from ..fit import solve  # noqa: F401
            from ..fit.basis import default_basis, static_alpha_for
            b = default_basis(static_alpha=static_alpha_for(self.state.base_material))
            b.energy_rows()
            SRBF.model_validate(b.to_material(np.zeros((b.J, 3)), (0.0, 0.0, 0.0))).pack()
            if renderer.can("polynomial_transfer"):
                renderer.prepare_basis(b)
        if renderer.can("drag_level"):
            renderer.coarse_cuts()           # the drag-time level of detail
        if not self.state.readonly:
            self._make_live()
        self._last_ids = None            # the last frame's object ids (H, W) int32 (picking)
        # the stored strokes are replayed (each view's fit rows built: seconds at a studio
        # canvas's size) when the session first needs its fitter, not before its first frame:
        # the stored material already is their fit, so a reopened session shows it at once
        # (a reload waited 3-12 s on a blank canvas for one stroke)
        self._unreplayed: list[dict] | None = list(stored.get("strokes") or [])
        if self.state.auto_exposure and not self.state.readonly:
            self.events += self._auto_expose()
        # the curve of the edited object's material: the studio draws this, never its own BRDF
        if not self.state.readonly:
            m = self.state.material_of(self.state.object)
            self.events.append(CurveEvent(object=self.state.object, curve=brdf_curve(m)).model_dump())
        # saves the server has not stored yet (the worker died before they were): run again
        self._resave = list(self.state.pending_saves)

    def _restore_region_steps(self, rows: list[dict]) -> None:
        """The stacks of stored region steps (server/sessions_store.py region_steps, in order):
        those not undone to undo, the last on top; the undone ones to redo, the first on top."""
        def step(r):
            return (r["object"], parse_material(r["before"]), parse_material(r["after"]), r.get("region_before"),
                    r.get("region_after"))
        self._region_undo = [step(r) for r in rows if not r.get("undone")][-MAX_REGION_STEPS:]
        self._region_redo = [step(r) for r in reversed(rows) if r.get("undone")]

    def replay_stored(self) -> None:
        """Replay the stored strokes if they are not yet (__init__): before the first message,
        fit or background build, so every edit applies on top of them."""
        if self._unreplayed is not None:
            strokes, self._unreplayed = self._unreplayed, None
            self._replay(strokes)

    def _replay(self, strokes: list[dict]) -> None:
        """Replay stored stroke records of the edited object's epoch (undone ones form the redo
        stack, most recent undone last); rejected ones are reported."""
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

    def _switch_renderer(self, kind: str) -> None:
        if kind not in self.renderers:
            if self.renderer_for is None:
                raise FitError(f"this worker cannot switch to the {kind} renderer")
            self.renderers[kind] = self.renderer_for(kind)
        self.renderer = self.renderers[kind]
        if self.renderer.can("place"):       # movable objects where the session has them
            self.renderer.place(self.state.transforms or None)
        self.fitter = None                         # fit rows belong to a renderer
        self._vt = None
        self._pending.clear()
        self._completions.clear()
        self._env_key = ("switched",)            # the new renderer gets the session's map
        if not self.state.readonly:
            self._make_live()

    def _make_live(self) -> None:
        """A renderer that prepares per edited object (``live_object``: the GI one freezes the
        others) does it now, when the object is picked, not on its first edit."""
        if self.renderer.can("live_object") and not self.state.fixed(self.state.object):
            self.renderer.make_live(self.state.object_index, self.state.materials)

    def _paint(self, name: str, seq) -> list[dict]:
        """The lobes material for the stored readings of an object (worker/paint/session.py)."""
        from ..paint.session import apply_paint

        mat, ev = apply_paint({**self.state.paint[name], "object": name, "seq": seq})
        i = self.state.objects.index(name)
        self._set_material(i, mat)
        if name == self.state.object:
            self.state.base_material = mat
            self.fitter = None
        return [ev, CurveEvent(seq=seq, object=name, curve=brdf_curve(mat)).model_dump()]

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
        before = (self.state.camera, self.state.rotation_deg, self.state.intensity)
        self.state, eff = apply(self.state, msg)
        if isinstance(eff, SelectObject):
            self._unreplayed = None        # the object left: its strokes come back when it is picked again
        else:
            self.replay_stored()           # before the effect: an undo undoes a stored stroke
        if (self.state.camera, self.state.rotation_deg, self.state.intensity) != before:
            self._view_changed_at = time.monotonic()
        if msg.drags:
            self._drag = msg.drag
            mark_busy(id(self))
        # the answer to a message is drawn with one sample and interpolated; its settled, refined
        # frame follows when the session is idle and gives way to the next message
        # (session_thread ``_settle``). Refined at four samples, a sharp paint on the test bunny
        # took 31 CPU s at 640×480, and a save's frame of the same image held the next edit back
        self._quick_next = True
        return EFFECTS[type(eff)](self, msg, eff)

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

    def close(self) -> None:
        """The session ended: its queued background work (view builds, a region refit in parts)
        is cancelled (a running build ends with its current view; none starts after, and a
        finished refit is not taken), and the renderer's cached primary hits of a
        big camera are dropped (a build under way holds the fitter, so the renderer, until it
        ends), so the worker goes back to resting memory (the caller then releases memory,
        worker.memory.release_memory). Before, after an 8192×8192 stream closed its prefetch
        kept both cores busy ~60 s and the worker stayed at 7 GB."""
        self.closed = True
        futs = list(self._pending.values()) + [c[2] for c in self._completions.values()]
        if self._parts_future is not None:
            futs.append(self._parts_future[2])          # a region refit in parts not yet started
        for fut in futs:
            fut.cancel()
        self._drop_fit_work()
        self._vt = None
        self.fitter = None
        cam = self.state.camera
        if cam.width * cam.height >= BIG_FRAME_PIXELS:
            for r in self.renderers.values():
                if r.can("view_cache"):
                    r.forget_views(BIG_FRAME_PIXELS)

    def _measure(self, name: str, width: int = MEASURE_WIDTH):
        """material -> (3,) mean linear radiance of object ``name`` drawn with it in the session's
        view and light at ``width`` pixels (None when the object is not in view): how a model
        conversion keeps what the designer sees (models/convert.py)."""
        st = self.state
        i = st.objects.index(name)
        camera, lighting = st.camera, Lighting(st.rotation_deg, st.intensity)
        if not st.allows("camera"):
            camera = self.scene.spec.camera
            lighting = Lighting(self.scene.spec.environment.rotation_deg, st.intensity)
        k = min(1.0, width / camera.width)
        if st.allows("camera"):
            camera = camera.model_copy(update={"width": max(16, int(camera.width * k)),
                                               "height": max(16, int(camera.height * k))})

        def measure(m):
            mats = list(st.materials)
            mats[i] = m
            out = self.renderer.render(FrameRequest(camera=camera, lighting=lighting, materials=mats, samples=1,
                                                    ground_shadow=st.shadow, transforms=st.transforms or None))
            sel = out.object_id == i
            return out.radiance[sel].mean(axis=0) if sel.any() else None
        return measure

    def _auto_expose(self) -> list[dict]:
        """Expose so that the median pixel of the objects is middle grey (a small frame of the
        session's view; core/tonemap.py auto_exposure): an uploaded scene's first exposure."""
        from ..core.tonemap import auto_exposure

        st = self.state
        cam = st.camera
        k = min(1.0, MEASURE_WIDTH / cam.width)
        if st.allows("camera"):
            cam = cam.model_copy(update={"width": max(16, int(cam.width * k)), "height": max(16, int(cam.height * k))})
        else:
            cam = self.scene.spec.camera
        out = self.renderer.render(FrameRequest(camera=cam, lighting=Lighting(st.rotation_deg, st.intensity),
                                                materials=st.materials, samples=1, ground_shadow=False,
                                                transforms=st.transforms or None))
        ev = auto_exposure(out.radiance, out.object_id >= 0)
        st.auto_exposure = False
        if ev is None:
            return []
        st.exposure = round(ev, 2)
        return [ExposureEvent(exposure=st.exposure, reason="the median object pixel shown as middle grey").model_dump()]

    # -- frames -----------------------------------------------------------------------------------
    @property
    def frame_budget_ms(self) -> float:
        return self.lod.frame_budget_ms

    @frame_budget_ms.setter
    def frame_budget_ms(self, ms: float) -> None:
        self.lod.frame_budget_ms = ms

    @property
    def drag_scale(self) -> int:
        return self.lod.drag_scale

    def level_of_detail(self) -> tuple[str, int]:
        """(lod, samples) of the next frame (lod.py LevelOfDetail.choose)."""
        return self.lod.choose(self.state, self._drag)

    def _still_view_ready(self, camera, samples: int) -> bool:
        return not self.renderer.can("view_cache") or self.renderer.has_view(camera, samples, STILL_ANTIALIAS)

    def needs_still_frame(self) -> bool:
        """Whether the last frame was a moving one (one sample, or the drag level of detail) and
        the session is not dragging: when no message is waiting, one more frame (``frame``) is
        the settled, anti-aliased image of the same state."""
        return self.lod.needs_still(self._drag)

    def frame(self, ack: int, skipped: int = 0, cancelled=None) -> tuple[dict, bytes]:
        """The current frame: (header (FrameHeader fields), JPEG bytes). cancelled : for a frame
        that may give way (renderers.base.FrameRequest.cancelled), a checkpoint that may block
        while strokes elsewhere go first (the header's ``ms_paused``, not counted in the frame's
        own times, which set the level of detail) and says when the frame is no longer wanted;
        the renderer may then raise renderers.base.FrameCancelled (nothing changes)."""
        # nothing the image depends on changed since the settled frame (a save, a message seen
        # again): that frame again under the new ack. Drawn anew, it was a one-sample frame
        # (faceted where the still is refined) and then the still once more: 7 s for a sharp
        # paint on the test bunny after each "Keep".
        if self._settled is not None and not self._drag and self._settled[0] == self._image_key():
            self._quick_next = False
            self.frame_no += 1
            return {**self._settled[1], "frame": self.frame_no, "ack": ack, "skipped": skipped, "ms_render": 0.0,
                    "ms_encode": 0.0, "ms_paused": 0.0}, self._settled[2]
        t0 = time.perf_counter()
        clock = compose.PauseClock(cancelled)
        st = self.state
        change = self.lod.change(st)
        lod, samples = self.level_of_detail()
        camera, lighting = st.camera, Lighting(st.rotation_deg, st.intensity)
        if not st.allows("camera"):          # a fixed-view renderer draws its own camera and light
            camera = self.scene.spec.camera
            lighting = Lighting(self.scene.spec.environment.rotation_deg, st.intensity)
        # progressive: a new fit, or a camera whose anti-aliased primary hits are not traced yet
        # (the user just let go), is shown at once with one sample; the anti-aliased frame
        # follows when the session is idle (needs_still_frame, the worker's loop), and that one
        # is not put off again
        follow_up = self.lod.follows_moving_frame(st)
        if samples > 1 and (self._quick_next or (not follow_up and not self._still_view_ready(camera, samples))):
            lod, samples = "quick", 1
        self._quick_next = False
        req = FrameRequest(camera=camera, lighting=lighting, materials=st.materials, lod=lod, samples=samples,
                           antialias=STILL_ANTIALIAS, drag_scale=self.lod.drag_scale, cancelled=clock.cancelled,
                           ground_shadow=st.shadow, transforms=st.transforms or None,
                           # the per-vertex transfer is per view: built for still views, not per drag frame
                           vertex_radiance=None if self._drag else self._override(),
                           # a settled frame is shaded per pixel where vertex shading is wrong
                           # (refined); the one-sample frames of a moving camera, light or object
                           # and a new fit's first frame are interpolated, and their settled frame
                           # follows as soon as the session is idle (an orbit at full quality ran at
                           # half the rate refined: 8.0 against 13-16 fps on the demo chair)
                           shading="refined" if samples > 1 else "vertex")
        out = self.renderer.render(req)
        self._last_ids = out.object_id
        rgb = compose.tone(out.radiance, st.exposure, st.tone)
        t1 = clock.now()
        w, h, jpeg = compose.jpeg(rgb, st.quality, self._drag)
        t2 = clock.now()
        self.lod.record(st, self._drag, lod, samples, change, (t2 - t0) * 1e3)
        self.frame_no += 1
        compose.release_scratch(w, h)
        # settled: the session thread draws no still after it (needs_still_frame once the user
        # lets go) and no refit is on its way (a stroke's quick view being completed: the full
        # view's fit changes the material); a drag frame is never settled, its still follows the drag
        hdr = compose.header(self.frame_no, ack, w, h, lod, out.info, (t1 - t0) * 1e3, (t2 - t1) * 1e3,
                             clock.paused * 1e3, skipped,
                             settled=not self._drag and not self.needs_still_frame() and not self.fit_pending())
        # a deep copy: a nested part of the state changed in place would change the key with it
        self._settled = (self._image_key(deep=True), hdr, jpeg) if hdr["settled"] else None
        return hdr, jpeg

    def _image_key(self, deep: bool = False):
        """What a frame's pixels depend on: the state but for what only the service keeps (the
        last seq, saves it has not stored yet), the renderer's identity, and the placement of
        movable objects it was last given (compared with ==)."""
        return (self.state.model_copy(update={"last_seq": -1, "pending_saves": []}, deep=deep), id(self.renderer),
                self._moves)


# -- what each effect does in the worker ----------------------------------------------------------


@handles(NoEffect)
def _nothing(rt: SessionRuntime, msg, eff) -> list[dict]:
    return []


@handles(Moved)
def _moved(rt: SessionRuntime, msg, eff: Moved) -> list[dict]:
    # fit views and the vertex transfer were of the old placement
    if rt.renderer.can("place"):
        rt.renderer.place(rt.state.transforms or None)
    rt._moves += 1
    rt._vt = None
    rt._drop_fit_work()
    return []


@handles(NewMaterial)
def _new_material(rt: SessionRuntime, msg, eff: NewMaterial) -> list[dict]:
    if eff.rebase:
        rt.fitter = None             # strokes painted over the old material do not carry over
        rt._needs_fit = False
        rt._drop_fit_work()
    _forget_region_steps(rt, eff.object)
    return [{"type": "curve", "seq": msg.seq, "object": eff.object, "curve": brdf_curve(msg.material)}]


# region steps (rename, erase, merge, material) kept for undo and redo per session: the
# materials before and after (a design's steps, not its strokes); protocol MAX_REGION_STEPS of them


def _forget_region_steps(rt: SessionRuntime, obj: str) -> None:
    """The object's material changed otherwise (a material message, a conversion, the paint
    designer): undoing a region step would put back a material from before that change."""
    rt._region_undo = [x for x in rt._region_undo if x[0] != obj]
    rt._region_redo = [x for x in rt._region_redo if x[0] != obj]


def _rebase(rt: SessionRuntime) -> None:
    rt.fitter = None             # the strokes so far are part of the material now
    rt._needs_fit = False
    rt._fitted = None
    rt._drop_fit_work()


@handles(RegionsChanged)
def _regions_changed(rt: SessionRuntime, msg, eff: RegionsChanged) -> list[dict]:
    _rebase(rt)
    m = rt.state.materials[rt.state.object_index]
    if eff.before is not None:
        rt._region_undo = (rt._region_undo + [(eff.object, eff.before, m, eff.region_before, rt.state.region)])[
            -MAX_REGION_STEPS:]
        rt._region_redo = []
    return [FitEvent(object=eff.object, material=_dump(m), curve=brdf_curve(m),
                     stats={"strokes": 0, "regions": region_names(m), "painting": rt.state.region}).model_dump()]


def _region_step(rt: SessionRuntime, what: str) -> list[dict] | None:
    """Undo (or redo) the edited object's last region step, when its strokes since are all
    undone: the material before (after) it, painted over by the next strokes in a new epoch, as
    the region message did. None when there is none."""
    src, dst = (rt._region_undo, rt._region_redo) if what == "undo" else (rt._region_redo, rt._region_undo)
    if not src or src[-1][0] != rt.state.object:
        return None
    step = src.pop()
    dst.append(step)
    obj, before, after, region_before, region_after = step
    m, region = (before, region_before) if what == "undo" else (after, region_after)
    st = rt.state
    rt._set_material(st.object_index, m)
    st.base_material, st.region, st.epoch = m, region, st.fresh_epoch()
    _rebase(rt)
    return [FitEvent(object=obj, material=_dump(m), curve=brdf_curve(m), rebase=True, painting=region,
                     stats={"strokes": 0, "regions": region_names(m), "painting": region}).model_dump()]


@handles(RecordStroke)
def _stroke(rt: SessionRuntime, msg, eff: RecordStroke) -> list[dict]:
    se = rt._add_stroke({**eff.stroke, "seq": msg.seq}, live=True)
    # a new edit: the region steps undone are gone, even when the stroke is rejected (the server
    # drops their rows when the stroke comes, before the worker has seen it)
    rt._region_redo = []
    if not se.rejected:
        rt._needs_fit = True
    return [se.model_dump()]


def _undo_redo(rt: SessionRuntime, msg, what: str) -> list[dict]:
    fx = rt.fitter
    if fx is not None and (fx.undo() if what == "undo" else fx.redo()) is not None:
        rt._needs_fit = True
        return []
    step = _region_step(rt, what)
    if step is not None:
        return step
    return [NoteEvent(seq=msg.seq, message=f"nothing to {what}").model_dump()]


@handles(Undo)
def _undo(rt: SessionRuntime, msg, eff) -> list[dict]:
    return _undo_redo(rt, msg, "undo")


@handles(Redo)
def _redo(rt: SessionRuntime, msg, eff) -> list[dict]:
    return _undo_redo(rt, msg, "redo")


@handles(Refit)
def _refit(rt: SessionRuntime, msg, eff) -> list[dict]:
    rt._needs_fit = True
    return []


@handles(Save)
def _save(rt: SessionRuntime, msg, eff: Save) -> list[dict]:
    return rt.fit_if_needed() + [rt._save_request(eff.save)]


@handles(SwitchRenderer)
def _switch(rt: SessionRuntime, msg, eff) -> list[dict]:
    from ..renderers import controls

    rt._switch_renderer(rt.state.renderer)
    rt._apply_environment()
    return [RendererEvent(seq=msg.seq, kind=rt.state.renderer,
                          controls=sorted(controls(rt.state.renderer))).model_dump()]


@handles(Relight)
def _relight(rt: SessionRuntime, msg, eff) -> list[dict]:
    from ..core.tonemap import auto_exposure

    rt._apply_environment()
    st = rt.state
    if getattr(msg, "preset", None) is None or st.readonly or rt.env_loader is None:
        return []
    # an uploaded map (a capture) is shown in the units of its preview: the map's median
    # luminance as middle grey, the exposure its preview was made with
    env = st.environments[st.environment_index]
    ev = auto_exposure(rt.env_loader(env))
    out = []
    if ev is not None and st.allows("environment"):
        st.exposure = round(ev, 2)
        out.append(ExposureEvent(seq=msg.seq, exposure=st.exposure,
                                 reason=f"as the preview of {env.label or env.filename}").model_dump())
    out.append(NoteEvent(seq=msg.seq, message=f"lighting applied: {env.label or env.filename}" +
                         (f", exposure {st.exposure:+.2f} EV as in its preview" if out else "")).model_dump())
    return out


@handles(FitPaint)
def _fit_paint(rt: SessionRuntime, msg, eff: FitPaint) -> list[dict]:
    _forget_region_steps(rt, eff.object)
    return rt._paint(eff.object, msg.seq)


@handles(SelectObject)
def _select_object(rt: SessionRuntime, msg, eff: SelectObject) -> list[dict]:
    # the fitter, its views and the vertex transfer were the other object's
    rt.fitter = None
    rt._fitted = None
    rt._vt = None
    rt._drop_fit_work()
    rt._replay(getattr(msg, "strokes", None) or [])
    out = rt.events
    rt.events = []
    rt._make_live()
    m = rt.state.material_of(eff.object)
    n = len(rt.fitter.history) if rt.fitter is not None else 0
    return out + [ObjectEvent(seq=msg.seq, object=eff.object, material=_dump(m), curve=brdf_curve(m),
                              strokes=n).model_dump()]


@handles(Pick)
def _pick(rt: SessionRuntime, msg, eff: Pick) -> list[dict]:
    ids = rt._last_ids
    name = None
    if ids is not None and ids.size:
        h, w = ids.shape
        i = int(ids[min(h - 1, int(eff.v * h)), min(w - 1, int(eff.u * w))])
        name = rt.state.objects[i] if 0 <= i < len(rt.state.objects) else None
    return [PickedEvent(seq=msg.seq, u=eff.u, v=eff.v, object=name).model_dump()]


@handles(Convert)
def _convert(rt: SessionRuntime, msg, eff: Convert) -> list[dict]:
    from ..models.convert import convert

    c = convert(rt.state.material_of(eff.object), eff.model, measure=rt._measure(eff.object))
    rt._set_material(rt.state.objects.index(eff.object), c.material)
    _forget_region_steps(rt, eff.object)
    if eff.object == rt.state.object:
        rt.state.base_material = c.material     # a new base: strokes of earlier epochs do not carry over
        rt.fitter = None
        rt._needs_fit = False
        rt._drop_fit_work()
    return [ConvertedEvent(seq=msg.seq, object=eff.object, material=_dump(c.material), curve=brdf_curve(c.material),
                           error=round(c.error, 4), albedo_error=round(c.albedo_error, 4)).model_dump()]
