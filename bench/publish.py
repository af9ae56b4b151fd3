"""Static publications measured from outside, as a shop would use them: ``glint bench publish``
(building a bundle, its weight, the rebuild after one design changed) and ``glint bench viewer``
(many concurrent shoppers opening and turning a published object on loopback, and the first
image of the viewer page in Chromium).

Both start ``glint serve`` as a child process (bench/stream.py Server), upload a scene file's
assets, precompute it, and publish two variants under two environments.
"""
from __future__ import annotations

import asyncio
import json
import os
import random
import sys
import time
from pathlib import Path

from .stream import ROOT, Server, pct

SCENE = ROOT / "tests" / "scenes" / "bunny-ground.json"
SECOND_ENV = ROOT / "tests" / ".cache" / "assets" / "env" / "sunset.exr"
VARIANTS = [{"name": "Cherry red", "material": {"model": "ggx", "alpha": 0.2, "specular": [0.3, 0.3, 0.3],
                                                 "albedo": [0.6, 0.04, 0.04]}},
            {"name": "Navy", "material": {"model": "lambert", "albedo": [0.04, 0.08, 0.5]}}]


def _upload(c, kind: str, path: Path) -> str:
    r = c.post(f"/v1/assets/{kind}", params={"filename": path.name}, content=path.read_bytes())
    r.raise_for_status()
    return r.json()["id"]


def _wait(c, url: str, key, timeout: float = 3600.0) -> dict:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        d = key(c.get(url).json())
        if d["status"] in ("done", "failed"):
            if d["status"] == "failed":
                raise RuntimeError(f"{url}: {d.get('message')}")
            return d
        time.sleep(0.1)
    raise TimeoutError(url)


def setup(srv, scene: Path = SCENE, env2: Path = SECOND_ENV) -> tuple[str, str, list[str]]:
    """(scene id, second envmap id, design ids) on the server, the scene precomputed."""
    import httpx

    scene = Path(scene)
    spec = json.loads(scene.read_text())
    with httpx.Client(base_url=srv.base, timeout=600) as c:
        spec["environment"]["map"] = _upload(c, "envmaps", (scene.parent / spec["environment"]["map"]).resolve())
        for o in spec["objects"]:
            o["mesh"] = _upload(c, "meshes", (scene.parent / o["mesh"]).resolve())
        env2_id = _upload(c, "envmaps", Path(env2))
        sid = c.post("/v1/scenes", json=spec, params={"name": scene.stem}).raise_for_status().json()["id"]
        pre = c.post(f"/v1/scenes/{sid}/precompute").raise_for_status().json()
        _wait(c, f"/v1/precomputations/{pre['id']}", lambda d: d)
        ids = [c.post("/v1/materials", json=v).raise_for_status().json()["id"] for v in VARIANTS]
    return sid, env2_id, ids


def publish_body(sid: str, env2: str, ids: list[str], bundle: dict) -> dict:
    return {"name": "bench", "scene_id": sid, "bundle": bundle, "variants": [{"material_id": i} for i in ids],
            "environments": [{}, {"asset_id": env2}]}


def bench_publish(azimuths: int = 72, elevations: int = 2, width: int = 640, height: int = 480,
                  port: int | None = None, data_dir: str | None = None, workers: int | None = None,
                  scene: str | None = None, quiet: bool = False, keep: bool = False, env2: str | None = None,
                  samples: int | None = None, antialias: str | None = None):
    """Build a bundle of 2 variants × 2 environments × ``azimuths`` × ``elevations`` at
    width × height (and its 2× set), then republish with one variant changed. Returns the
    figures (and, with keep, the running server and the publication id). Without ``data_dir``
    (and ``port``) the server gets a fresh temporary data folder, removed afterwards unless
    kept: frames stored by an earlier run under the same keys would be reused, not built."""
    import shutil
    import tempfile

    import httpx

    tmp = None
    if data_dir is None and port is None:
        data_dir = tmp = tempfile.mkdtemp(prefix="glint-bench-publish-")
    srv = Server(port, data_dir, quiet, workers=workers, demo=False)
    try:
        sid, env2, ids = setup(srv, Path(scene) if scene else SCENE, Path(env2) if env2 else SECOND_ENV)
        cam = json.loads(Path(scene or SCENE).read_text())["camera"]
        from worker.publish.turntable import default_elevations

        els = default_elevations(cam)
        els = (els + [min(80.0, els[-1] + 20.0 * k) for k in range(1, 4)])[:elevations]
        bundle = {"azimuths": azimuths, "elevations_deg": els, "width": width, "height": height}
        if samples is not None:         # else the service's default
            bundle["samples"] = samples
        if antialias is not None:
            bundle["antialias"] = antialias
        body = publish_body(sid, env2, ids, bundle)
        with httpx.Client(base_url=srv.base, timeout=600) as c:
            cpu0 = srv.cpu_seconds()
            t0 = time.perf_counter()
            pub = c.post("/v1/publications", json=body).raise_for_status().json()
            b = _wait(c, f"/v1/publications/{pub['id']}", lambda d: d["bundle"])
            build_s = time.perf_counter() - t0
            cpu1 = srv.cpu_seconds()
            man = c.get(f"/v1/publications/{pub['id']}/manifest").json()
            sizes = {"avif1": 0, "jpeg1": 0, "avif2": 0}
            seen = set()
            for per_v in man["frames"]:
                for per_e in per_v:
                    for per_el in per_e:
                        for f in per_el:
                            for k in sizes:
                                if f[k] not in seen:
                                    seen.add(f[k])
                                    sizes[k] += len(c.get(f"/v1/bundle-files/{f[k]}").content)
            # one design changes: only its frames are rendered again
            c.put(f"/v1/materials/{ids[1]}", json={"material": {"model": "lambert", "albedo": [0.05, 0.3, 0.1]}})
            t1 = time.perf_counter()
            c.put(f"/v1/publications/{pub['id']}", json=body).raise_for_status()
            b2 = _wait(c, f"/v1/publications/{pub['id']}", lambda d: d["bundle"])
            rebuild_s = time.perf_counter() - t1
        views = len(VARIANTS) * 2 * azimuths * len(els)
        res = {"publication": pub["id"], "views": views, "width": width, "height": height, "azimuths": azimuths, "elevations_deg": els,
               "build_seconds": round(build_s, 2), "build_stats": b["stats"],
               "ms_per_view": round(1e3 * build_s / views, 1),
               "worker_cpu_seconds": round(cpu1["workers"] - cpu0["workers"], 1),
               "bundle_bytes": man["bytes"], "bundle_mb": round(man["bytes"] / 1e6, 2),
               "bytes_by_set": sizes, "files": man["files"],
               "rebuild_seconds": round(rebuild_s, 2), "rebuild_rendered": b2["stats"]["rendered"],
               "rebuild_reused": b2["stats"]["reused"]}
        if b["stats"]["rendered"] != views:
            raise RuntimeError(f"the build rendered {b['stats']['rendered']} of {views} views (the rest were stored "
                               "already): measure with a fresh --data-dir")
        if keep:
            return res, srv, pub["id"]
        return res
    finally:
        if not keep:
            srv.close()
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)


_TLS = None       # one TLS context for every shopper's client (loopback is plain HTTP; httpx builds
                  # one per client otherwise, reading the CA bundle: ~30 ms of CPU each)


async def _shopper(base: str, pid: str, man: dict, frames: int, interval: float, delay: float, lat: list,
                   opened: list, errors: list) -> None:
    """One shopper: opens the viewer page (page, scripts, manifest, first frame), then turns the
    object, fetching one frame it does not have yet every ``interval`` s (a browser caches
    the immutable files, so each is fetched once). Its own client and connection, as a
    browser's: one pool shared by a thousand connections spent the benchmark's CPU in
    httpcore's pool bookkeeping rather than in requests."""
    import httpx

    await asyncio.sleep(delay)
    try:
        async with httpx.AsyncClient(base_url=base, timeout=60, verify=_TLS) as c:
            t0 = time.perf_counter()
            for u in (f"/view/{pid}", "/web/js/viewer.js", "/web/js/player.js", "/web/css/viewer.css",
                      f"/v1/publications/{pid}/manifest"):
                r = await c.get(u)
                if r.status_code != 200:
                    errors.append(f"{u}: {r.status_code}")
                    return
            ring = man["frames"][0][0][0]
            a = random.randrange(len(ring))
            for k in range(frames + 1):
                t1 = time.perf_counter()
                r = await c.get(f"/v1/bundle-files/{ring[(a + k) % len(ring)]['avif1']}")
                dt = time.perf_counter() - t1
                if r.status_code != 200:
                    errors.append(f"frame: {r.status_code}")
                lat.append(dt)
                if k == 0:
                    opened.append(time.perf_counter() - t0)
                await asyncio.sleep(interval * (0.5 + random.random()))
    except Exception as e:   # a refused or dropped connection is a result, counted
        errors.append(f"{type(e).__name__}: {e}")


async def _load(base: str, pid: str, clients: int, frames: int, interval: float, ramp: float) -> dict:
    import httpx

    import ssl

    global _TLS
    _TLS = ssl.create_default_context()
    async with httpx.AsyncClient(base_url=base, timeout=60) as c:
        man = (await c.get(f"/v1/publications/{pid}/manifest")).json()
    lat, opened, errors = [], [], []
    t0 = time.perf_counter()
    await asyncio.gather(*(_shopper(base, pid, man, frames, interval, ramp * i / clients, lat, opened, errors)
                           for i in range(clients)))
    wall = time.perf_counter() - t0
    ms = [x * 1e3 for x in lat]
    return {"clients": clients, "frame_requests": len(ms), "errors": len(errors), "error_examples": errors[:3],
            "seconds": round(wall, 1), "requests_per_s": round(len(ms) / wall, 1),
            "p50_ms": round(pct(ms, 50), 2), "p95_ms": round(pct(ms, 95), 2), "p99_ms": round(pct(ms, 99), 2),
            "open_p95_ms": round(pct([x * 1e3 for x in opened], 95), 1)}


def first_image_ms(base: str, pid: str, runs: int = 3) -> dict:
    """Milliseconds from navigation start to the viewer's first drawn frame in Chromium
    (the player's ``glint-first-frame`` mark): a cold cache (new context) each run."""
    import shutil

    from playwright.sync_api import sync_playwright

    out = []
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=shutil.which("chromium") or "/usr/bin/chromium", headless=True,
                              args=["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"])
        for _ in range(runs):
            ctx = b.new_context(viewport={"width": 1280, "height": 860})
            page = ctx.new_page()
            page.goto(f"{base}/view/{pid}")
            page.wait_for_function("() => performance.getEntriesByName('glint-first-frame').length > 0", timeout=30_000)
            out.append(page.evaluate("() => performance.getEntriesByName('glint-first-frame')[0].startTime"))
            ctx.close()
        b.close()
    return {"first_image_ms": [round(x, 1) for x in out], "first_image_ms_max": round(max(out), 1)}


def bench_viewer(clients: int = 1000, frames: int = 24, interval: float = 1.0, ramp: float = 2.0, runs: int = 2,
                 port: int | None = None, publication: str | None = None, data_dir: str | None = None,
                 browser: bool = True, quiet: bool = False, azimuths: int = 72) -> dict:
    """``clients`` concurrent shoppers on one published object (built here at 640×480 unless
    ``publication`` on ``port`` is given), ``runs`` times: per-frame request latency, server
    memory after each run (flat: the file cache is bounded), the workers' CPU time during the
    runs (no frame is rendered), and the first image in Chromium."""
    srv = None
    if publication is None:
        res, srv, publication = bench_publish(azimuths=azimuths, port=port, data_dir=data_dir, quiet=quiet, keep=True)
        if not quiet:
            print(json.dumps(res), file=sys.stderr)
    else:
        res = None
        # a publication of a data folder: served by a server this starts on it (so its
        # processes' memory and CPU can be read), or by the one on ``port``
        srv = Server(port, data_dir, quiet, demo=False)
    try:
        out = {"publication": publication, "build": res, "runs": []}
        mem0 = srv.memory()
        cpu0 = srv.cpu_seconds()
        for _ in range(runs):
            r = asyncio.run(_load(srv.base, publication, clients, frames, interval, ramp))
            r["memory"] = srv.memory()
            out["runs"].append(r)
            if not quiet:
                print(json.dumps(r), file=sys.stderr)
        cpu1 = srv.cpu_seconds()
        out.update({"clients": clients, "p95_ms": max(r["p95_ms"] for r in out["runs"]),
                    "errors": sum(r["errors"] for r in out["runs"]),
                    "server_rss_mib": [round(mem0["rss_mib_server"], 1)] + [round(r["memory"]["rss_mib_server"], 1)
                                                                           for r in out["runs"]],
                    "worker_cpu_seconds": round(cpu1["workers"] - cpu0["workers"], 2),
                    "server_cpu_seconds": round(cpu1["server"] - cpu0["server"], 1)})
        if browser:
            out.update(first_image_ms(srv.base, publication))
        return out
    finally:
        srv.close()


class _LocalCache:
    """What worker/publish/frames.py asks of a worker's data cache (a renderer, environment
    maps, a part store), from a scene file in this process: the frame cost without the service."""

    def __init__(self, renderer, maps: dict, store):
        self._r, self._maps, self.parts = renderer, maps, store

    def renderer(self, scene, kind=None):
        return self._r

    def envmap(self, e):
        return self._maps[e["sha256"]]


def frame_cost(scene: str | None = None, cameras: int = 4, width: int = 640, height: int = 480,
               env2: Path = SECOND_ENV, samples: int | None = None, shading: str | None = None,
               antialias: str | None = None) -> dict:
    """CPU seconds per view of the bundle_frames job, in this process (all its threads:
    time.process_time), over ``cameras`` cameras × 2 variants × 2 environments at width ×
    height, by stage: the machine's other load does not count, so it bounds the build time of
    an idle machine (CPU seconds / cores)."""
    import hashlib
    import tempfile
    import types

    from worker.blobs import BlobStore, PartStore
    from worker.cli import _renderer
    from worker.envmap import load_envmap
    from worker.publish.frames import render_frames
    from worker.publish.manifest import plan
    from worker.publish.turntable import default_elevations

    path = Path(scene) if scene else SCENE
    from worker.core.cuts import DEFAULT_TAU

    r, _ = _renderer(types.SimpleNamespace(scene=str(path), cuts=None, tau=DEFAULT_TAU), quiet=True)
    spec = json.loads(path.read_text())
    envs = [(path.parent / spec["environment"]["map"]).resolve(), Path(env2)]
    maps, env_list = {}, []
    for p in envs:
        sha = hashlib.sha256(p.read_bytes()).hexdigest()
        maps[sha] = load_envmap(p)
        env_list.append({"sha256": sha, "filename": p.name, "rotation_deg": 0.0, "intensity": 1.0})
    payload = {"renderer": "cuts", "parts": {"scene": hashlib.sha256(path.read_bytes()).hexdigest()},
               "files": {o["mesh"]: {"sha256": o["mesh"]} for o in spec["objects"]}, "spec": spec}
    opts = {"azimuths": 72, "elevations_deg": default_elevations(spec["camera"]), "width": width, "height": height,
            # the service's defaults (docs/guides/publishing.md) unless asked
            "samples": 4 if samples is None else samples, "antialias": antialias or "edges",
            "shading": shading or "refined", "tone": "neutral", "exposure": 0.0,
            "ground_shadow": bool(spec.get("ground")),
            "encode": {"avif_quality": 60, "avif_quality_2x": 40, "avif_speed": 10, "jpeg_quality": 85}}
    pl = plan(payload, spec["objects"][0]["name"], [v["material"] for v in VARIANTS], env_list, opts)
    views = pl["views"][:4 * cameras]
    with tempfile.TemporaryDirectory() as d:
        cache = _LocalCache(r, maps, PartStore(BlobStore(d)))
        job = {"scene": payload, "object": spec["objects"][0]["name"], "variants": [v["material"] for v in VARIANTS],
               "environments": env_list, "render": pl["render"], "encode": pl["encode"]}
        render_frames(cache, {**job, "views": pl["views"][-4:]}, lambda f, m: None)    # warm: maps, tables
        c0, t0 = time.process_time(), time.perf_counter()
        res = render_frames(cache, {**job, "views": views}, lambda f, m: None)
        cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    n = len(views)
    return {"views": n, "width": width, "height": height, "samples": opts["samples"],
            "antialias": pl["render"].get("antialias"), "shading": opts["shading"],
            "cpu_s_per_view": round(cpu / n, 4),
            "wall_s_per_view": round(wall / n, 4), "stage_ms_per_view": {k: round(v / n, 1) for k, v in res["ms"].items()},
            "bytes_per_view": round(sum(sum(m["bytes"].values()) for m in res["meta"].values()) / n),
            "idle_2core_estimate_s_576_views": round(576 * cpu / n / 2, 1)}


def bench_viewer_static(publication: str, data_dir: str, clients: int = 1000, rates=(25, 50, 100, 200), nice: int = 5,
                        port: int | None = None, quiet: bool = False, visit_s: float = 0.0) -> dict:
    """``clients`` shoppers of a published object through nginx in front of the service
    (bench/static.py): the requests a real Chromium viewer makes (recorded once), replayed by
    h2load at each arrival rate (shoppers a second) of ``rates``, the client at ``nice``;
    with ``visit_s`` each shopper stays connected that long and switches variant at its end
    (bench.static.h2load), so that rate × visit_s shoppers are on the page at once.
    Reports per-request latency (client side, every request; nginx's own time per frame),
    offered and served rates, every process's CPU seconds, and the service's memory and
    workers' CPU (no frame rendered)."""
    from .static import Nginx, h2load, server_times, shopper_requests

    srv = Server(port, data_dir, quiet, demo=False)
    ngx = None
    try:
        ngx = Nginx(data_dir, f"127.0.0.1:{srv.port}")
        shop = shopper_requests(ngx.base, publication)
        ngx.rotate_log()
        frames = sum(1 for u in shop["urls"] if u.startswith("/v1/bundle-files/"))
        out = {"publication": publication, "clients": clients, "shopper": {
            "requests": len(shop["urls"]), "frame_requests": frames, "on_open": shop["on_open"],
            "first_image_ms": shop["first_image_ms"], "turn": shop["turn"],
            "opening_ms": shop["times_ms"][shop["on_open"] - 1] if shop["on_open"] else None,
            "viewport": shop["viewport"], "dpr": shop["dpr"], "first": shop["urls"][:6]}, "runs": []}
        mem0, cpu0 = srv.memory(), srv.cpu_seconds()
        for rate in rates:
            n0, s0 = ngx.cpu_seconds(), srv.cpu_seconds()
            r = h2load(ngx.base_h2, shop["urls"], clients, int(rate), nice=nice, visit_s=visit_s,
                       on_open=shop["on_open"], times_ms=shop["times_ms"])
            n1, s1 = ngx.cpu_seconds(), srv.cpu_seconds()
            r["server"] = server_times(ngx.rotate_log())
            r["nginx_cpu_seconds"] = round(n1 - n0, 2)
            r["service_cpu_seconds"] = round(s1["server"] - s0["server"], 2)
            r["service_rss_mib"] = round(srv.memory()["rss_mib_server"], 1)
            r["load_average"] = [round(x, 2) for x in os.getloadavg()]
            out["runs"].append(r)
            if not quiet:
                print(json.dumps(r), file=sys.stderr)
        cpu1 = srv.cpu_seconds()
        out.update({"service_rss_mib_before": round(mem0["rss_mib_server"], 1),
                    "worker_cpu_seconds": round(cpu1["workers"] - cpu0["workers"], 2)})
        return out
    finally:
        if ngx is not None:
            ngx.close()
        srv.close()
