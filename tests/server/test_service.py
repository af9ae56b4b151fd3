"""The service end to end, over real HTTP and WebSocket against the server fixture."""
import asyncio
import io
import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import websockets
from PIL import Image

from helpers import connect, next_event, next_frame

ROOT = Path(__file__).resolve().parents[2]


def test_session_stroke_save_and_crash_recovery(server, client, bunny_scene, artifacts):
    r = client.post("/v1/sessions", json={"scene_id": bunny_scene})
    assert r.status_code == 201, r.text
    ses = r.json()
    sid, token = ses["id"], ses["token"]
    stroke = {"points": [[62, 62], [88, 64]], "color": [4.0, 4.0, 4.0], "diameter": 10, "kappa": 0.05}

    async def part1():
        async with connect(server, ses["stream"], token) as ws:
            hello = json.loads(await ws.recv())
            assert hello["type"] == "hello"
            hdr0, img0 = await next_frame(ws)
            assert (hdr0["width"], hdr0["height"], hdr0["format"]) == (160, 120, "jpeg")
            assert img0.std() > 5                                   # not blank
            ev = []
            await ws.send(json.dumps({"seq": 1, "type": "stroke", "stroke": stroke}))
            hdr1, img1 = await next_frame(ws, 1, ev)
            assert hdr1["ack"] >= 1 and hdr1["frame"] > hdr0["frame"]
            fit = [e for e in ev if e["type"] == "fit"]
            assert fit and fit[0]["material"]["model"] == "srbf"
            # the fit's curve follows its frame (off the path from stroke to frame)
            while not any(e["type"] == "curve" for e in ev):
                x = await asyncio.wait_for(ws.recv(), 30)
                if not isinstance(x, bytes):
                    ev.append(json.loads(x))
            curve = [e for e in ev if e["type"] == "curve"][0]
            assert curve["object"] == fit[0]["object"] and len(curve["curve"]["theta_deg"]) > 10
            # pixels changed where painted, far more than elsewhere
            diff = np.abs(img1 - img0).mean(axis=2)
            yy, xx = np.mgrid[0:120, 0:160]
            near = (np.abs(yy - 63) <= 4) & (xx >= 62) & (xx <= 88)
            assert diff[near].mean() > 3 * max(diff[~near].mean(), 0.5), (diff[near].mean(), diff[~near].mean())
            Image.fromarray(np.concatenate([img0, img1], 1).astype(np.uint8)).save(artifacts / "service-stroke.png")
            # save the design: a material version
            ev = []
            await ws.send(json.dumps({"seq": 2, "type": "save", "name": "painted bunny"}))
            await next_frame(ws, 2, ev)
            saved = [e for e in ev if e["type"] == "saved"]
            assert saved and saved[0]["version"] == 1
            return saved[0]["material_id"]

    mid = asyncio.run(part1())
    m = client.get(f"/v1/materials/{mid}").json()
    assert m["material"]["model"] == "srbf" and m["name"] == "painted bunny"

    async def part2():
        async with connect(server, ses["stream"], token) as ws:
            await ws.recv()                                          # hello
            hdr, _ = await next_frame(ws)
            while not hdr["settled"]:
                # the still that follows a first frame, taken before the kill: still in flight
                # then, it would be read as the new worker's frame (without the restore's note)
                hdr, _ = await next_frame(ws)
            info = client.get(f"/v1/sessions/{sid}", headers={"X-Session-Token": token}).json()
            pid = info["worker_pid"]
            assert pid and len(info["strokes"]) == 1
            os.kill(pid, signal.SIGKILL)                             # the worker holding the session dies
            ev = []
            hdr, img = await next_frame(ws, 2, ev, timeout=120)       # restored: a frame from the new worker
            assert any(e["type"] == "note" and "restored" in e["message"] for e in ev), ev
            after = client.get(f"/v1/sessions/{sid}", headers={"X-Session-Token": token}).json()
            assert after["worker_pid"] != pid
            assert len(after["strokes"]) == 1 and after["strokes"][0]["stroke"]["points"] == stroke["points"]
            assert after["state"]["materials"][0]["model"] == "srbf"
            # and the session goes on
            await ws.send(json.dumps({"seq": 3, "type": "undo"}))
            hdr3, _ = await next_frame(ws, 3)
            assert hdr3["ack"] == 3

    asyncio.run(part2())
    health = client.get("/healthz").json()
    assert health["worker_restarts"] >= 1 and health["workers_alive"] == 2
    s = client.get(f"/v1/sessions/{sid}", headers={"X-Session-Token": token}).json()
    assert s["strokes"][0]["undone"] is True


def test_region_steps_survive_a_worker_restart(server, client, bunny_scene):
    """Undo and redo cover region steps after the session is rebuilt on a new worker: the server
    keeps each step (the material before and after) as rows, and the undone ones as the redo
    stack, as it keeps strokes."""
    ses = client.post("/v1/sessions", json={"scene_id": bunny_scene}).json()
    sid, token = ses["id"], ses["token"]
    stroke = {"points": [[62, 62], [88, 64]], "mode": "scale", "scale": 0.3, "diameter": 10, "kappa": 0.05}

    def regions(ev):
        fits = [e for e in ev if e["type"] == "fit"]
        assert fits, ev
        return [r["name"] for r in fits[-1]["material"].get("regions", [])]

    async def go():
        async with connect(server, ses["stream"], token) as ws:
            await ws.recv()                                          # hello
            await next_frame(ws)
            for seq, msg in enumerate([{"type": "region", "action": "paint", "name": "ear"},
                                       {"type": "stroke", "stroke": stroke}], 1):
                await ws.send(json.dumps({"seq": seq, **msg}))
                await next_frame(ws, seq)
            ev = []
            await ws.send(json.dumps({"seq": 3, "type": "region", "action": "rename", "name": "ear",
                                      "new_name": "left ear"}))
            await next_frame(ws, 3, ev)
            assert regions(ev) == ["left ear"]
            ev = []
            await ws.send(json.dumps({"seq": 4, "type": "undo"}))    # the rename (no stroke since)
            await next_frame(ws, 4, ev)
            assert regions(ev) == ["ear"]
            pid = client.get(f"/v1/sessions/{sid}", headers={"X-Session-Token": token}).json()["worker_pid"]
            os.kill(pid, signal.SIGKILL)
            ev = []
            await next_frame(ws, 4, ev, timeout=120)                 # restored on a new worker
            assert any(e["type"] == "note" and "restored" in e["message"] for e in ev), ev
            ev = []
            await ws.send(json.dumps({"seq": 5, "type": "redo"}))
            await next_frame(ws, 5, ev)
            assert regions(ev) == ["left ear"], ev
            ev = []
            await ws.send(json.dumps({"seq": 6, "type": "undo"}))
            await next_frame(ws, 6, ev)
            assert regions(ev) == ["ear"], ev

    asyncio.run(go())
    got = client.get(f"/v1/sessions/{sid}", headers={"X-Session-Token": token}).json()
    assert [r["name"] for r in got["state"]["materials"][0]["regions"]] == ["ear"]
    (step,) = got["region_steps"]                  # REST clients see the step and that it is undone
    assert step["seq"] == 3 and step["undone"] and not step["dropped"] and step["object"] == "bunny"
    assert (step["region_before"], step["region_after"]) == ("ear", "left ear")


def test_a_short_region_stroke_is_refined_in_parts_over_the_stream(server, client, bunny_scene):
    """Over the WebSocket: a white highlight painted as a region comes back fitted in one part
    (its stats say a fit in parts will follow); after its frame the worker fits it in parts in
    the background and, unprompted, sends that fit and its frame; the server's copy of the
    session state takes it."""
    ses = client.post("/v1/sessions", json={"scene_id": bunny_scene}).json()
    sid, token = ses["id"], ses["token"]
    stroke = {"points": [[62, 62], [88, 64]], "color": [4.0, 4.0, 4.0], "diameter": 10, "kappa": 0.05}

    async def go():
        async with connect(server, ses["stream"], token) as ws:
            await ws.recv()                                          # hello
            await next_frame(ws)
            await ws.send(json.dumps({"seq": 1, "type": "region", "action": "paint", "name": "hl"}))
            await next_frame(ws, 1)
            ev = []
            await ws.send(json.dumps({"seq": 2, "type": "stroke", "stroke": stroke}))
            await next_frame(ws, 2, ev)
            first = [e for e in ev if e["type"] == "fit"][-1]["stats"]
            assert first["parts"] == 1 and first["parts_later"], first
            # no message from the client: the fit in parts and its frame arrive by themselves
            # (after the stroke's fit view is completed and refitted in one part)
            got = []
            while not any(e.get("stats", {}).get("refined_in_parts") or e["type"] == "note" for e in got):
                await next_frame(ws, 2, got, timeout=120)
            refined = [e for e in got if e.get("stats", {}).get("refined_in_parts")]
            assert refined, got
            return [f["stats"] for f in got if f["type"] == "fit"], refined[-1]

    fits, refined = asyncio.run(go())
    one = ([f for f in fits if not f.get("refined_in_parts")] or [None])[-1]
    st = refined["stats"]
    print(f"stream: one part {one and one['achieved']}, {st['parts']} parts {st['achieved']:.3f}")
    assert st["parts"] >= 2 and [r["name"] for r in refined["material"]["regions"]] == \
        [f"hl/{i + 1}" for i in range(st["parts"])]
    got = client.get(f"/v1/sessions/{sid}", headers={"X-Session-Token": token}).json()
    assert [r["name"] for r in got["state"]["materials"][0]["regions"]] == \
        [f"hl/{i + 1}" for i in range(st["parts"])]


def test_stream_errors_keep_the_session_alive(server, client, bunny_scene):
    ses = client.post("/v1/sessions", json={"scene_id": bunny_scene}).json()

    async def go():
        async with connect(server, ses["stream"], ses["token"]) as ws:
            await ws.recv()
            await next_frame(ws)
            for bad in ("not json", json.dumps([1, 2]), json.dumps({"seq": 5, "type": "view", "eye": "up"}),
                        json.dumps({"seq": 6, "type": "teleport"}), json.dumps({"seq": 7, "type": "view", "eye": [0, 0.05, 0]})):
                await ws.send(bad)
                ev = await next_event(ws)
                assert ev["type"] == "error" and ev["message"], ev
            # eye == target is refused at the edge, not persisted: the session still renders
            await ws.send(json.dumps({"seq": 8, "type": "light", "rotation_deg": 90}))
            hdr, _ = await next_frame(ws, 8)
            assert hdr["ack"] == 8
        # unknown session and wrong token
        for path, token, code in (("/v1/sessions/nosuch/stream", "x", 4404), (ses["stream"], "wrong", 4403)):
            async with connect(server, path, token) as ws:
                ev = json.loads(await ws.recv())
                assert ev["type"] == "error" and ev["code"] in (403, 404)
                with pytest.raises(websockets.ConnectionClosed) as e:
                    await ws.recv()
                assert e.value.rcvd.code == code

    asyncio.run(go())
    assert client.get(f"/v1/sessions/{ses['id']}", headers={"X-Session-Token": "wrong"}).status_code == 403
    assert client.get("/v1/sessions/nosuch", headers={"X-Session-Token": "x"}).status_code == 404


def test_rest_render_fit_and_material_versions(client, bunny_scene):
    png = client.post("/v1/renders", json={"scene_id": bunny_scene})
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    img = np.asarray(Image.open(io.BytesIO(png.content)))
    assert img.shape == (120, 160, 3) and img.std() > 5
    exr = client.post("/v1/renders", json={"scene_id": bunny_scene, "format": "exr",
                                           "materials": {"bunny": {"model": "ggx", "alpha": 0.3, "specular": [0.5, 0.5, 0.5]}}})
    assert exr.status_code == 200 and exr.content[:4] == b"\x76\x2f\x31\x01"       # OpenEXR magic
    # fit to strokes, saved as a design
    fit = client.post("/v1/fits", json={"scene_id": bunny_scene, "object": "bunny", "fit_scale": 1.0, "save_as": "glossy",
                                        "strokes": [{"points": [[60, 60], [90, 62]], "color": [3, 3, 3], "diameter": 8}]})
    assert fit.status_code == 200, fit.text
    f = fit.json()
    assert f["material"]["model"] == "srbf" and f["stats"]["painted"] > 0 and f["version"] == 1
    assert f["stats"]["energy_max"] <= f["stats"]["energy_bound"] + 1e-7
    # fit to an uploaded target image (a linear EXR render)
    tgt = client.post("/v1/assets/images", params={"filename": "target.exr"}, content=exr.content)
    assert tgt.status_code == 201, tgt.text
    fit2 = client.post("/v1/fits", json={"scene_id": bunny_scene, "object": "bunny", "target_asset": tgt.json()["id"],
                                         "albedo": [0.0, 0.0, 0.0], "fit_scale": 1.0})
    assert fit2.status_code == 200, fit2.text
    assert fit2.json()["stats"]["residual_rel"] < 0.1
    # versions: every save is new, nothing overwritten, delete archives
    mid = f["material_id"]
    v2 = client.put(f"/v1/materials/{mid}", json={"material": {"model": "lambert", "albedo": [0.2, 0.3, 0.4]}, "note": "flat"})
    assert v2.status_code == 200 and v2.json()["version"] == 2
    vs = client.get(f"/v1/materials/{mid}/versions").json()
    assert [v["version"] for v in vs] == [1, 2] and vs[0]["material"]["model"] == "srbf"
    assert client.get(f"/v1/materials/{mid}/versions/1").json()["material"] == f["material"]
    assert client.delete(f"/v1/materials/{mid}").json()["archived"] is True
    assert client.get(f"/v1/materials/{mid}/versions/2").status_code == 200
    assert client.put(f"/v1/materials/{mid}", json={"material": {"model": "lambert"}}).status_code == 409
    assert client.get("/v1/materials/nosuch").status_code == 404


def _raw_post(port, path, headers: dict, body: bytes):
    """Send a request by hand (for truncated bodies) and return the status line or ''."""
    s = socket.create_connection(("127.0.0.1", port), timeout=10)
    head = f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n" + "".join(f"{k}: {v}\r\n" for k, v in headers.items()) + "\r\n"
    s.sendall(head.encode() + body)
    s.shutdown(socket.SHUT_WR)
    try:
        return s.recv(200).decode(errors="replace").split("\r\n")[0]
    except OSError:
        return ""
    finally:
        s.close()


def test_bad_input_gets_clear_4xx(server, client, shared_assets, tmp_path):
    def post(kind, name, data):
        return client.post(f"/v1/assets/{kind}", params={"filename": name}, content=data)

    r = post("meshes", "big.obj", b"v 0 0 0\n" * (1_200_000))                      # 9.6 MB > 8 MB cap
    assert r.status_code == 413 and "limit" in r.json()["detail"]
    r = post("meshes", "cat.obj", (shared_assets / "env" / "sunset.exr").read_bytes())   # not a mesh
    assert r.status_code == 422 and r.json()["detail"]
    r = post("meshes", "notes.txt", b"hello")
    assert r.status_code == 415
    exr = (shared_assets / "env" / "sunset.exr").read_bytes()
    r = post("envmaps", "half.exr", exr[: len(exr) // 2])                             # truncated file
    assert r.status_code == 422, r.text
    # a NaN-filled EXR
    from worker.envmap import save_exr
    nan = np.full((16, 32, 3), np.nan, np.float32)
    try:
        save_exr(tmp_path / "nan.exr", nan)
        data = (tmp_path / "nan.exr").read_bytes()
    except Exception:
        import OpenEXR
        OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                     {"RGB": nan}).write(str(tmp_path / "nan.exr"))
        data = (tmp_path / "nan.exr").read_bytes()
    r = post("envmaps", "nan.exr", data)
    assert r.status_code == 422 and "NaN" in r.json()["detail"], r.text
    # a body cut off before its declared length: the server answers or drops, and stays up
    status = _raw_post(server["port"], "/v1/assets/meshes?filename=x.ply",
                       {"Content-Length": "500000", "Content-Type": "application/octet-stream"}, b"ply\n" * 100)
    assert status == "" or " 400 " in status
    # JSON with wrong types, unknown references
    assert client.post("/v1/scenes", json={"version": 1, "camera": {"eye": "up"}}).status_code == 422
    assert client.post("/v1/renders", json={"scene_id": 5}).status_code == 422
    assert client.post("/v1/renders", json={"scene_id": "nosuch"}).status_code == 404
    assert client.post("/v1/sessions", json={"scene_id": "nosuch"}).status_code == 404
    assert client.post("/v1/fits", json={"scene_id": "nosuch", "object": "x"}).status_code == 422
    r = client.post("/v1/scenes", json={"version": 1, "environment": {"map": "nosuch"},
                                        "camera": {"eye": [0, 0, 3], "target": [0, 0, 0]},
                                        "objects": [{"name": "a", "mesh": "nosuch"}]})
    assert r.status_code == 422 and "asset" in r.json()["detail"]
    assert client.get("/healthz").json()["status"] == "ok"


def test_api_tokens(server, client):
    r = client.get("/v1/materials", headers={"Authorization": "Bearer nope"})
    assert r.status_code == 401
    out = subprocess.run([sys.executable, "-m", "glint", "token", "create", "--name", "ci", "--data-dir", str(server["data"])],
                         capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert out.returncode == 0, out.stderr
    token = out.stdout.strip()
    assert client.get("/v1/materials", headers={"Authorization": f"Bearer {token}"}).status_code == 200
    assert client.get("/v1/materials", headers={"Authorization": "Basic abc"}).status_code == 401


def test_openapi_yaml_is_current():
    """openapi.yaml at the repository root is generated from the app (glint openapi --out openapi.yaml)."""
    from server.cli import openapi_yaml

    assert (ROOT / "openapi.yaml").read_text() == openapi_yaml(), "openapi.yaml drifted: run `glint openapi --out openapi.yaml`"


@pytest.mark.both_databases
def test_camera_moves_are_kept_though_written_in_batches(server, client, bunny_scene):
    """View messages change a copy of the state the stream holds, written at most
    0.5 s later (FLUSH_S), not one transaction each. Nothing is lost: a GET, a restore after the
    worker dies, and a reconnect all see the latest camera."""
    ses = client.post("/v1/sessions", json={"scene_id": bunny_scene}).json()
    sid, token = ses["id"], ses["token"]
    eye = lambda k: [round(0.02 * k, 3), 0.6, 3.2]            # noqa: E731

    def stored_eye():
        return client.get(f"/v1/sessions/{sid}", headers={"X-Session-Token": token}).json()["state"]["camera"]["eye"]

    async def go():
        async with connect(server, ses["stream"], token) as ws:
            await ws.recv()
            await next_frame(ws)
            for k in range(1, 21):
                await ws.send(json.dumps({"seq": k, "type": "view", "eye": eye(k), "drag": True}))
            await next_frame(ws, 20)
            assert stored_eye() == eye(20)
            await ws.send(json.dumps({"seq": 21, "type": "view", "eye": eye(21), "drag": True}))
            await next_frame(ws, 21)
            pid = client.get(f"/v1/sessions/{sid}", headers={"X-Session-Token": token}).json()["worker_pid"]
            os.kill(pid, signal.SIGKILL)
            ev = []
            await ws.send(json.dumps({"seq": 22, "type": "view", "eye": eye(22), "drag": False}))
            await next_frame(ws, 22, ev, timeout=120)
            assert stored_eye() == eye(22)
        async with connect(server, ses["stream"], token) as ws:
            hello = json.loads(await ws.recv())
            assert hello["state"]["camera"]["eye"] == eye(22) and hello["state"]["last_seq"] == 22, hello["state"]

    asyncio.run(go())


@pytest.mark.both_databases
def test_a_stroke_is_its_row_and_its_fit_is_kept_with_the_camera(server, client, bunny_scene):
    """A stroke is stored as its row before the worker sees it, the session's state
    (its last seq, the fit's material) like a camera move, at most 0.5 s later. A GET sees the
    fitted material at once, a restore after the worker dies applies the stroke once, and the
    material and the stroke survive a reconnect."""
    ses = client.post("/v1/sessions", json={"scene_id": bunny_scene}).json()
    sid, token = ses["id"], ses["token"]
    get = lambda: client.get(f"/v1/sessions/{sid}", headers={"X-Session-Token": token}).json()   # noqa: E731
    stroke = {"points": [[62, 63], [88, 64]], "color": [2.5, 2.5, 2.5], "diameter": 8}

    async def go():
        async with connect(server, ses["stream"], token) as ws:
            await ws.recv()
            await next_frame(ws)
            await ws.send(json.dumps({"seq": 1, "type": "view", "eye": [0.05, 0.6, 3.2], "drag": False}))
            await ws.send(json.dumps({"seq": 2, "type": "stroke", "stroke": stroke}))
            ev = []
            await next_frame(ws, 2, ev)
            fit = [e for e in ev if e["type"] == "fit"]
            assert fit, ev
            now = get()
            assert len(now["strokes"]) == 1 and now["state"]["last_seq"] == 2, now["state"]["last_seq"]
            assert now["state"]["materials"][0] == fit[-1]["material"]
            os.kill(now["worker_pid"], signal.SIGKILL)
            await ws.send(json.dumps({"seq": 3, "type": "view", "eye": [0.06, 0.6, 3.2], "drag": False}))
            await next_frame(ws, 3, timeout=120)
            # the restored worker holds the stroke once: a second one makes two
            await ws.send(json.dumps({"seq": 4, "type": "stroke", "stroke": {**stroke, "points": [[62, 70], [88, 71]]}}))
            ev = []
            await next_frame(ws, 4, ev)
            refit = [e for e in ev if e["type"] == "fit"]
            assert refit and refit[-1]["stats"]["strokes"] == 2, [e.get("stats") for e in refit]
            return refit[-1]["material"]

    material = asyncio.run(go())
    s = get()
    assert len(s["strokes"]) == 2 and s["state"]["last_seq"] == 4
    assert s["state"]["materials"][0] == material

    async def reconnect():
        async with connect(server, ses["stream"], token) as ws:
            hello = json.loads(await ws.recv())
            assert hello["strokes"] == 2 and hello["state"]["materials"][0] == material

    asyncio.run(reconnect())
