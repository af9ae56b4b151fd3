"""The worker pool: the one narrow interface between the server and the workers.

``WorkerPool`` is what the routes use: ``run_job`` (precompute, render, fit, with progress),
``open_session`` / ``send`` / ``close_session`` and a per-session queue of frames and events.
``LocalWorkerPool`` implements it with local processes (multiprocessing, spawn); a Ray-backed
pool implements the same methods.

A worker that dies is replaced; its sessions are re-opened on the new process from what the
server persisted (``restore`` callback), and its running jobs fail with a clear error. While a
session is being restored, messages for it are held and sent after its ``open``, so the new
worker sees them in order; the runtime skips any the restored state already covers.
"""
from __future__ import annotations

import asyncio
import itertools
import logging
import multiprocessing as mp
import shutil
import threading
from typing import Callable

from worker.jobs.ipc import Reply, Request

log = logging.getLogger("glint.workers")


class JobFailed(RuntimeError):
    def __init__(self, message: str, status: int = 500):
        super().__init__(message)
        self.status = status


class WorkerPool:
    """Interface (see module docstring)."""

    async def run_job(self, job: dict, on_progress: Callable[..., None] | None = None) -> dict:
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

    def health(self) -> dict:
        return {}

    def worker_of(self, sid: str) -> int | None:
        """The process id of the worker serving a session; None when it has none (or the pool
        cannot tell)."""
        return None


class SessionQueue(asyncio.Queue):
    """Frames and events for one stream. Frames are latest-wins: when the client reads slower
    than frames come, older unread frames are dropped (and counted) rather than queued."""

    def __init__(self):
        super().__init__()
        self.dropped_frames = 0

    def push(self, kind: str, p) -> None:
        if kind == "frame":
            kept = [it for it in list(self._queue) if it[0] != "frame"]
            self.dropped_frames += len(self._queue) - len(kept)
            self._queue.clear()
            self._queue.extend(kept)
        elif self.qsize() > 512:        # a stalled client: events are bounded too
            self._queue.popleft()
        self.put_nowait((kind, p))


class _Worker:
    """One worker process and its two pipes. Plain pipes rather than multiprocessing queues:
    queues hold named semaphores, which a killed worker leaves behind (the resource tracker's
    'leaked semaphore' warnings at every shutdown); a pipe holds nothing but two descriptors."""

    def __init__(self, slot: int, ctx, settings, urgent=None):
        from worker.jobs.runner import PipeOut, worker_main

        self.slot = slot
        self.settings = settings
        req_r, req_w = ctx.Pipe(duplex=False)
        rep_r, rep_w = ctx.Pipe(duplex=False)
        self.proc = ctx.Process(target=worker_main, args=(slot, req_r, rep_w, settings, urgent),
                                name=f"glint-worker-{slot}", daemon=True)
        self.proc.start()
        req_r.close()                   # the child's ends: closed here so EOF means it is gone
        rep_w.close()
        self.inq = PipeOut(req_w)
        self.replies = rep_r
        self.sessions: set[str] = set()
        self.jobs: set[str] = set()

    def close_queues(self) -> None:
        for c in (self.inq, self.replies):
            try:
                c.close()
            except Exception:
                pass


class LocalWorkerPool(WorkerPool):
    """``n`` local worker processes.

    settings : a factory slot -> worker.jobs.runner.WorkerSettings (each worker gets its own
        scratch folder). restore : sid -> the open payload of a session from the database
        (used after a worker dies).
    """

    def __init__(self, n: int, settings: Callable[[int], object], restore: Callable[[str], dict] | None = None):
        self.n = n
        self.make_settings = settings
        self.restore = restore
        self.ctx = mp.get_context("spawn")
        # the workers' stroke counts, for strokes before frames across the machine's cores
        # (worker/jobs/runner.py Priority): shared memory without a lock, so nothing is left
        # behind when a worker is killed
        self.urgent = self.ctx.RawArray("i", 2 * n)     # strokes, then busy sessions, per worker
        self.workers: list[_Worker] = []
        self.loop: asyncio.AbstractEventLoop | None = None
        self.session_queues: dict[str, SessionQueue] = {}
        self.owner: dict[str, _Worker] = {}
        self.held: dict[str, list[dict]] = {}          # sessions being restored: their messages wait
        self.futures: dict[str, tuple[asyncio.Future, Callable | None]] = {}
        self._ids = itertools.count()
        self._lock = threading.Lock()
        self._stopping = False
        self.restarts = 0
        self._threads: list[threading.Thread] = []

    # -- lifecycle ------------------------------------------------------------------------------
    def start(self) -> None:
        self.loop = asyncio.get_running_loop()
        for i in range(self.n):
            self._spawn(i)
        t = threading.Thread(target=self._monitor, daemon=True, name="glint-pool-monitor")
        t.start()
        self._threads.append(t)

    def _spawn(self, slot: int) -> _Worker:
        settings = self.make_settings(slot)
        shutil.rmtree(settings.tmp_dir, ignore_errors=True)      # what a dead worker left behind
        self.urgent[slot] = 0           # a worker killed during a stroke must not hold the others
        self.urgent[self.n + slot] = 0
        w = _Worker(slot, self.ctx, settings, self.urgent)
        if slot < len(self.workers):
            self.workers[slot] = w
        else:
            self.workers.append(w)
        t = threading.Thread(target=self._reader, args=(w,), daemon=True, name=f"glint-pool-reader-{slot}")
        t.start()
        self._threads.append(t)
        return w

    def stop(self) -> None:
        self._stopping = True
        for w in self.workers:
            try:
                w.inq.put(Request("stop", None, None))
            except Exception:
                pass
        for w in self.workers:
            w.proc.join(timeout=5)
            if w.proc.is_alive():
                w.proc.kill()
                w.proc.join(timeout=2)
        for t in self._threads:
            t.join(timeout=2)
        for w in self.workers:
            w.close_queues()
            shutil.rmtree(w.settings.tmp_dir, ignore_errors=True)

    def health(self) -> dict:
        alive = [w.proc.is_alive() for w in self.workers]
        return {"workers": len(alive), "workers_alive": sum(alive), "worker_restarts": self.restarts,
                "sessions": len(self.owner)}

    # -- routing --------------------------------------------------------------------------------
    def _least_loaded(self) -> _Worker:
        # a worker found dead is skipped (the monitor is replacing it); if all are, any will do:
        # the monitor fails its jobs and restores its sessions within a moment
        alive = [w for w in self.workers if w.proc.is_alive()] or self.workers
        return min(alive, key=lambda w: (len(w.sessions) + 2 * len(w.jobs), w.slot))

    async def run_job(self, job: dict, on_progress=None) -> dict:
        jid = f"j{next(self._ids)}"
        fut = self.loop.create_future()
        with self._lock:
            w = self._least_loaded()
            w.jobs.add(jid)
            self.futures[jid] = (fut, on_progress)
        w.inq.put(Request("job", jid, job))
        try:
            return await fut
        finally:
            with self._lock:
                w.jobs.discard(jid)
                self.futures.pop(jid, None)

    def open_session(self, sid: str, payload: dict) -> SessionQueue:
        with self._lock:
            q = self.session_queues.get(sid)
            if q is None:
                q = self.session_queues[sid] = SessionQueue()
            w = self.owner.get(sid)
            if w is None:
                w = self._least_loaded()
                w.sessions.add(sid)
                self.owner[sid] = w
        w.inq.put(Request("open", sid, payload))
        return q

    def send(self, sid: str, msg: dict) -> None:
        while True:
            with self._lock:
                if sid in self.held:
                    self.held[sid].append(msg)
                    return
                w = self.owner.get(sid)
            if w is None:
                raise KeyError(sid)
            try:
                w.inq.put(Request("msg", sid, msg))
                return
            except (OSError, ValueError):
                # the worker died and the monitor (every 0.25 s) has not replaced it yet: its
                # pipe is broken (or already closed). Hold the message as the monitor would; it
                # goes to the replacement after the session is re-opened from the database
                # (which already holds what the message changed, so it is applied once)
                with self._lock:
                    if self.owner.get(sid) is w and sid not in self.held:
                        self.held[sid] = []

    def close_session(self, sid: str) -> None:
        with self._lock:
            w = self.owner.pop(sid, None)
            self.session_queues.pop(sid, None)
            self.held.pop(sid, None)
            if w is not None:
                w.sessions.discard(sid)
        if w is not None:
            w.inq.put(Request("close", sid, None))

    def worker_of(self, sid: str) -> int | None:
        w = self.owner.get(sid)
        return w.proc.pid if w else None

    # -- replies --------------------------------------------------------------------------------
    def _reader(self, w: _Worker) -> None:
        while True:
            try:
                if not w.replies.poll(0.5):
                    if not w.proc.is_alive() or self._stopping:
                        return
                    continue
                item = w.replies.recv()
            except (EOFError, OSError, ValueError, TypeError):
                return
            try:
                self.loop.call_soon_threadsafe(self._dispatch, item)
            except RuntimeError:        # the event loop is closed: the server is stopping
                return

    def _dispatch(self, item) -> None:
        kind, key, p = item
        if kind in ("progress", "result", "error"):
            fut, on_progress = self.futures.get(key, (None, None))
            if fut is None or fut.done():
                return
            if kind == "progress":
                if on_progress:
                    extra = {k: v for k, v in p.items() if k not in ("progress", "message")}
                    if extra:       # what the job shows before it ends (a precomputation's preview)
                        on_progress(p["progress"], p["message"], extra)
                    else:
                        on_progress(p["progress"], p["message"])
            elif kind == "result":
                fut.set_result(p)
            else:
                if p.get("trace"):
                    log.error("job failed in a worker:\n%s", p["trace"])
                fut.set_exception(JobFailed(p["message"], p.get("status", 500)))
            return
        if kind == "closed":
            return
        q = self.session_queues.get(key)
        if q is not None:
            q.push(kind, p)

    # -- failure --------------------------------------------------------------------------------
    def _monitor(self) -> None:
        import time

        while not self._stopping:
            time.sleep(0.25)
            for slot, w in enumerate(list(self.workers)):
                if w.proc.is_alive() or self._stopping:
                    continue
                self._replace(slot, w)

    def _replace(self, slot: int, w: _Worker) -> None:
        """A dead worker: a new one in its slot, its jobs failed, its sessions restored."""
        log.warning("worker %d (pid %s) died with exit code %s; replacing it", slot, w.proc.pid, w.proc.exitcode)
        self.restarts += 1
        with self._lock:
            nw = self._spawn(slot)
            lost_jobs = list(w.jobs)
            moved = list(w.sessions)
            for sid in moved:
                self.owner[sid] = nw
                nw.sessions.add(sid)
                # hold its messages until it is open again (with those ``send`` already held
                # when it found the dead worker's pipe broken)
                self.held.setdefault(sid, [])
        w.close_queues()
        for jid in lost_jobs:
            fut, _ = self.futures.get(jid, (None, None))
            if fut is not None:
                self.loop.call_soon_threadsafe(
                    lambda f=fut: f.done() or f.set_exception(JobFailed("the worker running this job died; retry it", 503)))
        for sid in moved:
            self._restore(sid, nw)

    def _restore(self, sid: str, nw: _Worker) -> None:
        try:
            payload = self.restore(sid) if self.restore else None
            if payload is not None:
                # the runtime sends the refit of the stored strokes at once (a fit event the
                # server stores): what the dead worker fitted last may never have reached it
                payload = {**payload, "restored": True}
        except Exception as e:  # the session cannot come back: tell its client
            log.error("cannot restore session %s: %s", sid, e)
            payload = None
        with self._lock:
            held = self.held.pop(sid, [])
            if payload is not None and self.owner.get(sid) is nw:
                nw.inq.put(Request("open", sid, payload))
                for m in held:
                    nw.inq.put(Request("msg", sid, m))
        if payload is None:
            self.loop.call_soon_threadsafe(self._dispatch, Reply("event", sid, {
                "type": "error", "fatal": True, "message": "the session could not be restored"}))
            return
        self.loop.call_soon_threadsafe(self._dispatch, Reply("event", sid, {
            "type": "note", "message": "the worker restarted; the session was restored"}))


def make_pool(settings, restore: Callable[[str], dict] | None = None) -> WorkerPool:
    """The pool ``settings.backend`` names: local processes (default) or a Ray cluster."""
    if settings.backend == "ray":
        from .ray_pool import RayWorkerPool

        def host_settings(slot: int):
            return settings.worker_settings(slot).model_copy(update={
                "tmp_dir": str(settings.data_dir / "tmp" / f"ray-{slot}"), "threads": settings.worker_threads})
        return RayWorkerPool(settings.workers, host_settings, restore=restore, address=settings.ray_address,
                             node_ip=settings.ray_node_ip, chunks_per_cpu=settings.ray_chunks_per_cpu)
    return LocalWorkerPool(settings.workers, settings.worker_settings, restore=restore)
