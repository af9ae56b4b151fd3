"""The worker process's entry point (``worker_main``): jobs (precompute, render, fit, capture)
on a job thread, and every interactive session on a thread of its own, talking to the server
through two pipes (the requests and replies are in ipc.py).

The parts live one concept a file: settings.py (WorkerSettings), ipc.py (PipeOut, JobError,
the pipe protocol), data_cache.py (DataCache), handlers.py (the job handlers' registry),
scheduling.py (Priority, FrameSlots), session_thread.py (SessionThread), and the session's
runtime in runtime.py. Their public names are importable from here too.

The worker reads no environment variables: everything comes in ``WorkerSettings``.
"""
from __future__ import annotations

import os
import queue
import threading
import traceback

from worker.memory import cap_malloc_arenas

from .data_cache import DataCache
from .handlers import JOBS, run_job  # noqa: F401
from .ipc import JobError, PipeOut, Reply, Request  # noqa: F401
from .scheduling import FRAME_SLOTS, MAX_PAUSE_S, PRIORITY, FrameSlots, Priority, is_urgent  # noqa: F401
from .session_thread import STILL_DELAY_S, SessionThread  # noqa: F401
from .settings import WorkerSettings


def _freeze_modules() -> None:
    """Import what sessions and jobs use, then freeze what exists (worker.memory.freeze_start_up)."""
    import worker.fit.fitter  # noqa: F401
    import worker.fit.solve  # noqa: F401
    import worker.jobs.runtime  # noqa: F401
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
        # with rendering at the server's priority, a stroke's message and its frame
        # waited ~30 ms (p50) behind frames in the server's event loop and the pipes
        os.nice(settings.nice)

    # before NumPy loads: BLAS must not spawn threads beside the OpenMP kernels (docs/design/conventions.md, measured facts)
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
                # extra: what the job has to show before it ends (a precomputation's preview)
                res = run_job(cache, p, lambda f, msg, extra=None, jid=jid: outq.put(
                    Reply("progress", jid, {"progress": f, "message": msg, **(extra or {})})))
                outq.put(Reply("result", jid, res))
            except JobError as e:
                outq.put(Reply("error", jid, {"message": str(e), "status": e.status}))
            except GlintError as e:
                outq.put(Reply("error", jid, {"message": str(e), "status": e.status}))
            except ValueError as e:
                outq.put(Reply("error", jid, {"message": str(e), "status": 422}))
            except Exception as e:  # a bug: keep the worker alive, report it
                outq.put(Reply("error", jid, {"message": f"internal error: {type(e).__name__}: {e}", "status": 500,
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
                    outq.put(Reply("event", key, {"type": "error", "fatal": True,
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
