"""The studio's export panel (web/js/export.js) in headless Chromium: a saved design exported as
a glTF variant downloads a .glb that the Khronos glTF-Validator accepts, and the panel shows the
approximation errors the server reported."""
import shutil

import pytest

from helpers import validate_gltf, wait_new_frame

pw = pytest.importorskip("playwright.sync_api")
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"


def test_studio_exports_a_glb_with_its_saved_designs(server, bunny_scene, artifacts, tmp_path):
    with pw.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True,
                              args=["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                                    "--disable-background-networking"])
        try:
            ctx = b.new_context(viewport={"width": 1280, "height": 860}, accept_downloads=True)
            page = ctx.new_page()
            errors = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(server["base"] + "/")
            wait_new_frame(page, 0)
            page.fill("#design-name", "export me")
            page.click("#save")
            page.wait_for_function("() => document.getElementById('status').textContent.includes('saved')",
                                   timeout=60_000)
            page.select_option("#export-format", "gltf")
            page.click("#export")
            link = page.locator("#export-link")
            link.wait_for(state="visible", timeout=180_000)
            assert link.inner_text().startswith("download ") and ".glb" in link.inner_text()
            assert "BRDF error" in page.locator("#export-report").inner_text()
            page.locator("#export-panel").scroll_into_view_if_needed()
            page.screenshot(path=str(artifacts / "web-export.png"))
            with page.expect_download() as dl:
                link.click()
            out = tmp_path / dl.value.suggested_filename
            dl.value.save_as(out)
            v = validate_gltf(out)
            assert v["issues"]["numErrors"] == 0, v["issues"]["messages"]
            assert "KHR_materials_variants" in v["info"]["extensionsUsed"]
            assert not errors, errors
        finally:
            b.close()
