"""Worker-side Ray pieces: the session host actor and the precomputation tasks.

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
in the same messages as a local worker. The serial work around the tasks is kept short
(``_run_precompute``): worker processes warm up while the host loads the scene, the tasks get
the loaded scene and the direction tree from the object store, and every part is submitted at
once; the job's stats carry a ``timeline`` of where the time went.

Blobs: the host reads meshes and maps and writes parts through ``BlobStore`` at ``blob_root``;
the tasks read nothing from it (their scene comes through Ray's object store). Session hosts on
several machines must all reach that path: a shared directory (NFS, a mounted volume) or an
S3-compatible store behind the same methods (worker/blobs.py).

Nothing here imports the tracer, OpenCV or the solvers at module level: the API process imports
this module to name the actor class, and must stay free of them (tests/scale/test_ray.py).
"""
from __future__ import annotations

import itertools
import os
import queue
import threading
import time
import traceback
from collections import OrderedDict, deque

import ray

from ..keys import content_key
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

    def __init__(self, slot: int, settings: WorkerSettings, chunks_per_cpu: float = 32.0):
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
        # what every precomputation's coordination needs (modules, the direction tree: ~2 s in a
        # fresh process), made once when the host starts rather than inside its first job
        self._warm = threading.Thread(target=_host_warm_up, daemon=True, name="glint-host-warm-up")
        self._warm.start()

    def whoami(self) -> dict:
        ctx = ray.get_runtime_context()
        return {"pid": os.getpid(), "node_id": ctx.get_node_id(), "slot": self.slot}

    def ready(self) -> bool:
        """Wait until the host's start-up warm-up (modules, direction tree) is done."""
        self._warm.join()
        return True

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
        """The parts missing from the store, each split into chunk tasks over the cluster.

        What is serial is kept short and overlapped (timeline in the stats):
        - warm-up tasks start a worker process on every node and import the numerical modules
          *while* this host loads the scene and names the parts;
        - the loaded scene and the direction tree go into the object store once (``ray.put``)
          and every task reads them from there (NumPy arrays without a copy): no task re-reads
          or re-verifies a blob, parses a mesh or builds the tree;
        - the chunks of every missing part are submitted at once, so a part's assembly overlaps
          the next part's tasks; a part is assembled as soon as its own chunks are back.
        """
        w_job = time.time()
        scene_p = p["scene"]
        kind = scene_p.get("renderer") or "cuts"
        cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
        warm = [warm_up.options(scheduling_strategy="SPREAD").remote(kind) for _ in range(cpus)]
        self._warm.join()
        from worker.core.directions import get_tree
        from worker.renderers import get

        from .runner import DataCache

        if self._pre_cache is None:
            self._pre_cache = DataCache(self.settings.model_copy(update={"tmp_dir": self.settings.tmp_dir + "-pre"}))
        cache = self._pre_cache
        _, pre = get(kind)
        sc = cache.scene(scene_p)
        options = scene_p.get("options") or {}
        parts = pre.parts(sc, options)
        total = max(1, sum(x.work for x in parts))
        with self._jobs_lock:
            self._jobs[jid] = [0, total, -1.0]
        n = max(1, round(cpus * self.chunks_per_cpu))
        me = ray.get_runtime_context().current_actor
        t0 = time.perf_counter()
        tl: dict = {"prepare": time.time() - w_job}
        info, computed, ray_stats, todo, jobs, preview = {}, 0, {}, [], [], {}
        for part in parts:
            blob = cache.parts.get(part.key)
            if blob is not None:
                info[part.key] = {"label": part.label, "cached": True, **pre.describe(sc, part, blob)}
                self.tick(jid, part.work)
            else:
                todo.append(part)
        if todo:
            w_sub = time.time()
            shipped = [_scene_key(scene_p), ray.put(_portable(sc)), ray.put(get_tree())]
            for part in todo:
                chunks = guided(pre.chunks(sc, part, options, n), cpus)
                jobs.append((part, chunks, [compute_chunk.options(scheduling_strategy="SPREAD").remote(
                    shipped, kind, part, options, ch, me, jid) for ch in chunks]))
            tl["submit"] = time.time() - w_sub
            if len(sc.mesh.vertices) >= self.settings.preview_min_vertices:
                # the first look (renderers/cuts/preview.py), drawn here while the cluster traces
                from .handlers import first_look

                preview = first_look(cache, sc)
                if preview:
                    with self._jobs_lock:
                        st = self._jobs.get(jid) or [0, 1, 0.0]
                    self.replies.send(("progress", jid, {"progress": min(1.0, st[0] / st[1]),
                                                         "message": "a first look at the scene: ready",
                                                         "preview": preview}))
        for part, chunks, refs in jobs:
            results = ray.get(refs)                 # in chunk order, whatever order they finished in
            w_res = time.time()
            blob, stats = pre.assemble(sc, part, options, [r["result"] for r in results])
            w_asm = time.time()
            cache.parts.put(part.key, blob)
            tl.update(_timeline(results, w_sub, w_res, w_asm))
            wall = time.time() - w_sub              # from submission (all parts at once) to this part stored
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
        try:             # which processes warmed up (never waited for: a busy cluster may still queue them)
            done, _ = ray.wait(warm, num_returns=len(warm), timeout=0)
            tl["warm_processes"] = len(set(ray.get(done)))
        except Exception as e:                      # noqa: BLE001 -- a warm-up is no part of the result
            tl["warm_error"] = f"{type(e).__name__}: {e}"
        manifest = {k: cache.parts.sha(k) for k in info}
        flat = {}
        for v in info.values():
            flat.update({k: x for k, x in v.items() if k != "label"})
        tl["job"] = time.time() - w_job
        return {"kind": kind, "parts": manifest,
                "stats": {**flat, "seconds": time.perf_counter() - t0, "computed": computed, "backend": "ray",
                          "timeline": tl, **({"preview": preview} if preview else {})}}


def guided(pieces: list, cpus: int) -> list:
    """Consecutive pieces grouped into chunks of decreasing size (guided self-scheduling): each
    chunk takes 1/(2·cpus) of the pieces left, at least one, so the first chunks are large (few
    tasks) and the last ones single pieces (the nodes finish together). Ray hands the chunks, in
    order, to whichever CPU is free. Only for pieces that are contiguous (start, stop) ranges,
    as cut vertex ranges and GI tile ranges are; other chunk lists are returned as they are.
    A group is the range (first start, last stop): for the cut renderer on batch boundaries, so
    the same batches are traced and the assembly is the same bytes."""
    ok = len(pieces) > 1 and all(isinstance(c, tuple) and len(c) == 2 and all(isinstance(x, int) for x in c)
                                 for c in pieces) and all(a[1] == b[0] for a, b in itertools.pairwise(pieces))
    if not ok:
        return pieces
    out, i = [], 0
    while i < len(pieces):
        k = max(1, (len(pieces) - i) // (2 * max(1, cpus)))
        out.append((pieces[i][0], pieces[i + k - 1][1]))
        i += k
    return out


def _host_warm_up() -> None:
    """Imports a scene load needs (mesh and map readers: ~1 s in a fresh process) and the tree."""
    import cv2  # noqa: F401
    import OpenEXR  # noqa: F401
    import trimesh  # noqa: F401

    import worker.blobs
    import worker.scene  # noqa: F401
    from worker.core.directions import get_tree
    from worker.renderers import get

    get("cuts")
    get_tree()


def _timeline(results: list[dict], w_sub: float, w_res: float, w_asm: float) -> dict:
    """Where a part's wall time went (seconds, from the tasks' and the host's wall clocks):
    submission to the first task running (worker start), the tasks' set-up (first task of a
    process: imports; every task: the scene from the object store) and compute, the gap between
    the first and the last node finishing (imbalance), the last result to the end of assembly,
    then storing."""
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
def _scene_key(scene_p: dict) -> str:
    """Content key of a scene payload (its spec and its files' hashes): the cache key of the
    scene in a task process, stable across jobs (the GI precomputation keeps per-scene set-up)."""
    return content_key("scene-payload", 1, spec=scene_p["spec"], files=scene_p.get("files"))


def _portable(sc):
    """The loaded scene without its blob resolver (a closure over this host's cache), for the
    object store; tasks never resolve files."""
    from worker.scene import LoadedScene

    c = LoadedScene.__new__(LoadedScene)
    c.__dict__.update(sc.__dict__)
    c._resolver = None
    return c


_task_scenes: OrderedDict = OrderedDict()          # scene content key -> LoadedScene, in a task process
_task_lock = threading.Lock()


def _task_scene(shipped: list):
    """The job's scene and tree in this task process: fetched from the object store by the first
    chunk of the process, then kept (a few, least recently used first out) so that every chunk
    of a process shares one scene object (renderers cache set-up per scene object)."""
    from worker.core.directions import adopt_tree

    key, scene_ref, tree_ref = shipped
    with _task_lock:
        sc = _task_scenes.get(key)
        if sc is None:
            sc, tree = ray.get([scene_ref, tree_ref])
            adopt_tree(tree)
            _task_scenes[key] = sc
            while len(_task_scenes) > 2:
                _task_scenes.popitem(last=False)
        else:
            _task_scenes.move_to_end(key)
        return sc


def _task_imports():
    os.environ["OPENBLAS_NUM_THREADS"] = "1"         # before NumPy loads in a fresh task process
    from worker import native
    from worker.renderers import get

    native.set_threads(1)                            # one CPU per task: no OpenMP oversubscription
    return get


@ray.remote(num_cpus=1, max_retries=0)
def warm_up(kind: str) -> tuple:
    """Start a task process on a node and import what chunks of a ``kind`` precomputation need
    (while the host loads the scene). Returns (node id, pid)."""
    _task_imports()(kind)
    import worker.trace.embree  # noqa: F401

    return ray.get_runtime_context().get_node_id(), os.getpid()


@ray.remote(num_cpus=1, max_retries=1)
def compute_chunk(shipped: list, kind: str, part, options: dict, chunk, host, jid: str) -> dict:
    """One chunk of a part, on one CPU of whichever node Ray chose; progress goes to ``host``
    at most a few times a second. ``shipped``: [scene content key, ObjectRef of the scene,
    ObjectRef of the direction tree] (refs inside a list: fetched only by a process that lacks
    them). Returns {"result": what Precomputation.assemble takes, "node_id", "seconds",
    "cpu_seconds", "pid", "t": wall-clock (start, ready, end)}."""
    w0 = time.time()
    get = _task_imports()
    t0, c0 = time.perf_counter(), time.process_time()
    _, pre = get(kind)
    sc = _task_scene(shipped)
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
