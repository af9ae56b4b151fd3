"""The studio as a designer's tool, in headless Chromium against the real server: the settled
frame comes anti-aliased without input, the curve drawn is the worker's, a model switch keeps
the object's colour, a click picks the second object of a scene and a stroke changes only it,
and GI and car-paint scenes are created from the studio's scene dialog. Screenshots go to
test-artifacts/web-objects-*.png."""
import asyncio
import json
import threading
import time

import httpx
import numpy as np
import pytest
from helpers import drag, frame_no, open_scene, settle, wait_new_frame
from scipy.ndimage import median_filter

pytest.importorskip("playwright.sync_api")

# grain of a GI scene made in the studio: median |pixel − its 3×3 median| over the bunny's body,
# relative to its mean. Measured 0.0028 at 256×192 with denoised tensors; 0.0175 at the 128×96
# the studio asked for before, without denoising
GRAIN_MAX = 0.008

# every drawn frame's number, samples, size and mean absolute Laplacian of its luminance (the
# high frequencies that aliasing adds at edges), recorded as the canvas draws it
RECORD_JS = """() => {
  window.__frames = [];
  const c = document.getElementById('view');
  new MutationObserver(() => {
    const g = c.getContext('2d'), W = c.width, H = c.height, d = g.getImageData(0, 0, W, H).data;
    const L = (x, y) => { const k = 4 * (y * W + x); return 0.2126 * d[k] + 0.7152 * d[k + 1] + 0.0722 * d[k + 2]; };
    let s = 0, n = 0;
    for (let y = 1; y < H - 1; y++) for (let x = 1; x < W - 1; x++) {
      s += Math.abs(4 * L(x, y) - L(x - 1, y) - L(x + 1, y) - L(x, y - 1) - L(x, y + 1)); n++;
    }
    window.__frames.push({ frame: +c.dataset.frame, samples: +c.dataset.samples, quick: c.dataset.quick === 'true',
                           w: W, h: H, lap: s / n, t: performance.now() });
  }).observe(c, { attributes: true, attributeFilter: ['data-frame'] });
  // when the renderer line last changed (a new session's hello)
  const r = document.getElementById('renderer-info');
  new MutationObserver(() => { window.__rendererAt = performance.now(); })
    .observe(r, { childList: true, characterData: true, subtree: true });
}"""

# the canvas as linear RGB (sRGB decoded) on a W×H grid, read in the page
GRID_JS = """([W, H]) => {
  const c = document.getElementById('view'), g = c.getContext('2d');
  const d = g.getImageData(0, 0, c.width, c.height).data, out = [];
  const lin = (v) => { v /= 255; return v <= 0.04045 ? v / 12.92 : ((v + 0.055) / 1.055) ** 2.4; };
  for (let j = 0; j < H; j++) for (let i = 0; i < W; i++) {
    const x = Math.floor((i + 0.5) * c.width / W), y = Math.floor((j + 0.5) * c.height / H), k = 4 * (y * c.width + x);
    out.push([lin(d[k]), lin(d[k + 1]), lin(d[k + 2])]);
  }
  return out;
}"""


def rgb(page, w=96, h=72):
    return np.asarray(page.evaluate(GRID_JS, [w, h]), np.float64).reshape(h, w, 3)


def _page(browser, server, errors):
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server["base"] + "/")
    page.wait_for_function("() => document.getElementById('scene-select').options.length > 0", timeout=60_000)
    return page


def _open(page, scene_id):
    open_scene(page, scene_id)


def _status(page, text, timeout=120_000):
    page.wait_for_function("(t) => document.getElementById('status').textContent.includes(t)", arg=text,
                           timeout=timeout)


def _upload_scene(client, shared_assets, spec_file, name):
    from helpers import scene_file

    mesh = client.post("/v1/assets/meshes", params={"filename": "bunny.ply"},
                       content=(shared_assets / "meshes" / "bunny.ply").read_bytes()).json()
    env = client.post("/v1/assets/envmaps", params={"filename": "sunset.exr"},
                      content=(shared_assets / "env" / "sunset.exr").read_bytes()).json()
    spec = json.loads(scene_file(spec_file).read_text())
    spec["environment"]["map"] = env["id"]
    for o in spec["objects"]:
        o["mesh"] = mesh["id"]
    sc = client.post("/v1/scenes", json=spec, params={"name": name}).json()
    pre = client.post(f"/v1/scenes/{sc['id']}/precompute").json()
    for _ in range(900):
        p = client.get(f"/v1/precomputations/{pre['id']}").json()
        if p["status"] in ("done", "failed"):
            break
        time.sleep(0.5)
    assert p["status"] == "done", p
    return sc["id"]


def test_settled_frame_curve_and_model_switch(server, bunny_scene, browser, artifacts):
    from worker.jobs.curves import brdf_curve
    from worker.models import parse_material

    errors = []
    page = _page(browser, server, errors)
    page.evaluate(RECORD_JS)
    _open(page, bunny_scene)
    # 1. with no input at all, the settled frame is the anti-aliased one, at the canvas's size
    page.wait_for_function("() => window.__frames.some((f) => f.samples > 1)", timeout=90_000)
    settle(page)
    frames = page.evaluate("() => window.__frames")
    still = [f for f in frames if f["samples"] > 1][-1]
    rough = [f for f in frames if f["samples"] == 1 and (f["w"], f["h"]) == (still["w"], still["h"])]
    page.screenshot(path=str(artifacts / "web-objects-1-settled.png"))
    assert rough, frames
    assert frames[-1]["samples"] > 1, frames                      # the last one drawn is the settled one
    assert still["lap"] < 0.9 * rough[-1]["lap"], (still, rough[-1])   # smoother edges than one sample
    box = page.locator("#view").bounding_box()
    dpr = page.evaluate("() => window.devicePixelRatio")
    assert abs(still["w"] - box["width"] * dpr) <= 2 and abs(still["h"] - box["height"] * dpr) <= 2, (still, box)

    # 2. the object's pixels (a black albedo makes them black), then a coloured diffuse material
    page.fill("#param-albedo", "#000000")
    n = frame_no(page)
    wait_new_frame(page, n)
    settle(page)
    dark = rgb(page).mean(axis=2)
    page.fill("#param-albedo", "#b4825a")
    n = frame_no(page)
    wait_new_frame(page, n)
    settle(page)
    base = rgb(page)
    mask = (dark < 0.004) & (base.mean(axis=2) > 0.02)
    assert mask.sum() > 200, mask.sum()
    c0 = base[mask].mean(axis=0)
    # 3. switching models converts the look: the object's mean colour stays within 5 %
    for model in ("ggx", "blinn-phong", "ashikhmin-shirley"):
        n = frame_no(page)
        page.select_option("#model", model)
        _status(page, "fitted to the old look")
        wait_new_frame(page, n)
        settle(page)
        assert page.locator("#model").input_value() == model
        c1 = rgb(page)[mask].mean(axis=0)
        rel = np.abs(c1 - c0) / c0
        page.screenshot(path=str(artifacts / f"web-objects-2-{model}.png"))
        assert rel.max() < 0.05, (model, c0.round(4).tolist(), c1.round(4).tolist())
    # 4. the curve drawn is the worker's curve of the Ashikhmin-Shirley material being rendered
    mat = json.loads(page.locator("#curve").get_attribute("data-material"))
    drawn = np.asarray(json.loads(page.locator("#curve").get_attribute("data-drawn")))
    assert mat["model"] == "ashikhmin-shirley"
    want = np.asarray(brdf_curve(parse_material(mat))["specular"])
    assert drawn.shape == want.shape and np.allclose(drawn, want, rtol=1e-4, atol=1e-6), np.abs(drawn - want).max()
    assert page.locator("#lobe").get_attribute("data-incident") == "40"
    assert not errors, errors
    page.close()


def test_click_picks_the_second_object_and_a_stroke_changes_only_it(server, client, shared_assets, browser, artifacts):
    sid = _upload_scene(client, shared_assets, "two-bunnies.json", "two bunnies")
    errors = []
    # the page's session streams pass through here, so the test can cut one (a network drop)
    # and hold the reconnect while another client changes the session
    routes, hold = [], []

    def on_ws(ws):
        routes.append(ws)
        if not hold:
            ws.connect_to_server()
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.route_web_socket("**/stream", on_ws)
    page.goto(server["base"] + "/")
    page.wait_for_function("() => document.getElementById('scene-select').options.length > 0", timeout=60_000)
    _open(page, sid)
    settle(page)
    assert page.locator("#object-select").input_value() == "left"
    box = page.locator("#view").bounding_box()
    x, y, w, h = box["x"], box["y"], box["width"], box["height"]
    # a click on the right bunny picks it
    page.mouse.click(x + 0.68 * w, y + 0.55 * h)
    page.wait_for_function("() => document.getElementById('object-select').dataset.edited === 'right'", timeout=60_000)
    settle(page)
    before = rgb(page)
    page.check("#tool-brush")
    page.fill("#brush-diameter", "40")
    page.locator("#brush-strength").fill("6")
    n = frame_no(page)
    drag(page, x + 0.62 * w, y + 0.55 * h, 0.12 * w, 0, steps=10)
    wait_new_frame(page, n)
    settle(page)
    after = rgb(page)
    page.screenshot(path=str(artifacts / "web-objects-3-second-object-stroke.png"))
    change = np.abs(after - before).mean(axis=2)
    left, right = change[:, : change.shape[1] // 2], change[:, change.shape[1] // 2:]
    assert right.max() > 0.05 and right.mean() > 5 * max(left.mean(), 1e-4), (left.mean(), right.mean())
    assert left.max() < 0.01, left.max()                  # the left bunny did not change at all

    # a network drop: while this tab is away another client edits the left bunny; the hello of
    # the reconnect names it, and the object menu follows (not only the material panel)
    hold.append(True)
    routes[-1].close()
    page.wait_for_function("() => /disconnected/.test(document.getElementById('status').textContent)", timeout=30_000)
    sess = page.evaluate("() => { const id = new URLSearchParams(location.search).get('session');"
                         " return { id, ...JSON.parse(localStorage.getItem('glint.session.' + id)) }; }")
    # (in a thread of its own: Playwright's sync API holds this one's event loop)
    err = []
    t = threading.Thread(target=lambda: err.extend(_run(_edit_object(server, sess, "left"))))
    t.start()
    t.join(120)
    assert not err, err
    hold.clear()
    routes[-1].close()                                   # the held reconnect: the next one gets through
    page.wait_for_function("() => document.getElementById('object-select').dataset.edited === 'left'", timeout=60_000)
    assert page.locator("#object-select").input_value() == "left"
    page.screenshot(path=str(artifacts / "web-objects-4-reconnected.png"))
    assert not errors, errors
    page.close()


def _run(coro) -> list:
    try:
        asyncio.run(coro)
        return []
    except Exception as e:          # reported by the test's thread
        return [repr(e)]


async def _edit_object(server, sess, name):
    """Another client (a second tab) of the session edits ``name`` and waits until it is stored."""
    from helpers import connect

    async with connect(server, f"/v1/sessions/{sess['id']}/stream", sess["token"]) as ws:
        hello = json.loads(await ws.recv())
        seq = hello["state"]["last_seq"] + 1
        await ws.send(json.dumps({"seq": seq, "type": "object", "object": name}))
        while True:
            x = await asyncio.wait_for(ws.recv(), 60)
            if isinstance(x, str) and json.loads(x)["type"] == "object":
                return


@pytest.mark.parametrize("kind, label", [("gi", "global illumination"), ("paint", "car paint")])
def test_gi_and_paint_scenes_created_from_the_studio(server, bunny_scene, shared_assets, browser, artifacts, kind, label):
    errors = []
    page = _page(browser, server, errors)
    page.evaluate(RECORD_JS)
    page.locator("#scene-create summary").click()
    page.locator("#mesh-file").set_input_files(str(shared_assets / "meshes" / "bunny.ply"))
    page.locator("#env-file").set_input_files(str(shared_assets / "env" / "sunset.exr"))
    page.select_option("#scene-renderer", kind)
    page.fill("#scene-name", f"bunny {kind}")
    settle(page)                          # the scene the studio opened by itself
    page.click("#upload")
    _status(page, "precomputing", timeout=60_000)
    # the new scene opens by itself when its precomputation is done, with its renderer
    page.wait_for_function("(t) => document.getElementById('renderer-info').textContent.includes(t)",
                           arg=label, timeout=300_000)
    page.wait_for_function("() => window.__frames.some((f) => f.t > window.__rendererAt)", timeout=120_000)
    settle(page)
    page.screenshot(path=str(artifacts / f"web-objects-4-{kind}-created.png"))
    assert label in page.locator("#renderer-info").inner_text()
    assert rgb(page).std() > 0.01, "the new scene's frame is blank"
    # what the renderer does not offer is off, with its reason; nothing rejected is selected
    checked = page.locator("input[name=tool]:checked")
    assert checked.count() == 0 or not checked.is_disabled()
    if kind == "paint":
        assert page.locator("#tool-brush").is_disabled()
        assert "strokes" in page.locator("#renderer-off").inner_text()
    else:
        # GI: the brush paints through the multibounce tensors; a stroke across the bunny
        # brightens it where it was painted
        assert not page.locator("#tool-brush").is_disabled()
        assert "strokes" not in page.locator("#renderer-off").inner_text()
        # the studio asks for a frame the canvas can show and denoised tensors: no grain over
        # the bunny's body (the pixel's distance from its 3×3 median, over the canvas's middle)
        spec = next(s["spec"] for s in httpx.get(server["base"] + "/v1/scenes").json() if s["name"] == "bunny gi")
        assert spec["gi"].get("denoise") is True and spec["camera"]["width"] >= 256, spec
        lum = rgb(page, 192, 144) @ np.array([0.2126, 0.7152, 0.0722])
        body = lum[58:86, 76:116]
        grain = float(np.median(np.abs(body - median_filter(lum, 3)[58:86, 76:116])) / body.mean())
        print(f"GI scene from the studio: grain {grain:.4f}")
        assert grain < GRAIN_MAX, f"grain over the GI bunny's body: {grain:.4f}"
        before = rgb(page)
        box = page.locator("#view").bounding_box()
        x, y, w, h = box["x"], box["y"], box["width"], box["height"]
        page.check("#tool-brush")
        page.fill("#brush-diameter", "40")
        page.locator("#brush-strength").fill("6")
        n = frame_no(page)
        drag(page, x + 0.42 * w, y + 0.5 * h, 0.16 * w, 0, steps=10)
        wait_new_frame(page, n)
        settle(page)
        page.screenshot(path=str(artifacts / "web-objects-5-gi-stroke.png"))
        change = np.abs(rgb(page) - before).mean(axis=2)
        assert change.max() > 0.05, change.max()
        # one BRDF for the whole bunny falls short of a 6× highlight: the guidance box says what
        # it reached and spread (the light is not measured under GI: no rotation offered) and
        # offers a region, which the test takes
        page.locator("#guidance").wait_for(state="visible", timeout=30_000)
        page.locator("#guidance").scroll_into_view_if_needed()
        page.screenshot(path=str(artifacts / "web-objects-5b-gi-guidance.png"))
        text = page.locator("#guidance-text").inner_text()
        assert "one BRDF for the whole object reached" in text and "region" in text, text
        assert page.locator("#guidance-rotate").is_hidden()
        # a region painted under GI, then traced into the light transport: a new scene with the
        # region in its gi.painted, precomputed and opened with its region listed
        page.click("#guidance-region")
        assert page.locator("#region-paint").is_checked() and page.locator("#guidance").is_hidden()
        _status(page, "no strokes")
        page.select_option("#brush-mode", "scale")
        page.fill("#brush-scale", "0.3")
        settle(page)
        before_region = rgb(page)
        n = frame_no(page)
        drag(page, x + 0.42 * w, y + 0.62 * h, 0.16 * w, 0, steps=10)
        wait_new_frame(page, n)
        page.locator("#region-trace").wait_for(state="visible", timeout=60_000)
        settle(page)
        before_trace = rgb(page)
        page.click("#region-trace")
        page.wait_for_function("() => (document.getElementById('scene-select').selectedOptions[0]?.textContent || '')"
                               ".includes('regions traced')", timeout=300_000)
        page.locator("#region-list li").first.wait_for(timeout=120_000)
        settle(page)
        page.screenshot(path=str(artifacts / "web-objects-6-gi-traced.png"))
        traced = next(s for s in httpx.get(server["base"] + "/v1/scenes").json()
                      if s["name"] == "bunny gi · regions traced")
        (painted,) = traced["spec"]["gi"]["painted"]
        assert painted["object"] == "bunny" and painted["material"]["model"] == "regions", painted
        assert traced["spec"]["objects"][0]["material"]["model"] == "regions"
        assert "global illumination" in page.locator("#renderer-info").inner_text()
        # the traced scene shows the design as the session did (same exposure; what the eye sees
        # of the region is exact either way, only the light it sends on differs)
        traced_img = rgb(page)
        assert traced_img.std() > 0.01, "the traced scene's frame is blank"
        diff = float(np.abs(traced_img - before_trace).mean())
        region = float(np.abs(before_trace - before_region).mean())
        print(f"traced scene against the painted session: mean |Δ| {diff:.4f}; the region stroke's change {region:.4f}")
        assert diff < 0.3 * region, (diff, region)
    # the uploaded scene was exposed automatically (median object pixel middle grey)
    page.wait_for_function("() => +document.getElementById('exposure').value !== 0", timeout=60_000)
    assert not errors, errors
    page.close()
