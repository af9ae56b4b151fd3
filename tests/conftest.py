"""Shared fixtures. Precomputed cuts are cached in tests/.cache (content-addressed by geometry),
so only the first run pays for tracing. ``server`` is a real Glint server (uvicorn in a subprocess
on a free loopback port, two worker processes); ``bunny_scene`` is the bunny under the sunset HDRI
uploaded and precomputed through its API."""
import json
import os
import time
from pathlib import Path

import httpx
import pytest
from helpers import AssetDir, GlintServer, free_port, open_renderer, scene_file  # noqa: F401

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parent.parent
CACHE = ROOT / "tests" / ".cache"
ARTIFACTS = ROOT / "test-artifacts"


@pytest.fixture(scope="session")
def shared_assets() -> AssetDir:
    """The real test assets (tests/.cache/assets), each file fetched on first use (helpers.AssetDir)."""
    return AssetDir()


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

    return open_renderer(load_scene(scene_file("bunny.json")))


@pytest.fixture(scope="session")
def bunny(bunny_renderer):
    """(LoadedScene, CutSet) of tests/scenes/bunny.json, cuts cached."""
    return bunny_renderer.scene, bunny_renderer.cuts



# The service tests that also run against PostgreSQL: sessions, strokes, saves and
# material versions, i.e. what depends on the database's transactions and locks. Everything else
# that uses ``server`` runs on SQLite only, so the suite does not double. A new test opts in with
# @pytest.mark.both_databases.
POSTGRES_TOO = {
    "test_service.py::test_session_stroke_save_and_crash_recovery",
    "test_service.py::test_rest_render_fit_and_material_versions",
    "test_security.py::test_archived_designs_refuse_session_saves_and_fresnel_zero_means_zero",
}


@pytest.fixture(autouse=True)
def _background_work_ends_with_its_test():
    """A session's background work (view builds, a region refit in parts: jobs/fit_driver.py's
    one builder thread) ends before the next test: it runs on the renderer it was given, often a
    module's or the session's shared one, and would otherwise change that renderer's state under
    the next test (a GI region test once saw another unit frozen between two of its calls)."""
    yield
    import sys
    fd = sys.modules.get("worker.jobs.fit_driver")
    if fd is not None:
        t0 = time.perf_counter()
        fd._builder.submit(lambda: None).result(timeout=600)   # one thread, first in first out
        if os.environ.get("GLINT_DEBUG_BG"):
            print(f"\n[background work waited {time.perf_counter() - t0:.3f} s]")


def pytest_configure(config):
    config.addinivalue_line("markers", "both_databases: run this service test on SQLite and on PostgreSQL")


# Folders whose files take minutes each (real browsers, servers, databases), handed out first:
# pytest-xdist gives files to its workers in collection order (the Makefile turns off its own
# reordering, by number of tests, which put these few-test files last), and when they came last
# one worker ran them alone while the other idled (make test 15.4 min).
SLOW_FIRST = ("/web/", "/server/", "/scale/")


def pytest_collection_modifyitems(session, config, items):
    def rank(item):
        path = "/" + item.nodeid.split("::", 1)[0]
        return next((k for k, d in enumerate(SLOW_FIRST) if d in path), len(SLOW_FIRST))
    items.sort(key=rank)                  # stable: each file's own order is kept


def pytest_generate_tests(metafunc):
    """Every test that needs ``database`` (through ``server``) gets it as a parameter: sqlite, and
    postgresql too for the tests named above or marked both_databases."""
    if "database" not in metafunc.fixturenames:
        return
    name = f"{Path(metafunc.definition.fspath).name}::{metafunc.definition.originalname}"
    both = name in POSTGRES_TOO or metafunc.definition.get_closest_marker("both_databases") is not None
    metafunc.parametrize("database", ["sqlite", "postgresql"] if both else ["sqlite"], indirect=True, scope="session")


@pytest.fixture(scope="session")
def postgres():
    """A PostgreSQL server in a temporary folder, started on first use (tests/pg.py)."""
    from pg import PostgresServer

    pg = PostgresServer()
    yield pg
    pg.stop()


@pytest.fixture(scope="session")
def database(request):
    """The server's database: "sqlite" (its data folder, the default) or "postgresql" (a fresh
    database on the test PostgreSQL server). Returns (name, environment for GlintServer)."""
    if request.param == "postgresql":
        return "postgresql", {"GLINT_DATABASE_URL": request.getfixturevalue("postgres").new_database()}
    return "sqlite", {}


@pytest.fixture(scope="session")
def server(tmp_path_factory, database):
    name, env = database
    # the suite opens many viewer sessions from one address within a minute (test_resources:
    # 40 in a row); the limit itself is tested on a server of its own (test_stream_abuse)
    # its scenes' precomputations are copied from the test servers' shared folder when another
    # server computed them before (tests of precomputation itself start servers of their own)
    srv = GlintServer(tmp_path_factory.mktemp(f"glint-data-{name}"),
                      env={"GLINT_VIEWER_SESSIONS_PER_MINUTE": "1000", **env}, shared_parts=True)
    yield {**srv.as_dict(), "database": name}
    srv.stop()


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
    assert p["stats"]["vertices"] == 2882
    return sid
