"""Streams and public endpoints under abuse, bounded in count and time, all on loopback against
one real server (one worker): concurrent viewer streams against the stream limits, a burst of
public viewer sessions against the rate limit and their expiry, malformed WebSocket frames,
stale and malformed sequence numbers, a camera over the frame budget (and a big allowed frame's
memory), and the material a restored session stores."""
import asyncio
import json
import os
import signal
import sqlite3
import time
from pathlib import Path

import httpx
import pytest
import websockets

from helpers import GlintServer, connect, next_event, next_frame, proc_cpu_s
from test_security import _upload_scene

VIEWER_LIMIT = 100          # viewer sessions a minute per address in this server
VIEWER_SECONDS = 6          # a viewer session unused this long is deleted
MESSAGE_BYTES = 256 * 1024  # stream message size limit in this server
STROKE = {"points": [[62, 62], [88, 64]], "color": [4.0, 4.0, 4.0], "diameter": 10, "kappa": 0.05}


@pytest.fixture(scope="module")
def abuse(tmp_path_factory, shared_assets):
    srv = GlintServer(tmp_path_factory.mktemp("abuse"), workers=1, env={
        "GLINT_VIEWER_SESSIONS_PER_MINUTE": str(VIEWER_LIMIT), "GLINT_VIEWER_SESSION_SECONDS": str(VIEWER_SECONDS),
        "GLINT_JANITOR_SECONDS": "1", "GLINT_MAX_STREAM_MESSAGE_BYTES": str(MESSAGE_BYTES)}, shared_parts=True)
    with httpx.Client(base_url=srv.base, timeout=120) as c:
        scene = _upload_scene(c, shared_assets)
        m = c.post("/v1/materials", json={"name": "grey", "material": {"model": "lambert"}}).json()
        pub = c.post("/v1/publications", json={"name": "p", "scene_id": scene, "live": True, "bundle": {"azimuths": 1, "elevations_deg": [20]},
                                               "variants": [{"material_id": m["id"]}]})
        assert pub.status_code == 201, pub.text
        yield srv, c, scene, pub.json()["id"]
    srv.stop()


def _clean_log(srv) -> None:
    log = srv.log()
    for bad in ("Traceback", "unhandled", "Exception in ASGI"):
        assert bad not in log, log[max(0, log.find(bad) - 2000):log.find(bad) + 2000]


def _viewer_rows(srv) -> int:
    db = sqlite3.connect(f"file:{Path(srv.data) / 'glint.db'}?mode=ro", uri=True)
    try:
        return db.execute("select count(*) from sessions where json_extract(state, '$.readonly')").fetchone()[0]
    finally:
        db.close()


def test_concurrent_viewer_streams_are_bounded_per_client(abuse):
    """80 viewer streams from one address at once: at most max_sessions_per_client (8) get a
    hello, the others are refused with 4429 and a message naming the limit."""
    srv, c, _, pub = abuse
    sessions = [c.post(f"/v1/publications/{pub}/sessions") for _ in range(80)]
    assert all(r.status_code == 201 for r in sessions), [r.text for r in sessions if r.status_code != 201][:1]
    sessions = [r.json() for r in sessions]

    async def one(s):
        ws = await websockets.connect(f"ws://127.0.0.1:{srv.port}{s['stream']}", max_size=None, open_timeout=60)
        await ws.send(json.dumps({"type": "auth", "token": s["token"]}))
        first = json.loads(await asyncio.wait_for(ws.recv(), 60))
        if first["type"] == "hello":
            return ws, first, None
        try:
            await asyncio.wait_for(ws.recv(), 30)
        except websockets.ConnectionClosed as e:
            return ws, first, e.rcvd.code
        return ws, first, "not closed"

    async def go():
        res = await asyncio.gather(*[one(s) for s in sessions])
        opened = [ws for ws, ev, _ in res if ev["type"] == "hello"]
        refused = [(ev, code) for _, ev, code in res if ev["type"] != "hello"]
        for ws, _, _ in res:
            await ws.close()
        return opened, refused

    opened, refused = asyncio.run(go())
    print(f"viewer streams opened of 80 concurrent: {len(opened)}")
    assert 1 <= len(opened) <= 8, f"{len(opened)} of 80 concurrent streams opened; the limit is 8"
    assert len(opened) + len(refused) == 80
    for ev, code in refused:
        assert code in (4429, 4503) and ev["type"] == "error" and ev["code"] in (429, 503), (ev, code)
        assert "limit is 8" in ev["message"] or "limit of" in ev["message"], ev
    # the slots are given back: a new stream opens
    for _ in range(100):
        if c.get("/healthz").json()["streams"] == 0:
            break
        time.sleep(0.1)
    assert c.get("/healthz").json()["streams"] == 0
    _clean_log(srv)


def test_viewer_session_creation_is_rate_limited_and_unused_ones_are_deleted(abuse):
    srv, c, scene, pub = abuse
    editing = c.post("/v1/sessions", json={"scene_id": scene}).json()
    codes, first_429 = [], None
    t0 = time.monotonic()
    for _ in range(1000):
        r = c.post(f"/v1/publications/{pub}/sessions")
        codes.append(r.status_code)
        if r.status_code == 429 and first_429 is None:
            first_429 = r
    took = time.monotonic() - t0
    made = codes.count(201)
    print(f"1000 viewer-session POSTs in {took:.1f} s: {made} made, {codes.count(429)} refused (429); "
          f"viewer rows now {_viewer_rows(srv)}")
    assert set(codes) <= {201, 429}, set(codes)
    # the earlier test made 80 in this minute; the window is a moving one
    assert first_429 is not None and made <= VIEWER_LIMIT, (made, codes[:5])
    assert codes.index(429) == made and codes[made:] == [429] * (1000 - made)
    wait = int(first_429.headers["Retry-After"])
    assert 1 <= wait <= 60, first_429.headers
    detail = first_429.json()["detail"]
    assert f"more than {VIEWER_LIMIT} requests in 60 s" in detail and "viewer_sessions_per_minute" in detail, detail
    # unused viewer sessions are deleted after VIEWER_SECONDS; the editing session stays
    deadline = time.monotonic() + VIEWER_SECONDS + 15
    while _viewer_rows(srv) and time.monotonic() < deadline:
        time.sleep(0.5)
    assert _viewer_rows(srv) == 0, f"{_viewer_rows(srv)} viewer sessions left"
    kept = c.get(f"/v1/sessions/{editing['id']}", headers={"X-Session-Token": editing["token"]})
    assert kept.status_code == 200 and not kept.json()["closed"]
    _clean_log(srv)


async def _closed_with(ws, timeout=30):
    """(events received, close code) once the server closes the stream."""
    events = []
    try:
        while True:
            x = await asyncio.wait_for(ws.recv(), timeout)
            if isinstance(x, str):
                events.append(json.loads(x))
    except websockets.ConnectionClosed as e:
        return events, e.rcvd.code if e.rcvd else None


def test_malformed_frames_get_an_error_or_the_right_close_code(abuse):
    srv, c, scene, _ = abuse
    ses = c.post("/v1/sessions", json={"scene_id": scene}).json()
    get = lambda: c.get(f"/v1/sessions/{ses['id']}", headers={"X-Session-Token": ses["token"]}).json()  # noqa: E731
    deep = "[" * 100_000 + "]" * 100_000                     # 200 KB, under the size limit
    url = f"ws://127.0.0.1:{srv.port}{ses['stream']}"

    async def after_hello(payload, **kw):
        async with connect(srv.as_dict(), ses["stream"], ses["token"]) as ws:
            assert json.loads(await ws.recv())["type"] == "hello"
            await next_frame(ws)
            await ws.send(payload, **kw)
            return await _closed_with(ws)

    async def as_auth(payload):
        async with websockets.connect(url, max_size=None) as ws:
            await ws.send(payload)
            return await _closed_with(ws)

    async def go():
        out = {}
        out["binary"] = await after_hello(b"\x00\x01binary")
        out["too big"] = await after_hello(json.dumps({"seq": 1, "type": "fit", "pad": "x" * (MESSAGE_BYTES + 10)}))
        out["too deep"] = await after_hello(deep)
        out["too deep in a message"] = await after_hello('{"seq": 1, "type": "view", "eye": ' + deep + "}")
        # a text frame that is not UTF-8: the WebSocket layer closes it before the app reads it
        out["not utf-8"] = await after_hello(b'{"seq": 1, "type": "undo", "x": "\xff\xfe"}', text=True)
        out["auth binary"] = await as_auth(b"\x00binary")
        out["auth nested"] = await as_auth('{"type": "auth", "token": ' + deep + "}")
        out["auth not json"] = await as_auth("{auth")
        # not JSON after the hello: an error event, and the stream goes on
        async with connect(srv.as_dict(), ses["stream"], ses["token"]) as ws:
            await ws.recv()
            await next_frame(ws)
            await ws.send("{not json")
            ev = await next_event(ws)
            assert ev["type"] == "error" and "not JSON" in ev["message"], ev
            await ws.send(json.dumps({"seq": 1, "type": "light", "rotation_deg": 30}))
            hdr, _ = await next_frame(ws, 1)
            assert hdr["ack"] == 1
        return out

    out = asyncio.run(go())
    want = {"binary": (1003, "binary frame"), "too big": (1009, "max_stream_message_bytes"),
            "too deep": (4400, "max_stream_message_depth"), "not utf-8": (1007, None), "too deep in a message": (4400, "levels deep"),
            "auth binary": (4403, "binary frame"), "auth nested": (4403, "max_stream_message_depth"),
            "auth not json": (4403, "not JSON")}
    for case, (code, words) in want.items():
        events, got = out[case]
        assert got == code, (case, got, events)
        errors = [e for e in events if e["type"] == "error"]
        assert words is None or (errors and words in errors[-1]["message"]), (case, events)
    # nothing of the refused messages was applied: the one good message is the last seq
    assert get()["state"]["last_seq"] == 1
    _clean_log(srv)


def test_stale_and_string_seqs_are_refused_before_anything_is_stored(abuse):
    srv, c, scene, _ = abuse
    ses = c.post("/v1/sessions", json={"scene_id": scene}).json()
    get = lambda: c.get(f"/v1/sessions/{ses['id']}", headers={"X-Session-Token": ses["token"]}).json()  # noqa: E731

    async def error_for(ws, seq):
        while True:
            x = await asyncio.wait_for(ws.recv(), 20)
            if isinstance(x, str) and json.loads(x)["type"] == "error":
                return json.loads(x)

    async def go():
        async with connect(srv.as_dict(), ses["stream"], ses["token"]) as ws:
            await ws.recv()
            await next_frame(ws)
            await ws.send(json.dumps({"seq": 17, "type": "stroke", "stroke": STROKE}))
            await next_frame(ws, 17)
            # a client that restarted its numbering: refused, with the way on
            await ws.send(json.dumps({"seq": 3, "type": "stroke", "stroke": {**STROKE, "points": [[60, 70], [90, 71]]}}))
            ev = await error_for(ws, 3)
            assert ev["seq"] == 3 and "seq 3 is not above the last one, 17" in ev["message"] \
                and "state.last_seq" in ev["message"], ev
            await ws.send(json.dumps({"seq": 17, "type": "undo"}))
            ev = await error_for(ws, 17)
            assert "seq 17 is not above the last one, 17" in ev["message"], ev
            # a string is not a seq
            await ws.send(json.dumps({"seq": "18", "type": "undo"}))
            ev = await error_for(ws, None)
            assert ev["message"].startswith("seq:") and "integer" in ev["message"], ev
        s = get()
        assert len(s["strokes"]) == 1 and not s["strokes"][0]["undone"], s["strokes"]
        assert s["state"]["last_seq"] == 17
        # a reconnecting client numbers on from the hello's state
        async with connect(srv.as_dict(), ses["stream"], ses["token"]) as ws:
            hello = json.loads(await ws.recv())
            assert hello["state"]["last_seq"] == 17 and hello["strokes"] == 1
            nxt = hello["state"]["last_seq"] + 1
            await ws.send(json.dumps({"seq": nxt, "type": "undo"}))
            hdr, _ = await next_frame(ws, nxt)
            assert hdr["ack"] == nxt

    asyncio.run(go())
    assert get()["strokes"][0]["undone"] is True
    _clean_log(srv)


def _rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def test_a_camera_over_the_frame_budget_is_refused_and_a_big_frame_gives_its_memory_back(abuse):
    srv, c, scene, _ = abuse
    cam = {"eye": [0.0, 0.6, 3.2], "target": [0.0, 0.1, 0.0], "fov_y_deg": 30}
    r = c.post("/v1/sessions", json={"scene_id": scene, "camera": {**cam, "width": 8192, "height": 8192}})
    assert r.status_code == 422, r.text
    d = r.json()["detail"]
    assert "8192×8192" in d and "max_frame_pixels" in d and str(2560 * 1600) in d, d
    # a view message may resize the frames (to the canvas), capped at the budget with its aspect kept
    small = c.post("/v1/sessions", json={"scene_id": scene}).json()
    ses = c.post("/v1/sessions", json={"scene_id": scene, "camera": {**cam, "width": 1920, "height": 1080}}).json()

    async def go():
        # resting memory: the worker with the scene loaded, after a small session closed
        async with connect(srv.as_dict(), small["stream"], small["token"]) as ws:
            await ws.recv()
            await next_frame(ws)
            await ws.send(json.dumps({"seq": 1, "type": "display", "exposure": 0.0}))
            while (await next_frame(ws, 1))[0]["samples"] < 4:       # the same work as below, small
                pass
            pid = c.get(f"/v1/sessions/{small['id']}", headers={"X-Session-Token": small["token"]}).json()["worker_pid"]
        await asyncio.sleep(1.0)
        before = _rss_mib(pid)
        async with connect(srv.as_dict(), ses["stream"], ses["token"]) as ws:
            await ws.recv()
            assert c.get(f"/v1/sessions/{ses['id']}", headers={"X-Session-Token": ses["token"]}).json()["worker_pid"] == pid
            await ws.send(json.dumps({"seq": 1, "type": "view", "width": 8192, "height": 8192}))
            await ws.send(json.dumps({"seq": 2, "type": "display", "exposure": 0.0}))   # a step, then its still
            deadline = time.monotonic() + 60
            still = None
            errors = []
            while time.monotonic() < deadline:       # the anti-aliased still, at the budget's size
                hdr, _ = await next_frame(ws, events=errors, timeout=60)
                if hdr["samples"] >= 4:
                    still = hdr
                    break
            assert still, errors
            w, h = still["width"], still["height"]
            assert w * h <= 2560 * 1600 and abs(w - h) <= 1 and w * h > 0.98 * 2560 * 1600, \
                f"an 8192×8192 view should be capped to the 2560×1600-pixel budget, square: got {w}×{h}"
            during = _rss_mib(pid)
            # a stroke, then a new view: the worker prepares the full fit views in the background
            await ws.send(json.dumps({"seq": 3, "type": "stroke", "stroke": {**STROKE, "points": [[900, 500], [1000, 520]]}}))
            await next_frame(ws, 3, timeout=120)
            await ws.send(json.dumps({"seq": 4, "type": "view", "eye": [0.3, 0.6, 3.1]}))
            await next_frame(ws, 4, timeout=120)
            return pid, before, during

    pid, before, during = asyncio.run(go())
    cpu0, t0 = proc_cpu_s([pid]), time.monotonic()
    after = during
    for _ in range(80):       # the session's thread ends, its build under way ends, it releases
        time.sleep(0.25)
        after = _rss_mib(pid)
        if after - before < 0.5 * (during - before):
            break
    busy = (proc_cpu_s([pid]) - cpu0) / (time.monotonic() - t0)
    print(f"worker RSS: {before:.0f} MiB resting (the scene loaded) before a 1920×1080 session, {during:.0f} MiB with its still "
          f"frame, {after:.0f} MiB {time.monotonic() - t0:.1f} s after it closed (worker CPU meanwhile {busy:.2f} cores)")
    assert during > before + 300, (before, during)           # the frame is big enough to measure
    # back near rest: the big session's background builds are not left running on (they held
    # the runtime, its renderer and their views: 1.3 GB over rest 10 s after close, before)
    assert after - before < 0.5 * (during - before), \
        f"the worker kept {after - before:.0f} of the {during - before:.0f} MiB the big session took"
    _clean_log(srv)


def test_a_restored_session_stores_the_refit_material(abuse):
    """The worker dies after the stroke is stored but before its fit reached the server: the
    new worker's refit of the stored strokes is what the session row and the next hello carry."""
    srv, c, scene, _ = abuse
    ses = c.post("/v1/sessions", json={"scene_id": scene}).json()
    get = lambda: c.get(f"/v1/sessions/{ses['id']}", headers={"X-Session-Token": ses["token"]}).json()  # noqa: E731

    async def go():
        async with connect(srv.as_dict(), ses["stream"], ses["token"]) as ws:
            hello = json.loads(await ws.recv())
            assert hello["state"]["materials"][0]["model"] == "lambert"
            await next_frame(ws)
            pid = get()["worker_pid"]
            os.kill(pid, signal.SIGSTOP)          # the stroke reaches the database, not the fit
            try:
                await ws.send(json.dumps({"seq": 1, "type": "stroke", "stroke": STROKE}))
                for _ in range(100):
                    if len(get()["strokes"]) == 1:
                        break
                    await asyncio.sleep(0.1)
                assert len(get()["strokes"]) == 1
            finally:
                os.kill(pid, signal.SIGKILL)
            ev = []
            await next_frame(ws, 1, ev, timeout=120)          # from the new worker
            assert any(e["type"] == "note" and "restored" in e["message"] for e in ev), ev
            fits = [e for e in ev if e["type"] == "fit"]
            assert fits and fits[-1]["material"]["model"] == "srbf", [e["type"] for e in ev]
            return fits[-1]["material"]

    fitted = asyncio.run(go())
    s = get()
    assert s["worker_pid"] is None and s["state"]["materials"][0] == fitted

    async def reconnect():
        async with connect(srv.as_dict(), ses["stream"], ses["token"]) as ws:
            hello = json.loads(await ws.recv())
            assert hello["state"]["materials"][0] == fitted and hello["strokes"] == 1

    asyncio.run(reconnect())
