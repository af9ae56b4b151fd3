"""Large and hostile requests, bounded: the server stays responsive (health checks and streams
go on while it validates a big scene), and refusals name the limit and the measured value."""
import asyncio
import json
import threading
import time
from pathlib import Path

import httpx

from helpers import connect, next_frame

ROOT = Path(__file__).resolve().parents[2]
N_OBJECTS = 20_000                     # the default max_scene_objects: the largest scene accepted


def _big_scene(client, bunny_scene, n):
    spec = client.get(f"/v1/scenes/{bunny_scene}").json()["spec"]
    o = spec["objects"][0]
    spec["objects"] = [{"name": f"o{i}", "mesh": o["mesh"], "material": o["material"]} for i in range(n)]
    return spec


def test_a_large_scene_does_not_stall_health_checks_or_streams(server, client, bunny_scene):
    spec = _big_scene(client, bunny_scene, N_OBJECTS)
    body = json.dumps(spec).encode()
    r = client.post("/v1/sessions", json={"scene_id": bunny_scene})
    assert r.status_code == 201, r.text
    ses = r.json()
    done = threading.Event()
    health: list[float] = []
    frames: list[float] = []
    window = [0.0, 0.0]

    def poll():
        with httpx.Client(base_url=server["base"], timeout=30) as c:
            while not done.is_set():
                t = time.perf_counter()
                assert c.get("/healthz").status_code == 200
                health.append(time.perf_counter() - t)
                time.sleep(0.02)

    async def stream():
        async with connect(server, ses["stream"], ses["token"]) as ws:
            await ws.recv()                                           # hello
            await next_frame(ws)
            started.set()
            seq = 0
            while not done.is_set():
                seq += 1
                await ws.send(json.dumps({"seq": seq, "type": "light", "rotation_deg": (7 * seq) % 360}))
                await next_frame(ws, seq, timeout=30)
                frames.append(time.perf_counter())

    started = threading.Event()
    streamer = threading.Thread(target=lambda: asyncio.run(stream()))
    streamer.start()
    assert started.wait(60), "the stream gave no first frame"
    poller = threading.Thread(target=poll)
    poller.start()
    time.sleep(0.3)
    try:
        window[0] = time.perf_counter()
        with httpx.Client(base_url=server["base"], timeout=600) as c:
            created = c.post("/v1/scenes", content=body, params={"name": "big"},
                             headers={"Content-Type": "application/json"})
        window[1] = time.perf_counter()
        time.sleep(0.3)
    finally:
        done.set()
        poller.join(60)
        streamer.join(60)
    post_s = window[1] - window[0]
    assert created.status_code == 201, created.text[:500]
    assert len(created.json()["spec"]["objects"]) == N_OBJECTS
    assert len(health) >= 5, health
    worst = max(health)
    # a stalled event loop holds /healthz for the whole parse (~post_s); a loaded 2-core machine
    # alone can delay one answer by a quarter second (254 ms measured once, median 7 ms)
    bound = max(0.1, 0.5 * post_s)
    assert worst < bound, (f"/healthz took up to {1000 * worst:.0f} ms (median {1000 * sorted(health)[len(health) // 2]:.0f} ms) "
                         f"while a {N_OBJECTS}-object scene ({len(body)} bytes) was created in {post_s:.2f} s; bound {1000 * bound:.0f} ms")
    during = [t for t in frames if window[0] <= t <= window[1]]
    gaps = [b - a for a, b in zip([window[0]] + during, during + [window[1]])]
    assert max(gaps) < 1.0, f"frames stopped for {max(gaps):.2f} s during the {post_s:.2f} s POST ({len(during)} frames)"
    # the list stays cheap with the big scene in it
    t = time.perf_counter()
    lst = client.get("/v1/scenes", params={"limit": 10})
    list_s = time.perf_counter() - t
    assert lst.status_code == 200 and len(lst.json()) <= 10
    assert list_s < 2.0, f"GET /v1/scenes took {list_s:.2f} s"
    print(f"POST {N_OBJECTS} objects: {post_s:.2f} s; /healthz worst {1000 * worst:.0f} ms over {len(health)}; "
          f"{len(during)} frames during the POST, largest gap {max(gaps):.2f} s; GET /v1/scenes {list_s:.2f} s")


def test_scene_over_the_object_limit_is_refused_naming_it(client, bunny_scene):
    spec = _big_scene(client, bunny_scene, N_OBJECTS + 1)
    r = client.post("/v1/scenes", json=spec)
    assert r.status_code == 413, r.text[:500]
    assert f"{N_OBJECTS + 1} objects" in r.json()["detail"] and f"limit of {N_OBJECTS}" in r.json()["detail"], r.text
    dup = _big_scene(client, bunny_scene, 3)
    dup["objects"][2]["name"] = "o0"
    r = client.post("/v1/scenes", json=dup)
    assert r.status_code == 422 and "o0" in r.json()["detail"], r.text


def test_stream_tokens_never_reach_the_log_in_any_spelling(server, client, bunny_scene):
    import websockets

    r = client.post("/v1/sessions", json={"scene_id": bunny_scene})
    ses = r.json()
    token = ses["token"]
    path = ses["stream"]

    async def go():
        # "%74oken" is "token" percent-encoded (the server decodes names, so it authenticates);
        # "token%3D…" decodes to "token=…"; any case of the name
        for query in (f"%74oken={token}", f"token%3D{token}", f"TOKEN={token}", f"x=1&%2574oken={token}"):
            async with websockets.connect(f"ws://127.0.0.1:{server['port']}{path}?{query}", max_size=None) as ws:
                await ws.send(json.dumps({"type": "auth", "token": token}))
                first = json.loads(await ws.recv())
                assert first["type"] == "hello", first
    asyncio.run(go())
    time.sleep(0.5)
    log = server["server"].log()
    assert path.split("?")[0] in log                       # the lines are there, without the token
    assert token not in log, [ln for ln in log.splitlines() if token in ln][:3]


def test_huge_or_negative_integers_in_paths_are_refused(client):
    m = client.post("/v1/materials", json={"name": "ints", "material": {"model": "lambert", "albedo": [0.5, 0.5, 0.5]}})
    assert m.status_code == 201, m.text
    mid = m.json()["id"]
    assert client.get(f"/v1/materials/{mid}/versions/1").status_code == 200
    for v in ("9810356179484963864838144", str(2**31), "0", "-1"):
        r = client.get(f"/v1/materials/{mid}/versions/{v}")
        assert r.status_code == 422, (v, r.status_code, r.text)
        assert "version" in r.json()["detail"], r.text
    for q in ({"limit": 10**30}, {"offset": -1}, {"limit": 0}):
        r = client.get("/v1/scenes", params=q)
        assert r.status_code == 422, (q, r.text)


def test_leftover_partial_uploads_are_deleted_at_start(tmp_path):
    import os
    import subprocess
    import sys

    from helpers import GlintServer

    host = "".join(c if c.isalnum() else "_" for c in os.uname().nodename)[:40]
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    tmp = tmp_path / "blobs" / "tmp"
    tmp.mkdir(parents=True)
    of_dead = tmp / f"up-{host}-{dead.pid}-abc"
    of_live = tmp / f"up-{host}-{os.getpid()}-def"          # this test process: alive
    old = tmp / "tmpq1w2e3"                                  # an unnamed one, two hours old
    scratch = tmp_path / "tmp" / "ray-7"
    scratch.mkdir(parents=True)
    for f in (of_dead, of_live, old, scratch / "part.bin"):
        f.write_bytes(b"\0" * 65536)
    two_h = time.time() - 7200
    os.utime(old, (two_h, two_h))
    os.utime(scratch / "part.bin", (two_h, two_h))
    os.utime(scratch, (two_h, two_h))
    srv = GlintServer(tmp_path, workers=1)
    try:
        assert not of_dead.exists() and not old.exists() and not scratch.exists(), sorted(os.listdir(tmp))
        assert of_live.exists(), "a live process's partial upload was deleted"
        assert "leftover temporary" in srv.log()
    finally:
        srv.stop()


def _wait_capture(client, cid, timeout=120):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        c = client.get(f"/v1/captures/{cid}").json()
        if c["status"] in ("done", "failed"):
            return c
        time.sleep(0.2)
    raise AssertionError(f"capture {cid} still {c['status']} after {timeout} s")


def test_a_zip_bomb_capture_fails_fast_naming_the_ratio(client):
    import io
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as z:
        z.writestr("manifest.json", "{}")
        z.writestr("bracket-0.jpg", b"\0" * (32 << 20))        # 32 MiB of zeros: ~32 KiB compressed
    assert len(buf.getvalue()) < 100_000
    t = time.perf_counter()
    r = client.post("/v1/captures", content=buf.getvalue(), headers={"Content-Type": "application/zip"})
    assert r.status_code == 202, r.text
    c = _wait_capture(client, r.json()["id"])
    assert c["status"] == "failed", c
    assert "compression ratio" in c["message"] and "100:1" in c["message"] and "bracket-0.jpg" in c["message"], c
    assert time.perf_counter() - t < 30


def test_a_full_disk_answers_507_and_keeps_earlier_data(tmp_path):
    """The data folder on a 20 MiB tmpfs, filled by uploads: the one that does not fit is a 507
    saying the disk is full; what was stored before stays listed, readable and intact."""
    import hashlib
    import io
    import sqlite3
    import subprocess

    import numpy as np
    import pytest
    from PIL import Image

    from helpers import GlintServer

    data = tmp_path / "data"
    data.mkdir()
    m = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=20m", "tmpfs", str(data)], capture_output=True, text=True)
    if m.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs to fill (needs root or CAP_SYS_ADMIN): {m.stderr.strip()}")
    srv = None
    try:
        srv = GlintServer(data, workers=1, log_path=tmp_path / "server.log")
        rng = np.random.default_rng(5)
        stored, full = [], None
        with httpx.Client(base_url=srv.base, timeout=120) as c:
            for k in range(20):
                # incompressible noise, different every time (the store keeps one copy of equal files)
                png = io.BytesIO()
                Image.fromarray(rng.integers(0, 256, (900, 900, 3), dtype=np.uint8)).save(png, "PNG", compress_level=0)
                r = c.post("/v1/assets/images", params={"filename": f"noise{k}.png"}, content=png.getvalue())
                if r.status_code == 201:
                    stored.append((r.json(), hashlib.sha256(png.getvalue()).hexdigest()))
                    continue
                full = r
                break
            assert full is not None, "20 uploads of 2.4 MB fitted on a 20 MiB disk"
            assert full.status_code == 507, (full.status_code, full.text)
            assert "disk is full" in full.json()["detail"], full.text
            assert len(stored) >= 2, stored
            for a, sha in stored:
                g = c.get(f"/v1/assets/{a['id']}")
                assert g.status_code == 200 and g.json()["sha256"] == sha
                blob = data / "blobs" / sha[:2] / sha
                assert hashlib.sha256(blob.read_bytes()).hexdigest() == sha
            assert c.get("/healthz").status_code == 200
        assert not list((data / "blobs" / "tmp").iterdir()), "the cut-off upload's temporary file was left"
        srv.stop()
        srv = None
        with sqlite3.connect(data / "glint.db") as db:
            assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
            assert db.execute("SELECT count(*) FROM assets").fetchone()[0] == len(stored)
    finally:
        if srv is not None:
            srv.stop()
        subprocess.run(["umount", "-l", str(data)], capture_output=True)


def test_json_bodies_are_capped_before_parsing(client, bunny_scene):
    strokes = [{"points": [[10.0 + k % 100, 20.0]] * 50, "color": [1.0, 1.0, 1.0]} for k in range(3000)]
    body = json.dumps({"scene_id": bunny_scene, "object": "bunny", "strokes": strokes}).encode()
    assert len(body) > 2 * 1024 * 1024
    r = client.post("/v1/fits", content=body, headers={"Content-Type": "application/json"})
    assert r.status_code == 413, r.text[:300]
    assert f"{len(body)} bytes" in r.json()["detail"] and f"{2 * 1024 * 1024}-byte limit" in r.json()["detail"], r.text

    def chunked():                      # no Content-Length: counted as it comes
        for k in range(0, len(body), 65536):
            yield body[k:k + 65536]
    r = client.post("/v1/fits", content=chunked(), headers={"Content-Type": "application/json"})
    assert r.status_code == 413 and "limit" in r.json()["detail"], r.text[:300]
    # a small body passes through (here refused for what it says, not for its size)
    r = client.post("/v1/fits", content=json.dumps({"scene_id": bunny_scene, "object": "nope", "strokes": strokes[:2]}),
                    headers={"Content-Type": "application/json"})
    assert r.status_code == 422 and "nope" in r.json()["detail"], r.text[:300]


def test_a_huge_integer_in_a_body_is_refused_not_a_server_error(client, bunny_scene):
    m = client.post("/v1/materials", json={"name": "big", "material": {"model": "lambert", "albedo": [0.5, 0.5, 0.5]}})
    r = client.post("/v1/publications", json={"name": "p", "scene_id": bunny_scene, "object": "bunny",
                                              "variants": [{"material_id": m.json()["id"], "version": 10**30}]})
    assert r.status_code == 422 and "out of range" in r.json()["detail"], (r.status_code, r.text)


def test_json_in_pieces_is_json():
    """server/jsonchunks.py reads and writes exactly what json does, errors included."""
    import pytest

    from server import jsonchunks

    docs = [{"a": [1, 2, {"b": [3]}], "c": "x", "d": None}, [], {}, [[], [{}]], "s", 1.5, None,
            {"objects": [{"name": f"o{i}", "m": [0.1, i]} for i in range(1000)]}]
    for doc in docs:
        for text in (json.dumps(doc), json.dumps(doc, indent=2)):
            assert jsonchunks.loads(text) == doc == jsonchunks.loads(text.encode())
        assert json.loads(jsonchunks.dumps(doc, depth=3)) == doc
    for bad in ("{", "[1,]", '{"a" 1}', "[1 2]", '{"a": 1} x', "", "{'a': 1}"):
        with pytest.raises(json.JSONDecodeError):
            jsonchunks.loads(bad)
        with pytest.raises(json.JSONDecodeError):
            json.loads(bad)
