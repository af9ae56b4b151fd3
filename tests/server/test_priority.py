"""Strokes before frames (worker/jobs/scheduling.py Priority): a frame waits while a stroke
is handled in this worker or in another worker of the local pool, and never longer than
MAX_WAIT_S. Only lower bounds on time are asserted (a wait that ended early is a defect
whatever the machine's speed)."""
from __future__ import annotations

import multiprocessing as mp
import os
import threading
import time
from contextlib import contextmanager

import pytest

from worker.jobs.runner import Priority


def _hold_stroke(counts, slot: int, hold_s: float, conn) -> None:
    """Another worker process: handles a 'stroke' for hold_s, says when it began and ended."""
    p = Priority()
    p.share(counts, slot)
    with p.first():
        conn.send(("began", time.monotonic()))
        time.sleep(hold_s)
        ended = time.monotonic()
    conn.send(("ended", ended))


@contextmanager
def _held_elsewhere(cm):
    """Enter cm on another thread and keep it entered while the with-block runs."""
    inside, release = threading.Event(), threading.Event()

    def hold():
        with cm:
            inside.set()
            release.wait(30)

    t = threading.Thread(target=hold)
    t.start()
    inside.wait()
    try:
        yield
    finally:
        release.set()
        t.join()


def test_a_frame_waits_for_a_stroke_in_the_same_worker():
    p = Priority()
    began, released = threading.Event(), []

    def stroke():
        with p.first():
            began.set()
            time.sleep(0.1)
            released.append(time.monotonic())

    t = threading.Thread(target=stroke)
    t.start()
    began.wait()
    p.wait_turn()
    returned = time.monotonic()
    t.join()
    assert released and returned >= released[0], "the frame started before the stroke was done"


def test_a_frame_waits_for_a_stroke_in_another_worker():
    ctx = mp.get_context("spawn")
    counts = ctx.RawArray("i", 4)          # two workers: strokes, then busy sessions
    mine = Priority()
    mine.share(counts, 0)
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=_hold_stroke, args=(counts, 1, 0.15, child))
    proc.start()
    try:
        assert parent.poll(60), "the other worker did not start"
        kind, _ = parent.recv()
        assert kind == "began"
        mine.wait_turn()                    # the other worker's stroke holds this frame
        returned = time.monotonic()
        kind, ended = parent.recv()
        assert kind == "ended"
        assert returned >= ended, f"the frame started {ended - returned:.3f} s before the other worker's stroke ended"
        assert counts[1] == 0
    finally:
        proc.join(30)


def test_a_count_left_by_a_killed_worker_holds_frames_at_most_max_wait():
    ctx = mp.get_context("spawn")
    counts = ctx.RawArray("i", 4)          # two workers: strokes, then busy sessions
    counts[1] = 1                           # a worker killed in the middle of a stroke
    p = Priority()
    p.share(counts, 0)
    t0 = time.monotonic()
    p.wait_turn()
    waited = time.monotonic() - t0
    assert waited >= Priority.MAX_WAIT_S * 0.99, f"waited {waited:.3f} s, not for the stroke"
    # the bound itself is the pool's (it resets a slot when it starts a worker in it); here
    # only that the wait ends: a generous ceiling, not a speed claim
    assert waited < Priority.MAX_WAIT_S + 5.0, f"waited {waited:.3f} s for a stale count"


def test_the_pool_resets_a_slot_when_it_starts_a_worker_in_it(tmp_path):
    from server.workers import LocalWorkerPool
    from worker.jobs.runner import WorkerSettings

    pool = LocalWorkerPool(1, lambda slot: WorkerSettings(blob_root=str(tmp_path / "blobs"),
                                                          tmp_dir=str(tmp_path / f"w{slot}")))
    pool.urgent[0] = 3                      # left by a worker killed during strokes
    pool.urgent[1] = 2                      # and its busy sessions
    w = pool._spawn(0)
    try:
        assert list(pool.urgent) == [0, 0]
    finally:
        w.inq.put(("stop", None, None))
        w.proc.join(30)
        w.close_queues()


def test_a_stroke_of_the_waiting_session_ends_its_wait():
    """A session waiting its turn with a camera move takes its own new stroke at once."""
    p = Priority()
    calls = []

    def stroke_arrived() -> bool:          # true from its third poll on
        calls.append(1)
        return len(calls) >= 3

    with _held_elsewhere(p.first()):
        p.wait_turn(interrupt=stroke_arrived)
        # ended by the interrupt (a timeout ends the loop before calling it a third time)
        assert len(calls) == 3, f"the wait ended after {len(calls)} polls, not by the arriving stroke"
        assert p.urgent == 1, "the other stroke was still being handled"


def test_kernel_threads_share_the_cores_among_busy_sessions():
    """A session step's OpenMP threads: every core for a stroke or a session alone on the
    machine, the cores split among the busy sessions of every worker otherwise."""
    cores = os.cpu_count() or 1
    counts = mp.get_context("spawn").RawArray("i", 4)
    p = Priority()
    p.share(counts, 0)
    assert p.kernel_threads(1, urgent=False) == cores          # alone
    counts[3] = 3                                              # the other worker: three orbiting
    assert p.kernel_threads(1, urgent=False) == max(1, cores // 4)
    assert counts[2] == 1, "this worker's busy sessions are published for the others"
    assert p.kernel_threads(1, urgent=True) == cores           # a stroke: the others' frames wait


def test_openmp_threads_are_set_per_calling_thread():
    """Why a session thread sets its own thread count: libgomp keeps omp_set_num_threads per
    calling thread, so the worker's main thread setting it left every session thread at the
    default (two OpenMP threads each for eight sessions on two cores)."""
    from worker import native

    if native.lib is None:
        pytest.skip("the native kernels are not built")
    got = []

    def other():
        got.append(native.lib.glk_max_threads())
        native.set_threads(1)
        got.append(native.lib.glk_max_threads())

    before = native.lib.glk_max_threads()
    t = threading.Thread(target=other)
    t.start()
    t.join()
    assert got == [before, 1], got
    assert native.lib.glk_max_threads() == before, "another thread's setting changed this one's"


def test_a_frame_under_way_stands_aside_for_a_stroke_and_is_dropped_for_its_own():
    """A session's frame that answers no stroke calls its checkpoint between parts: it waits
    while a stroke is handled (here in this worker), and is given up at once when a stroke of
    its own session arrives (that stroke's frame shows the same messages one step later)."""
    from worker.jobs.runner import MAX_PAUSE_S, PRIORITY, SessionThread

    th = SessionThread("s1", {}, None, None)
    th.pause_left = MAX_PAUSE_S                                 # as a step sets it per frame
    assert th._checkpoint(th._urgent_waiting) is False          # nothing else going on

    def stroke_elsewhere(hold_s: float):
        holding, released = threading.Event(), []

        def other_stroke():
            with PRIORITY.first():
                holding.set()
                time.sleep(hold_s)
                released.append(time.monotonic())

        t = threading.Thread(target=other_stroke)
        t.start()
        holding.wait()
        t0 = time.monotonic()
        assert th._checkpoint(th._urgent_waiting) is False
        return t, t0, time.monotonic(), released

    t, _, returned, released = stroke_elsewhere(0.5 * MAX_PAUSE_S)
    t.join()
    assert released and returned >= released[0], "the frame went on while the stroke was handled"
    # a slow stroke holds a frame for what is left of its MAX_PAUSE_S, not longer
    th.pause_left = MAX_PAUSE_S
    t, t0, returned, released = stroke_elsewhere(10 * MAX_PAUSE_S)
    assert not released, "the frame waited for the whole of a slow stroke"
    assert returned - t0 >= 0.99 * MAX_PAUSE_S, f"paused {returned - t0:.3f} s, not for the stroke"
    assert th.pause_left <= 0
    assert th._checkpoint(th._urgent_waiting) is False          # spent: no second pause
    assert not released
    t.join()
    th.post({"seq": 5, "type": "view", "eye": [0, 0, 3]})
    assert th._checkpoint(th._urgent_waiting) is False          # a camera move does not drop it
    assert th._checkpoint(th._any_waiting) is True               # ... but does drop a still
    th.post({"seq": 6, "type": "stroke", "stroke": {}})
    assert th._checkpoint(th._urgent_waiting) is True


def test_frames_queue_for_a_slot_and_give_way_to_their_own_stroke():
    """A worker draws at most one stroke-less frame per slot at once; a frame waiting for a
    slot is given up (FrameCancelled) when its own session's stroke arrives."""
    from worker.jobs.runner import FrameSlots
    from worker.renderers.base import FrameCancelled

    slots = FrameSlots(1)
    polls = []
    with _held_elsewhere(slots.take(lambda: False)):        # another session's frame
        with pytest.raises(FrameCancelled):
            with slots.take(lambda: polls.append(1) or len(polls) >= 3):
                pytest.fail("a second frame got the only slot")
        assert len(polls) == 3
    with slots.take(lambda: True):          # a free slot is taken at once
        pass


def test_a_message_for_a_worker_that_just_died_is_held_for_its_replacement(tmp_path):
    """Between a worker's death and the monitor noticing it (every 0.25 s) its pipe is broken:
    a message sent then is held for the replacement, which gets it after the session is
    re-opened (it was a stream closed with 1011 "could not store your input")."""
    import asyncio
    import signal

    from server.workers import LocalWorkerPool
    from worker.jobs.runner import WorkerSettings

    seen = {}

    def restore(sid):
        seen["held"] = list(pool.held.get(sid, []))     # what waits for the re-opened session
        return None                                     # (not re-opened here: no scene)

    pool = LocalWorkerPool(1, lambda slot: WorkerSettings(blob_root=str(tmp_path / "blobs"),
                                                          tmp_dir=str(tmp_path / f"w{slot}")), restore=restore)
    pool.loop = asyncio.new_event_loop()                # the monitor is not started: no race
    w = pool._spawn(0)
    pool.owner["s1"] = w
    w.sessions.add("s1")
    msg = {"seq": 1, "type": "view", "eye": [0, 1, 3]}
    nw = None
    try:
        os.kill(w.proc.pid, signal.SIGKILL)
        w.proc.join(30)
        pool.send("s1", msg)                            # raised BrokenPipeError
        assert pool.held.get("s1") == [msg], pool.held
        pool._replace(0, w)
        nw = pool.workers[0]
        assert nw is not w and pool.owner["s1"] is nw
        assert seen["held"] == [msg], f"the monitor dropped the held message: {seen}"
    finally:
        for x in (w, nw):
            if x is not None and x.proc.is_alive():
                x.inq.put(("stop", None, None))
                x.proc.join(30)
            if x is not None:
                x.close_queues()
        pool.loop.close()
