"""Painted regions in the studio (headless Chromium, the shared server): with "Paint a region"
on, a stroke changes what it covers and the rest of the bunny stays as it was; the region is
listed, given a material from the list (and the step undone), renamed and erased. Screenshot:
test-artifacts/web-regions.png."""
import json

import numpy as np
import pytest

from helpers import canvas_grid, drag, frame_no, open_scene, settle, wait_new_frame

pytest.importorskip("playwright.sync_api")


def _status_has(page, text, timeout=60_000):
    page.wait_for_function(f"() => document.getElementById('status').textContent.includes({json.dumps(text)})",
                           timeout=timeout)


def _regions(page):
    return page.evaluate("() => [...document.querySelectorAll('#region-list li')].map((li) => li.dataset.region)")


def _still(page, after: int, timeout=90_000):
    """Wait for the anti-aliased still (samples > 1) drawn after frame ``after``, then for quiet:
    a one-sample frame and a still differ along every silhouette."""
    page.wait_for_function(f"() => {{ const c = document.getElementById('view'); "
                           f"return +c.dataset.frame > {after} && +c.dataset.samples > 1; }}", timeout=timeout)
    settle(page)


def _studio(server, bunny_scene, browser):
    """(context, page, page errors) of the studio at 1280×720 on the bunny scene, settled."""
    errors = []
    ctx = browser.new_context(viewport={"width": 1280, "height": 720})
    page = ctx.new_page()
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server["base"] + "/")
    wait_new_frame(page, 0)
    settle(page)
    if page.locator("#scene-select").input_value() != bunny_scene:
        open_scene(page, bunny_scene)
        settle(page)
    return ctx, page, errors


def test_a_stroke_paints_a_region_and_the_rest_stays(server, bunny_scene, browser, artifacts):
    ctx, page, errors = _studio(server, bunny_scene, browser)
    _still(page, 0)
    g0 = canvas_grid(page)
    page.fill("#region-name", "belly")
    page.check("#region-paint")
    _status_has(page, "no strokes")
    # a darkening across the middle of the bunny
    page.check("#tool-brush")
    page.select_option("#brush-mode", "scale")
    page.fill("#brush-scale", "0.2")
    page.fill("#brush-diameter", "30")
    b = page.locator("#view").bounding_box()
    n = frame_no(page)
    drag(page, b["x"] + 0.42 * b["width"], b["y"] + 0.55 * b["height"], 0.14 * b["width"], 0, steps=10)
    _status_has(page, "region “belly”")
    _status_has(page, "achieved")
    wait_new_frame(page, n)
    _still(page, n)
    g1 = canvas_grid(page)
    page.screenshot(path=str(artifacts / "web-regions.png"))
    assert _regions(page) == ["belly"]
    rows, cols = slice(int(0.55 * 48) - 1, int(0.55 * 48) + 2), slice(int(0.44 * 64), int(0.54 * 64))
    assert (g0 - g1)[rows, cols].mean() > 8, "the stroke did not darken what it covers"
    # the top and bottom of the frame (far from the stroke) are unchanged
    far = np.r_[0:int(0.3 * 48), int(0.8 * 48):48]
    assert np.abs(g1 - g0)[far].max() <= 2, np.abs(g1 - g0)[far].max()
    # a material from the list (Lambert's defaults) for the region: what it covers changes,
    # nothing far from it; undo takes the step back
    n = frame_no(page)
    page.select_option("#region-list li[data-region='belly'] .region-material", "model:lambert")
    wait_new_frame(page, n)
    _still(page, n)
    g2 = canvas_grid(page)
    page.locator("#region-list").scroll_into_view_if_needed()
    page.locator("#region-list").screenshot(path=str(artifacts / "web-regions-list.png"))
    assert np.abs(g2 - g1)[rows, cols].mean() > 5, "the region's material did not change it"
    assert np.abs(g2 - g1)[far].max() <= 2
    n = frame_no(page)
    page.click("#undo")
    wait_new_frame(page, n)
    _still(page, n)
    assert np.abs(canvas_grid(page) - g1)[rows, cols].mean() < 1.5, "undo did not take the material back"
    # renamed to the name in the field, then erased: the bunny is as it was
    page.fill("#region-name", "front")
    n = frame_no(page)
    page.click("#region-list li[data-region='belly'] .region-rename")
    page.wait_for_function("() => document.querySelector(\"#region-list li[data-region='front']\") !== null",
                           timeout=30_000)
    page.click("#region-list li[data-region='front'] .region-erase")
    page.wait_for_function("() => document.querySelectorAll('#region-list li').length === 0", timeout=30_000)
    wait_new_frame(page, n)
    settle(page)
    assert np.abs(canvas_grid(page) - g0).mean() < 1.0
    assert not page.locator("#region-paint").is_checked()
    assert not errors, errors
    ctx.close()


def test_a_short_region_highlight_comes_back_in_parts(server, bunny_scene, browser, artifacts):
    """A white highlight painted as a region falls short in one part; without another action the
    studio receives its fit in parts: the status line says so ("in K parts"), the region is listed
    once, and the frame changes where the stroke was. Screenshot: test-artifacts/web-region-parts.png."""
    ctx, page, errors = _studio(server, bunny_scene, browser)
    page.fill("#region-name", "shine")
    page.check("#region-paint")
    _status_has(page, "no strokes")
    page.check("#tool-brush")
    page.select_option("#brush-mode", "color")          # the default white
    page.fill("#brush-diameter", "30")
    b = page.locator("#view").bounding_box()
    drag(page, b["x"] + 0.42 * b["width"], b["y"] + 0.45 * b["height"], 0.14 * b["width"], 0, steps=10)
    _status_has(page, "region “shine”")
    _status_has(page, "parts (one BRDF each)", timeout=120_000)
    n = frame_no(page)
    _still(page, n - 1)
    page.screenshot(path=str(artifacts / "web-region-parts.png"))
    assert _regions(page) == ["shine"]
    text = page.locator("#status").text_content()
    assert "achieved" in text and "fitting it in parts" not in text, text
    assert not errors, errors
    ctx.close()
