"""Worker-side Ray pieces (issue 17): the session host actor and the precomputation tasks.

``SessionHost`` is a worker process whose two pipes are Ray calls: it runs the very same
``worker_main`` as a local worker (runner.py: jobs on a thread, every session on a thread of its
own, loaded scenes shared through one ``DataCache``), fed by ``control`` and drained by ``poll``.
A Ray pool (server/ray_pool.py) keeps a few of them spread over the cluster's nodes and places
each session on the least loaded one, exactly as the local pool places sessions on processes;
when one dies, the pool re-opens its sessions on a replacement from the database.

Precomputations are not run inside the host: the host coordinates them. It loads the scene,
asks the renderer's ``Precomputation`` for its parts, splits each missing part into ``chunks``
(vertex ranges on batch boundaries for the cut renderer), runs one Ray task per chunk with
``SPREAD`` scheduling so that every node of the cluster takes a share, gathers the results in
chunk order and ``assemble``\\ s them into the part's bytes: the same bytes as a single local run
(tests/scale). Tasks report progress back to the host (``tick``), which reports it to the pool
in the same messages as a local worker.

Blobs: every node reads meshes and maps, and the host writes parts, through ``BlobStore`` at the
same ``blob_root`` path; on several hosts that path must be a shared directory (NFS, a mounted
volume) or the store an S3-compatible one behind the same methods (worker/blobs.py).

Nothing here imports the tracer, OpenCV or the solvers at module level: the API process imports
this module to name the actor class, and must stay free of them (tests/scale/test_ray.py).
"""
from __future__ import annotations

import atexit
import os
import queue
import shutil
import tempfile
import threading
import time
import traceback
from collections import deque
from pathlib import Path

import ray

from .runner import JobError, WorkerSettings, worker_main


# -- the host's pipes --------------------------------------------------------------------------


class _Inbox:
    """The requests end worker_main reads (``recv``), filled by ``control`` calls."""

    def __init__(self):
        self.q: queue.Queue = queue.Queue()

    def recv(self):
        return self.q.get()

    def put(self, item) -> None:
        self.q.put(item)

    def close(self) -> None:
        pass


class _Outbox:
    """The replies end worker_main writes (``send``), drained by ``poll`` in batches."""

    def __init__(self):
        self.items: deque = deque()
        self.cv = threading.Condition()

    def send(self, item) -> None:
        with self.cv:
            self.items.append(item)
            self.cv.notify_all()

    def drain(self, timeout: float, limit: int = 256) -> list:
        with self.cv:
            if not self.items:
                self.cv.wait(timeout)
            out = []
            while self.items and len(out) < limit:
                out.append(self.items.popleft())
            return out

    def close(self) -> None:
        pass


def _error_reply(e: BaseException) -> dict:
    """The same mapping as a local worker's job loop: bad input → its status, a bug → 500."""
    from worker.errors import GlintError

    if isinstance(e, (JobError, GlintError)):
        return {"message": str(e), "status": e.status}
    if isinstance(e, ValueError):
        return {"message": str(e), "status": 422}
    return {"message": f"internal error: {type(e).__name__}: {e}", "status": 500, "trace": traceback.format_exc()}


class SessionHost:
    """A Ray actor running ``worker_main`` (see the module docstring).

    ``control(n, item)`` delivers the n-th request of the pool to this host (items as in
    runner.py: ("job" | "open" | "msg" | "close" | "stop", key, payload)); a threaded actor does
    not keep call order, so requests are applied strictly by n. ``poll(timeout)`` returns the
    replies queued since the last poll (waiting up to timeout for the first)."""

    def __init__(self, slot: int, settings: WorkerSettings, chunks_per_cpu: float = 2.0):
        self.slot = slot
        self.chunks_per_cpu = chunks_per_cpu
        self.settings = settings
        self.requests = _Inbox()
        self.replies = _Outbox()
        self._next = 0
        self._pending: dict[int, tuple] = {}
        self._order = threading.Lock()
        self._jobs: dict[str, list] = {}            # precompute job id -> [done, total, last reported]
        self._jobs_lock = threading.Lock()
        self._pre_cache = None
        self.thread = threading.Thread(target=worker_main, args=(slot, self.requests, self.replies, settings),
                                       daemon=True, name="glint-worker-main")
        self.thread.start()

    def whoami(self) -> dict:
        ctx = ray.get_runtime_context()
        return {"pid": os.getpid(), "node_id": ctx.get_node_id(), "slot": self.slot}

    def control(self, n: int, item: tuple) -> None:
        with self._order:
            self._pending[n] = item
            while self._next in self._pending:
                it = self._pending.pop(self._next)
                self._next += 1
                self._route(it)

    def _route(self, item: tuple) -> None:
        kind, key, p = item
        if kind == "job" and isinstance(p, dict) and p.get("type") == "precompute":
            threading.Thread(target=self._precompute, args=(key, p), daemon=True, name=f"glint-pre-{key}").start()
        else:
            self.requests.put(item)

    def poll(self, timeout: float = 0.5) -> list:
        return self.replies.drain(timeout)

    def stop(self) -> bool:
        self.requests.put(("stop", None, None))
        self.thread.join(timeout=5)
        if self._pre_cache is not None:
            self._pre_cache.close()
        return not self.thread.is_alive()

    # -- precomputations across the cluster ------------------------------------------------------
    def tick(self, jid: str, k: int) -> None:
        """Units of work done by a chunk task (or a cached part) of job ``jid``."""
        with self._jobs_lock:
            st = self._jobs.get(jid)
            if st is None:
                return
            st[0] += k
            f = min(1.0, st[0] / st[1])
            if not (f - st[2] >= 0.01 or st[0] >= st[1]):
                return
            st[2] = f
            done, total = st[0], st[1]
        self.replies.send(("progress", jid, {"progress": f, "message": f"{done}/{total}"}))

    def _precompute(self, jid: str, p: dict) -> None:
        try:
            res = self._run_precompute(jid, p)
            self.replies.send(("result", jid, res))
        except BaseException as e:  # noqa: BLE001 -- reported to the pool, the host lives on
            self.replies.send(("error", jid, _error_reply(e)))
        finally:
            with self._jobs_lock:
                self._jobs.pop(jid, None)

    def _run_precompute(self, jid: str, p: dict) -> dict:
        from worker.renderers import get

        from .runner import DataCache

        if self._pre_cache is None:
            self._pre_cache = DataCache(self.settings.model_copy(update={"tmp_dir": self.settings.tmp_dir + "-pre"}))
        cache = self._pre_cache
        w_job = time.time()
        scene_p = p["scene"]
        kind = scene_p.get("renderer") or "cuts"
        _, pre = get(kind)
        sc = cache.scene(scene_p)
        options = scene_p.get("options") or {}
        parts = pre.parts(sc, options)
        total = max(1, sum(x.work for x in parts))
        with self._jobs_lock:
            self._jobs[jid] = [0, total, -1.0]
        cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
        n = max(1, round(cpus * self.chunks_per_cpu))
        me = ray.get_runtime_context().current_actor
        t0 = time.perf_counter()
        tl = {"prepare": time.time() - w_job}
        info, computed, ray_stats = {}, 0, {}
        for part in parts:
            blob = cache.parts.get(part.key)
            if blob is not None:
                info[part.key] = {"label": part.label, "cached": True, **pre.describe(sc, part, blob)}
                self.tick(jid, part.work)
                continue
            t1, w_sub = time.perf_counter(), time.time()
            chunks = pre.chunks(sc, part, options, n)
            refs = [compute_chunk.options(scheduling_strategy="SPREAD").remote(
                self.settings, scene_p, kind, part, options, ch, me, jid) for ch in chunks]
            results = ray.get(refs)                 # in chunk order, whatever order they finished in
            w_res = time.time()
            blob, stats = pre.assemble(sc, part, options, [r["result"] for r in results])
            w_asm = time.time()
            cache.parts.put(part.key, blob)
            tl.update(_timeline(results, w_sub, w_res, w_asm))
            wall = time.perf_counter() - t1
            nodes = sorted({r["node_id"] for r in results})
            ray_stats = {"ray_chunks": len(chunks), "ray_nodes": len(nodes), "ray_cpus": cpus,
                         "seconds_wall": wall, "seconds_chunks_max": max(r["seconds"] for r in results),
                         # chunk seconds summed over wall time: how many chunks ran at once (the
                         # parallelism the cluster gave, whatever else loads the machines)
                         "seconds_chunks_sum": sum(r["seconds"] for r in results),
                         "cpu_seconds_chunks_sum": sum(r["cpu_seconds"] for r in results)}
            info[part.key] = {"label": part.label, "cached": False, "seconds": wall, "bytes": len(blob),
                              **stats, **ray_stats}
            computed += 1
        manifest = {k: cache.parts.sha(k) for k in info}
        flat = {}
        for v in info.values():
            flat.update({k: x for k, x in v.items() if k != "label"})
        return {"kind": kind, "parts": manifest,
                "stats": {**flat, "seconds": time.perf_counter() - t0, "computed": computed, "backend": "ray",
                          "timeline": tl}}


def _timeline(results: list[dict], w_sub: float, w_res: float, w_asm: float) -> dict:
    """Where a part's wall time went (seconds, from the tasks' and the host's wall clocks):
    submission to the first task running (worker start), the tasks' set-up (imports, scene,
    tracer: first task of each process) and compute, the gap between the first and the last
    node finishing (imbalance), the last result to the end of assembly, then storing."""
    first = min(r["t"][0] for r in results)
    ends: dict = {}
    for r in results:
        ends[r["node_id"]] = max(ends.get(r["node_id"], 0.0), r["t"][2])
    return {"submit_to_first_task": first - w_sub,
            "task_setup_max": max(r["t"][1] - r["t"][0] for r in results),
            "task_setup_sum": sum(r["t"][1] - r["t"][0] for r in results),
            "task_compute_sum": sum(r["t"][2] - r["t"][1] for r in results),
            "tasks_span": max(ends.values()) - first,
            "node_finish_spread": max(ends.values()) - min(ends.values()),
            "last_task_to_results": w_res - max(ends.values()),
            "assemble": w_asm - w_res, "store": time.time() - w_asm,
            "processes": len({(r["node_id"], r["pid"]) for r in results})}


# -- chunk tasks ----------------------------------------------------------------------------------
_task_caches: dict[str, object] = {}


def _task_cache(settings: WorkerSettings):
    """One DataCache per Ray worker process and blob store (task processes are reused, so a scene
    loaded by one chunk is there for the next); its scratch folder is local to the node."""
    from .runner import DataCache

    c = _task_caches.get(settings.blob_root)
    if c is None:
        # Ray ends its worker processes without running atexit, so each process's folder is named
        # by its pid and the folders of processes that are gone are removed here
        base = Path(tempfile.gettempdir())
        for old in base.glob("glint-task-*"):
            pid = old.name.split("-")[2]                  # glint-task-<pid>-<n>
            if pid.isdigit() and not _alive(int(pid)):
                shutil.rmtree(old, ignore_errors=True)
        tmp = base / f"glint-task-{os.getpid()}-{len(_task_caches)}"
        atexit.register(shutil.rmtree, tmp, True)
        c = _task_caches[settings.blob_root] = DataCache(settings.model_copy(update={"tmp_dir": str(tmp)}))
    return c


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@ray.remote(num_cpus=1, max_retries=1)
def compute_chunk(settings: WorkerSettings, scene_p: dict, kind: str, part, options: dict, chunk, host, jid: str) -> dict:
    """One chunk of a part, on one CPU of whichever node Ray chose; progress goes to ``host``
    at most a few times a second. Returns {"result": what Precomputation.assemble takes,
    "node_id", "seconds"}."""
    w0 = time.time()
    os.environ["OPENBLAS_NUM_THREADS"] = "1"         # before NumPy loads in a fresh task process
    from worker import native
    from worker.renderers import get

    native.set_threads(1)                            # one CPU per task: no OpenMP oversubscription
    t0, c0 = time.perf_counter(), time.process_time()
    cache = _task_cache(settings)
    _, pre = get(kind)
    sc = cache.scene(scene_p)
    w1 = time.time()
    pending = [0, time.monotonic()]
    lock = threading.Lock()

    def progress(k: int) -> None:
        with lock:
            pending[0] += k
            if time.monotonic() - pending[1] < 0.25:
                return
            k, pending[0], pending[1] = pending[0], 0, time.monotonic()
        host.tick.remote(jid, k)

    res = pre.compute(sc, part, options, chunk, progress, threads=1)
    if pending[0]:
        host.tick.remote(jid, pending[0])
    return {"result": res, "node_id": ray.get_runtime_context().get_node_id(), "seconds": time.perf_counter() - t0,
            "cpu_seconds": time.process_time() - c0, "pid": os.getpid(), "t": (w0, w1, time.time())}
