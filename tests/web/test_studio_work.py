"""The studio as a designer's tool, in headless Chromium against the shared server fixture: work
survives a reload and is shared by a second tab (the URL names the session, the server keeps it),
designs have names, "save as" and a version list with thumbnails, publish works after a reload,
and the canvas stays in view and uses the window at 1280×720 to 2560×1440. Screenshots go to
test-artifacts/web-work-*.png."""
import json
import time

import httpx
import numpy as np
import pytest

from helpers import canvas_grid, drag, frame_no, open_scene, settle, wait_new_frame

pytest.importorskip("playwright.sync_api")


def _open(ctx, url, errors, scene=None):
    """The studio at url; with ``scene``, on that scene (the shared server also holds scenes
    other test modules made, e.g. GI ones, which the studio may open first)."""
    page = ctx.new_page()
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    wait_new_frame(page, 0)
    settle(page)
    if scene is not None and page.locator("#scene-select").input_value() != scene:
        open_scene(page, scene)
        settle(page)
    return page


def _stroke(page, fx=0.42, fy=0.55, fw=0.14, sign="1"):
    """A brush stroke across the bunny (sign "1" adds light, "-1" removes it); returns once its
    fit's frame is drawn."""
    page.check("#tool-brush")
    page.select_option("#brush-sign", sign)
    page.fill("#brush-diameter", "30")
    page.locator("#brush-strength").fill("6")
    b = page.locator("#view").bounding_box()
    n = frame_no(page)
    drag(page, b["x"] + fx * b["width"], b["y"] + fy * b["height"], fw * b["width"], 0, steps=10)
    page.wait_for_function("() => document.getElementById('status').textContent.includes('achieved')", timeout=60_000)
    wait_new_frame(page, n)
    settle(page)


def _token(page, sid):
    return json.loads(page.evaluate(f"() => localStorage.getItem('glint.session.{sid}')"))["token"]


def _sid(page):
    return page.evaluate("() => new URLSearchParams(location.search).get('session')")


ROWS, COLS = slice(int(0.55 * 48) - 2, int(0.55 * 48) + 3), slice(int(0.42 * 64), int(0.56 * 64) + 1)


def test_reload_and_a_second_tab_reopen_the_session(server, bunny_scene, browser, artifacts):
    base = server["base"]
    errors = []
    ctx = browser.new_context(viewport={"width": 1280, "height": 720})
    page = _open(ctx, base + "/", errors, scene=bunny_scene)
    sid = _sid(page)
    assert sid, page.url                                   # the URL names the session
    g0 = canvas_grid(page)
    _stroke(page)
    g1 = canvas_grid(page)
    assert (g1 - g0)[ROWS, COLS].mean() > 4, "the stroke did not brighten the frame"
    points = page.locator("#curve").get_attribute("data-points")
    model = page.locator("#model").input_value()

    # a reload reopens the same session: its stroke (in the frame and the stored rows), material
    page.reload()
    wait_new_frame(page, 0)
    settle(page)
    g2 = canvas_grid(page)
    page.screenshot(path=str(artifacts / "web-work-1-reloaded.png"))
    assert _sid(page) == sid
    assert np.abs(g2 - g1).mean() < 1.5 and (g2 - g0)[ROWS, COLS].mean() > 4, "the reload lost the stroke"
    assert page.locator("#model").input_value() == model
    # the plot is the worker's evaluation of the stored material: a reopened session shows it
    # without refitting, and the settled frame the stroke waited for came after the fit over the
    # full view (a quick view's fit can differ from it by 0.1 where the strokes leave the lobe
    # free), so the curve is the same one
    after = np.array(json.loads(page.locator("#curve").get_attribute("data-points")))
    before = np.array(json.loads(points))
    assert after.shape == before.shape and np.abs(after - before).max() < 1e-4, \
        f"the reload lost the material: the curve moved by {np.abs(after - before).max():.3f}"
    got = httpx.get(f"{base}/v1/sessions/{sid}", headers={"X-Session-Token": _token(page, sid)}).json()
    assert len([s for s in got["strokes"] if not s["undone"]]) == 1, got["strokes"]

    # a second tab on the same URL shares the session and sees the first one's next stroke
    other = _open(ctx, page.url, errors)
    assert _sid(other) == sid
    assert np.abs(canvas_grid(other) - g2).mean() < 1.5, "the second tab does not show the session"
    n_other = frame_no(other)
    _stroke(page, sign="-1")             # the first one is at the energy bound: take light away
    wait_new_frame(other, n_other)
    settle(other)
    g3, g3o = canvas_grid(page), canvas_grid(other)
    other.screenshot(path=str(artifacts / "web-work-2-second-tab.png"))
    assert (g3 - g2)[ROWS, COLS].mean() < -3, (g3 - g2)[ROWS, COLS].mean()
    assert np.abs(g3o - g3).mean() < 1.5, "the second tab did not get the first tab's stroke"
    # its material panel follows too (the fit event reaches every tab)
    assert other.locator("#curve").get_attribute("data-points") == page.locator("#curve").get_attribute("data-points")

    # the undo history came back with the session: undo in the second tab takes the stroke off both
    n = frame_no(page)
    other.click("#undo")
    wait_new_frame(page, n)
    settle(page)
    settle(other)
    assert np.abs(canvas_grid(page) - g2).mean() < 1.5 and np.abs(canvas_grid(other) - g2).mean() < 1.5
    assert not errors, errors
    ctx.close()


def test_designs_save_as_versions_and_publish_after_a_reload(server, bunny_scene, browser, artifacts):
    base = server["base"]
    errors = []
    # a designer west of UTC: the version list's dates are in their time zone
    ctx = browser.new_context(viewport={"width": 1280, "height": 800}, timezone_id="America/New_York")
    page = _open(ctx, base + "/?session=none", errors, scene=bunny_scene)          # an unknown session: a new one is opened
    page.click("#new-design")
    page.fill("#design-name", "oak")
    page.click("#save")
    page.wait_for_function("() => document.getElementById('status').textContent.includes('saved “oak” version 1')",
                           timeout=60_000)
    _stroke(page)
    page.fill("#version-name", "brighter")
    page.click("#save")                                            # a new version of "oak"
    page.wait_for_function("() => document.getElementById('status').textContent.includes('saved “oak” version 2')",
                           timeout=60_000)
    page.fill("#design-name", "walnut")
    page.click("#save-as")                                         # a second design
    page.wait_for_function("() => document.getElementById('status').textContent.includes('saved “walnut” version 1')",
                           timeout=60_000)
    designs = {d["name"]: d for d in httpx.get(f"{base}/v1/materials").json()}
    assert designs["oak"]["version"] == 2 and designs["walnut"]["version"] == 1, designs
    assert designs["oak"]["id"] != designs["walnut"]["id"]
    assert "design=" + designs["walnut"]["id"] in page.url

    # the version list of "oak": names, dates, thumbnails (JPEGs of the frame saved)
    page.select_option("#design-select", designs["oak"]["id"])
    page.wait_for_function("() => document.querySelectorAll('#versions li').length === 2 && "
                           "[...document.querySelectorAll('#versions img')].every((i) => i.complete && i.naturalWidth > 0)",
                           timeout=30_000)
    items = page.locator("#versions li")
    assert "v2 · brighter" in items.nth(0).inner_text() and "v1 · oak" in items.nth(1).inner_text()
    assert all(any(ch.isdigit() for ch in items.nth(k).locator("small").inner_text()) for k in range(2))
    # the saves were made in the last minutes: their dates read as the page's clock did then, in
    # New York (the server's UTC time read as local time would be 5 hours ahead)
    shown = items.nth(1).locator("small").inner_text().split(" · ")[0]
    recent = page.evaluate("() => [...Array(6).keys()].map((m) => new Date(Date.now() - 60000 * m)"
                           ".toLocaleString([], { dateStyle: 'short', timeStyle: 'short' }))")
    assert shown in recent, (shown, recent)
    sizes = page.evaluate("() => [...document.querySelectorAll('#versions img')].map((i) => [i.naturalWidth, i.naturalHeight])")
    assert all(0 < w <= 192 and 0 < h <= 144 for w, h in sizes), sizes
    vs = httpx.get(f"{base}/v1/materials/{designs['oak']['id']}/versions").json()
    jpeg = httpx.get(base + vs[1]["thumbnail"])
    assert jpeg.headers["content-type"] == "image/jpeg" and jpeg.content[:2] == b"\xff\xd8" and len(jpeg.content) < 32768
    page.locator("#designs-panel").screenshot(path=str(artifacts / "web-work-3-versions.png"))

    # after a reload the design is still the one edited, and it can be published
    page.reload()
    wait_new_frame(page, 0)
    page.wait_for_function("() => document.getElementById('design-info').textContent.includes('oak')", timeout=30_000)
    page.click("#publish")
    link = page.locator("#publish-link")
    link.wait_for(state="visible", timeout=30_000)
    pub = httpx.get(base + "/v1/publications/" + link.get_attribute("href").rsplit("/", 1)[-1]).json()
    assert [v["material_id"] for v in pub["variants"]] == [designs["oak"]["id"]], pub

    # autosave: an edit, then the tab is closed; the edited design gets an "autosave" version
    _stroke(page, sign="-1")
    page.close(run_before_unload=True)
    oak = designs["oak"]["id"]
    for _ in range(100):
        vs = httpx.get(f"{base}/v1/materials/{oak}/versions").json()
        if len(vs) == 3:
            break
        time.sleep(0.2)
    assert [v["name"] for v in vs] == ["oak", "brighter", "autosave"], vs
    assert vs[2]["material"] != vs[1]["material"]          # the stroke's look, not the saved one
    assert not errors, errors
    ctx.close()


@pytest.fixture(scope="module")
def bunny_again(server, bunny_scene):
    """A second, newer scene (the bunny's spec again: its precomputation is reused), which the
    studio opens by default."""
    base = server["base"]
    spec = httpx.get(f"{base}/v1/scenes/{bunny_scene}").json()["spec"]
    newer = httpx.post(f"{base}/v1/scenes", json=spec, params={"name": "bunny again"}).json()["id"]
    pre = httpx.post(f"{base}/v1/scenes/{newer}/precompute").json()
    for _ in range(600):
        if httpx.get(f"{base}/v1/precomputations/{pre['id']}").json()["status"] in ("done", "failed"):
            break
        time.sleep(0.2)
    return newer


def _switch(page, scene):
    """Open ``scene`` from the Scene panel; returns once its session draws."""
    old = _sid(page)
    page.select_option("#scene-select", scene)
    page.click("#open-scene")
    page.wait_for_function(f"() => new URLSearchParams(location.search).get('session') !== {json.dumps(old)}",
                           timeout=60_000)
    page.wait_for_function(f"() => document.getElementById('view').dataset.frame !== undefined && "
                           f"new URLSearchParams(location.search).get('scene') === {json.dumps(scene)}", timeout=60_000)
    settle(page)


def test_a_look_at_another_scene_loses_nothing(server, bunny_scene, bunny_again, browser, artifacts):
    """A designer paints, opens another scene, and opens the first one again: it comes back as
    they left it (the same session, its stroke and undo history), not as a new empty session;
    and while it reopens, the canvas shows nothing of the other scene."""
    errors = []
    ctx = browser.new_context(viewport={"width": 1280, "height": 720})
    page = _open(ctx, server["base"] + "/", errors, scene=bunny_scene)
    sid = _sid(page)
    g0 = canvas_grid(page)
    _stroke(page)
    g1 = canvas_grid(page)
    _switch(page, bunny_again)
    assert _sid(page) != sid
    _switch(page, bunny_scene)
    page.screenshot(path=str(artifacts / "web-work-8-back-to-the-scene.png"))
    page.click("#status")                                # the recent messages
    recent = page.locator("#status-panel").inner_text()
    assert "bunny: 1 stroke(s) restored" in recent
    assert "disconnected" not in recent, recent          # the page closed those streams itself
    page.keyboard.press("Escape")
    assert _sid(page) == sid
    g2 = canvas_grid(page)
    assert np.abs(g2 - g1).mean() < 1.5 and (g2 - g0)[ROWS, COLS].mean() > 4, "the stroke was lost"
    n = frame_no(page)
    page.click("#undo")                                  # its undo history came back too
    wait_new_frame(page, n)
    settle(page)
    assert np.abs(canvas_grid(page) - g0).mean() < 1.5
    assert not errors, errors
    ctx.close()


def test_a_session_url_in_another_browser_opens_its_scene(server, bunny_scene, bunny_again, browser, artifacts):
    """A studio URL opened in a browser that does not hold its session's key (a colleague's, a
    private window) opens a new session of the same scene, not the default one; and there,
    Publish with nothing edited yet shows the designs to tick."""
    base = server["base"]
    errors = []
    first = browser.new_context(viewport={"width": 1280, "height": 720})
    page = _open(first, base + "/", errors, scene=bunny_scene)
    assert f"scene={bunny_scene}" in page.url, page.url
    other = browser.new_context(viewport={"width": 1280, "height": 720})
    there = _open(other, page.url, errors)
    assert _sid(there) != _sid(page)                      # its own session: it holds no key for the first
    assert there.locator("#scene-select").input_value() == bunny_scene
    assert f"scene={bunny_scene}" in there.url
    there.click("#status")                                 # the recent messages say why
    assert "opening a new session of the same scene" in there.locator("#status-panel").inner_text()
    there.keyboard.press("Escape")

    # a design saved in the first browser; the second, reloaded, lists it and asks to tick it
    page.fill("#design-name", "shared look")
    page.click("#save")
    page.wait_for_function("() => document.getElementById('status').textContent.includes('saved “shared look”')",
                           timeout=60_000)
    there.reload()
    wait_new_frame(there, 0)
    there.wait_for_function("() => [...document.querySelectorAll('#publish-pick label')]"
                            ".some((l) => l.textContent.includes('shared look'))", timeout=30_000)
    assert not there.locator("#publish-details").evaluate("d => d.open")
    there.click("#publish")
    assert there.locator("#publish-details").evaluate("d => d.open")
    assert "tick the designs" in there.locator("#status").inner_text()
    box = there.locator("#publish-pick label", has_text="shared look")
    box.locator("input").check()
    there.click("#publish")
    there.locator("#publish-link").wait_for(state="visible", timeout=30_000)
    there.screenshot(path=str(artifacts / "web-work-7-other-browser-publish.png"))
    assert not errors, errors
    first.close()
    other.close()


def _inside(box, w, h):
    return box["x"] >= 0 and box["y"] >= 0 and box["x"] + box["width"] <= w + 0.5 and box["y"] + box["height"] <= h + 0.5


def test_canvas_stays_in_view_and_uses_the_width(server, bunny_scene, browser, artifacts):
    base = server["base"]
    errors = []
    ctx = browser.new_context(viewport={"width": 1280, "height": 720})
    page = _open(ctx, base + "/", errors, scene=bunny_scene)
    view = page.locator("#view")
    assert _inside(view.bounding_box(), 1280, 720)
    # editing the curve (the last panels, scrolled to) keeps the canvas where it was
    page.locator("#curve").scroll_into_view_if_needed()
    pts = json.loads(page.locator("#curve").get_attribute("data-points"))
    box = page.locator("#curve").bounding_box()
    n = frame_no(page)
    drag(page, box["x"] + pts[1][0] * box["width"], box["y"] + pts[1][1] * box["height"], 0, -40, steps=5)
    assert _inside(view.bounding_box(), 1280, 720), view.bounding_box()
    wait_new_frame(page, n)
    # the paint sliders and the capture panel, further down
    page.locator("#paint-details summary").click()
    slider = page.locator("#paint-panel input[type=range]").first
    slider.scroll_into_view_if_needed()
    slider.fill(slider.get_attribute("max") or "1")
    # a −15° reading far above the 15° one, which no cosine-lobe paint has (they read the same):
    # the panel names the unmet readings and marks their rows
    page.locator("#paint-panel input[aria-label='level -15°']").fill("2")
    page.wait_for_function("() => (document.querySelector('#paint-panel .paint-status')?.textContent || '')"
                           ".includes('cannot be met')", timeout=20_000)
    warning = page.locator("#paint-panel .paint-status").inner_text()
    assert "-15:" in warning or " 15:" in warning, warning
    assert page.locator("#paint-panel .paint-unmet").count() >= 1
    # the scene dialog's menus (long renderer names) stay inside their panel
    page.locator("#scene-create summary").click()
    for kind in ("cuts", "gi", "paint"):
        page.select_option("#scene-renderer", kind)
        past = page.evaluate("() => [...document.querySelectorAll('aside select')].filter((s) => s.offsetParent)"
                             ".map((s) => [s.id, s.getBoundingClientRect().right - s.closest('section').getBoundingClientRect().right])"
                             ".filter(([, d]) => d > 0.5)")
        assert not past, (kind, past)
    page.locator("#scene-create summary").click()
    page.locator("#capture-details summary").click()
    page.locator("#capture-panel").scroll_into_view_if_needed()
    page.screenshot(path=str(artifacts / "web-work-4-1280x720.png"))
    assert _inside(view.bounding_box(), 1280, 720), view.bounding_box()
    assert page.evaluate("() => window.scrollY") == 0

    # the fit status can be read in full: a click on the status line opens the recent messages
    _stroke(page)
    line = page.locator("#status").inner_text()
    page.click("#status")
    panel = page.locator("#status-panel")
    assert panel.is_visible() and line in panel.inner_text()
    assert "achieved" in panel.inner_text() and "spill" in panel.inner_text()
    page.screenshot(path=str(artifacts / "web-work-5-status.png"))
    page.keyboard.press("Escape")
    assert not panel.is_visible()

    # wider windows: the canvas grows with the height, the panels take the rest, no empty band
    for w, h in ((1920, 1080), (2560, 1440)):
        page.set_viewport_size({"width": w, "height": h})
        page.wait_for_timeout(200)
        v, a = view.bounding_box(), page.locator("aside").bounding_box()
        page.screenshot(path=str(artifacts / f"web-work-6-{w}x{h}.png"))
        assert _inside(v, w, h), (w, h, v)
        assert v["height"] > 0.8 * h, (w, h, v)                       # as tall as the window allows
        assert a["x"] - (v["x"] + v["width"]) < 40, (w, v, a)          # the panels right beside it
        assert w - (a["x"] + a["width"]) < 40, (w, a)                  # and up to the window's edge
    assert not errors, errors
    ctx.close()
