"""``glint bench-ray``: a scene's precomputation on a Ray cluster, timed.

The scene's files go into a fresh blob store (so nothing is cached) at a path every node can
read, and one ``SessionHost`` actor coordinates the precomputation exactly as the service does:
the part split into chunks, one Ray task per chunk spread over the nodes, assembled into the
part's bytes, on a host that has started (as the service's hosts start with the server) but
with fresh task processes (this bench is a new Ray job each run). Reported: seconds of the chunk
phase and assembly (``seconds_wall``), of the whole job from its request to its result
(``seconds_job``: with the host's scene load and naming of the parts), the chunk
count, the nodes and CPUs used, and the SHA-256 of the assembled part (equal across cluster
sizes: the assembly is byte-identical) and a ``timeline`` of where the time went (ray_actors.py).
``scripts/bench-ray`` runs it on one node, adds a second,
runs it again and prints the speed-up.
"""
from __future__ import annotations

import json
import shutil
import tempfile
import time
from pathlib import Path


def bench_ray_precompute(scene_path: str, address: str, node_ip: str | None = None, chunks_per_cpu: float = 32.0,
                         store: str | None = None, repeat: int = 1) -> list[dict]:
    """``repeat`` precomputations of the scene, each into a fresh blob store, by one host in one
    Ray job: the first on fresh task processes (``task_processes: "fresh"``, as the first job of
    a just-started server), the others on the task processes the first left (``"warm"``, as
    every later job of a running server). One dict per run."""
    import ray

    from worker.jobs.ray_actors import SessionHost

    scene_path = Path(scene_path).resolve()
    root = Path(tempfile.mkdtemp(prefix="glint-bench-ray-", dir=store))
    kw = {"address": address, "logging_level": "WARNING", "namespace": "glint-bench"}
    if node_ip:
        kw["_node_ip_address"] = node_ip
    out = []
    try:
        ray.init(**kw)
        try:
            nodes = sum(1 for n in ray.nodes() if n.get("Alive"))
            for i in range(repeat):
                payload, settings = _fresh_store(scene_path, root / f"run{i}")
                host = ray.remote(SessionHost).options(num_cpus=0, max_concurrency=16).remote(0, settings, chunks_per_cpu)
                # as in the service, whose hosts start with the server: the job is timed on a
                # running host (its process started, modules imported, tree built)
                ray.get(host.ready.remote())
                t0 = time.perf_counter()
                host.control.remote(0, ("job", "bench", {"type": "precompute", "scene": payload}))
                res = None
                while res is None:
                    for kind, _, p in ray.get(host.poll.remote(1.0)):
                        if kind == "result":
                            res = p
                        elif kind == "error":
                            raise RuntimeError(p["message"])
                total = time.perf_counter() - t0
                ray.get(host.stop.remote())
                ray.kill(host)
                shutil.rmtree(root / f"run{i}", ignore_errors=True)
                st = res["stats"]
                (_, sha), = res["parts"].items()
                out.append({"benchmark": "ray precompute (cuts, cold data: fresh blob store)", "scene": str(scene_path),
                            "task_processes": "fresh" if i == 0 else "warm",
                            "vertices": st.get("vertices"), "nodes_in_cluster": nodes, "ray_cpus": st["ray_cpus"],
                            "ray_chunks": st["ray_chunks"], "ray_nodes_used": st["ray_nodes"],
                            "seconds_wall": st["seconds_wall"], "seconds_chunks_max": st["seconds_chunks_max"],
                            "chunk_concurrency": st["seconds_chunks_sum"] / st["seconds_wall"],
                            "cpu_share_of_chunk_time": st["cpu_seconds_chunks_sum"] / st["seconds_chunks_sum"],
                            "seconds_chunks_sum": st["seconds_chunks_sum"],
                            "cpu_seconds_chunks_sum": st["cpu_seconds_chunks_sum"],
                            "seconds_job": total, "part_sha256": sha, "timeline": st.get("timeline")})
        finally:
            ray.shutdown()
    finally:
        shutil.rmtree(root, ignore_errors=True)
    return out


def _fresh_store(scene_path: Path, root: Path):
    """The scene's files in a new blob store under root: (job payload, WorkerSettings)."""
    from worker.blobs import BlobStore
    from worker.jobs.runner import WorkerSettings

    spec = json.loads(scene_path.read_text())
    blobs = BlobStore(root / "blobs")
    files = {}

    def add(rel: str) -> str:
        p = (scene_path.parent / rel).resolve()
        ref = f"f{len(files)}"
        files[ref] = {"sha256": blobs.put(p.read_bytes()), "filename": p.name}
        return ref

    spec["environment"]["map"] = add(spec["environment"]["map"])
    for o in spec["objects"]:
        o["mesh"] = add(o["mesh"])
    payload = {"scene_id": "bench", "spec": spec, "files": files, "renderer": spec.get("renderer", "cuts"),
               "options": spec.get("precompute") or {}, "parts": None}
    return payload, WorkerSettings(blob_root=str(root / "blobs"), tmp_dir=str(root / "tmp"))


def cmd_bench_ray(a) -> int:
    runs = bench_ray_precompute(a.scene, a.address, a.node_ip, a.chunks_per_cpu, a.store, a.repeat)
    for res in runs:
        print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items()))
    return 0


def add_commands(sub) -> None:
    p = sub.add_parser("bench-ray", help="time a scene's precomputation on a Ray cluster (JSON with --json)")
    p.add_argument("scene")
    p.add_argument("--address", required=True, help="the cluster's GCS address host:port")
    p.add_argument("--node-ip", help="this process's address as the cluster sees it (e.g. 127.0.0.2)")
    p.add_argument("--chunks-per-cpu", type=float, default=32.0, help="pieces per cluster CPU (grouped into guided chunks)")
    p.add_argument("--repeat", type=int, default=1, help="runs in one Ray job: the first on fresh task processes, then warm")
    p.add_argument("--store", help="folder for the temporary blob store (must be readable by every node; default /tmp)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(fn=cmd_bench_ray)
