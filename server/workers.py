"""The worker pool: the one narrow interface between the server and the workers.

``WorkerPool`` is what the routes use: ``run_job`` (precompute, render, fit, with progress),
``open_session`` / ``send`` / ``close_session`` and a per-session queue of frames and events.
``LocalWorkerPool`` implements it with local processes (multiprocessing, spawn); a Ray-backed
pool would implement the same methods.

A worker that dies is replaced; its sessions are re-opened on the new process from what the
server persisted (``restore`` callback), and its running jobs fail with a clear error.
"""
from __future__ import annotations

import asyncio
import itertools
import logging
import multiprocessing as mp
import os
import queue
import threading
from typing import Callable

log = logging.getLogger("glint.workers")


class JobFailed(RuntimeError):
    def __init__(self, message: str, status: int = 500):
        super().__init__(message)
        self.status = status


class WorkerPool:
    """Interface (see module docstring)."""

    async def run_job(self, job: dict, on_progress: Callable[[float, str], None] | None = None) -> dict:
        raise NotImplementedError

    def open_session(self, sid: str, payload: dict) -> asyncio.Queue:
        raise NotImplementedError

    def send(self, sid: str, msg: dict) -> None:
        raise NotImplementedError

    def close_session(self, sid: str) -> None:
        raise NotImplementedError

    def start(self) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        raise NotImplementedError


class _Worker:
    def __init__(self, wid: int, ctx, blob_root: str, threads: int):
        from worker.jobs.runner import worker_main

        self.wid = wid
        self.inq = ctx.Queue()
        self.outq = ctx.Queue()
        env = {"OPENBLAS_NUM_THREADS": "1", "OMP_WAIT_POLICY": "PASSIVE"}
        if threads:
            env["GLINT_THREADS"] = str(threads)
        old = {k: os.environ.get(k) for k in env}
        os.environ.update(env)           # inherited by the spawned interpreter
        try:
            self.proc = ctx.Process(target=worker_main, args=(wid, self.inq, self.outq, blob_root),
                                    name=f"glint-worker-{wid}", daemon=True)
            self.proc.start()
        finally:
            for k, v in old.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        self.sessions: set[str] = set()
        self.jobs: set[str] = set()


class LocalWorkerPool(WorkerPool):
    """``n`` local worker processes. ``restore(sid)`` returns the open payload of a session
    from the database (used after a worker dies)."""

    def __init__(self, n: int, blob_root: str, restore: Callable[[str], dict] | None = None, threads: int = 0):
        self.n = n
        self.blob_root = str(blob_root)
        self.restore = restore
        self.threads = threads
        self.ctx = mp.get_context("spawn")
        self.workers: list[_Worker] = []
        self.loop: asyncio.AbstractEventLoop | None = None
        self.session_queues: dict[str, asyncio.Queue] = {}
        self.owner: dict[str, _Worker] = {}
        self.futures: dict[str, tuple[asyncio.Future, Callable | None]] = {}
        self._ids = itertools.count()
        self._lock = threading.Lock()
        self._stopping = False
        self.restarts = 0

    # -- lifecycle ------------------------------------------------------------------------------
    def start(self) -> None:
        self.loop = asyncio.get_running_loop()
        for i in range(self.n):
            self._spawn(i)
        threading.Thread(target=self._monitor, daemon=True, name="glint-pool-monitor").start()

    def _spawn(self, slot: int) -> _Worker:
        w = _Worker(slot, self.ctx, self.blob_root, self.threads)
        if slot < len(self.workers):
            self.workers[slot] = w
        else:
            self.workers.append(w)
        threading.Thread(target=self._reader, args=(w,), daemon=True, name=f"glint-pool-reader-{slot}").start()
        return w

    def stop(self) -> None:
        self._stopping = True
        for w in self.workers:
            try:
                w.inq.put(("stop", None, None))
            except Exception:
                pass
        for w in self.workers:
            w.proc.join(timeout=3)
            if w.proc.is_alive():
                w.proc.kill()
            for q in (w.inq, w.outq):
                q.close()
                q.cancel_join_thread()

    # -- routing --------------------------------------------------------------------------------
    def _least_loaded(self) -> _Worker:
        return min(self.workers, key=lambda w: (len(w.sessions) + len(w.jobs), w.wid))

    async def run_job(self, job: dict, on_progress=None) -> dict:
        jid = f"j{next(self._ids)}"
        fut = self.loop.create_future()
        with self._lock:
            w = self._least_loaded()
            w.jobs.add(jid)
            self.futures[jid] = (fut, on_progress)
        w.inq.put(("job", jid, job))
        try:
            return await fut
        finally:
            with self._lock:
                w.jobs.discard(jid)
                self.futures.pop(jid, None)

    def open_session(self, sid: str, payload: dict) -> asyncio.Queue:
        with self._lock:
            q = self.session_queues.get(sid)
            if q is None:
                q = self.session_queues[sid] = asyncio.Queue(maxsize=256)
            w = self.owner.get(sid)
            if w is None:
                w = self._least_loaded()
                w.sessions.add(sid)
                self.owner[sid] = w
        w.inq.put(("open", sid, payload))
        return q

    def send(self, sid: str, msg: dict) -> None:
        w = self.owner.get(sid)
        if w is None:
            raise KeyError(sid)
        w.inq.put(("msg", sid, msg))

    def close_session(self, sid: str) -> None:
        with self._lock:
            w = self.owner.pop(sid, None)
            self.session_queues.pop(sid, None)
            if w is not None:
                w.sessions.discard(sid)
        if w is not None:
            w.inq.put(("close", sid, None))

    def worker_of(self, sid: str) -> int | None:
        w = self.owner.get(sid)
        return w.proc.pid if w else None

    # -- replies --------------------------------------------------------------------------------
    def _reader(self, w: _Worker) -> None:
        while True:
            try:
                item = w.outq.get(timeout=0.5)
            except queue.Empty:
                if not w.proc.is_alive() or self._stopping:
                    if w.outq.empty():
                        return
                continue
            except (EOFError, OSError):
                return
            self.loop.call_soon_threadsafe(self._dispatch, item)

    def _dispatch(self, item) -> None:
        kind, key, p = item
        if kind in ("progress", "result", "error"):
            fut, on_progress = self.futures.get(key, (None, None))
            if fut is None or fut.done():
                return
            if kind == "progress":
                if on_progress:
                    on_progress(p["progress"], p["message"])
            elif kind == "result":
                fut.set_result(p)
            else:
                if p.get("trace"):
                    log.error("job failed in a worker:\n%s", p["trace"])
                fut.set_exception(JobFailed(p["message"], p.get("status", 500)))
            return
        q = self.session_queues.get(key)
        if q is None:
            return
        if q.full():            # a stalled client: drop its oldest item rather than grow
            try:
                q.get_nowait()
            except asyncio.QueueEmpty:
                pass
        q.put_nowait((kind, p))

    # -- failure --------------------------------------------------------------------------------
    def _monitor(self) -> None:
        import time

        while not self._stopping:
            time.sleep(0.25)
            for slot, w in enumerate(list(self.workers)):
                if w.proc.is_alive() or self._stopping:
                    continue
                log.warning("worker %d (pid %s) died with exit code %s; replacing it", slot, w.proc.pid, w.proc.exitcode)
                self.restarts += 1
                with self._lock:
                    nw = self._spawn(slot)
                    lost_jobs = list(w.jobs)
                    moved = list(w.sessions)
                    for sid in moved:
                        self.owner[sid] = nw
                        nw.sessions.add(sid)
                for jid in lost_jobs:
                    fut, _ = self.futures.get(jid, (None, None))
                    if fut is not None:
                        self.loop.call_soon_threadsafe(
                            lambda f=fut: f.done() or f.set_exception(JobFailed("the worker running this job died; retry it", 503)))
                for sid in moved:
                    try:
                        payload = self.restore(sid) if self.restore else None
                    except Exception as e:  # the session cannot come back: tell its client
                        log.error("cannot restore session %s: %s", sid, e)
                        payload = None
                    if payload is None:
                        self.loop.call_soon_threadsafe(self._dispatch, ("event", sid, {
                            "type": "error", "fatal": True, "message": "the session could not be restored"}))
                        continue
                    nw.inq.put(("open", sid, payload))
                    self.loop.call_soon_threadsafe(self._dispatch, ("event", sid, {
                        "type": "note", "message": "the worker restarted; the session was restored"}))
