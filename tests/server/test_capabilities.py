"""The new capabilities through the service: a lighting capture uploaded as a zip becomes an
environment map that lights a session; a GI scene's session edits materials with the view and
light fixed, and switches back to the cut renderer; a paint scene's session fits lobes to the
paint designer's readings."""
import asyncio
import io
import json
import time
import zipfile

import numpy as np
import pytest

from helpers import connect, next_event, next_frame


def _zip_of(folder) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:
        for p in sorted(folder.iterdir()):
            if p.suffix.lower() in (".jpg", ".json") and p.name != "truth.json":
                z.write(p, p.name)
    return buf.getvalue()


def test_a_capture_becomes_an_environment_that_lights_a_session(server, client, bunny_scene, tmp_path, shared_assets):
    from worker.capture.synth import synthesize
    from worker.envmap import load_envmap

    env = load_envmap(shared_assets / "env" / "apartment.exr")
    synthesize(env, tmp_path / "cap", width=360, height=240, brackets=3, seed=1)
    bad = client.post("/v1/captures", content=b"not a zip", headers={"Content-Type": "application/zip"})
    assert bad.status_code == 202
    r = client.post("/v1/captures", content=_zip_of(tmp_path / "cap"), headers={"Content-Type": "application/zip"})
    assert r.status_code == 202, r.text
    cid = r.json()["id"]
    for _ in range(600):
        c = client.get(f"/v1/captures/{cid}").json()
        if c["status"] in ("done", "failed"):
            break
        time.sleep(0.5)
    assert c["status"] == "done", c
    assert c["stats"]["dynamic_range_stops"] > 5 and "frame_pixels_removed" in c["stats"], c["stats"]
    png = client.get(c["preview"])
    assert png.status_code == 200 and png.content[:4] == b"\x89PNG"
    asset = client.get(f"/v1/assets/{c['asset_id']}").json()
    assert asset["kind"] == "envmap"
    b = client.get(f"/v1/captures/{bad.json()['id']}").json()
    for _ in range(100):
        if b["status"] in ("done", "failed"):
            break
        time.sleep(0.2)
        b = client.get(f"/v1/captures/{bad.json()['id']}").json()
    assert b["status"] == "failed" and "zip" in b["message"], b

    ses = client.post("/v1/sessions", json={"scene_id": bunny_scene}).json()

    async def go():
        async with connect(server, ses["stream"], ses["token"]) as ws:
            await ws.recv()
            _, before = await next_frame(ws)
            await ws.send(json.dumps({"seq": 1, "type": "environment", "asset_id": c["asset_id"]}))
            _, after = await next_frame(ws, 1)
            await ws.send(json.dumps({"seq": 2, "type": "environment", "preset": {"sha256": "0" * 64, "filename": "x.exr"}}))
            ev = await next_event(ws)
            assert ev["type"] == "error" and "asset_id" in ev["message"], ev
            return before, after
    before, after = asyncio.run(go())
    assert np.abs(after - before).mean() > 2, "the captured lighting did not change the frame"
    info = client.get(f"/v1/sessions/{ses['id']}", headers={"X-Session-Token": ses["token"]}).json()
    assert info["state"]["environments"][-1]["sha256"] == asset["sha256"]


def _scene_with(client, bunny_scene, **fields) -> str:
    spec = client.get(f"/v1/scenes/{bunny_scene}").json()["spec"]
    spec.update(fields)
    sid = client.post("/v1/scenes", json=spec).json()["id"]
    pre = client.post(f"/v1/scenes/{sid}/precompute").json()
    for _ in range(1200):
        p = client.get(f"/v1/precomputations/{pre['id']}").json()
        if p["status"] in ("done", "failed"):
            break
        time.sleep(0.5)
    assert p["status"] == "done", p
    return sid


@pytest.mark.slow
def test_a_gi_session_edits_materials_and_goes_back_to_direct_light(server, client, bunny_scene):
    """GI at the bunny scene's 160×120, 2 bounces, 16 spp (small: a service test, not an
    accuracy test — tests/gi holds those)."""
    sid = _scene_with(client, bunny_scene, renderer="gi", gi={"bounces": 2, "spp": 16, "series": [16, 1]})
    ses = client.post("/v1/sessions", json={"scene_id": sid}).json()

    async def go():
        async with connect(server, ses["stream"], ses["token"]) as ws:
            hello = json.loads(await ws.recv())
            assert hello["renderer"] == "gi" and hello["controls"] == ["materials", "strokes"] and "cuts" in hello["renderers"], hello
            _, f0 = await next_frame(ws)
            await ws.send(json.dumps({"seq": 1, "type": "material", "material": {"model": "lambert", "albedo": [0.9, 0.2, 0.1]}}))
            _, f1 = await next_frame(ws, 1)
            assert np.abs(f1 - f0).mean() > 2
            await ws.send(json.dumps({"seq": 2, "type": "view", "eye": [1, 0.6, 3]}))
            ev = await next_event(ws)
            assert ev["type"] == "error" and "fixed camera" in ev["message"], ev
            evs = []
            await ws.send(json.dumps({"seq": 3, "type": "renderer", "kind": "cuts"}))
            await next_frame(ws, 3, evs)
            assert any(e["type"] == "renderer" and "camera" in e["controls"] for e in evs), evs
            await ws.send(json.dumps({"seq": 4, "type": "view", "eye": [1, 0.6, 3]}))
            hdr, _ = await next_frame(ws, 4)
            return hdr
    assert asyncio.run(go())["ack"] == 4


def test_a_paint_session_fits_lobes_to_readings(server, client, bunny_scene):
    sid = _scene_with(client, bunny_scene, renderer="paint")
    ses = client.post("/v1/sessions", json={"scene_id": sid}).json()
    readings = {"gloss": 85.0, "aspecular": {"15": [0.9, 0.2, 0.2], "25": [0.5, 0.1, 0.1], "45": [0.2, 0.05, 0.05],
                                             "75": [0.1, 0.03, 0.03], "110": [0.08, 0.02, 0.02]}}

    async def go():
        async with connect(server, ses["stream"], ses["token"]) as ws:
            assert json.loads(await ws.recv())["renderer"] == "paint"
            _, f0 = await next_frame(ws)
            evs = []
            await ws.send(json.dumps({"seq": 1, "type": "paint", **readings}))
            _, f1 = await next_frame(ws, 1, evs)
            paint = [e for e in evs if e["type"] == "paint"]
            assert paint and paint[0]["material"]["model"] == "lobes" and paint[0]["ms_fit"] > 0, evs
            assert abs(paint[0]["measured"]["aspecular"]["45"][0] - 0.2) < 0.05, paint[0]["measured"]
            assert np.abs(f1 - f0).mean() > 2
    asyncio.run(go())
    info = client.get(f"/v1/sessions/{ses['id']}", headers={"X-Session-Token": ses["token"]}).json()
    assert info["state"]["materials"][0]["model"] == "lobes" and info["state"]["paint"]["bunny"]["gloss"] == 85.0
