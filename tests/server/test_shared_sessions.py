"""Sessions shared by several streams (a reload, a second tab) and the versions they save: both
streams get every frame and each other's changes as peer events, their messages are numbered in
the session (neither refuses the other's), the session reopens after both have gone, and a save
stores a version with its name and a thumbnail of the frame."""
import asyncio
import io
import json
import time

import pytest
from PIL import Image

from helpers import connect, next_frame
from server.sessions_store import SessionStore, StreamRefused, THUMB_MAX_BYTES


async def _until(ws, kind, timeout=60):
    """The next event of type ``kind`` (frames and other events are skipped)."""
    while True:
        x = await asyncio.wait_for(ws.recv(), timeout)
        if isinstance(x, str) and json.loads(x)["type"] == kind:
            return json.loads(x)


def test_two_streams_share_a_session_and_it_reopens(server, client, bunny_scene):
    ses = client.post("/v1/sessions", json={"scene_id": bunny_scene}).json()

    async def go():
        async with connect(server, ses["stream"], ses["token"]) as a:
            ha = json.loads(await a.recv())
            assert ha["type"] == "hello" and ha["streams"] == 1
            await next_frame(a)
            async with connect(server, ses["stream"], ses["token"]) as b:
                hb = json.loads(await b.recv())
                assert hb["type"] == "hello" and hb["streams"] == 2, hb
                base = hb["state"]["last_seq"]
                await next_frame(b)                      # the newest frame, sent as it joins
                # A moves the camera: B gets the change and its frame
                await a.send(json.dumps({"seq": base + 1, "type": "view", "eye": [0.3, 0.6, 3.1]}))
                peer = await _until(b, "peer")
                assert peer["message"]["type"] == "view" and peer["message"]["eye"] == [0.3, 0.6, 3.1]
                assert peer["message"]["seq"] == base + 1 and peer["streams"] == 2
                await next_frame(a, base + 1)
                # B numbers on from its own hello, so it uses A's seq again: not refused, given
                # the session's next number; B's frame acknowledges it in B's numbering
                await b.send(json.dumps({"seq": base + 1, "type": "light", "rotation_deg": 40}))
                peer = await _until(a, "peer")
                assert peer["message"]["type"] == "light" and peer["message"]["seq"] == base + 2, peer
                events = []
                hdr, _ = await next_frame(b, base + 1, events=events)
                assert hdr["ack"] == base + 1
                assert not [e for e in events if e["type"] == "error"], events
                # a stream's own seqs must still increase
                await b.send(json.dumps({"seq": base + 1, "type": "light", "rotation_deg": 50}))
                err = await _until(b, "error")
                assert "not above the last one" in err["message"] and err["seq"] == base + 1
            # B has gone; A goes on with the same worker session
            await a.send(json.dumps({"seq": base + 2, "type": "display", "exposure": 1.0}))
            hdr, _ = await next_frame(a, base + 2)
        return base

    base = asyncio.run(go())
    # both streams have ended: the session is kept, and reopens with both tabs' changes
    got = client.get(f"/v1/sessions/{ses['id']}", headers={"X-Session-Token": ses["token"]}).json()
    assert not got["closed"]
    st = got["state"]
    assert st["camera"]["eye"] == [0.3, 0.6, 3.1] and st["rotation_deg"] == 40.0 and st["exposure"] == 1.0, st
    assert st["last_seq"] == base + 3

    async def reopen():
        async with connect(server, ses["stream"], ses["token"]) as c:
            h = json.loads(await c.recv())
            await next_frame(c)
            return h
    h = asyncio.run(reopen())
    assert h["state"]["rotation_deg"] == 40.0 and h["state"]["last_seq"] == base + 3


def test_a_saved_version_has_its_name_and_a_thumbnail(server, client, bunny_scene):
    ses = client.post("/v1/sessions", json={"scene_id": bunny_scene}).json()

    async def go():
        async with connect(server, ses["stream"], ses["token"]) as ws:
            seq = json.loads(await ws.recv())["state"]["last_seq"]
            await next_frame(ws)
            await ws.send(json.dumps({"seq": seq + 1, "type": "save", "name": "sage"}))
            first = await _until(ws, "saved")
            await ws.send(json.dumps({"seq": seq + 2, "type": "save", "name": "darker",
                                      "material_id": first["material_id"]}))
            return first, await _until(ws, "saved")

    first, second = asyncio.run(go())
    assert second["material_id"] == first["material_id"] and second["version"] == 2 and second["name"] == "sage"
    mid = first["material_id"]
    vs = client.get(f"/v1/materials/{mid}/versions").json()
    assert [v["name"] for v in vs] == ["sage", "darker"]
    d = client.get(f"/v1/materials/{mid}").json()
    assert d["name"] == "sage" and d["version_name"] == "darker" and d["thumbnail"] == vs[1]["thumbnail"]
    r = client.get(vs[0]["thumbnail"])
    assert r.status_code == 200 and r.headers["content-type"] == "image/jpeg"
    assert len(r.content) <= THUMB_MAX_BYTES
    im = Image.open(io.BytesIO(r.content))
    assert im.format == "JPEG" and 0 < im.width <= 192 and 0 < im.height <= 144, im.size
    assert abs(im.width / im.height - 640 / 480) < 0.05            # the frame's aspect, shrunk
    assert float(Image.Image.getextrema(im.convert("L"))[1]) > 30   # a picture, not a blank
    # a version saved over REST has none: null in the list, 404 from the endpoint
    rest = client.put(f"/v1/materials/{mid}", json={"material": {"model": "lambert", "albedo": [0.2, 0.3, 0.2]}})
    assert rest.status_code == 200 and rest.json()["thumbnail"] is None
    assert client.get(f"/v1/materials/{mid}/versions/3").json()["thumbnail"] is None
    assert client.get(f"/v1/materials/{mid}/versions/3/thumbnail").status_code == 404
    assert client.get(f"/v1/materials/{mid}/versions/9/thumbnail").status_code == 404


def test_a_save_sent_as_the_tab_closes_is_stored(server, client, bunny_scene):
    """A client that saves and leaves at once (a tab's autosave as it closes) does not wait for
    the answer: the worker session outlives the stream until the save is stored."""
    ses = client.post("/v1/sessions", json={"scene_id": bunny_scene}).json()

    async def go():
        async with connect(server, ses["stream"], ses["token"]) as ws:
            seq = json.loads(await ws.recv())["state"]["last_seq"]
            await next_frame(ws)
            await ws.send(json.dumps({"seq": seq + 1, "type": "save", "name": "closing"}))
    asyncio.run(go())
    for _ in range(100):
        found = [d for d in client.get("/v1/materials").json() if d["name"] == "closing"]
        if found:
            break
        time.sleep(0.1)
    assert found and found[0]["version"] == 1, "the save sent as the stream closed was not stored"
    got = client.get(f"/v1/sessions/{ses['id']}", headers={"X-Session-Token": ses["token"]}).json()
    assert got["state"]["pending_saves"] == []


def test_the_store_counts_every_stream_against_the_limits(tmp_path):
    """attach/detach: the first stream of a session opens it, the last one's end closes it, and
    every stream (also a second one of a session) counts against the limits."""
    store = SessionStore(db=None)
    a1, a2, b1, c1 = object(), object(), object(), object()
    ss, first = store.attach("s1", a1, "addr:1", max_total=3, max_per_client=2)
    assert first and store.is_streamed("s1")
    ss2, first = store.attach("s1", a2, "addr:1", max_total=3, max_per_client=2)
    assert ss2 is ss and not first and store.open_streams() == 2
    with pytest.raises(StreamRefused) as e:                      # a third stream of addr:1
        store.attach("s2", object(), "addr:1", max_total=3, max_per_client=2)
    assert e.value.code == 4429 and e.value.http == 429
    store.attach("s2", b1, "addr:2", max_total=3, max_per_client=2)
    with pytest.raises(StreamRefused) as e:                      # a fourth in all
        store.attach("s3", c1, "addr:3", max_total=3, max_per_client=2)
    assert e.value.code == 4503 and e.value.http == 503
    assert not store.detach("s1", a1)                            # a2 still streams s1
    assert store.is_streamed("s1") and store.thumbnail("s1") is None
    assert store.detach("s1", a2) and not store.is_streamed("s1")
    assert not store.detach("s1", a2)                            # twice is nothing
    _, first = store.attach("s1", c1, "addr:3", max_total=3, max_per_client=2)
    assert first                                                 # reopened afresh
