"""CPU scheduling of a worker's sessions: strokes before frames (``Priority``, one per process:
``PRIORITY``), the OpenMP threads a session step's kernels get, and at most one frame per core
at once (``FrameSlots``: ``FRAME_SLOTS``). Which messages are urgent is their classes' policy
(worker/protocol/messages.py ``urgent``)."""
from __future__ import annotations

import os
import threading
import time
from contextlib import contextmanager

from ..protocol import _MESSAGES


def is_urgent(msg: dict) -> bool:
    """A client message (as sent) that goes before other sessions' frames: a stroke, undo,
    redo or fit (its class's ``urgent``)."""
    cls = _MESSAGES.get(msg.get("type"))
    return cls is not None and cls.urgent


class Priority:
    """Strokes before frames: while a session handles a stroke, undo or redo (a fit
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
