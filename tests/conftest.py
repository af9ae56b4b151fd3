"""Shared fixtures. Precomputed cuts are cached in tests/.cache (content-addressed by geometry),
so only the first run pays for tracing. ``server`` is a real Glint server (uvicorn in a subprocess
on a free loopback port, two worker processes); ``bunny_scene`` is the bunny under the sunset HDRI
uploaded and precomputed through its API."""
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from helpers import open_renderer

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "assets"
CACHE = ROOT / "tests" / ".cache"
ARTIFACTS = ROOT / "test-artifacts"


@pytest.fixture(scope="session")
def shared_assets() -> Path:
    if not SHARED.is_dir():
        pytest.fail(f"real test assets not found at {SHARED} (../shared/assets beside the repository)")
    return SHARED


@pytest.fixture(scope="session")
def cache_dir() -> Path:
    CACHE.mkdir(parents=True, exist_ok=True)
    return CACHE


@pytest.fixture(scope="session")
def artifacts() -> Path:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    return ARTIFACTS


@pytest.fixture(scope="session")
def bunny_renderer(shared_assets, cache_dir):
    """The cut renderer of tests/scenes/bunny.json (cuts cached)."""
    from worker.scene import load_scene

    return open_renderer(load_scene(ROOT / "tests" / "scenes" / "bunny.json"))


@pytest.fixture(scope="session")
def bunny(bunny_renderer):
    """(LoadedScene, CutSet) of tests/scenes/bunny.json, cuts cached."""
    return bunny_renderer.scene, bunny_renderer.cuts



def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")
def server(tmp_path_factory):
    data = tmp_path_factory.mktemp("glint-data")
    port = free_port()
    env = {**os.environ, "GLINT_MAX_MESH_BYTES": str(8 * 1024 * 1024), "PYTHONUNBUFFERED": "1"}
    log = open(data / "server.log", "w")
    proc = subprocess.Popen([sys.executable, "-m", "worker.cli", "serve", "--port", str(port), "--data-dir", str(data),
                             "--workers", "2", "--no-demo"], cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    for _ in range(300):
        try:
            if httpx.get(base + "/healthz", timeout=1).status_code == 200:
                break
        except httpx.HTTPError:
            pass
        if proc.poll() is not None:
            raise RuntimeError("server exited: " + (data / "server.log").read_text()[-3000:])
        time.sleep(0.2)
    else:
        proc.kill()
        raise RuntimeError("server did not start: " + (data / "server.log").read_text()[-3000:])
    yield {"base": base, "port": port, "data": data, "proc": proc}
    proc.terminate()
    try:
        proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
    log.close()


@pytest.fixture(scope="session")
def client(server):
    with httpx.Client(base_url=server["base"], timeout=120) as c:
        yield c


@pytest.fixture(scope="session")
def bunny_scene(client, shared_assets):
    """Scene id of the bunny under the sunset HDRI, uploaded and precomputed through the API."""
    mesh = client.post("/v1/assets/meshes", params={"filename": "bunny.ply"},
                       content=(shared_assets / "meshes" / "bunny.ply").read_bytes())
    assert mesh.status_code == 201, mesh.text
    env = client.post("/v1/assets/envmaps", params={"filename": "sunset.exr"},
                      content=(shared_assets / "env" / "sunset.exr").read_bytes())
    assert env.status_code == 201, env.text
    spec = json.loads((ROOT / "tests" / "scenes" / "bunny.json").read_text())
    spec["environment"]["map"] = env.json()["id"]
    spec["objects"][0]["mesh"] = mesh.json()["id"]
    sc = client.post("/v1/scenes", json=spec, params={"name": "bunny"})
    assert sc.status_code == 201, sc.text
    sid = sc.json()["id"]
    pre = client.post(f"/v1/scenes/{sid}/precompute")
    assert pre.status_code == 202, pre.text
    seen = set()
    for _ in range(600):
        p = client.get(f"/v1/precomputations/{pre.json()['id']}").json()
        seen.add(p["status"])
        if p["status"] in ("done", "failed"):
            break
        time.sleep(0.5)
    assert p["status"] == "done", p
    assert p["stats"]["vertices"] == 2826
    return sid
