"""The studio's Move tool in headless Chromium (as tests/web), on the crate scene precomputed by
the real server: a drag slides the box over the floor under the pointer, Shift-drag turns it (by
CSS pixels, the same at any device pixel ratio),
``drag: true`` while dragging and a last message without it. Screenshots go to
test-artifacts/web-move-*.png."""
import json
import shutil

import numpy as np
import pytest

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
import helpers
from helpers import frame_no

pw = pytest.importorskip("playwright.sync_api")


def project(cam, p):
    """Frame pixel (x, y) of a world point (docs/design/conventions.md camera)."""
    eye = np.asarray(cam["eye"], float)
    fwd = np.asarray(cam["target"], float) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, cam.get("up", [0, 1, 0]))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    rel = np.asarray(p, float) - eye
    t = np.tan(np.radians(cam["fov_y_deg"]) / 2)
    x = (rel @ right) / (rel @ fwd) / (t * cam["width"] / cam["height"])
    y = (rel @ up) / (rel @ fwd) / t
    return (x + 1) / 2 * cam["width"], (1 - y) / 2 * cam["height"]


def settle(page):
    helpers.settle(page, quiet_ms=1000)


def drag(page, x, y, dx, dy):
    helpers.drag(page, x, y, dx, dy, steps=10, step_ms=40)


def test_move_tool_slides_and_turns_the_object(server, crate, crate_scene, artifacts):
    cam = crate.spec["camera"]
    box = crate.spec["objects"][1]["transform"]["translate"]
    with pw.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True,
                              args=["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"])
        try:
            # a device pixel ratio above 1: frames have more pixels than the canvas has CSS pixels
            page = b.new_page(viewport={"width": 1280, "height": 860}, device_scale_factor=1.5)
            errors, sent = [], []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.on("websocket", lambda ws: ws.on("framesent", lambda m: sent.append(m)))
            page.goto(server["base"] + "/")
            page.wait_for_function(f"() => [...document.querySelectorAll('#scene-select option')]"
                                   f".some(o => o.value === '{crate_scene}' && !o.disabled)", timeout=60_000)
            helpers.open_scene(page, crate_scene)
            page.wait_for_function("() => !document.getElementById('move-tool').classList.contains('hidden')",
                                   timeout=60_000)
            settle(page)
            page.check("#tool-move")
            assert page.locator("#move-object").input_value() == "box"
            # the crate has no ground: its shadow toggle is off and says why
            assert page.locator("#shadow").is_disabled()
            why = page.locator("label", has=page.locator("#shadow")).get_attribute("title")
            assert why.startswith("no ground shadow:") and "no ground" in why, why
            page.screenshot(path=str(artifacts / "web-move-1-opened.png"))
            c = page.locator("#view").bounding_box()
            sx, sy = c["width"] / cam["width"], c["height"] / cam["height"]
            # grab the box's top and slide it 60 frame pixels to the right
            px, py = project(cam, [box[0], 30.0, box[2]])
            n = frame_no(page)
            drag(page, c["x"] + px * sx, c["y"] + py * sy, 60 * sx, 0)
            page.wait_for_function(f"() => +document.getElementById('view').dataset.frame > {n}", timeout=60_000)
            settle(page)
            page.screenshot(path=str(artifacts / "web-move-2-slid.png"))
            moves = [json.loads(m) for m in sent if isinstance(m, str) and '"move"' in m]
            assert moves and moves[-1]["drag"] is False and any(m["drag"] for m in moves[:-1]), moves
            t = moves[-1]["transform"]
            # the point grabbed stays under the pointer: the box's new place projects 60 px right
            # of where it was, on the plane through its origin
            h = box[1]
            qx, _ = project(cam, [t["translate"][0], h, t["translate"][2]])
            p0x, _ = project(cam, [box[0], h, box[2]])
            assert abs((qx - p0x) - 60) < 6 and t["translate"][1] == h, (t, qx - p0x)
            assert t["translate"][0] > box[0] + 5 and t["rotate_deg"] == [0, 0, 0]
            # Shift-drag turns it about +Y, 0.5° per CSS pixel, whatever the device pixel ratio
            sent.clear()
            n = frame_no(page)
            page.keyboard.down("Shift")
            drag(page, c["x"] + qx * sx, c["y"] + py * sy, 40 * sx, 0)
            page.keyboard.up("Shift")
            page.wait_for_function(f"() => +document.getElementById('view').dataset.frame > {n}", timeout=60_000)
            settle(page)
            page.screenshot(path=str(artifacts / "web-move-3-turned.png"))
            moves = [json.loads(m) for m in sent if isinstance(m, str) and '"move"' in m]
            last = moves[-1]["transform"]
            # frames follow canvas × device pixel ratio, but the turn follows the hand's motion
            fw = page.evaluate("() => document.getElementById('view').width")
            assert fw > 1.3 * c["width"], (fw, c["width"])     # frame pixels are not CSS pixels here
            want = 0.5 * 40 * sx
            assert abs(last["rotate_deg"][1] - want) < 0.1 * want and last["translate"] == t["translate"], (last, want)
            assert not errors, errors
        finally:
            b.close()


def test_a_stroke_painted_while_the_frame_size_changes_lands_under_the_brush(server, crate, crate_scene, artifacts):
    """The window is resized: the studio asks for frames of the canvas's new size, and until one
    arrives it still shows (and paints on) the old frame, stretched to the new canvas. A stroke
    painted then is recorded on the rays it was painted on (the old camera's pixel (x, y) is the
    new camera's (W/2 + (x − w/2) s, y s), s = H / h: the same vertical field of view), not at the
    old pixel numbers in the new frame. Frames are held back by routing the stream, so the stroke
    is always painted in that window."""
    if server["database"] != "sqlite":
        pytest.skip("reads the stroke's row from the SQLite file")
    import re
    import sqlite3

    hold = {"on": False, "held": [], "page": None, "sent": []}

    def route(ws):
        up = ws.connect_to_server()
        hold["page"] = ws

        def send(m):
            hold["sent"].append(m)
            up.send(m)
        ws.on_message(send)
        up.on_message(lambda m: hold["held"].append(m) if hold["on"] else ws.send(m))

    with pw.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True,
                              args=["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"])
        try:
            page = b.new_page(viewport={"width": 1280, "height": 860}, device_scale_factor=1.5)
            errors = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.route_web_socket(re.compile(r".*/stream$"), route)
            page.goto(server["base"] + "/")
            page.wait_for_function(f"() => [...document.querySelectorAll('#scene-select option')]"
                                   f".some(o => o.value === '{crate_scene}' && !o.disabled)", timeout=60_000)
            helpers.open_scene(page, crate_scene)
            settle(page)
            c0 = page.locator("#view").bounding_box()
            page.wait_for_function("(w) => document.getElementById('view').width > 1.3 * w", arg=c0["width"],
                                   timeout=60_000)
            w0, h0 = page.evaluate("() => [document.getElementById('view').width, document.getElementById('view').height]")
            sid = page.evaluate("() => new URLSearchParams(location.search).get('session')")
            hold["on"] = True
            n_sent = len(hold["sent"])
            page.set_viewport_size({"width": 900, "height": 700})
            c = page.locator("#view").bounding_box()
            assert c["width"] < 0.9 * c0["width"], (c, c0)
            page.wait_for_timeout(600)                      # the new size is asked for (held: no frame)
            views = [json.loads(m) for m in hold["sent"][n_sent:] if isinstance(m, str) and '"view"' in m]
            assert views and views[-1]["width"] < 0.9 * w0, views
            assert page.evaluate("() => document.getElementById('view').width") == w0     # still the old frame
            page.check("#tool-brush")
            fx, fy, dx = 0.3, 0.62, 0.08                    # on the floor, in front of the box
            helpers.drag(page, c["x"] + fx * c["width"], c["y"] + fy * c["height"], dx * c["width"], 0)
            page.wait_for_timeout(300)
            hold["on"] = False
            for m in hold["held"]:
                hold["page"].send(m)
            hold["held"].clear()
            body = None
            for _ in range(100):
                with sqlite3.connect(server["data"] / "glint.db") as con:
                    rows = con.execute("SELECT body FROM strokes WHERE session_id = ?", (sid,)).fetchall()
                if rows:
                    body = json.loads(rows[-1][0])
                    break
                page.wait_for_timeout(100)
            assert body is not None, "no stroke row"
            cam, pts = body["camera"], np.asarray(body["stroke"]["points"], float)
            W, H = cam["width"], cam["height"]
            assert (W, H) == (views[-1]["width"], views[-1]["height"]), (cam, views[-1])
            s = H / h0
            want = [W / 2 + (fx * w0 - w0 / 2) * s, fy * h0 * s]
            assert np.allclose(pts[0], want, atol=0.01 * W), (pts[0], want, (w0, h0), (W, H))
            assert np.isclose(pts[-1][0] - pts[0][0], dx * w0 * s, atol=0.01 * W), pts
            assert np.isclose(body["stroke"]["diameter"], float(page.input_value("#brush-diameter")) * s), body
            page.wait_for_function("(w) => document.getElementById('view').width === w", arg=W, timeout=60_000)
            settle(page)
            page.screenshot(path=str(artifacts / "web-move-4-stroke-new-size.png"))
            assert not errors, errors
        finally:
            b.close()
