"""One session's thread in a worker: its own inbox, latest wins.

A session's thread drains every message queued for it, applies them in order, fits at most
once and renders one frame whose ``ack`` is the newest ``seq`` applied; intermediate views are
never rendered (the header counts them as ``skipped``). Sessions do not wait for each other:
one session's fit does not stall another's frames.
"""
from __future__ import annotations

import threading
import time
import traceback
from collections import deque
from contextlib import nullcontext

from worker.memory import release_memory

from .data_cache import DataCache
from .ipc import Reply
from .scheduling import FRAME_SLOTS, MAX_PAUSE_S, PRIORITY, is_urgent


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
            if is_urgent(msg) and not any(is_urgent(m) for m in self.inbox):
                self.oldest_urgent = time.perf_counter()
            self.inbox.append(msg)
            self.cv.notify()

    def _urgent_waiting(self) -> bool:
        with self.cv:
            return self.stopping or any(is_urgent(m) for m in self.inbox)

    def _any_waiting(self) -> bool:
        with self.cv:
            return self.stopping or bool(self.inbox)

    def _checkpoint(self, wanted_until) -> bool:
        """Between parts of a frame that answers no stroke (renderers.base.FrameRequest.cancelled):
        stand aside while a stroke is handled anywhere on the machine, at most MAX_PAUSE_S per
        frame (``pause_left``, set by the step), then say whether the frame is still wanted
        (``wanted_until`` turns True when it is not: this session's own stroke, or any new
        message for a still). Before, a stroke waited for the frames already under way in
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
        self.outq.put(Reply("event", self.sid, e))

    def _quiet_for(self, seconds: float) -> bool:
        """Whether no message (nor stop) arrives within ``seconds``."""
        with self.cv:
            self.cv.wait_for(lambda: self.inbox or self.stopping, timeout=seconds)
            return not self.inbox and not self.stopping

    def run(self) -> None:
        from worker import native
        from worker.jobs.lod import busy_sessions
        from worker.jobs.reporting import error_event
        from worker.jobs.runtime import SessionRuntime

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
            self.outq.put(Reply("frame", self.sid, rt.frame(ack)))
            self._after_frame(rt)
            # the first frame is a quick one (one sample) when the view's anti-aliased primary
            # hits are not traced yet: its settled frame follows without waiting for input
            self._settle(rt, ack)
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
                urgent = any(is_urgent(m) for m in msgs)
                if not urgent:
                    # a stroke of this session arriving meanwhile ends the wait: it is taken
                    # into this step (it waited up to MAX_WAIT_S behind others' strokes before)
                    PRIORITY.wait_turn(interrupt=self._urgent_waiting)
                    with self.cv:
                        msgs += list(self.inbox)
                        self.inbox.clear()
                        arrived_urgent = self.oldest_urgent
                    urgent = any(is_urgent(m) for m in msgs)
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
                    self._settle(rt, ack)
                    wait = rt.prefetch()     # a view that stayed: what a stroke there will need
                    if wait > 0 and self._quiet_for(wait):
                        rt.prefetch()
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
            self.outq.put(Reply("closed", self.sid, None))

    def _settle(self, rt, ack: int) -> None:
        """After a moving frame (one sample, or the drag level of detail), when the session
        stays idle STILL_DELAY_S: the settled, anti-aliased image of the same state, given up
        as soon as a message arrives (that one's frame comes first)."""
        from worker.jobs.reporting import error_event
        from worker.renderers.base import FrameCancelled

        if not (rt.needs_still_frame() and self._quiet_for(STILL_DELAY_S)):
            return
        PRIORITY.wait_turn()
        self.pause_left = MAX_PAUSE_S
        try:
            with FRAME_SLOTS.take(self._any_waiting):
                self.outq.put(Reply("frame", self.sid, rt.frame(
                    ack, cancelled=lambda: self._checkpoint(self._any_waiting))))
        except FrameCancelled:
            pass
        except Exception as ex:
            self._event(error_event(ex, ack) | {"message": f"render failed: {error_event(ex)['message']}"})

    def _step(self, rt, msgs: list, ack: int, arrived: float = 0.0, checkpoint=None) -> int:
        """Apply messages, fit if needed, send the frame; returns the new ack. arrived :
        perf_counter() when the oldest of msgs reached this worker (0: not known). checkpoint :
        for a step that answers no stroke, the frame's (``_checkpoint``): the frame gives way
        to strokes elsewhere, and is dropped for a stroke of this session (whose frame, one
        step later, shows these messages too)."""
        from worker.jobs.reporting import error_event
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
            self.outq.put(Reply("frame", self.sid, (hdr, jpeg)))
        except FrameCancelled:
            self.dropped += len(msgs)       # counted as skipped by the next frame
        except Exception as ex:
            self._event(error_event(ex, ack) | {"message": f"render failed: {error_event(ex)['message']}"})
        self._after_frame(rt)
        return ack

    def _after_frame(self, rt) -> None:
        """Events that follow the frame (a fit's curve and guidance: off the path from stroke to frame)."""
        from worker.jobs.reporting import error_event

        try:
            for e in rt.after_frame():
                self._event(e)
        except Exception as ex:
            self._event(error_event(ex) | {"message": f"after the frame (curve, guidance): {error_event(ex)['message']}"})
