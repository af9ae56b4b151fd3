"""The service database on SQLite and on a real PostgreSQL server.

- Alembic: the models and the migrations agree (``compare_metadata`` finds no difference) on a
  new database and on one upgraded from release 0.3, on both databases.
- A database made by release 0.3 (tests/data/glint-0.3.0.db: tables from ``create_all``, no
  version table) is upgraded by ``glint db upgrade`` in place, on SQLite as the file itself and on
  PostgreSQL with its schema and rows loaded there; a server then serves its rows.
- Concurrent sessions saving designs, and REST updates of the same design at the same time: every
  save is stored exactly once, versions are 1…N without gaps or duplicates, on both databases.
"""
import asyncio
import json
import shutil
import subprocess
import sys
import threading
import time

import httpx
import pytest
from sqlalchemy import MetaData, create_engine, inspect, select

from helpers import ROOT, GlintServer, connect, next_frame

RELEASE_0_3 = ROOT / "tests" / "data" / "glint-0.3.0.db"
ORDER = ["assets", "scenes", "precomputations", "materials", "material_versions", "sessions", "strokes",
         "publications", "api_tokens"]


@pytest.fixture(params=["sqlite", "postgresql"])
def empty_db(request, tmp_path):
    """The URL of a new empty database of each kind."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'glint.db'}"
    return request.getfixturevalue("postgres").new_database("migr")


def _differences(url: str) -> list:
    from alembic.autogenerate import compare_metadata
    from alembic.runtime.migration import MigrationContext

    from server.db import Base, make_engine

    eng = make_engine(url)
    try:
        with eng.connect() as conn:
            mc = MigrationContext.configure(conn, opts={"compare_type": True, "compare_server_default": False})
            return compare_metadata(mc, Base.metadata)
    finally:
        eng.dispose()


def test_models_and_migrations_agree(empty_db):
    from server.db import make_engine
    from server.migrate import current, head, upgrade

    eng = make_engine(empty_db)
    assert upgrade(eng) is None                      # a new database: from nothing to head
    assert current(eng) == head()
    eng.dispose()
    diff = _differences(empty_db)
    assert diff == [], f"the models differ from what the migrations create: {diff}"


def _load_release_0_3(url: str) -> None:
    """Release 0.3's database, recreated at ``url``: the 0.3 schema (migration 0001, as 0.3's
    create_all made it, without Alembic's version table) and every row of the 0.3 file."""
    from server.db import make_engine
    from server.migrate import upgrade

    eng = make_engine(url)
    upgrade(eng, "0001")
    src = create_engine(f"sqlite:///{RELEASE_0_3}")
    smeta, dmeta = MetaData(), MetaData()
    smeta.reflect(src)
    dmeta.reflect(eng)
    assert set(ORDER) == set(smeta.tables), sorted(smeta.tables)
    with src.connect() as s, eng.begin() as d:
        d.exec_driver_sql("DROP TABLE alembic_version")     # 0.3 had none
        for name in ORDER:
            rows = [dict(r._mapping) for r in s.execute(select(smeta.tables[name]))]
            if rows:
                d.execute(dmeta.tables[name].insert(), rows)
        if eng.dialect.name == "postgresql":                # rows came with their ids: move the sequences on
            for name in ("material_versions", "strokes"):
                d.exec_driver_sql(f"SELECT setval(pg_get_serial_sequence('{name}', 'id'), (SELECT max(id) FROM {name}))")
    src.dispose()
    eng.dispose()


@pytest.mark.parametrize("kind", ["sqlite", "postgresql"])
def test_a_release_0_3_database_is_upgraded_and_served(kind, tmp_path, request):
    if kind == "sqlite":
        shutil.copy(RELEASE_0_3, tmp_path / "glint.db")
        url = f"sqlite:///{tmp_path / 'glint.db'}"
    else:
        url = request.getfixturevalue("postgres").new_database("rel03")
        _load_release_0_3(url)
    eng = create_engine(url)
    assert "alembic_version" not in inspect(eng).get_table_names()
    eng.dispose()
    out = subprocess.run([sys.executable, "-m", "glint", "db", "upgrade", "--database-url", url,
                          "--data-dir", str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    from server.migrate import head

    assert f": 0001 -> {head()}" in out.stdout, out.stdout
    assert _differences(url) == []
    # the upgraded rows, through a real server on that database
    srv = GlintServer(tmp_path / "data", workers=1, env={"GLINT_DATABASE_URL": url})
    try:
        with httpx.Client(base_url=srv.base, timeout=60) as c:
            p = c.get("/v1/precomputations/p1").json()
            assert p["status"] == "done" and p["kind"] == "cuts", p
            m = c.get("/v1/materials/m1").json()
            assert m["version"] == 1 and m["material"]["model"], m
            r = c.put("/v1/materials/m1", json={"material": m["material"], "note": "after the upgrade"})
            assert r.status_code == 200 and r.json()["version"] == 2, r.text     # the id sequence moved on
            assert c.get("/v1/scenes").json()[0]["id"] == "s1"
    finally:
        assert srv.stop() == 0


@pytest.mark.both_databases
def test_concurrent_sessions_save_designs(server, client, bunny_scene):
    """Four sessions save into one design at the same moment, and into a design of their own,
    while REST clients put new versions of the same design: every save is stored once, and the
    design's versions are 1…N with no gap or duplicate (the design row is locked while a version
    is numbered)."""
    base = client.post("/v1/materials", json={"name": "shared", "material": {"model": "lambert", "albedo": [0.5, 0.5, 0.5]}})
    assert base.status_code == 201, base.text
    mid = base.json()["id"]
    sessions = [client.post("/v1/sessions", json={"scene_id": bunny_scene}).json() for _ in range(4)]

    puts: list[int] = []

    def rest_puts():
        with httpx.Client(base_url=server["base"], timeout=120) as c:
            for k in range(3):
                r = c.put(f"/v1/materials/{mid}", json={"material": {"model": "lambert", "albedo": [0.1 * k, 0.2, 0.3]}})
                puts.append(r.status_code)

    ready: list[str] = []

    async def one(ses, go: asyncio.Event):
        async with connect(server, ses["stream"], ses["token"]) as ws:
            await ws.recv()
            await next_frame(ws, timeout=180)
            ready.append(ses["id"])
            await go.wait()
            await ws.send(json.dumps({"seq": 1, "type": "save", "material_id": mid}))
            await ws.send(json.dumps({"seq": 2, "type": "save", "name": f"own {ses['id']}"}))
            ev = []
            t0 = time.monotonic()
            while sum(e["type"] == "saved" for e in ev) < 2 and time.monotonic() - t0 < 180:
                x = await asyncio.wait_for(ws.recv(), 180)
                if isinstance(x, str):
                    e = json.loads(x)
                    assert e["type"] != "error", e
                    ev.append(e)
            return [e for e in ev if e["type"] == "saved"]

    async def all_():
        go = asyncio.Event()
        tasks = [asyncio.create_task(one(s, go)) for s in sessions]
        # every stream has its first frame before the saves and the REST puts start together
        while len(ready) < len(tasks) and not any(t.done() for t in tasks):
            await asyncio.sleep(0.1)
        threads = [threading.Thread(target=rest_puts) for _ in range(2)]
        go.set()
        for t in threads:
            t.start()
        res = await asyncio.gather(*tasks)
        for t in threads:
            t.join()
        return res
    saved = asyncio.run(all_())
    assert puts == [200] * 6, puts
    shared = sorted(e["version"] for evs in saved for e in evs if e["material_id"] == mid)
    own = [e for evs in saved for e in evs if e["material_id"] != mid]
    assert len(shared) == 4 and len(own) == 4 and all(e["version"] == 1 for e in own), saved
    versions = [v["version"] for v in client.get(f"/v1/materials/{mid}/versions").json()]
    assert versions == list(range(1, 1 + 1 + 4 + 6)), versions
    assert "IntegrityError" not in server["server"].log() and "unhandled error" not in server["server"].log()


def test_make_test_installs_postgresql_before_the_tests():
    """`make test` runs scripts/ensure-postgresql before pytest (a fresh machine has no server)."""
    out = subprocess.run(["make", "-n", "test"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    lines = out.splitlines()
    setup = [i for i, line in enumerate(lines) if "ensure-postgresql" in line]
    tests = [i for i, line in enumerate(lines) if "-m pytest" in line]
    assert setup and tests and setup[0] < tests[0], out
    assert "apt-get install" in (ROOT / "scripts" / "ensure-postgresql").read_text()


def test_versions_are_numbered_one_after_the_other_under_contention(empty_db, monkeypatch):
    """Eight threads add a version to one design at the same moment, each pausing between
    reading the latest version and inserting the next (the race window, widened): the lock on the
    design makes the versions 1…9 on SQLite and on PostgreSQL (without it, they collide)."""
    import server.services.materials as materials
    from server.db import MaterialDesign, MaterialVersion, make_sessionmaker

    Session_ = make_sessionmaker(empty_db)
    with Session_() as s, s.begin():
        d = MaterialDesign(name="contended")
        s.add(d)
        s.flush()
        materials.add_version(s, d, {"model": "lambert", "albedo": [0.5, 0.5, 0.5]})
        did = d.id
    real = materials.latest_version

    def slow_latest(db, design_id):
        v = real(db, design_id)
        time.sleep(0.05)
        return v
    monkeypatch.setattr(materials, "latest_version", slow_latest)
    go = threading.Barrier(8)
    errors = []

    def add(k):
        try:
            go.wait()
            with Session_() as s, s.begin():
                materials.add_version(s, s.get(MaterialDesign, did), {"model": "lambert", "albedo": [0.1 * k, 0.2, 0.3]})
        except Exception as e:  # noqa: BLE001 -- collected for the assertion
            errors.append(repr(e))
    threads = [threading.Thread(target=add, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    with Session_() as s:
        versions = sorted(s.scalars(select(MaterialVersion.version).where(MaterialVersion.design_id == did)))
    Session_.kw["bind"].dispose()
    assert not errors and versions == list(range(1, 10)), (errors[:2], versions)


def test_sqlite_writers_of_one_process_queue_on_a_lock_not_in_sqlite(tmp_path):
    """SQLite's busy handler sleeps 1, 2, 5, … up to 100 ms between retries, which
    put 50-180 ms on strokes' rows under load. A second writer in the process now waits on the
    process's write lock, which the first releases at its commit or rollback; reads do not take
    it."""
    from server.db import _WRITE_LOCK, ApiToken, make_sessionmaker

    S = make_sessionmaker(f"sqlite:///{tmp_path / 'glint.db'}")
    order, started = [], threading.Event()

    def free() -> bool:
        """Whether another thread could take the write lock now (it is re-entrant here)."""
        got = []

        def probe():
            got.append(_WRITE_LOCK.acquire(blocking=False))
            if got[0]:
                _WRITE_LOCK.release()

        t = threading.Thread(target=probe)
        t.start()
        t.join()
        return got[0]

    def second_writer():
        started.set()
        with S() as s, s.begin():
            s.add(ApiToken(name="second", token_sha256="b" * 64))
        order.append("second committed")

    with S() as r:
        r.scalars(select(ApiToken)).all()
        assert free(), "a read took the write lock"
    with S() as s:
        with s.begin():
            s.add(ApiToken(name="first", token_sha256="a" * 64))
            s.flush()                                   # the INSERT: this connection writes
            assert not free(), "a writing connection does not hold the write lock"
            t = threading.Thread(target=second_writer)
            t.start()
            started.wait()
            time.sleep(0.2)
            assert order == [], "the second writer did not wait for the first"
            order.append("first committing")
        t.join(30)
    assert order == ["first committing", "second committed"]
    with S() as s:
        try:
            with s.begin():
                s.add(ApiToken(name="third", token_sha256="c" * 64))
                s.flush()
                raise RuntimeError("rolled back")
        except RuntimeError:
            pass
    assert free(), "a rollback left the write lock held"
    with S() as s:
        assert sorted(s.scalars(select(ApiToken.name))) == ["first", "second"]
