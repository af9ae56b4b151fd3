"""Security of the embedded default: DNS rebinding (Host), cross-site requests
(Origin), secrets kept out of logs, bounded and expiring sessions, archived designs, uploads
read in a child process with a time limit, and the REST fit's fresnel_f0."""
import asyncio
import json
import threading
import time

import httpx
import numpy as np
import pytest
import websockets

from helpers import ROOT, GlintServer, connect, next_event, next_frame


def _upload_scene(c: httpx.Client, shared_assets) -> str:
    mesh = c.post("/v1/assets/meshes", params={"filename": "bunny.ply"},
                  content=(shared_assets / "meshes" / "bunny.ply").read_bytes())
    env = c.post("/v1/assets/envmaps", params={"filename": "sunset.exr"},
                 content=(shared_assets / "env" / "sunset.exr").read_bytes())
    assert mesh.status_code == 201 and env.status_code == 201, (mesh.text, env.text)
    spec = json.loads((ROOT / "tests" / "scenes" / "bunny.json").read_text())
    spec["environment"]["map"], spec["objects"][0]["mesh"] = env.json()["id"], mesh.json()["id"]
    sid = c.post("/v1/scenes", json=spec).json()["id"]
    pre = c.post(f"/v1/scenes/{sid}/precompute").json()
    for _ in range(600):
        p = c.get(f"/v1/precomputations/{pre['id']}").json()
        if p["status"] in ("done", "failed"):
            break
        time.sleep(0.5)
    assert p["status"] == "done", p
    return sid


def test_host_and_origin_are_checked(server):
    base = server["base"]
    # DNS rebinding: a page on evil.example resolving to 127.0.0.1 still sends its own Host
    r = httpx.get(base + "/v1/materials", headers={"Host": "evil.example"})
    assert r.status_code == 421 and "Host" in r.json()["detail"], r.text
    assert httpx.get(base + "/v1/materials", headers={"Host": f"localhost:{server['port']}"}).status_code == 200
    # a cross-site form post or fetch carries Origin: refused for anything that changes state
    body = {"name": "x", "material": {"model": "lambert"}}
    r = httpx.post(base + "/v1/materials", json=body, headers={"Origin": "http://evil.example"})
    assert r.status_code == 403, r.text
    assert httpx.post(base + "/v1/materials", json=body, headers={"Origin": base}).status_code == 201
    assert httpx.post(base + "/v1/materials", json=body).status_code == 201            # scripts send none

    async def ws_origin():
        with pytest.raises(websockets.InvalidStatus) as e:
            async with websockets.connect(f"ws://127.0.0.1:{server['port']}/v1/sessions/x/stream",
                                          origin="http://evil.example"):
                pass
        return e.value.response.status_code
    assert asyncio.run(ws_origin()) == 403


def test_tokens_stay_out_of_the_log(server, client, bunny_scene):
    """Old clients may still put the token in the URL; the access log never shows it."""
    ses = client.post("/v1/sessions", json={"scene_id": bunny_scene}).json()

    async def go():
        async with websockets.connect(f"ws://127.0.0.1:{server['port']}{ses['stream']}?token={ses['token']}",
                                      max_size=None) as ws:
            assert json.loads(await ws.recv())["type"] == "hello"
    asyncio.run(go())
    client.get(f"/v1/sessions/{ses['id']}", headers={"X-Session-Token": ses["token"]})
    time.sleep(0.5)
    log = server["server"].log()
    assert ses["token"] not in log
    assert "token=[redacted]" in log


def test_archived_designs_refuse_session_saves_and_fresnel_zero_means_zero(server, client, bunny_scene):
    """A session save into an archived design is refused like REST PUT (409), and a REST fit's
    fresnel_f0 of 0 is 0, not the default 1."""
    d = client.post("/v1/materials", json={"name": "old", "material": {"model": "lambert"}}).json()
    client.delete(f"/v1/materials/{d['id']}")
    ses = client.post("/v1/sessions", json={"scene_id": bunny_scene}).json()

    async def go():
        async with connect(server, ses["stream"], ses["token"]) as ws:
            await ws.recv()
            await next_frame(ws)
            ev = []
            await ws.send(json.dumps({"seq": 1, "type": "save", "material_id": d["id"]}))
            await next_frame(ws, 1, ev)
            for _ in range(20):
                if any(e["type"] in ("error", "saved") for e in ev):
                    break
                x = await asyncio.wait_for(ws.recv(), 30)
                if isinstance(x, str):
                    ev.append(json.loads(x))
            return ev
    ev = asyncio.run(go())
    err = [e for e in ev if e["type"] == "error"]
    assert err and err[0]["code"] == 409 and "archived" in err[0]["message"], ev
    assert [v["version"] for v in client.get(f"/v1/materials/{d['id']}/versions").json()] == [1]
    fit = client.post("/v1/fits", json={"scene_id": bunny_scene, "object": "bunny", "fresnel_f0": 0.0, "fit_scale": 0.5,
                                        "strokes": [{"points": [[60, 60], [90, 62]], "color": [3, 3, 3], "diameter": 8}]})
    assert fit.status_code == 200, fit.text
    assert fit.json()["material"]["fresnel_f0"] == 0.0


def test_materials_a_client_sends_are_bounded(server, client, bunny_scene):
    """No message can make a worker allocate without bound: an srbf over 4,096 centres is refused
    at the edge (the stream's messages are also capped at 4 MiB)."""
    ses = client.post("/v1/sessions", json={"scene_id": bunny_scene}).json()
    n = 5000
    big = {"model": "srbf", "centers": [[0, 0, 1]] * n, "bandwidth": 80.0, "coefficients": [[0.1, 0.1, 0.1]] * n}

    async def go():
        async with connect(server, ses["stream"], ses["token"]) as ws:
            await ws.recv()
            await next_frame(ws)
            await ws.send(json.dumps({"seq": 1, "type": "material", "material": big}))
            ev = await next_event(ws)
            assert ev["type"] == "error" and "centers" in ev["message"], ev
            await ws.send(json.dumps({"seq": 2, "type": "light", "rotation_deg": 10}))
            hdr, _ = await next_frame(ws, 2)
            return hdr
    assert asyncio.run(go())["ack"] == 2


@pytest.fixture(scope="module")
def limited(tmp_path_factory, shared_assets):
    """A server with small limits: 2 streams per client, 3 in total, 3 s idle."""
    srv = GlintServer(tmp_path_factory.mktemp("limited"), workers=1, env={
        "GLINT_MAX_SESSIONS_PER_CLIENT": "2", "GLINT_MAX_SESSIONS": "3", "GLINT_SESSION_IDLE_SECONDS": "3"},
                      shared_parts=True)
    with httpx.Client(base_url=srv.base, timeout=120) as c:
        scene = _upload_scene(c, shared_assets)
        yield srv, c, scene
    srv.stop()


def test_streams_are_bounded_and_expire(limited):
    srv, c, scene = limited
    sessions = [c.post("/v1/sessions", json={"scene_id": scene}).json() for _ in range(3)]

    async def go():
        opened = []
        for s in sessions[:2]:
            ws = await websockets.connect(f"ws://127.0.0.1:{srv.port}{s['stream']}", max_size=None)
            await ws.send(json.dumps({"type": "auth", "token": s["token"]}))
            assert json.loads(await ws.recv())["type"] == "hello"
            opened.append(ws)
        # a third stream from the same client is refused with a clear reason
        ws = await websockets.connect(f"ws://127.0.0.1:{srv.port}{sessions[2]['stream']}")
        await ws.send(json.dumps({"type": "auth", "token": sessions[2]["token"]}))
        ev = json.loads(await ws.recv())
        assert ev["type"] == "error" and ev["code"] == 429, ev
        with pytest.raises(websockets.ConnectionClosed) as e:
            await ws.recv()
        assert e.value.rcvd.code == 4429
        # an idle stream is closed after 3 s, with a message
        t0 = time.monotonic()
        got = None
        while time.monotonic() - t0 < 30:
            x = await asyncio.wait_for(opened[0].recv(), 30)
            if isinstance(x, str) and json.loads(x)["type"] == "error":
                got = json.loads(x)
                break
        assert got and got["code"] == 408 and "without input" in got["message"], got
        assert 2.5 < time.monotonic() - t0 < 20
        for w in opened:
            await w.close()
    asyncio.run(go())
    # the freed slots open again
    h = c.get("/healthz").json()
    assert h["streams"] <= 1, h


def _big_obj() -> bytes:
    rng = np.random.default_rng(0)
    n = 200_000                                    # ~7 MB of OBJ, under the 8 MB cap
    v = rng.random((n, 3))
    f = rng.integers(1, n + 1, size=(n // 2, 3))
    body = "".join(f"v {a:.5f} {b:.5f} {d:.5f}\n" for a, b, d in v) + "".join(f"f {a} {b} {d}\n" for a, b, d in f)
    return body.encode()


def test_uploads_are_read_in_a_child(client):
    """While a child reads a big mesh the API answers other requests: no health check waits for
    the upload. On the shared server (the default 300 s read limit) the read always finishes, so
    the upload is accepted and its triangles counted; the refusal is tested below with a limit
    no read can meet."""
    body = _big_obj()
    lat = []
    done = threading.Event()

    def poll():
        with httpx.Client(base_url=str(client.base_url), timeout=60) as c:
            while not done.is_set():
                t0 = time.perf_counter()
                c.get("/healthz")
                lat.append(time.perf_counter() - t0)
                time.sleep(0.02)
    t = threading.Thread(target=poll)
    t.start()
    t0 = time.perf_counter()
    r = client.post("/v1/assets/meshes", params={"filename": "big.obj"}, content=body)
    took = time.perf_counter() - t0
    done.set()
    t.join()
    assert r.status_code == 201, r.text
    meta = r.json()["meta"]
    rep = meta["repair"]                           # random indices repeat: those faces are dropped
    assert rep["faces_in"] == 100_000 and meta["faces"] == rep["faces_out"] > 99_000, meta
    # the read took `took` seconds; a health check that waited for it would take as long
    assert len(lat) >= 3 and max(lat) < 0.5 * took, \
        f"{len(lat)} health checks during a {took:.2f} s upload, the slowest {max(lat or [0]):.3f} s"


def test_an_upload_read_too_slowly_is_refused(tmp_path_factory):
    """A 50 ms limit: parsing 7 MB of OBJ text takes longer on any machine, so the reader is
    stopped and the upload refused with a reason."""
    srv = GlintServer(tmp_path_factory.mktemp("slowread"), workers=1, env={"GLINT_INSPECT_SECONDS": "0.05"})
    try:
        with httpx.Client(base_url=srv.base, timeout=120) as c:
            r = c.post("/v1/assets/meshes", params={"filename": "big.obj"}, content=_big_obj())
            assert r.status_code == 422 and "within 0.05 s" in r.json()["detail"], r.text
    finally:
        srv.stop()


def test_security_headers_and_no_server_header(server, client):
    def csp(r):
        return {d.split()[0]: d.split()[1:] for d in (x.strip() for x in r.headers["content-security-policy"].split(";")) if d}

    studio = client.get("/")
    assert studio.status_code == 200
    p = csp(studio)
    assert p["frame-ancestors"] == ["'self'"] and studio.headers["x-frame-options"] == "SAMEORIGIN"
    assert p["script-src"] == ["'self'"] and p["style-src"] == ["'self'"]          # no inline script or style
    assert "blob:" in p["img-src"] and f"ws://127.0.0.1:{server['port']}" in p["connect-src"]
    viewer = client.get("/view/some-publication")
    assert csp(viewer)["frame-ancestors"] == ["*"] and "x-frame-options" not in viewer.headers
    for r in (studio, viewer, client.get("/healthz"), client.get("/web/js/studio.js"), client.get("/v1/scenes/nope"),
              client.get("/openapi.json")):
        assert r.headers["x-content-type-options"] == "nosniff", r.url
        assert r.headers["referrer-policy"] == "no-referrer", r.url
        assert "server" not in r.headers, (r.url, r.headers.get("server"))
        assert "content-security-policy" in r.headers, r.url
    assert csp(client.get("/healthz"))["default-src"] == ["'none'"]
