"""The worker process: runs jobs (precompute, render, fit) on a job thread and interactive
sessions on its main loop, talking to the server through two multiprocessing queues.

Requests (server → worker):
    ("job", job_id, {"type": "precompute" | "render" | "fit", "scene": {...}, ...})
    ("open", session_id, {"scene": {...}, "state": {...}, "strokes": [...], "ack": int})
    ("msg", session_id, {client message})
    ("close", session_id, None)
    ("stop", None, None)
Replies (worker → server):
    ("progress", job_id, {"progress": 0..1, "message": str})
    ("result", job_id, {...}) / ("error", job_id, {"message": str, "status": int})
    ("frame", session_id, (header, jpeg bytes)) / ("event", session_id, {...})

Latest wins: the loop drains every queued request before working, applies all of a session's
messages, fits at most once and renders one frame whose ``ack`` is the newest ``seq`` applied;
intermediate views are never rendered.
"""
from __future__ import annotations

import io
import os
import queue
import tempfile
import threading
import traceback
from collections import OrderedDict
from pathlib import Path


class JobError(Exception):
    """A job that cannot be done as asked (bad input): reported with an HTTP-like status."""

    def __init__(self, message: str, status: int = 422):
        super().__init__(message)
        self.status = status


class SceneCache:
    """Loaded scenes and cuts of this worker, by scene id and cuts hash (a few, LRU)."""

    def __init__(self, blob_root: str, size: int = 4):
        from server.blobs import BlobStore

        self.blobs = BlobStore(blob_root)
        self.tmp = Path(tempfile.mkdtemp(prefix="glint-worker-"))
        self.size = size
        self._scenes: OrderedDict = OrderedDict()
        self._lock = threading.RLock()    # the job thread and the session loop share the cache
        self._maps: dict = {}

    def scene(self, p: dict):
        with self._lock:
            return self._scene(p)

    def _scene(self, p: dict):
        from worker.scene import LoadedScene, SceneError, parse_scene

        key = p["scene_id"]
        if key in self._scenes:
            self._scenes.move_to_end(key)
            return self._scenes[key][0]

        def resolve(ref: str) -> Path:
            f = p["files"].get(ref)
            if f is None:
                raise SceneError(f"{ref!r} is not an uploaded asset")
            return _linked(self, f)

        sc = LoadedScene(parse_scene(p["spec"]), self.tmp, resolver=resolve)
        self._scenes[key] = [sc, {}]
        while len(self._scenes) > self.size:
            self._scenes.popitem(last=False)
        return sc

    def envmap(self, f: dict):
        """An environment map blob (verified), decoded once."""
        from worker.envmap import load_envmap

        with self._lock:
            key = ("env", f["sha256"])
            if key not in self._maps:
                if len(self._maps) > 8:
                    self._maps.clear()
                self._maps[key] = load_envmap(_linked(self, f))
            return self._maps[key]

    def cuts(self, p: dict):
        from worker.core import cuts as cutmod

        sha = p.get("cuts_sha256")
        if not sha:
            raise JobError("the scene has no finished precomputation; start one first", 409)
        with self._lock:
            self._scene(p)
            store = self._scenes[p["scene_id"]][1]
            if sha not in store:
                store.clear()
                store[sha] = cutmod.decode(self.blobs.get(sha))
            return store[sha]


def _render(cache: SceneCache, p: dict) -> dict:
    import numpy as np
    from PIL import Image
    from pydantic import TypeAdapter

    from worker.core.tonemap import tonemap
    from worker.engine import Engine
    from worker.scene import Camera, Material

    sc = cache.scene(p["scene"])
    eng = Engine(sc, cache.cuts(p["scene"]))
    names = [o.name for o in sc.spec.objects]
    mats = list(sc.materials)
    ta = TypeAdapter(Material)
    for name, m in (p.get("materials") or {}).items():
        if name not in names:
            raise JobError(f"materials: no object {name!r} in the scene (objects: {', '.join(names)})")
        mats[names.index(name)] = ta.validate_python(m)
    eng.set_materials(mats)
    cam = Camera.model_validate(p["camera"]) if p.get("camera") else None
    img = eng.render(cam, p.get("rotation_deg"), p.get("intensity"), mode=p.get("mode", "vertex"))
    if p.get("format") == "exr":
        from worker.envmap import save_exr

        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "r.exr"
            save_exr(path, img.astype(np.float32))
            return {"bytes": path.read_bytes(), "media_type": "image/x-exr"}
    buf = io.BytesIO()
    Image.fromarray(tonemap(img, p.get("exposure", 0.0), p.get("tone", "neutral"))).save(buf, format="PNG")
    return {"bytes": buf.getvalue(), "media_type": "image/png"}


def _fit(cache: SceneCache, p: dict) -> dict:
    import json

    import numpy as np

    from worker.engine import Engine
    from worker.fit.basis import default_basis
    from worker.fit.files import ViewSpec, load_mask, load_target
    from worker.fit.fitter import Fitter

    sc = cache.scene(p["scene"])
    eng = Engine(sc, cache.cuts(p["scene"]))
    req = p["request"]
    basis = default_basis(fresnel_f0=req.get("fresnel_f0") or 1.0)
    fx = Fitter(eng, req["object"], basis=basis, fit_scale=req.get("fit_scale") or 0.25, albedo=req.get("albedo"))
    notes = []
    if req.get("strokes"):
        for v in req.get("views") or [{}]:
            v = ViewSpec.model_validate(v)
            fx.add_view(v.camera, v.rotation_deg, v.intensity)
        for s in req["strokes"]:
            notes += fx.add_stroke(s)
        out = fx.fit(constrained=req.get("constrained", True), unpainted_weight=req.get("unpainted_weight", 1.0))
    else:
        fx.add_view()
        t = p["target"]
        target = load_target(_linked(cache, t))
        mask = load_mask(_linked(cache, p["mask"])) if p.get("mask") else None
        out = fx.fit_targets([target], [mask], constrained=req.get("constrained", True))
    s = out.solve
    return {"material": json.loads(out.material.model_dump_json()),
            "stats": {"seconds_transfer": out.seconds_transfer, "seconds_solve": s.seconds, "pixels": out.pixels,
                      "painted": out.painted, "basis": fx.basis.J, "residual_rms": s.residual_rms,
                      "residual_rel": s.residual_rel, "energy_max": s.energy_max,
                      "energy_bound": float(np.min(s.energy_bound)), "constrained": s.constrained,
                      "notes": list(dict.fromkeys(notes + out.notes))}}


def _linked(cache: SceneCache, f: dict) -> Path:
    """A verified blob under a name with its original extension (readers dispatch on it)."""
    src = cache.blobs.verified_path(f["sha256"])
    link = cache.tmp / (f["sha256"] + Path(f["filename"]).suffix.lower())
    if not link.exists():
        os.symlink(src, link)
    return link


def _precompute(cache: SceneCache, p: dict, progress) -> dict:
    from worker.core import cuts as cutmod
    from worker.engine import storage_stats
    from worker.precompute import DEFAULT_TAU, precompute_cuts

    m = cache.scene(p["scene"]).mesh
    n = len(m.vertices)
    done = [0, -1.0]

    def tick(k):
        done[0] += k
        f = done[0] / n
        if f - done[1] >= 0.01 or done[0] >= n:
            done[1] = f
            progress(f, f"{done[0]}/{n} vertices")

    cs, st = precompute_cuts(m.vertices, m.faces, m.normals, tau=p.get("tau", DEFAULT_TAU), progress=tick,
                             threads=int(os.environ.get("GLINT_THREADS", "0") or 2))
    blob = cutmod.encode(cs)
    sha = cache.blobs.put(blob)
    stats = {"seconds": st.seconds, "rays_traced": st.rays, "tau": p.get("tau", DEFAULT_TAU),
             "samples_per_second": st.vertices * st.directions / max(st.seconds, 1e-9),
             **storage_stats(cs, len(blob), cache.blobs.path(sha))}
    stats.pop("path", None)
    return {"cuts_sha256": sha, "stats": stats}


def worker_main(wid: int, inq, outq, blob_root: str) -> None:
    """Entry point of a worker process (multiprocessing, spawn)."""
    from worker import native  # noqa: F401  (loads the kernels, honours GLINT_THREADS)
    from worker.fit.fitter import FitError
    from worker.jobs.session import SessionRuntime
    from worker.scene import SceneError

    cache = SceneCache(blob_root)
    jobs: queue.Queue = queue.Queue()

    def job_loop():
        while True:
            item = jobs.get()
            if item is None:
                return
            _, jid, p = item
            try:
                kind = p["type"]
                if kind == "precompute":
                    res = _precompute(cache, p, lambda f, msg: outq.put(("progress", jid, {"progress": f, "message": msg})))
                elif kind == "render":
                    res = _render(cache, p)
                elif kind == "fit":
                    res = _fit(cache, p)
                else:
                    raise JobError(f"unknown job type {kind!r}", 400)
                outq.put(("result", jid, res))
            except JobError as e:
                outq.put(("error", jid, {"message": str(e), "status": e.status}))
            except (SceneError, FitError, ValueError) as e:
                outq.put(("error", jid, {"message": str(e), "status": 422}))
            except Exception as e:  # a bug: keep the worker alive, report it
                outq.put(("error", jid, {"message": f"internal error: {type(e).__name__}: {e}", "status": 500,
                                         "trace": traceback.format_exc()}))

    threading.Thread(target=job_loop, daemon=True, name="glint-jobs").start()
    sessions: dict = {}
    while True:
        batch = [inq.get()]
        while True:
            try:
                batch.append(inq.get_nowait())
            except queue.Empty:
                break
        pending: OrderedDict = OrderedDict()
        for kind, key, p in batch:
            if kind == "stop":
                jobs.put(None)
                return
            if kind == "job":
                jobs.put((kind, key, p))
            elif kind == "open":
                try:
                    sc = cache.scene(p["scene"])
                    cuts = cache.cuts(p["scene"])
                    sessions[key] = SessionRuntime(sc, cuts, p.get("state") or {}, p.get("strokes") or [],
                                                   env_loader=cache.envmap)
                    pending.setdefault(key, [])
                    pending[key].append({"_ack": int(p.get("ack", -1))})
                except Exception as e:
                    outq.put(("event", key, {"type": "error", "fatal": True, "message": f"cannot open the session: {e}"}))
            elif kind == "close":
                sessions.pop(key, None)
                pending.pop(key, None)
            elif kind == "msg":
                pending.setdefault(key, []).append(p)
        for sid, msgs in pending.items():
            rt = sessions.get(sid)
            if rt is None:
                outq.put(("event", sid, {"type": "error", "fatal": True, "message": "session is not open on this worker"}))
                continue
            ack = -1
            for m in msgs:
                if "_ack" in m:
                    ack = max(ack, m["_ack"])
                    continue
                try:
                    for e in rt.apply(m):
                        outq.put(("event", sid, e))
                except Exception as e:
                    outq.put(("event", sid, {"type": "error", "seq": m.get("seq"), "message": _msg(e)}))
                ack = max(ack, int(m.get("seq", -1)))
            try:
                for e in rt.fit_if_needed():
                    outq.put(("event", sid, e))
            except Exception as e:
                outq.put(("event", sid, {"type": "error", "seq": ack, "message": f"fit failed: {_msg(e)}"}))
            try:
                outq.put(("frame", sid, rt.frame(ack)))
            except Exception as e:
                outq.put(("event", sid, {"type": "error", "seq": ack, "message": f"render failed: {_msg(e)}"}))


def _msg(e: Exception) -> str:
    from pydantic import ValidationError

    if isinstance(e, ValidationError):
        err = e.errors()[0]
        return f"{'.'.join(str(x) for x in err['loc'])}: {err['msg']}"
    return str(e)
