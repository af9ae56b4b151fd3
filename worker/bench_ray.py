"""``glint bench ray-precompute``: a scene's precomputation on a Ray cluster, timed (issue 17).

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
                         store: str | None = None) -> dict:
    import ray

    from worker.blobs import BlobStore
    from worker.jobs.ray_actors import SessionHost
    from worker.jobs.runner import WorkerSettings

    scene_path = Path(scene_path).resolve()
    spec = json.loads(scene_path.read_text())
    root = Path(tempfile.mkdtemp(prefix="glint-bench-ray-", dir=store))
    try:
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
        kw = {"address": address, "logging_level": "WARNING", "namespace": "glint-bench"}
        if node_ip:
            kw["_node_ip_address"] = node_ip
        ray.init(**kw)
        try:
            settings = WorkerSettings(blob_root=str(root / "blobs"), tmp_dir=str(root / "tmp"))
            host = ray.remote(SessionHost).options(num_cpus=0, max_concurrency=16).remote(0, settings, chunks_per_cpu)
            # as in the service, whose hosts start with the server: the job is timed on a running
            # host (its process started, modules imported, tree built), not on the host's start
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
            nodes = sum(1 for n in ray.nodes() if n.get("Alive"))
        finally:
            ray.shutdown()
        st = res["stats"]
        (key, sha), = res["parts"].items()
        return {"benchmark": "ray precompute (cuts, cold: fresh blob store)", "scene": str(scene_path),
                "vertices": st.get("vertices"), "nodes_in_cluster": nodes, "ray_cpus": st["ray_cpus"],
                "ray_chunks": st["ray_chunks"], "ray_nodes_used": st["ray_nodes"],
                "seconds_wall": st["seconds_wall"], "seconds_chunks_max": st["seconds_chunks_max"],
                "chunk_concurrency": st["seconds_chunks_sum"] / st["seconds_wall"],
                "cpu_share_of_chunk_time": st["cpu_seconds_chunks_sum"] / st["seconds_chunks_sum"],
                "seconds_job": total, "part_sha256": sha, "timeline": st.get("timeline")}
    finally:
        shutil.rmtree(root, ignore_errors=True)


def cmd_bench_ray(a) -> int:
    res = bench_ray_precompute(a.scene, a.address, a.node_ip, a.chunks_per_cpu, a.store)
    print(json.dumps(res) if a.json else "\n".join(f"{k}: {v}" for k, v in res.items()))
    return 0


def add_commands(sub) -> None:
    p = sub.add_parser("bench-ray", help="time a scene's precomputation on a Ray cluster (JSON with --json)")
    p.add_argument("scene")
    p.add_argument("--address", required=True, help="the cluster's GCS address host:port")
    p.add_argument("--node-ip", help="this process's address as the cluster sees it (e.g. 127.0.0.2)")
    p.add_argument("--chunks-per-cpu", type=float, default=32.0)
    p.add_argument("--store", help="folder for the temporary blob store (must be readable by every node; default /tmp)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(fn=cmd_bench_ray)
