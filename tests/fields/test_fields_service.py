"""Moving an object through the service: a scene with a movable box uploaded and precomputed by a
real server (the ``server`` fixture), rendered over REST with transforms and moved in a session
with ``move`` messages; frames compared with the cut renderer run here on the same scene."""
import asyncio
import json

import numpy as np
import pytest
from helpers import connect, next_frame, open_renderer
from PIL import Image

from worker.core.tonemap import tonemap
from worker.envmap import _read_exr
from worker.renderers import FrameRequest, Lighting
from worker.scene import Transform

MOVED = {"rotate_deg": [0, 35, 0], "translate": [25.0, 15.0, -15.0]}


@pytest.fixture(scope="module")
def local(crate):
    """The same scene's cut renderer in this process (parts from tests/.cache)."""
    return open_renderer(crate.load())


def local_frame(r, transform=None, lod="full", camera=None):
    sc = r.scene
    return r.render(FrameRequest(camera=camera or sc.spec.camera, materials=sc.materials, lod=lod,
                                 lighting=Lighting(sc.spec.environment.rotation_deg, 1.0),
                                 transforms={"box": transform} if transform else None))


def test_rest_renders_take_transforms(client, crate_scene, local, tmp_path):
    def exr(body):
        r = client.post("/v1/renders", json={"scene_id": crate_scene, "format": "exr", **body})
        assert r.status_code == 200, r.text
        (tmp_path / "r.exr").write_bytes(r.content)
        return _read_exr(tmp_path / "r.exr")

    here = local_frame(local).radiance
    there = local_frame(local, Transform(**MOVED)).radiance
    a = exr({})
    b = exr({"transforms": {"box": MOVED}})
    assert np.abs(a - here).max() < 1e-3 * here.max() and np.abs(b - there).max() < 1e-3 * there.max()
    changed = np.abs(b - a).mean(-1) > 0.05 * a.mean()
    assert 0.02 < changed.mean() < 0.5, changed.mean()                # the box and its shadow, not the rest
    bad = client.post("/v1/renders", json={"scene_id": crate_scene, "transforms": {"floor": MOVED}})
    assert bad.status_code == 422 and "not movable: floor" in bad.text
    bad = client.post("/v1/renders", json={"scene_id": crate_scene, "transforms": {"nosuch": MOVED}})
    assert bad.status_code == 422 and "nosuch" in bad.text


def test_a_move_message_moves_the_object_in_the_session(server, client, crate_scene, local, artifacts):
    ses = client.post("/v1/sessions", json={"scene_id": crate_scene}).json()
    assert ses["state"]["movable"] == ["box"]
    cam = local.scene.spec.camera

    def expected(transform, lod="full"):
        out = local_frame(local, transform, lod)
        return tonemap(out.radiance, 0.0, "neutral").astype(np.float64)

    async def go():
        async with connect(server, ses["stream"], ses["token"]) as ws:
            hello = json.loads(await ws.recv())
            assert "move" in hello["controls"], hello
            _, img0 = await next_frame(ws)
            ev = []
            await ws.send(json.dumps({"seq": 1, "type": "move", "object": "box", "transform": MOVED, "drag": True}))
            hdr1, img1 = await next_frame(ws, 1, ev)
            # a drag frame is at the drag level of detail unless recent full frames fit the
            # session's frame budget (its level of detail): the header says which
            half = (hdr1["width"], hdr1["height"]) == (cam.width // 2, cam.height // 2)
            assert hdr1["lod"] == half and (half or (hdr1["width"], hdr1["height"]) == (cam.width, cam.height)), hdr1
            await ws.send(json.dumps({"seq": 2, "type": "move", "object": "box", "transform": MOVED}))
            hdr2, img2 = await next_frame(ws, 2, ev)
            assert not hdr2["lod"] and (hdr2["width"], hdr2["height"]) == (cam.width, cam.height)
            # refused by the state (the server persists nothing of them): errors, the session lives on
            await ws.send(json.dumps({"seq": 3, "type": "move", "object": "floor", "transform": MOVED}))
            await ws.send(json.dumps({"seq": 4, "type": "move", "object": "box",
                                      "transform": {**MOVED, "scale": [1, 2, 1]}}))
            await ws.send(json.dumps({"seq": 5, "type": "light", "rotation_deg": 141.0}))
            await next_frame(ws, 5, ev)
            errors = [e["message"] for e in ev if e["type"] == "error"]
            return img0, hdr1, img1, img2, errors

    img0, hdr1, img1, img2, errors = asyncio.run(go())
    # JPEG against the frames rendered here (8-bit, quality 90/60): the same pictures
    assert np.abs(img0 - expected(None)).mean() < 2.0
    assert np.abs(img2 - expected(Transform(**MOVED))).mean() < 2.0
    assert np.abs(img1 - expected(Transform(**MOVED), "drag" if hdr1["lod"] else "full")).mean() < 3.0
    moved = np.abs(img2 - img0).mean(-1) > 12
    assert 0.02 < moved.mean() < 0.5, moved.mean()
    Image.fromarray(np.concatenate([img0, img2], 1).astype(np.uint8)).save(artifacts / "service-move.png")
    assert any("not movable" in m for m in errors) and any("non-uniform scale" in m for m in errors), errors
    st = client.get(f"/v1/sessions/{ses['id']}", headers={"X-Session-Token": ses["token"]}).json()["state"]
    assert st["transforms"]["box"]["translate"] == MOVED["translate"]          # persisted by the server
