"""The worker pool on a Ray cluster: ``glint serve --backend ray [--ray-address ADDR]``.

Same interface and same behaviour as ``LocalWorkerPool`` (server/workers.py), whose routing,
session restore and message holding this class inherits unchanged; only what a "worker" is
differs:

- a worker is a ``SessionHost`` actor (worker/jobs/ray_actors.py) running the local worker's
  ``worker_main``; its pipes are Ray calls (``control`` in, ``poll`` out). The hosts are created
  with ``SPREAD`` scheduling, so they sit on different nodes, and a session goes to the host with
  the fewest sessions and jobs (placed by load). They reserve no CPU (num_cpus=0): the cluster's
  CPUs are left to the precomputation tasks.
- a precomputation is coordinated by a host and split into vertex-range tasks over every node
  of the cluster (byte-identical to a local run after assembly), with progress as today.
- a host that dies (its process killed, its node lost) is noticed by the call that polls it;
  the inherited monitor then starts a replacement, fails the jobs it ran (503, "died") and
  re-opens its sessions from the database, holding their messages until they are open.

The API process only submits and polls: it imports Ray but no numerical library.
"""
from __future__ import annotations

import logging
import signal
import threading
import time
from typing import Callable

import ray
from ray.exceptions import GetTimeoutError, RayActorError

from worker.jobs.ray_actors import SessionHost, warm_up

from .workers import LocalWorkerPool

log = logging.getLogger("glint.workers")
HostActor = ray.remote(SessionHost)


class _HostProcess:
    """What the inherited monitor reads of a worker process: alive, pid, exit code."""

    def __init__(self):
        self.alive = True
        self.pid: int | None = None
        self.node_id: str | None = None
        self.exitcode: str | None = None

    def is_alive(self) -> bool:
        return self.alive


class _HostInbox:
    """Requests to one host, numbered so that the host applies them in the order sent."""

    def __init__(self, actor):
        self.actor = actor
        self.n = 0
        self.lock = threading.Lock()

    def put(self, item) -> None:
        with self.lock:
            n, self.n = self.n, self.n + 1
            self.actor.control.remote(n, item)


class _RayWorker:
    def __init__(self, slot: int, actor, settings):
        self.slot = slot
        self.actor = actor
        self.settings = settings
        self.inq = _HostInbox(actor)
        self.proc = _HostProcess()
        self.sessions: set[str] = set()
        self.jobs: set[str] = set()

    def close_queues(self) -> None:
        try:
            ray.kill(self.actor, no_restart=True)
        except Exception:
            pass


class RayWorkerPool(LocalWorkerPool):
    """``n`` session hosts on the Ray cluster at ``address`` (None: start a local one).

    settings : slot -> WorkerSettings (blob_root must be reachable at that path on every node).
    restore : sid -> a session's open payload from the database (after a host dies).
    node_ip : this process's address as the cluster sees it (Ray's ``_node_ip_address``).
    chunks_per_cpu : pieces per cluster CPU a part is cut into (grouped into guided chunks).
    """

    def __init__(self, n: int, settings: Callable[[int], object], restore=None, address: str | None = None,
                 node_ip: str | None = None, chunks_per_cpu: float = 32.0):
        super().__init__(n, settings, restore)
        self.address = address
        self.node_ip = node_ip
        self.chunks_per_cpu = chunks_per_cpu
        self._owns_ray = False
        self._nodes_cache = (0.0, 0)

    # -- lifecycle ------------------------------------------------------------------------------
    def start(self) -> None:
        import asyncio

        if not ray.is_initialized():
            kw = {"namespace": "glint", "logging_level": logging.WARNING, "ignore_reinit_error": True}
            if self.node_ip:
                kw["_node_ip_address"] = self.node_ip
            if self.address:
                kw["address"] = self.address
            else:                       # a one-machine cluster of our own (never someone else's)
                kw.update(address="local", include_dashboard=False)
            # ray.init replaces the SIGTERM handler with sys.exit; the server's graceful
            # shutdown (uvicorn's handler) must keep it
            old = signal.getsignal(signal.SIGTERM) if threading.current_thread() is threading.main_thread() else None
            ray.init(**kw)
            if old is not None:
                signal.signal(signal.SIGTERM, old)
            self._owns_ray = True
        res = ray.cluster_resources()
        log.info("Ray cluster %s: %d node(s), %g CPU(s); %d session host(s)", self.address or "(local)",
                 self._nodes(), res.get("CPU", 0), self.n)
        self.loop = asyncio.get_running_loop()
        for i in range(self.n):
            self._spawn(i)
        # a task process per cluster CPU starts and imports now, not inside the first precomputation
        self._warm = [warm_up.options(scheduling_strategy="SPREAD").remote("cuts") for _ in range(int(res.get("CPU", 0)))]
        t = threading.Thread(target=self._monitor, daemon=True, name="glint-pool-monitor")
        t.start()
        self._threads.append(t)

    def _spawn(self, slot: int) -> _RayWorker:
        settings = self.make_settings(slot)
        actor = HostActor.options(num_cpus=0, max_concurrency=16, max_restarts=0, scheduling_strategy="SPREAD",
                                  name=None).remote(slot, settings, self.chunks_per_cpu)
        w = _RayWorker(slot, actor, settings)
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
        refs = []
        for w in self.workers:
            try:
                refs.append(w.actor.stop.remote())
            except Exception:
                pass
        if refs:
            try:
                ray.wait(refs, num_returns=len(refs), timeout=10)
            except Exception:
                pass
        for w in self.workers:
            w.close_queues()
        for t in self._threads:
            t.join(timeout=2)
        if self._owns_ray:
            ray.shutdown()

    def _nodes(self) -> int:
        t, n = self._nodes_cache
        if time.monotonic() - t > 2.0:
            n = sum(1 for x in ray.nodes() if x.get("Alive"))
            self._nodes_cache = (time.monotonic(), n)
        return n

    def health(self) -> dict:
        h = super().health()
        try:
            h["ray_nodes"] = self._nodes()
        except Exception:
            h["ray_nodes"] = 0
        return {**h, "backend": "ray"}

    # -- replies --------------------------------------------------------------------------------
    def _reader(self, w: _RayWorker) -> None:
        try:
            info = ray.get(w.actor.whoami.remote(), timeout=300)
            w.proc.pid, w.proc.node_id = info["pid"], info["node_id"]
            log.info("session host %d: pid %s on node %s", w.slot, info["pid"], info["node_id"][:8])
        except (RayActorError, GetTimeoutError) as e:
            if not self._stopping:
                log.error("session host %d did not start: %s", w.slot, e)
                time.sleep(1.0)                 # no busy loop of replacements if hosts cannot start
            w.proc.exitcode = "did not start"
            w.proc.alive = False
            return
        while not self._stopping:
            try:
                items = ray.get(w.actor.poll.remote(0.5), timeout=60)
            except GetTimeoutError:
                continue
            except RayActorError as e:
                w.proc.exitcode = type(e).__name__
                w.proc.alive = False
                return
            except Exception as e:  # the cluster is going away
                if not self._stopping:
                    log.error("session host %d: %s", w.slot, e)
                    w.proc.exitcode = type(e).__name__
                    w.proc.alive = False
                return
            for item in items:
                try:
                    self.loop.call_soon_threadsafe(self._dispatch, tuple(item))
                except RuntimeError:        # the event loop is closed: the server is stopping
                    return
