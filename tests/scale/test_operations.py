"""Operations: /healthz and /metrics (Prometheus text format), request ids in
responses and log lines (text and JSON), and a SIGTERM during a precomputation: the server exits
0 and the precomputation is already recorded as failed, with a message, before any restart.

A server of its own (one worker; stopped by the last test)."""
import asyncio
import json
import signal
import sqlite3
import time

import httpx
import pytest
from prometheus_client.parser import text_string_to_metric_families

from helpers import ROOT, GlintServer, connect, next_frame

STROKE = {"points": [[62, 62], [88, 64]], "color": [4.0, 4.0, 4.0], "diameter": 10, "kappa": 0.05}


@pytest.fixture(scope="module")
def ops(tmp_path_factory, shared_assets):
    srv = GlintServer(tmp_path_factory.mktemp("ops"), workers=1, env={"GLINT_LOG_FORMAT": "json"})
    c = httpx.Client(base_url=srv.base, timeout=120)
    mesh = c.post("/v1/assets/meshes", params={"filename": "bunny.ply"},
                  content=(shared_assets / "meshes" / "bunny.ply").read_bytes()).json()
    env = c.post("/v1/assets/envmaps", params={"filename": "sunset.exr"},
                 content=(shared_assets / "env" / "sunset.exr").read_bytes()).json()
    yield {"srv": srv, "c": c, "mesh": mesh["id"], "env": env["id"]}
    c.close()
    srv.stop()


def _scene(c, f, scale=1.0) -> str:
    spec = json.loads((ROOT / "tests" / "scenes" / "bunny.json").read_text())
    spec["environment"]["map"], spec["objects"][0]["mesh"] = f["env"], f["mesh"]
    spec["objects"][0]["transform"] = {"scale": scale}
    return c.post("/v1/scenes", json=spec).json()["id"]


def _wait(c, pre_id, until=("done", "failed"), timeout=900):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        p = c.get(f"/v1/precomputations/{pre_id}").json()
        if p["status"] in until:
            return p
        time.sleep(0.2)
    raise TimeoutError(p)


def _metrics(c) -> dict:
    r = c.get("/metrics")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain"), r.text[:300]
    out = {}
    for fam in text_string_to_metric_families(r.text):
        for s in fam.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return out


def _value(m, name, **labels):
    return sum(v for (n, ls), v in m.items() if n == name and all(dict(ls).get(k) == x for k, x in labels.items()))


def test_request_ids_and_json_logs(ops):
    c, srv = ops["c"], ops["srv"]
    r = c.get("/healthz", headers={"X-Request-ID": "trace-4711"})
    assert r.headers["x-request-id"] == "trace-4711" and r.json()["status"] == "ok"
    r2 = c.get("/v1/scenes/nope", headers={"X-Request-ID": "bad id with spaces"})
    rid = r2.headers["x-request-id"]
    assert r2.status_code == 404 and rid != "bad id with spaces" and len(rid) == 16     # a fresh id instead
    time.sleep(0.3)
    lines = [json.loads(x) for x in srv.log().splitlines() if x.startswith("{")]
    access = [x for x in lines if x["logger"] == "glint.access"]
    assert any(x["request_id"] == "trace-4711" and x["route"] == "/healthz" and x["status"] == 200 for x in access)
    assert any(x["request_id"] == rid and x["status"] == 404 and x["route"] == "/v1/scenes/{scene_id}" for x in access)
    assert all({"time", "level", "logger", "message", "request_id"} <= set(x) for x in lines)


def test_metrics_count_sessions_frames_latencies_and_jobs(ops):
    f, c = ops, ops["c"]
    scene = _scene(c, f)
    assert _wait(c, c.post(f"/v1/scenes/{scene}/precompute").json()["id"])["status"] == "done"
    before = _metrics(c)
    ses = c.post("/v1/sessions", json={"scene_id": scene}).json()

    async def go():
        async with connect(f["srv"].as_dict(), ses["stream"], ses["token"]) as ws:
            await ws.recv()
            await next_frame(ws)
            for s in range(1, 4):
                await ws.send(json.dumps({"seq": s, "type": "view", "eye": [0.1 * s, 0.6, 3.2]}))
                await next_frame(ws, s)
            await ws.send(json.dumps({"seq": 4, "type": "stroke", "stroke": STROKE}))
            await next_frame(ws, 4)
            return _metrics(c)
    during = asyncio.run(go())
    assert _value(during, "glint_sessions_open") == 1
    assert _value(during, "glint_frames_total") - _value(before, "glint_frames_total") >= 5
    assert _value(during, "glint_frame_render_seconds_count") >= 5
    assert _value(during, "glint_input_to_frame_seconds_count", type="stroke") == 1
    assert _value(during, "glint_input_to_frame_seconds_count", type="view") == 3
    assert 0 < _value(during, "glint_input_to_frame_seconds_sum", type="stroke") < 120
    assert _value(during, "glint_jobs_total", type="precompute", outcome="ok") == 1
    assert _value(during, "glint_job_duration_seconds_count", type="precompute", outcome="ok") == 1
    assert _value(during, "glint_workers") == 1 and _value(during, "glint_workers_alive") == 1
    assert ("glint_worker_restarts_total", ()) in during
    assert _value(during, "glint_http_requests_total", route="/v1/sessions", method="POST", status="201") >= 1
    assert _value(during, "glint_info", backend="local", database="sqlite") == 1
    time.sleep(0.5)
    assert _value(_metrics(c), "glint_sessions_open") == 0          # the stream has ended


def test_sigterm_during_a_precomputation_fails_it_with_a_message(ops):
    """The job is failed by the stopping server itself (read from the database before any
    restart), the process exits 0, and the metrics counted it as cancelled."""
    f, c, srv = ops, ops["c"], ops["srv"]
    scene = _scene(c, f, 1.05)                      # another geometry: a precomputation that runs
    pre = c.post(f"/v1/scenes/{scene}/precompute").json()
    p = _wait(c, pre["id"], until=("running",))
    while p["progress"] < 0.02 and p["status"] == "running":
        time.sleep(0.1)
        p = c.get(f"/v1/precomputations/{pre['id']}").json()
    assert p["status"] == "running", p
    assert srv.stop(signal.SIGTERM) == 0
    with sqlite3.connect(srv.data / "glint.db") as db:
        status, message = db.execute("SELECT status, message FROM precomputations WHERE id = ?", (pre["id"],)).fetchone()
    assert status == "failed" and "server stopped" in message, (status, message)
    log = srv.log()
    assert "precomputation(s) failed as cancelled" in log
