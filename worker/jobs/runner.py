"""The worker process: jobs (precompute, render, fit) on a job thread, and every
interactive session on a thread of its own, talking to the server through two pipes.

Requests (server → worker):
    ("job", job_id, {"type": "precompute" | "render" | "fit", ...})
    ("open", session_id, {"scene": {...}, "state": {...}, "strokes": [...], "ack": int})
    ("msg", session_id, {client message})
    ("close", session_id, None)
    ("stop", None, None)
Replies (worker → server):
    ("progress", job_id, {"progress": 0..1, "message": str})
    ("result", job_id, {...}) / ("error", job_id, {"message": str, "status": int})
    ("frame", session_id, (header, jpeg bytes)) / ("event", session_id, {...})
    ("closed", session_id, None)   (the session's thread has ended and released what it held)

Latest wins, per session: a session's thread drains every message queued for it, applies them
in order, fits at most once and renders one frame whose ``ack`` is the newest ``seq`` applied;
intermediate views are never rendered (the header counts them as ``skipped``). Sessions do not
wait for each other: one session's fit does not stall another's frames.

The worker reads no environment variables: everything comes in ``WorkerSettings``.
"""
from __future__ import annotations

import os
import queue
import shutil
import threading
import time
from contextlib import contextmanager, nullcontext
import traceback
from collections import OrderedDict, deque
from pathlib import Path

from pydantic import BaseModel

from worker.memory import cap_malloc_arenas, release_memory


class WorkerSettings(BaseModel):
    """What a worker process needs to know, passed explicitly by the pool.

    blob_root : the blob store. tmp_dir : this worker's scratch folder (removed on exit).
    threads : the jobs' ray-tracing threads (0: one per core); session steps set their own
    OpenMP threads (Priority.kernel_threads). kernels : "native", "numpy"
    or None (native when built). scenes : loaded scenes kept (LRU). nice : niceness added to
    the process (the API server's messages and frames go first under load)."""
    blob_root: str
    tmp_dir: str
    threads: int = 0
    kernels: str | None = None
    nice: int = 0
    scenes: int = 4


class PipeOut:
    """The writing end of a pipe, shared by threads (the server's event loop and monitor; the
    worker's job and session threads): one send at a time."""

    def __init__(self, conn):
        self.conn = conn
        self.lock = threading.Lock()

    def put(self, item) -> None:
        with self.lock:
            self.conn.send(item)

    def close(self) -> None:
        self.conn.close()


class JobError(Exception):
    """A job that cannot be done as asked (bad input): reported with an HTTP-like status."""

    def __init__(self, message: str, status: int = 422):
        super().__init__(message)
        self.status = status


class DataCache:
    """Loaded scenes and their renderers' data in this worker, shared by its jobs and sessions
    (a few, least recently used first out), and decoded environment maps."""

    def __init__(self, settings: WorkerSettings):
        from worker.blobs import BlobStore, PartStore

        self.settings = settings
        self.blobs = BlobStore(settings.blob_root)
        self.parts = PartStore(self.blobs)
        self.tmp = Path(settings.tmp_dir)
        self.tmp.mkdir(parents=True, exist_ok=True)
        self._scenes: OrderedDict = OrderedDict()
        self._data: OrderedDict = OrderedDict()
        self._maps: OrderedDict = OrderedDict()
        self._lock = threading.RLock()

    def linked(self, f: dict) -> Path:
        """A verified blob under a name with its original extension (readers dispatch on it)."""
        src = self.blobs.verified_path(f["sha256"])
        link = self.tmp / (f["sha256"] + Path(f["filename"]).suffix.lower())
        if not link.exists():
            try:
                os.symlink(src, link)
            except FileExistsError:
                pass
        return link

    def scene(self, p: dict):
        from worker.scene import LoadedScene, SceneError, parse_scene

        with self._lock:
            key = p["scene_id"]
            if key in self._scenes:
                self._scenes.move_to_end(key)
                return self._scenes[key]

            def resolve(ref: str) -> Path:
                f = p["files"].get(ref)
                if f is None:
                    raise SceneError(f"{ref!r} is not an uploaded asset")
                return self.linked(f)

            sc = LoadedScene(parse_scene(p["spec"]), self.tmp, resolver=resolve)
            self._scenes[key] = sc
            while len(self._scenes) > self.settings.scenes:
                self._scenes.popitem(last=False)
            return sc

    def renderer(self, p: dict, kind: str | None = None):
        """A new renderer for a scene payload (cheap: the heavy data is shared)."""
        from worker.native.kernels import kernels
        from worker.renderers import get, load

        if not p.get("parts"):
            raise JobError("the scene has no finished precomputation; start one first", 409)
        own = p.get("renderer") or "cuts"
        kind = kind or own
        options = (p.get("options") or {}) if kind == own else {}
        cls, pre = get(kind)
        sc = self.scene(p)
        if "legacy-cuts" in p["parts"] and kind == "cuts":
            # release 0.3 stored the cut blob without a key: adopt it under its content key
            (part,) = pre.parts(sc, options)
            if self.parts.sha(part.key) is None:
                self.parts.adopt(part.key, p["parts"]["legacy-cuts"])
            p = {**p, "parts": {part.key: p["parts"]["legacy-cuts"]}}
        with self._lock:
            key = (p["scene_id"], kind, tuple(sorted(p["parts"].items())))
            data = self._data.get(key)
            if data is None:
                data = load(pre, sc, self.parts, options)
                self._data[key] = data
                while len(self._data) > self.settings.scenes:
                    self._data.popitem(last=False)
            else:
                self._data.move_to_end(key)
        return cls(sc, data, kernels=kernels(self.settings.kernels))

    def envmap(self, f):
        """An environment map blob (verified), decoded once (a few kept)."""
        from worker.envmap import load_envmap

        sha = f["sha256"] if isinstance(f, dict) else f.sha256
        name = f["filename"] if isinstance(f, dict) else f.filename
        with self._lock:
            if sha not in self._maps:
                if len(self._maps) >= 4:
                    self._maps.popitem(last=False)
                self._maps[sha] = load_envmap(self.linked({"sha256": sha, "filename": name}))
            return self._maps[sha]

    def close(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)


# -- jobs ---------------------------------------------------------------------------------------------


def _render(cache: DataCache, p: dict) -> dict:
    import io

    import numpy as np
    from PIL import Image

    from worker.core.tonemap import tonemap
    from worker.models import parse_material
    from worker.renderers import FrameRequest, Lighting
    from worker.scene import Camera, Transform

    r = cache.renderer(p["scene"])
    sc = r.scene
    names = [o.name for o in sc.spec.objects]
    mats = list(sc.materials)
    for name, m in (p.get("materials") or {}).items():
        if name not in names:
            raise JobError(f"materials: no object {name!r} in the scene (objects: {', '.join(names)})")
        mats[names.index(name)] = parse_material(m)
    env = sc.spec.environment
    cam = Camera.model_validate(p["camera"]) if p.get("camera") else sc.spec.camera
    rot = env.rotation_deg if p.get("rotation_deg") is None else p["rotation_deg"]
    inten = env.intensity if p.get("intensity") is None else p["intensity"]
    transforms = {}
    for name, t in (p.get("transforms") or {}).items():
        if name not in names:
            raise JobError(f"transforms: no object {name!r} in the scene (objects: {', '.join(names)})")
        transforms[name] = Transform.model_validate(t)
    out = r.render(FrameRequest(camera=cam, lighting=Lighting(rot, inten), materials=mats,
                                shading=p.get("mode", "vertex"), transforms=transforms or None))
    img = out.radiance
    if p.get("format") == "exr":
        import tempfile

        from worker.envmap import save_exr

        with tempfile.TemporaryDirectory(dir=cache.tmp) as d:
            path = Path(d) / "r.exr"
            save_exr(path, img.astype(np.float32))
            return {"bytes": path.read_bytes(), "media_type": "image/x-exr"}
    buf = io.BytesIO()
    Image.fromarray(tonemap(img, p.get("exposure", 0.0), p.get("tone", "neutral"))).save(buf, format="PNG")
    return {"bytes": buf.getvalue(), "media_type": "image/png"}


def _fit(cache: DataCache, p: dict) -> dict:
    import json

    import numpy as np

    from worker.fit.basis import default_basis
    from worker.fit.files import ViewSpec, load_mask, load_target
    from worker.fit.fitter import DEFAULT_UNPAINTED_WEIGHT, Fitter

    r = cache.renderer(p["scene"])
    req = p["request"]
    f0 = req.get("fresnel_f0")
    basis = default_basis(fresnel_f0=1.0 if f0 is None else f0)     # 0 means 0 (issue 9)
    fx = Fitter(r, req["object"], basis=basis, fit_scale=req.get("fit_scale") or 0.25, albedo=req.get("albedo"))
    notes = []
    if req.get("strokes"):
        for v in req.get("views") or [{}]:
            v = ViewSpec.model_validate(v)
            fx.add_view(v.camera, v.rotation_deg, v.intensity)
        for s in req["strokes"]:
            notes += fx.add_stroke(s)
        out = fx.fit(constrained=req.get("constrained", True),
                     unpainted_weight=req.get("unpainted_weight", DEFAULT_UNPAINTED_WEIGHT))
    else:
        fx.add_view()
        target = load_target(cache.linked(p["target"]))
        mask = load_mask(cache.linked(p["mask"])) if p.get("mask") else None
        out = fx.fit_targets([target], [mask], constrained=req.get("constrained", True))
    s = out.solve
    return {"material": json.loads(out.material.model_dump_json()),
            "stats": {"seconds_transfer": out.seconds_transfer, "seconds_solve": s.seconds, "pixels": out.pixels,
                      "painted": out.painted, "basis": fx.basis.J, "residual_rms": s.residual_rms,
                      "residual_rel": s.residual_rel, "energy_max": s.energy_max,
                      "energy_bound": float(np.min(s.energy_bound)), "constrained": s.constrained,
                      "notes": list(dict.fromkeys(notes + out.notes))}}


def _precompute(cache: DataCache, p: dict, progress) -> dict:
    """Ensure a scene's precomputation in the blob store (parts already there are reused)."""
    from worker.renderers import get

    kind = p["scene"].get("renderer") or "cuts"
    sc = cache.scene(p["scene"])
    options = p["scene"].get("options") or {}
    # the scene's renderer, and the cut renderer for every scene (a GI scene's way back to direct
    # light and a free camera; the paint renderer's self-shadowing)
    kinds = [kind] + (["cuts"] if kind != "cuts" else [])
    pres = [get(k)[1] for k in kinds]
    total = max(1, sum(x.work for pre in pres for x in pre.parts(sc, options if pre.kind == kind else {})))
    done = [0, -1.0]

    def tick(k):
        done[0] += k
        f = min(1.0, done[0] / total)
        if f - done[1] >= 0.01 or done[0] >= total:
            done[1] = f
            progress(f, f"{done[0]}/{total}")

    from worker.renderers import ensure

    manifest, flat, seconds, computed = {}, {}, 0.0, 0
    for pre in pres:
        stats = ensure(pre, sc, cache.parts, options if pre.kind == kind else {}, tick,
                       threads=cache.settings.threads or os.cpu_count() or 2)
        manifest.update({k: cache.parts.sha(k) for k in stats["parts"]})
        for info in stats["parts"].values():
            if pre.kind == kind:          # the scene renderer's figures are the job's headline
                flat.update({k: v for k, v in info.items() if k not in ("label",)})
        seconds += stats["seconds"]
        computed += stats["computed"]
    return {"kind": kind, "parts": manifest, "stats": {**flat, "seconds": seconds, "computed": computed,
                                                       "renderers": kinds}}


def _capture(cache: DataCache, p: dict, progress) -> dict:
    """A lighting capture (worker/capture): the uploaded zip extracted in this worker's scratch
    folder (paths checked, sizes capped), processed, and the map and its preview stored as blobs."""
    import shutil
    import tempfile

    from worker.capture.job import extract_capture_zip, run_capture

    work = Path(tempfile.mkdtemp(prefix="capture-", dir=cache.tmp))
    try:
        manifest = extract_capture_zip(cache.blobs.verified_path(p["zip_sha256"]), work, p.get("max_files", 64),
                                       p.get("max_total_bytes", 2 * 1024 ** 3))
        exr, png, stats = run_capture(manifest, progress, root=work)
        return {"exr_sha256": cache.blobs.put(exr), "exr_bytes": len(exr), "preview_sha256": cache.blobs.put(png),
                "stats": stats}
    finally:
        shutil.rmtree(work, ignore_errors=True)


JOBS = {"render": _render, "fit": _fit}
PROGRESS_JOBS = {"precompute": _precompute, "capture": _capture}


# -- sessions -----------------------------------------------------------------------------------------


class Priority:
    """Strokes before frames (issue 9): while a session handles a stroke, undo or redo (a fit
    the designer is waiting for), the other sessions' frames wait for it, at most MAX_WAIT_S
    each time. Under load a stroke otherwise got a quarter of a core beside three orbiting
    sessions and reached its frame in ~1 s; the frames it delays are each one of many a second.

    Within a worker process this is a condition variable. The local pool's workers share the
    machine's cores, so they also share their counts (``share``: one slot per worker in shared
    memory, each written only by its own worker, so no lock crosses processes): a frame waits
    for strokes in any worker, polling the others every POLL_S. With per-process priority only,
    a stroke's kernels still ran beside the other worker's frames at half the machine."""
    MAX_WAIT_S = 0.25
    POLL_S = 0.004

    def __init__(self):
        self.cv = threading.Condition()
        self.urgent = 0
        self.counts = None          # the local pool's shared array (multiprocessing RawArray "i")
        self.slot = -1

    def share(self, counts, slot: int) -> None:
        """Take part in the machine-wide priority: counts[slot] is this process's stroke count,
        counts[n + slot] its busy sessions (n workers; ``kernel_threads``)."""
        self.counts, self.slot = counts, slot
        counts[slot] = self.urgent

    def kernel_threads(self, busy_here: int, urgent: bool) -> int:
        """OpenMP threads for one session step's kernels: every core for a stroke (the other
        sessions' frames wait for it), else the cores shared among the sessions that are busy
        on this machine (this worker's ``busy_here`` and the other workers' published counts).
        One session alone gets every core; eight share two without 16 threads competing."""
        cores = os.cpu_count() or 1
        c = self.counts
        if c is None:
            return cores
        n = len(c) // 2
        c[n + self.slot] = busy_here
        if urgent:
            return cores
        busy = sum(c[n + i] for i in range(n))
        return max(1, cores // max(1, busy))

    def _others(self) -> int:
        c = self.counts
        return 0 if c is None else sum(c[i] for i in range(len(c) // 2) if i != self.slot)

    @contextmanager
    def first(self):
        with self.cv:
            self.urgent += 1
            if self.counts is not None:
                self.counts[self.slot] = self.urgent
        try:
            yield
        finally:
            with self.cv:
                self.urgent -= 1
                if self.counts is not None:
                    self.counts[self.slot] = self.urgent
                self.cv.notify_all()

    def wait_turn(self, interrupt=None, max_wait: float | None = None) -> None:
        """Wait while a stroke is handled anywhere, at most MAX_WAIT_S (or ``max_wait`` if
        less); interrupt : a function that ends the wait early when it returns True (polled
        every POLL_S)."""
        deadline = time.monotonic() + (self.MAX_WAIT_S if max_wait is None else min(self.MAX_WAIT_S, max_wait))
        poll = self.counts is not None or interrupt is not None
        with self.cv:
            while self.urgent or self._others():
                left = deadline - time.monotonic()
                if left <= 0 or (interrupt is not None and interrupt()):
                    return
                # a local stroke's end notifies; another worker's, or the interrupt, is polled
                self.cv.wait(min(left, self.POLL_S) if poll else left)


PRIORITY = Priority()
URGENT = frozenset({"stroke", "undo", "redo", "fit"})
# what a frame under way pauses at most for strokes elsewhere (SessionThread._checkpoint): a
# stroke's step takes ~60-100 ms under load; a slow one (a cold worker's first, ~0.5 s) must
# not stop every other session's frames for as long
MAX_PAUSE_S = 0.12


class FrameSlots:
    """At most one frame that answers no stroke per core drawn at once in a worker; the other
    sessions' frames queue for a slot instead of being time-sliced against each other. Issue
    9: eight session threads of one process drawing drag frames on two cores drew 257 frames
    a second in all, 345 two at a time (each frame's CPU 5.6 → 4.6 ms: caches and the GIL);
    under ``bench load`` the slowest session's fps rose too (BENCHMARKS.md). A stroke's step
    takes no slot, and a frame waiting for one gives way to its own session's stroke."""

    def __init__(self, n: int | None = None):
        self.sem = threading.Semaphore(n or os.cpu_count() or 1)

    @contextmanager
    def take(self, given_up):
        """Hold a slot for one frame; raises renderers.base.FrameCancelled when ``given_up()``
        turns True while waiting (polled every Priority.POLL_S)."""
        from worker.renderers.base import FrameCancelled

        while not self.sem.acquire(timeout=Priority.POLL_S):
            if given_up():
                raise FrameCancelled()
        try:
            yield
        finally:
            self.sem.release()


FRAME_SLOTS = FrameSlots()


# the anti-aliased still frame waits this long for the session to stay idle: a designer
# stroking or nudging a slider in quick succession does not wait behind a still they would
# never see (they come ~100 ms apart); one that stops sees it a moment later
STILL_DELAY_S = 0.12


class SessionThread(threading.Thread):
    """One session's thread: its own inbox, latest wins."""

    def __init__(self, sid: str, payload: dict, cache: DataCache, outq):
        super().__init__(daemon=True, name=f"glint-session-{sid}")
        self.sid = sid
        self.payload = payload
        self.cache = cache
        self.outq = outq
        self.inbox: deque = deque()
        self.cv = threading.Condition()
        self.stopping = False
        self.poked = False              # a background build for this session has finished
        self.oldest = 0.0               # perf_counter() when the oldest message in the inbox arrived
        self.oldest_urgent = 0.0        # … and the oldest stroke, undo, redo or fit in it
        self.dropped = 0                # messages of frames given up for a stroke (_step)
        self.pause_left = 0.0           # what the frame being drawn may still pause (_checkpoint)

    def poke(self) -> None:
        with self.cv:
            self.poked = True
            self.cv.notify()

    def post(self, msg: dict) -> None:
        with self.cv:
            if not self.inbox:
                self.oldest = time.perf_counter()      # the frame header's ms_wait
            if msg.get("type") in URGENT and not any(m.get("type") in URGENT for m in self.inbox):
                self.oldest_urgent = time.perf_counter()
            self.inbox.append(msg)
            self.cv.notify()

    def _urgent_waiting(self) -> bool:
        with self.cv:
            return self.stopping or any(m.get("type") in URGENT for m in self.inbox)

    def _any_waiting(self) -> bool:
        with self.cv:
            return self.stopping or bool(self.inbox)

    def _checkpoint(self, wanted_until) -> bool:
        """Between parts of a frame that answers no stroke (renderers.base.FrameRequest.cancelled):
        stand aside while a stroke is handled anywhere on the machine, at most MAX_PAUSE_S per
        frame (``pause_left``, set by the step), then say whether the frame is still wanted
        (``wanted_until`` turns True when it is not: this session's own stroke, or any new
        message for a still). Issue 9: a stroke waited for the frames already under way in
        every session, ~50 ms at p50 and 100-170 ms at p95 with eight sessions on two cores;
        frames only gave way between steps."""
        if wanted_until():
            return True
        if self.pause_left > 0:
            t0 = time.monotonic()
            PRIORITY.wait_turn(interrupt=wanted_until, max_wait=self.pause_left)
            self.pause_left -= time.monotonic() - t0
        return wanted_until()

    def stop(self) -> None:
        with self.cv:
            self.stopping = True
            self.cv.notify()

    def _event(self, e: dict) -> None:
        self.outq.put(("event", self.sid, e))

    def _quiet_for(self, seconds: float) -> bool:
        """Whether no message (nor stop) arrives within ``seconds``."""
        with self.cv:
            self.cv.wait_for(lambda: self.inbox or self.stopping, timeout=seconds)
            return not self.inbox and not self.stopping

    def run(self) -> None:
        from worker import native
        from worker.jobs.session import SessionRuntime, busy_sessions, error_event
        from worker.renderers.base import FrameCancelled

        rt = None
        try:
            p = self.payload
            renderer = self.cache.renderer(p["scene"], (p.get("state") or {}).get("renderer"))
            rt = SessionRuntime(renderer.scene, renderer, p, env_loader=self.cache.envmap,
                                renderer_for=lambda kind: self.cache.renderer(p["scene"], kind))
            rt.wake = self.poke
            ack = int(p.get("ack", -1))
            for e in rt.take_events():
                self._event(e)
            self.outq.put(("frame", self.sid, rt.frame(ack)))
            while True:
                with self.cv:
                    while not self.inbox and not self.stopping and not self.poked:
                        self.cv.wait()
                    if self.stopping:
                        return
                    msgs = list(self.inbox)
                    self.inbox.clear()
                    self.poked = False
                    arrived, arrived_urgent = self.oldest, self.oldest_urgent
                # background results (completed fit views, the vertex transfer): a new frame
                # only when they change it
                changed = rt.absorb()
                if not msgs and not changed:
                    with self.cv:
                        idle = not self.inbox
                    if idle:
                        rt.prefetch()
                    continue
                urgent = any(m.get("type") in URGENT for m in msgs)
                if not urgent:
                    # a stroke of this session arriving meanwhile ends the wait: it is taken
                    # into this step (it waited up to MAX_WAIT_S behind others' strokes before)
                    PRIORITY.wait_turn(interrupt=self._urgent_waiting)
                    with self.cv:
                        msgs += list(self.inbox)
                        self.inbox.clear()
                        arrived_urgent = self.oldest_urgent
                    urgent = any(m.get("type") in URGENT for m in msgs)
                if urgent:
                    arrived = arrived_urgent    # a stroke's frame says how long the stroke waited
                # OpenMP's thread count is per calling thread (libgomp): set for this step
                native.set_threads(PRIORITY.kernel_threads(busy_sessions(time.monotonic()), urgent))
                if urgent:
                    with PRIORITY.first():
                        ack = self._step(rt, msgs, ack, arrived)
                else:
                    ack = self._step(rt, msgs, ack, arrived,
                                     checkpoint=lambda: self._checkpoint(self._urgent_waiting))
                with self.cv:
                    idle = not self.inbox
                if idle:
                    rt.prefetch()
                    if rt.needs_still_frame() and self._quiet_for(STILL_DELAY_S):
                        # the settled, anti-aliased image of the same state
                        PRIORITY.wait_turn()
                        self.pause_left = MAX_PAUSE_S
                        try:
                            # given up as soon as a message arrives: that one's frame comes first
                            with FRAME_SLOTS.take(self._any_waiting):
                                self.outq.put(("frame", self.sid, rt.frame(
                                    ack, cancelled=lambda: self._checkpoint(self._any_waiting))))
                        except FrameCancelled:
                            pass
                        except Exception as ex:
                            self._event(error_event(ex, ack) | {"message": f"render failed: {error_event(ex)['message']}"})
        except Exception as ex:
            self._event({**error_event(ex), "fatal": True,
                         "message": f"cannot open the session: {error_event(ex)['message']}"})
            if not isinstance(ex, (ValueError, KeyError)):
                traceback.print_exc()
        finally:
            if rt is not None:
                rt.close()
            del rt
            release_memory()
            self.outq.put(("closed", self.sid, None))

    def _step(self, rt, msgs: list, ack: int, arrived: float = 0.0, checkpoint=None) -> int:
        """Apply messages, fit if needed, send the frame; returns the new ack. arrived :
        perf_counter() when the oldest of msgs reached this worker (0: not known). checkpoint :
        for a step that answers no stroke, the frame's (``_checkpoint``): the frame gives way
        to strokes elsewhere, and is dropped for a stroke of this session (whose frame, one
        step later, shows these messages too)."""
        from worker.jobs.session import error_event
        from worker.renderers.base import FrameCancelled

        t0 = time.perf_counter()
        for m in msgs:
            try:
                for e in rt.handle(m):
                    self._event(e)
            except Exception as ex:
                self._event(error_event(ex, m.get("seq")))
            ack = max(ack, int(m.get("seq", -1)))
        t1 = time.perf_counter()
        try:
            for e in rt.fit_if_needed() + rt.take_events():
                self._event(e)
        except Exception as ex:
            self._event(error_event(ex, ack) | {"message": f"fit failed: {error_event(ex)['message']}"})
        t2 = time.perf_counter()
        try:
            self.pause_left = MAX_PAUSE_S
            with FRAME_SLOTS.take(self._urgent_waiting) if checkpoint is not None else nullcontext():
                hdr, jpeg = rt.frame(ack, skipped=max(0, len(msgs) - 1) + self.dropped, cancelled=checkpoint)
            self.dropped = 0
            hdr.update(ms_wait=round(max(0.0, t0 - arrived) * 1e3, 2) if arrived else 0.0,
                       ms_apply=round((t1 - t0) * 1e3, 2), ms_fit=round((t2 - t1) * 1e3, 2))
            self.outq.put(("frame", self.sid, (hdr, jpeg)))
        except FrameCancelled:
            self.dropped += len(msgs)       # counted as skipped by the next frame
        except Exception as ex:
            self._event(error_event(ex, ack) | {"message": f"render failed: {error_event(ex)['message']}"})
        return ack


def _freeze_modules() -> None:
    """Import what sessions and jobs use, then freeze what exists (worker.memory.freeze_start_up)."""
    import worker.fit.fitter  # noqa: F401
    import worker.fit.solve  # noqa: F401
    import worker.jobs.session  # noqa: F401
    import worker.renderers.cuts  # noqa: F401
    import worker.scene  # noqa: F401
    from worker.memory import freeze_start_up

    freeze_start_up()


def worker_main(wid: int, requests, replies, settings: WorkerSettings, urgent=None) -> None:
    """Entry point of a worker process (multiprocessing, spawn): requests and replies are the
    two pipe ends (multiprocessing.connection.Connection); urgent : the local pool's shared
    stroke counts (a RawArray "i", one slot per worker; Priority), or None."""
    outq = PipeOut(replies)
    if urgent is not None:
        PRIORITY.share(urgent, wid)
    # the session threads' and OpenMP threads' freed memory in a few arenas (release_memory)
    cap_malloc_arenas()
    if settings.nice:
        # issue 9: with rendering at the server's priority, a stroke's message and its frame
        # waited ~30 ms (p50) behind frames in the server's event loop and the pipes
        os.nice(settings.nice)

    # before NumPy loads: BLAS must not spawn threads beside the OpenMP kernels (DESIGN.md §7)
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    from worker import native

    native.set_threads(settings.threads)
    _freeze_modules()
    cache = DataCache(settings)
    jobs: queue.Queue = queue.Queue()

    def job_loop():
        from worker.errors import GlintError

        while True:
            item = jobs.get()
            if item is None:
                return
            jid, p = item
            try:
                kind = p["type"]
                if kind in PROGRESS_JOBS:
                    res = PROGRESS_JOBS[kind](cache, p, lambda f, msg: outq.put(
                        ("progress", jid, {"progress": f, "message": msg})))
                elif kind in JOBS:
                    res = JOBS[kind](cache, p)
                else:
                    raise JobError(f"unknown job type {kind!r}", 400)
                outq.put(("result", jid, res))
            except JobError as e:
                outq.put(("error", jid, {"message": str(e), "status": e.status}))
            except GlintError as e:
                outq.put(("error", jid, {"message": str(e), "status": e.status}))
            except ValueError as e:
                outq.put(("error", jid, {"message": str(e), "status": 422}))
            except Exception as e:  # a bug: keep the worker alive, report it
                outq.put(("error", jid, {"message": f"internal error: {type(e).__name__}: {e}", "status": 500,
                                         "trace": traceback.format_exc()}))

    jt = threading.Thread(target=job_loop, daemon=True, name="glint-jobs")
    jt.start()
    sessions: dict[str, SessionThread] = {}
    try:
        while True:
            try:
                kind, key, p = requests.recv()
            except (EOFError, OSError):         # the server is gone
                break
            if kind == "stop":
                break
            if kind == "job":
                jobs.put((key, p))
            elif kind == "open":
                old = sessions.pop(key, None)
                if old is not None:
                    old.stop()
                t = sessions[key] = SessionThread(key, p, cache, outq)
                t.start()
            elif kind == "close":
                t = sessions.pop(key, None)
                if t is not None:
                    t.stop()
            elif kind == "msg":
                t = sessions.get(key)
                if t is None:
                    outq.put(("event", key, {"type": "error", "fatal": True,
                                             "message": "session is not open on this worker"}))
                else:
                    t.post(p)
            for k in [k for k, t in sessions.items() if not t.is_alive()]:
                sessions.pop(k)
    finally:
        jobs.put(None)
        for t in sessions.values():
            t.stop()
        for t in sessions.values():
            t.join(timeout=2)
        jt.join(timeout=2)
        cache.close()
        outq.close()
