"""The Ray backend on a real two-node Ray cluster on loopback (127.0.0.2 and 127.0.0.3,
one CPU each): a precomputation split across both nodes assembles to the very bytes of a local
run; a session streams frames, paints and saves through a session host actor; a host killed by
SIGKILL is replaced and its session restored from the database."""
import asyncio
import hashlib
import json
import os
import signal
import sys
import time
from pathlib import Path

import httpx
import pytest

from helpers import ROOT, GlintServer, connect, next_frame

sys.path.insert(0, str(Path(__file__).parent))
from raycluster import RayCluster  # noqa: E402

STROKE = {"points": [[62, 62], [88, 64]], "color": [4.0, 4.0, 4.0], "diameter": 10, "kappa": 0.05}


@pytest.fixture(scope="module")
def cluster():
    c = RayCluster(nodes=2, cpus=1)
    yield c
    c.stop()
    assert not c._leftovers(), "Ray processes of the test cluster outlived it"


@pytest.fixture(scope="module")
def ray_server(cluster, tmp_path_factory, shared_assets):
    # every precomputation draws its first look (the bunny is below the default's 8000 vertices)
    srv = GlintServer(tmp_path_factory.mktemp("ray-data"), workers=2,
                      env={**cluster.driver_env(), "GLINT_PREVIEW_MIN_VERTICES": "0"})
    c = httpx.Client(base_url=srv.base, timeout=120)
    mesh = c.post("/v1/assets/meshes", params={"filename": "bunny.ply"},
                  content=(shared_assets / "meshes" / "bunny.ply").read_bytes()).json()
    env = c.post("/v1/assets/envmaps", params={"filename": "sunset.exr"},
                 content=(shared_assets / "env" / "sunset.exr").read_bytes()).json()
    yield {"srv": srv, "c": c, "mesh": mesh["id"], "env": env["id"]}
    c.close()
    assert srv.stop(signal.SIGTERM) == 0, srv.log()[-3000:]


def _scene(c, f) -> str:
    spec = json.loads((ROOT / "tests" / "scenes" / "bunny.json").read_text())
    spec["environment"]["map"], spec["objects"][0]["mesh"] = f["env"], f["mesh"]
    r = c.post("/v1/scenes", json=spec)
    assert r.status_code == 201, r.text
    return r.json()["id"]


def test_health_names_the_cluster(ray_server):
    h = ray_server["c"].get("/healthz").json()
    assert h["backend"] == "ray" and h["ray_nodes"] == 2 and h["workers"] == 2, h
    t0 = time.monotonic()
    while h["workers_alive"] < 2 and time.monotonic() - t0 < 120:
        time.sleep(0.5)
        h = ray_server["c"].get("/healthz").json()
    assert h["status"] == "ok", h


@pytest.fixture(scope="module")
def ray_precomputed(ray_server):
    """(scene id, finished precomputation, progress values seen) of the bunny, precomputed on
    the two-node cluster once for the module's tests, whichever of them runs first."""
    f, c = ray_server, ray_server["c"]
    scene = _scene(c, f)
    pre = c.post(f"/v1/scenes/{scene}/precompute").json()
    seen = []
    t0 = time.monotonic()
    while time.monotonic() - t0 < 900:
        p = c.get(f"/v1/precomputations/{pre['id']}").json()
        seen.append(p["progress"])
        if p["status"] in ("done", "failed"):
            break
        time.sleep(0.3)
    assert p["status"] == "done", p
    return scene, p, seen


def test_precomputation_split_across_both_nodes_is_byte_identical(ray_server, ray_precomputed, bunny_renderer):
    """The cuts from vertex-range Ray tasks on two nodes are the bytes a local run stores."""
    from worker.artifacts import DirStore
    from worker.renderers import get

    f, c = ray_server, ray_server["c"]
    scene, p, seen = ray_precomputed
    st = p["stats"]
    assert st["ray_nodes"] == 2 and st["ray_chunks"] >= 2 and st["backend"] == "ray", st
    assert st["vertices"] == 2882
    assert any(0 < x < 1 for x in seen), f"no progress reported between 0 and 1: {sorted(set(seen))}"
    # the first look, drawn on the host while the cluster traced
    assert 0 < st["preview"]["rays"] <= 256 * st["vertices"], st.get("preview")
    look = c.get(f"/v1/precomputations/{p['id']}/preview")
    assert look.status_code == 200 and look.content[:2] == b"\xff\xd8", look.text[:300]
    # the local reference: the same scene's part, computed in one process (tests/.cache)
    _, pre_local = get("cuts")
    (part,) = pre_local.parts(bunny_renderer.scene, {})
    local = DirStore(ROOT / "tests" / ".cache", "cuts").get(part.key)
    assert local is not None
    data = f["srv"].data / "blobs"
    sha = (data / "keys" / part.key).read_text().strip()
    stored = (data / sha[:2] / sha).read_bytes()
    assert hashlib.sha256(stored).hexdigest() == hashlib.sha256(local).hexdigest(), \
        f"Ray assembly differs from the local run ({len(stored)} vs {len(local)} bytes)"
    # a REST render runs on a session host too
    r = c.post("/v1/renders", json={"scene_id": scene})
    assert r.status_code == 200 and r.headers["content-type"] == "image/png" and r.content[:4] == b"\x89PNG", r.text[:300]


def test_session_and_a_killed_actor(ray_server, ray_precomputed):
    """A session paints and saves on a session host; SIGKILL of that actor's process brings a
    replacement that restores the session (stroke kept, once), and the restart is counted."""
    f, c = ray_server, ray_server["c"]
    ses = c.post("/v1/sessions", json={"scene_id": ray_precomputed[0]}).json()
    hdr = {"X-Session-Token": ses["token"]}

    async def go():
        async with connect(f["srv"].as_dict(), ses["stream"], ses["token"]) as ws:
            assert json.loads(await ws.recv())["type"] == "hello"
            h0, img0 = await next_frame(ws, timeout=180)
            assert img0.std() > 5
            ev = []
            await ws.send(json.dumps({"seq": 1, "type": "stroke", "stroke": STROKE}))
            h, _ = await next_frame(ws, 1, ev, timeout=180)
            while not h["settled"]:          # its still too: nothing of this actor's left in flight
                h, _ = await next_frame(ws, 1, ev, timeout=180)
            assert any(e["type"] == "fit" for e in ev), ev
            pid = c.get(f"/v1/sessions/{ses['id']}", headers=hdr).json()["worker_pid"]
            assert pid and pid != f["srv"].proc.pid
            os.kill(pid, signal.SIGKILL)                      # the actor holding the session dies
            # what the old actor sent before it died may still arrive (a background refit's event
            # and frame): the service's note comes, then the restored session's frame
            ev = []
            t0 = time.monotonic()
            while not any(e["type"] == "note" and "restored" in e["message"] for e in ev):
                assert time.monotonic() - t0 < 300, ev
                x = await asyncio.wait_for(ws.recv(), 300)
                if isinstance(x, str):
                    ev.append(json.loads(x))
            await next_frame(ws, 1, ev, timeout=300)
            after = c.get(f"/v1/sessions/{ses['id']}", headers=hdr).json()
            assert after["worker_pid"] and after["worker_pid"] != pid
            ev = []
            await ws.send(json.dumps({"seq": 2, "type": "save", "name": "ray design"}))
            t0 = time.monotonic()
            while not any(e["type"] == "saved" for e in ev) and time.monotonic() - t0 < 180:
                x = await asyncio.wait_for(ws.recv(), 180)
                if isinstance(x, str):
                    ev.append(json.loads(x))
            saved = [e for e in ev if e["type"] == "saved"]
            assert saved and saved[0]["version"] == 1, ev
            await ws.send(json.dumps({"seq": 3, "type": "fit"}))
            ev = []
            await next_frame(ws, 3, ev, timeout=180)
            fits = [e for e in ev if e["type"] == "fit"]
            assert fits and fits[-1]["stats"]["strokes"] == 1, fits     # replayed once, not twice
    asyncio.run(go())
    h = c.get("/healthz").json()
    assert h["worker_restarts"] >= 1, h
    metrics = c.get("/metrics").text
    line = next(x for x in metrics.splitlines() if x.startswith("glint_worker_restarts_total"))
    assert float(line.split()[-1]) >= 1, line


def test_the_api_process_with_the_ray_pool_loads_no_numerical_libraries():
    """The Ray pool imports Ray and the actor classes, never Embree, OpenCV, trimesh or the QP solver (NumPy comes with the shared state models)."""
    import subprocess

    code = ("import sys; from server.config import Settings; from server.main import create_app; "
            "import server.ray_pool, worker.jobs.ray_actors; create_app(Settings(backend='ray', demo=False)); "
            "print(','.join(m for m in ('embreex', 'cv2', 'daqp', 'trimesh') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"the API process imported {out.stdout.strip()}"
