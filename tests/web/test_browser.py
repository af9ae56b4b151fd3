"""The studio and the shopper viewer in headless Chromium (Debian's, driven by Playwright),
against the real server fixture. Screenshots of every step go to test-artifacts/web-*.png."""
import base64
import io
import json
import time
import urllib.parse
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from helpers import canvas_grid, drag, frame_no, settle, validate_gltf, wait_new_frame
from worker.jobs.curves import brdf_lobe
from worker.models import parse_material
from worker.paint.swatch import swatch_png

pw = pytest.importorskip("playwright.sync_api")
ANDROID_UA = ("Mozilla/5.0 (Linux; Android 14; Pixel 8) AppleWebKit/537.36 (KHTML, like Gecko) Chrome/131.0.0.0 "
              "Mobile Safari/537.36")

def test_studio_and_viewer(server, client, bunny_scene, browser, artifacts):
    base = server["base"]
    ctx = browser.new_context(viewport={"width": 1280, "height": 860}, accept_downloads=True)
    page = ctx.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(base + "/")
    # 1. the studio loads and shows a non-blank frame
    wait_new_frame(page, 0)
    settle(page)
    g0 = canvas_grid(page)
    page.screenshot(path=str(artifacts / "web-1-loaded.png"))
    assert g0.std() > 5, "the first frame is blank"
    assert page.locator("#readout").inner_text().split()[0].isdigit()

    canvas = page.locator("#view").bounding_box()
    cx, cy, w, h = canvas["x"], canvas["y"], canvas["width"], canvas["height"]

    # 2. a drag orbits the view
    n = frame_no(page)
    drag(page, cx + 0.5 * w, cy + 0.5 * h, 96, 0)
    wait_new_frame(page, n)
    settle(page)
    g1 = canvas_grid(page)
    page.screenshot(path=str(artifacts / "web-2-orbited.png"))
    assert np.abs(g1 - g0).mean() > 2, "dragging did not change the view"

    # 3. a painted stroke brightens the pixels under it
    page.check("#tool-brush")
    page.fill("#brush-diameter", "30")
    page.locator("#brush-strength").fill("6")
    n = frame_no(page)
    drag(page, cx + 0.42 * w, cy + 0.55 * h, 0.14 * w, 0, steps=10)
    wait_new_frame(page, n)
    settle(page)
    g2 = canvas_grid(page)
    page.screenshot(path=str(artifacts / "web-3-stroke.png"))
    rows = slice(int(0.55 * 48) - 2, int(0.55 * 48) + 3)
    cols = slice(int(0.42 * 64), int(0.56 * 64) + 1)
    under = (g2 - g1)[rows, cols].mean()
    mask = np.ones_like(g2, bool)
    mask[rows, cols] = False
    # one BRDF serves the whole object, so a stroke also changes unpainted pixels that see the same
    # half vectors: at the default unpainted weight (0.25) the standard strokes spill about a third
    # of their change (BENCHMARKS.md, "Strokes"); under the stroke must still change most
    rest = np.abs(g2 - g1)[mask].mean()
    assert under > 4 and under > 2 * rest, (under, rest)
    # the designer is told what the stroke achieved and what spilled
    st = page.locator("#status").inner_text()
    assert "fit" in st and "achieved" in st and "spill" in st, st
    # a white highlight of 6× under the sunset is more than the light near the mirror directions
    # gives: after the frame the studio says how much it covers and offers what would help: a
    # painted region (one BRDF for the whole bunny brightens all of it), and a rotation of the
    # environment when one covers 10 points more
    page.locator("#guidance").wait_for(state="visible", timeout=30_000)
    page.locator("#guidance").scroll_into_view_if_needed()
    page.screenshot(path=str(artifacts / "web-3-guidance.png"))
    text = page.locator("#guidance-text").inner_text()
    assert "of the highlight asked" in text and "as a region" in text, text
    if page.locator("#guidance-rotate").is_visible():
        assert page.locator("#guidance-rotate").inner_text().startswith("Rotate the light to ")
    page.click("#guidance-region")
    assert page.locator("#region-paint").is_checked() and page.locator("#guidance").is_hidden()
    page.wait_for_function("() => document.getElementById('status').textContent.includes('no strokes')",
                           timeout=30_000)
    page.uncheck("#region-paint")                      # back to one BRDF for the steps below

    # 4. dragging a point of the curve editor changes the material and the frame
    pts = json.loads(page.locator("#curve").get_attribute("data-points"))
    page.locator("#curve").scroll_into_view_if_needed()              # the side panel is taller than the window
    box = page.locator("#curve").bounding_box()
    px, py = pts[1]
    n = frame_no(page)
    drag(page, box["x"] + px * box["width"], box["y"] + py * box["height"], 0, -50, steps=5)
    wait_new_frame(page, n)
    settle(page)
    g3 = canvas_grid(page)
    page.screenshot(path=str(artifacts / "web-4-curve.png"))
    assert page.locator("#model").input_value() == "curve"
    assert np.abs(g3 - g2).mean() > 1, "editing the curve did not change the frame"

    # 5. the Light tool turns the environment (half a degree a pixel): the publication shows it as
    # turned as the designer left it
    page.check("#tool-light")
    n = frame_no(page)
    drag(page, cx + 0.2 * w, cy + 0.2 * h, 60, 0, steps=6)
    wait_new_frame(page, n)
    page.check("#tool-orbit")

    # 6. save the design, publish it, open the viewer
    page.fill("#design-name", "curved bunny")
    page.click("#save")
    page.wait_for_function("() => document.getElementById('status').textContent.includes('saved')", timeout=60_000)
    page.locator("#versions li").first.wait_for(timeout=30_000)          # the version list loads
    page.select_option("#publish-frames", "24")                          # a draft turntable
    page.click("#publish")
    link = page.locator("#publish-link")
    link.wait_for(state="visible", timeout=30_000)
    href = link.get_attribute("href")
    assert href.startswith("/view/")
    page.screenshot(path=str(artifacts / "web-5-published.png"))
    (env,) = client.get(f"/v1/publications/{href.rsplit('/', 1)[1]}").json()["environments"]
    assert abs(env["rotation_deg"] - 30.0) < 1.0, env          # the scene's 0° turned by 60 px

    viewer = ctx.new_page()
    viewer.on("pageerror", lambda e: errors.append(str(e)))
    # every text the status line shows, from the page's first parse
    viewer.add_init_script("""document.addEventListener('DOMContentLoaded', () => {
      const s = document.getElementById('status'); window.statuses = [s.textContent];
      new MutationObserver(() => window.statuses.push(s.textContent))
        .observe(s, {childList: true, characterData: true, subtree: true}); });""")
    viewer.goto(base + href)
    # the publication's bundle is built as a job: the viewer waits for it, then plays it
    wait_drawn(viewer, 0, timeout=240_000)
    # meanwhile it said so in a shopper's words: how far, not the service's message
    said = viewer.evaluate("() => window.statuses")
    waiting = [t for t in said if t.startswith("Preparing this product's images")]
    assert waiting and not [t for t in said if "publication" in t or href.rsplit("/", 1)[1] in t], said
    gv = canvas_grid(viewer)
    viewer.screenshot(path=str(artifacts / "web-6-viewer.png"))
    # the turn the designer chose: 24 frames at each of the two default elevations
    assert client.get(f"/v1/publications/{href.rsplit('/', 1)[1]}").json()["bundle"]["stats"]["views"] == 48
    assert gv.std() > 5
    assert viewer.locator(".swatch").count() == 1
    assert viewer.locator(".swatch").inner_text() == "curved bunny"       # the design's name, shown
    assert viewer.locator("#design-name").count() == 0 and viewer.locator("#save").count() == 0   # read-only
    # the screenshot downloads a PNG of the 2× frame
    with viewer.expect_download() as dl:
        viewer.click("#screenshot")
    path = dl.value.path()
    assert open(path, "rb").read(8) == b"\x89PNG\r\n\x1a\n"
    from PIL import Image
    assert Image.open(path).size == (320, 240)                           # the scene camera's 160×120, twice
    assert dl.value.suggested_filename.endswith(".png")
    assert not errors, errors
    ctx.close()


def wait_drawn(page, after, timeout=60_000):
    """Wait until the bundle player has drawn more than ``after`` frames."""
    page.wait_for_function(f"() => +(document.getElementById('view').dataset.drawn || 0) > {after}", timeout=timeout)


def drawn(page) -> int:
    return int(page.evaluate("() => +(document.getElementById('view').dataset.drawn || 0)"))


def no_overflow(page) -> dict:
    """The page's scroll size against its viewport, and the stage's box."""
    return page.evaluate("""() => { const d = document.documentElement, b = document.getElementById('stage').getBoundingClientRect();
      return {sw: d.scrollWidth, sh: d.scrollHeight, w: innerWidth, h: innerHeight,
              stage: [b.left, b.top, b.right, b.bottom]}; }""")


def pinch(page, cx, cy, d0, d1, steps=8):
    """Two fingers from d0 to d1 apart about (cx, cy), through Chromium's touch input (CDP):
    Playwright's API has one pointer only."""
    cdp = page.context.new_cdp_session(page)

    def touch(kind, d):
        pts = [] if kind == "touchEnd" else [{"x": cx - d / 2, "y": cy, "id": 1}, {"x": cx + d / 2, "y": cy, "id": 2}]
        cdp.send("Input.dispatchTouchEvent", {"type": kind, "touchPoints": pts})
    touch("touchStart", d0)
    for k in range(1, steps + 1):
        touch("touchMove", d0 + (d1 - d0) * k / steps)
        page.wait_for_timeout(30)
    touch("touchEnd", d1)
    cdp.detach()


def test_viewer_plays_the_bundle_on_phones(server, bunny_scene, client, browser, artifacts, tmp_path):
    # two designs and a publication made through the API, with a small bundle
    m = client.post("/v1/materials", json={"name": "Cherry red", "material": {"model": "ggx", "alpha": 0.2, "specular": [0.5, 0.5, 0.5],
                                                                              "albedo": [0.5, 0.05, 0.05]}}).json()
    m2 = client.post("/v1/materials", json={"name": "Ocean blue", "material": {"model": "lambert", "albedo": [0.05, 0.1, 0.6]}}).json()
    pub = client.post("/v1/publications", json={"name": "bunny colours", "scene_id": bunny_scene, "live": True,
                                                "bundle": {"azimuths": 12, "elevations_deg": [10, 35], "width": 320, "height": 240},
                                                "variants": [{"material_id": m["id"]}, {"material_id": m2["id"]}],
                                                "environments": [{}, {"label": "Sunset, turned", "rotation_deg": 120}]})
    assert pub.status_code == 201, pub.text
    pid = pub.json()["id"]
    for _ in range(960):
        b = client.get(f"/v1/publications/{pid}").json()["bundle"]
        if b["status"] in ("done", "failed"):
            break
        time.sleep(0.25)
    assert b["status"] == "done", b

    ctx = browser.new_context(viewport={"width": 390, "height": 844}, is_mobile=True, has_touch=True, accept_downloads=True,
                              user_agent=ANDROID_UA)
    page = ctx.new_page()
    errors, requests = [], []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("request", lambda r: requests.append(r.url))
    page.goto(server["base"] + f"/view/{pid}")
    wait_drawn(page, 0)
    page.wait_for_timeout(1500)                 # the ring preloads
    g0 = canvas_grid(page)
    # Chromium decodes AVIF: the frames come from the AVIF set; a browser without it gets the JPEGs
    shown = [u for u in requests if "/v1/bundle-files/" in u and u.endswith((".avif", ".jpg"))]
    assert shown and all(u.endswith(".avif") for u in shown), shown[:4]
    assert page.evaluate("""() => { const p = window.glintViewer, f = p.entry(0, 0, 0, 0);
        p.avif = false; const u = [p.url(f, false), p.hi]; p.avif = true; return u; }""")[0].endswith(".jpg")
    o = no_overflow(page)
    assert o["sw"] <= o["w"], o                                       # portrait: nothing sticks out sideways
    bb = page.locator("#view").bounding_box()
    assert 300 < bb["width"] <= 390, bb                               # the stage takes the phone's width
    # swatches carry their names; the lighting menu the maps' true names
    labels = [page.locator(".swatch").nth(i).inner_text() for i in range(2)]
    assert labels == ["Cherry red", "Ocean blue"] and page.locator(".swatch-label").first.is_visible()
    assert page.locator("#environment option").all_inner_texts() == ["Sunset", "Sunset, turned"]
    assert page.locator("#readout").count() == 0 and "fps" not in page.inner_text("body")   # no debug figures
    page.screenshot(path=str(artifacts / "web-7-phone.png"))

    # the published design as a glTF model for any viewer, and on Android for Scene Viewer (AR)
    href = page.get_attribute("#model-file", "href")
    assert page.locator("#model-file").is_visible() and href.endswith(".glb"), href
    ar = page.get_attribute("#ar", "href")
    assert page.locator("#ar").is_visible() and ar.startswith("intent://arvr.google.com/scene-viewer/1.0?file=")
    assert urllib.parse.unquote(ar.split("file=", 1)[1].split("&", 1)[0]) == href    # its absolute URL
    glb = client.get(urllib.parse.urlsplit(href).path)
    assert glb.status_code == 200 and glb.headers["content-type"] == "model/gltf-binary", glb.headers
    assert "immutable" in glb.headers["cache-control"]
    (tmp_path / "published.glb").write_bytes(glb.content)
    rep = validate_gltf(tmp_path / "published.glb")
    assert rep["issues"]["numErrors"] == 0, rep["issues"]
    doc = json.loads(glb.content[20:20 + int.from_bytes(glb.content[12:16], "little")])
    assert [v["name"] for v in doc["extensions"]["KHR_materials_variants"]["variants"]] == ["Cherry red", "Ocean blue"]

    # a swipe turns the object: frames swap locally, nothing goes to a session or a worker
    before = len(requests)
    az0 = page.evaluate("() => window.glintViewer.az")
    n = drawn(page)
    drag(page, bb["x"] + 0.7 * bb["width"], bb["y"] + 0.5 * bb["height"], -0.4 * bb["width"], 0, steps=10)
    wait_drawn(page, n)
    assert page.evaluate("() => window.glintViewer.az") != az0
    g1 = canvas_grid(page)
    assert np.abs(g1 - g0).mean() > 1, "swiping did not turn the object"
    during = requests[before:]
    assert not [u for u in during if "/sessions" in u or "/v1/renders" in u or "/stream" in u], during
    assert all("/v1/bundle-files/" in u for u in during), during       # at most the frames not yet preloaded

    # turning as fast as the bundle allows (one azimuth per animation frame, real pointer events in
    # the page, bench/static.py): every tick draws the requested frame, and nothing is requested
    from bench.static import PRELOADED, turn_rate

    page.wait_for_function(PRELOADED, timeout=30_000)
    before = len(requests)
    t = turn_rate(page)
    assert t["ticks"] == 24 and t["drawn"] == 24 and t["exact_fraction"] == 1.0, t
    assert requests[before:] == [], requests[before:]

    # another variant and another lighting preset
    page.locator(".swatch").nth(1).click()
    page.wait_for_timeout(800)
    g2 = canvas_grid(page)
    assert np.abs(g2 - g1).mean() > 2
    page.select_option("#environment", "1")
    page.wait_for_timeout(800)
    assert np.abs(canvas_grid(page) - g2).mean() > 1
    page.screenshot(path=str(artifacts / "web-8-phone-variant.png"))

    # a pinch zooms in and switches to the 2× set
    assert page.evaluate("() => document.getElementById('view').dataset.set") == "1x"
    n2x = sum("/v1/bundle-files/" in u for u in requests)
    pinch(page, bb["x"] + bb["width"] / 2, bb["y"] + bb["height"] / 2, 60, 180)
    page.wait_for_function("() => document.getElementById('view').dataset.set === '2x'", timeout=10_000)
    assert page.evaluate("() => window.glintViewer.zoom") > 1.5
    assert sum("/v1/bundle-files/" in u for u in requests) > n2x       # the 2× frames were fetched
    page.screenshot(path=str(artifacts / "web-9-phone-zoomed.png"))
    assert not [u for u in requests if "/sessions" in u or "/stream" in u], requests
    ctx.close()

    # the same phone held sideways: the stage and the controls fit the screen, no scrolling
    ctx = browser.new_context(viewport={"width": 844, "height": 390}, is_mobile=True, has_touch=True)
    page = ctx.new_page()
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server["base"] + f"/view/{pid}")
    wait_drawn(page, 0)
    o = no_overflow(page)
    assert o["sw"] <= o["w"] and o["sh"] <= o["h"], o
    x0, y0, x1, y1 = o["stage"]
    assert x0 >= 0 and y0 >= 0 and x1 <= o["w"] and y1 <= o["h"] and (y1 - y0) > 0.8 * o["h"], o
    assert page.locator(".swatch-label").nth(1).is_visible()
    page.screenshot(path=str(artifacts / "web-10-phone-landscape.png"))
    assert not errors, errors
    ctx.close()

    # the downloaded bundle plays from a plain static file server, no Glint behind it
    import io
    import subprocess
    import sys
    import zipfile

    from helpers import free_port

    site = tmp_path / "site"
    zipfile.ZipFile(io.BytesIO(client.get(f"/v1/publications/{pid}/bundle.zip").content)).extractall(site)
    port = free_port()
    static = subprocess.Popen([sys.executable, "-m", "http.server", str(port), "--bind", "127.0.0.1"], cwd=site,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        ctx = browser.new_context(viewport={"width": 1024, "height": 800})
        page = ctx.new_page()
        page.on("pageerror", lambda e: errors.append(str(e)))
        hosts = []
        page.on("request", lambda r: hosts.append(r.url.split("/")[2]))
        for _ in range(50):
            try:
                page.goto(f"http://127.0.0.1:{port}/index.html")
                break
            except pw.Error:
                time.sleep(0.2)                 # the file server is starting
        wait_drawn(page, 0)
        page.wait_for_timeout(500)
        g0 = canvas_grid(page)
        bb = page.locator("#view").bounding_box()
        n = drawn(page)
        drag(page, bb["x"] + 0.7 * bb["width"], bb["y"] + 0.5 * bb["height"], -0.3 * bb["width"], 0, steps=8)
        wait_drawn(page, n)
        assert np.abs(canvas_grid(page) - g0).mean() > 1
        assert page.locator(".swatch").all_inner_texts() == ["Cherry red", "Ocean blue"]
        assert not page.locator("#ar").is_visible()                     # a desktop: no Scene Viewer link
        model = page.get_attribute("#model-file", "href")
        assert model.startswith(f"http://127.0.0.1:{port}/files/") and model.endswith(".glb")
        assert page.evaluate("async (u) => (await fetch(u)).status", model) == 200     # the static host has it
        assert set(hosts) == {f"127.0.0.1:{port}"}, set(hosts)        # everything from the static host
        page.screenshot(path=str(artifacts / "web-11-static-bundle.png"))
        assert not errors, errors
        ctx.close()
    finally:
        static.terminate()
        static.wait(timeout=10)

    # a viewer session (live mode, allowed here) cannot edit: strokes, materials and saves are refused
    from websockets.sync.client import connect      # (Playwright's sync API owns this thread's event loop)

    ses = client.post(f"/v1/publications/{pid}/sessions").json()
    with connect(f"ws://127.0.0.1:{server['port']}{ses['stream']}", max_size=None) as ws:
        ws.send(json.dumps({"type": "auth", "token": ses["token"]}))
        ws.recv(timeout=30)
        for msg in ({"seq": 1, "type": "stroke", "stroke": {"points": [[80, 60]]}},
                    {"seq": 2, "type": "material", "material": {"model": "lambert"}},
                    {"seq": 3, "type": "save", "name": "mine"}):
            ws.send(json.dumps(msg))
            while True:
                x = ws.recv(timeout=30)
                if isinstance(x, str):
                    ev = json.loads(x)
                    assert ev["type"] == "error" and "read-only" in ev["message"], ev
                    break
    # the published design is unchanged
    assert client.get(f"/v1/materials/{m['id']}").json()["version"] == 1


def test_studio_follows_the_demo_precomputation(browser, tmp_path, artifacts):
    """Someone who opens the studio while the demo scene still precomputes sees its
    progress and its first look (worker/renderers/cuts/preview.py), and the demo opens by
    itself when it is ready (no reload). The demo here is the bunny (GLINT_DEMO_SCENE),
    precomputed by a fresh server that draws a first look for any scene
    (``preview_min_vertices`` 0; the default draws none below 8000 vertices, and the bunny has
    2882). The first look is close to the final frame."""
    import httpx
    from PIL import Image

    from helpers import GlintServer, scene_file

    srv = GlintServer(tmp_path / "data", workers=1, demo=True,
                      env={"GLINT_DEMO_SCENE": str(scene_file("bunny.json")), "GLINT_PREVIEW_MIN_VERTICES": "0"})
    try:
        page = browser.new_page(viewport={"width": 1280, "height": 860})
        errors = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(srv.base + "/")
        # the studio shows the preparation while it runs (it takes seconds: the bunny's 2.8K vertices)
        page.wait_for_function("() => /demo/.test(document.getElementById('status').textContent)"
                               " && !document.getElementById('progress').classList.contains('hidden')", timeout=60_000)
        seen = page.locator("#status").inner_text()
        page.screenshot(path=str(artifacts / "web-0-demo-progress.png"))
        assert "demo" in seen and "opens by itself" in seen, seen
        # the first look comes while the precomputation runs, before any frame of a session
        page.wait_for_function("() => document.getElementById('view').dataset.preview === '1'", timeout=60_000)
        assert page.evaluate("() => document.getElementById('view').dataset.frame") is None
        assert "first look" in page.locator("#status").inner_text()
        page.screenshot(path=str(artifacts / "web-0-demo-first-look.png"))
        assert canvas_grid(page).std() > 5, "the first look on the canvas is blank"
        # then the scene opens without a reload and its frames replace the first look
        wait_new_frame(page, 0, timeout=240_000)
        settle(page)
        assert canvas_grid(page).std() > 5, "the demo frame is blank"
        assert page.evaluate("() => document.getElementById('view').dataset.preview") is None
        assert page.locator("#progress").evaluate("e => e.classList.contains('hidden')")
        assert not errors, errors
        page.close()
        with httpx.Client(base_url=srv.base, timeout=120) as c:
            sid = c.get("/v1/status").json()["demo"]["scene_id"]
            sc = c.get(f"/v1/scenes/{sid}").json()
            p, cam = sc["precomputation"], sc["spec"]["camera"]
            info = p["stats"]["preview"]
            # the coarse tree: at most 256 rays per vertex (the full precomputation traces up to 32 768)
            assert 0 < info["rays"] <= 256 * p["stats"]["vertices"], info
            assert (info["width"], info["height"]) == (cam["width"], cam["height"]), info
            r = c.get(f"/v1/precomputations/{p['id']}/preview")
            assert r.status_code == 200 and r.headers["content-type"] == "image/jpeg", r.text
            first = np.asarray(Image.open(io.BytesIO(r.content)).convert("RGB"), np.float64) / 255

            def png(body):
                r = c.post("/v1/renders", json=body)
                assert r.status_code == 200, r.text
                return np.asarray(Image.open(io.BytesIO(r.content)).convert("RGB"), np.float64) / 255
            final = png({"scene_id": sid})
            black = png({"scene_id": sid, "materials": {"bunny": {"model": "lambert", "albedo": [0, 0, 0]}}})
    finally:
        srv.stop()
    # against the final frame, on the object's pixels (where a black bunny differs from it)
    obj = np.abs(final - black).max(axis=2) > 0.05
    assert obj.mean() > 0.05, f"the bunny covers {obj.mean():.1%} of the frame"
    mean_err = abs(first[obj].mean() - final[obj].mean()) / final[obj].mean()
    pix_err = np.abs(first[obj] - final[obj]).mean() / final[obj].mean()
    print(f"first look: {info}; against the final frame mean {mean_err:.2%}, per pixel {pix_err:.2%}")
    assert mean_err < 0.03 and pix_err < 0.06, (f"first look vs final frame over {obj.sum()} object pixels: "
                                               f"mean {mean_err:.1%} (bound 3%), per pixel {pix_err:.1%} (bound 6%)")


def test_studio_paint_designer_and_lighting_capture(server, bunny_scene, browser, artifacts, tmp_path, shared_assets):
    """The paint panel fits lobes on every slider change and the frame follows; a capture chosen
    as photos is uploaded, stitched by the service and applied to the scene."""
    import httpx

    from worker.capture.synth import synthesize
    from worker.core.tonemap import auto_exposure
    from worker.envmap import load_envmap

    synthesize(load_envmap(shared_assets / "env" / "apartment.exr"), tmp_path / "cap", width=360, height=240,
               brackets=3, seed=2)
    page = browser.new_page(viewport={"width": 1280, "height": 1400})
    errors, sent = [], []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("websocket", lambda ws: ws.on("framesent", lambda m: sent.append(m)))
    page.goto(server["base"] + "/")
    wait_new_frame(page, 0)
    settle(page)
    g0 = canvas_grid(page)
    assert "direct light" in page.locator("#renderer-info").inner_text()
    # the paint designer: a brighter 15° reading makes a lobes material and a new frame
    page.locator("#paint-details summary").click()
    n = frame_no(page)
    page.locator("#paint-panel input[aria-label='level 15°']").fill("1.2")
    page.wait_for_function("() => document.getElementById('status').textContent.includes('paint: fitted')", timeout=60_000)
    wait_new_frame(page, n)
    settle(page)
    g1 = canvas_grid(page)
    assert page.locator("#model").input_value() == "lobes"
    assert np.abs(g1 - g0).mean() > 1, "the paint readings did not change the frame"
    assert "fit" in page.locator(".paint-status").inner_text()
    # the lobe plot draws the worker's lobe of the fitted paint, and a kept paint's swatch is the
    # worker's picture of it: the page evaluates no BRDF
    page.wait_for_function("() => { const c = document.getElementById('paint-lobe');"
                           " return c.dataset.drawn && JSON.parse(c.dataset.material || 'null')?.model === 'lobes'; }",
                           timeout=60_000)
    lobe = page.locator("#paint-lobe").evaluate("c => ({...c.dataset})")
    fitted = parse_material(json.loads(lobe["material"]))
    server_lobe = brdf_lobe(fitted)
    k = server_lobe["rgb_theta_i_deg"].index(int(float(lobe["incident"])))
    assert lobe["incident"] == "45"
    drawn = np.asarray(json.loads(lobe["drawn"]))
    assert np.allclose(drawn, server_lobe["rgb"][k], rtol=1e-3, atol=1e-9), np.abs(drawn - server_lobe["rgb"][k]).max()
    page.fill("#design-name", "red flop")
    page.click("#paint-keep")
    img = page.locator("#paint-palette img[alt='red flop']")
    img.wait_for(timeout=10_000)
    png = lambda url: np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))).convert("RGBA"), int)
    assert np.abs(png(img.get_attribute("src")) - png(swatch_png(fitted))).max() <= 1
    page.screenshot(path=str(artifacts / "web-9-paint.png"))
    # the capture: photos chosen in the panel, stitched by the service, applied to the scene
    page.locator("#capture-details summary").click()
    photos = sorted(str(p) for p in (tmp_path / "cap").glob("*.jpg")) + [str(tmp_path / "cap" / "manifest.json")]
    page.locator("#capture-panel input[type=file]").set_input_files(photos)
    page.get_by_role("button", name="Upload and stitch").click()
    apply = page.get_by_role("button", name="Apply to the scene")
    page.wait_for_function("(b) => !b.disabled", arg=apply.element_handle(), timeout=240_000)
    n = frame_no(page)
    apply.click()
    wait_new_frame(page, n)
    settle(page)
    g2 = canvas_grid(page)
    page.screenshot(path=str(artifacts / "web-10-captured-lighting.png"))
    assert np.abs(g2 - g1).mean() > 1, "the captured lighting did not change the frame"
    # applied in the units of its preview (the map's median luminance as middle grey, the
    # exposure the preview was made with), and the status line confirms it
    (env,) = [json.loads(m) for m in sent if isinstance(m, str) and '"environment"' in m]
    asset = httpx.get(f"{server['base']}/v1/assets/{env['asset_id']}").json()
    sha = asset["sha256"]
    stitched = tmp_path / ("stitched" + Path(asset["filename"]).suffix)
    stitched.write_bytes((Path(server["data"]) / "blobs" / sha[:2] / sha).read_bytes())
    want = auto_exposure(load_envmap(stitched))
    page.wait_for_function("() => /lighting applied/.test(document.getElementById('status').textContent)", timeout=30_000)
    line = page.locator("#status").inner_text()
    assert f"{want:+.2f} EV as in its preview" in line, (line, want)
    assert abs(float(page.locator("#exposure").input_value()) - want) <= 0.05, (page.locator("#exposure").input_value(), want)
    assert not errors, errors
    page.close()
