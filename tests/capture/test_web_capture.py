"""The studio panel's browser-side helpers (web/js/capture.js), run in Node: the stored-zip
writer produces archives Python's zipfile reads with valid CRCs and the service's extractor
accepts, and the manifest it builds from the chosen photos drives a real capture."""
from __future__ import annotations

import json
import shutil
import subprocess
import zipfile
from pathlib import Path

import pytest

from worker.capture.job import extract_capture_zip, run_capture

ROOT = Path(__file__).resolve().parents[2]
MODULE = ROOT / "web" / "js" / "capture.js"

SCRIPT = r"""
import { readFileSync, writeFileSync, readdirSync } from "node:fs";
import { join } from "node:path";
const m = await import(process.argv[2]);
const dir = process.argv[3], out = process.argv[4];
const names = readdirSync(dir).filter((n) => n.endsWith(".jpg"));
const shots = m.guessShots(names.map((n) => n.replace("shot0", "front").replace("shot1", "back")));
const photos = names.map((n) => ({ name: n, yaw_deg: shots[n.replace("shot0", "front").replace("shot1", "back")],
                                   exposure_s: null }));
const manifest = m.buildManifest(photos, { projection: "equidistant", fov_deg: "190" });
const entries = [{ name: "manifest.json", data: new TextEncoder().encode(JSON.stringify(manifest)) }];
for (const n of names) entries.push({ name: n, data: new Uint8Array(readFileSync(join(dir, n))) });
writeFileSync(out, m.zipStored(entries));
const checks = {
  crc_check: m.crc32(new TextEncoder().encode("123456789")),
  exposures: ["1/250", "0.004", "4ms", " 1/30 s", ""].map(m.parseExposure),
  bad: (() => { try { m.parseExposure("fast"); return null; } catch (e) { return e.message; } })(),
  traversal: (() => { try { m.zipStored([{ name: "../x", data: new Uint8Array(1) }]); return null; } catch (e) { return e.message; } })(),
  guess: m.guessShots(["IMG_2.jpg", "IMG_10.jpg", "IMG_1.jpg", "IMG_3.jpg"]),
  manifest,
};
console.log(JSON.stringify(checks));
"""


@pytest.fixture(scope="module")
def node():
    exe = shutil.which("node")
    if exe is None:
        pytest.fail("node is needed to test web/js/capture.js (apt-get install nodejs)")
    return exe


def test_browser_zip_runs_a_capture(node, captures, tmp_path):
    c = captures.get("city.exr", width=240, height=160, brackets=3, seed=9)
    script = tmp_path / "run.mjs"
    script.write_text(SCRIPT)
    out = tmp_path / "capture.zip"
    r = subprocess.run([node, script, MODULE.as_uri(), c["dir"], out], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    checks = json.loads(r.stdout)
    assert checks["crc_check"] == 0xCBF43926                     # the CRC-32 check value
    assert checks["exposures"] == [0.004, 0.004, 0.004, pytest.approx(1 / 30), None]
    assert "use seconds" in checks["bad"] and "bad file name" in checks["traversal"]
    assert checks["guess"] == {"IMG_1.jpg": 0, "IMG_2.jpg": 0, "IMG_3.jpg": 180, "IMG_10.jpg": 180}
    man = checks["manifest"]
    assert [s["yaw_deg"] for s in man["shots"]] == [0, 180] and man["fov_deg"] == 190
    assert all("exposure_s" not in im for s in man["shots"] for im in s["images"])

    with zipfile.ZipFile(out) as z:
        assert z.testzip() is None                               # every CRC matches
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_STORED}
        assert len(z.infolist()) == 7
    m = extract_capture_zip(out, tmp_path / "x", max_files=16, max_total_bytes=10 << 20)
    exr, png, stats = run_capture(m, width=256)
    assert stats["photos"] == 6 and stats["exposure_sources"] == ["exif"]
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(exr) > 1000


def test_panel_in_chromium(captures, tmp_path, artifacts):
    """The panel in Debian's Chromium: pick the photos, upload, follow the job, show the preview,
    Apply. The server's route is the lead's to write; here Playwright answers the REST contract
    (job.py's docstring) by running the real extract_capture_zip and run_capture on the uploaded
    bytes, so what is tested is the panel and the job functions, not a mock of the capture."""
    import io

    pw = pytest.importorskip("playwright.sync_api")
    from PIL import Image

    chromium = shutil.which("chromium") or "/usr/bin/chromium"
    c = captures.get("city.exr", width=240, height=160, brackets=3, seed=9)
    photos = sorted(str(p) for p in c["dir"].glob("*.jpg"))
    jobs, seen = {}, {}
    page_html = """<!doctype html><html><head><link rel="stylesheet" href="/web/css/app.css"></head><body>
      <div id="host"></div>
      <script type="module">
        import { api } from "/web/js/net.js";
        import { mountCapturePanel } from "/web/js/capture.js";
        mountCapturePanel(document.getElementById("host"), { api, onApply: (id) => { window.applied = id; } });
      </script></body></html>"""

    def handle(route, request):
        url = request.url.split("http://glint.test", 1)[1]
        if url == "/":
            return route.fulfill(status=200, content_type="text/html", body=page_html)
        if url.startswith("/web/"):
            f = ROOT / url.lstrip("/")
            ctype = "text/css" if f.suffix == ".css" else "text/javascript"
            return route.fulfill(status=200, content_type=ctype, body=f.read_bytes())
        if url == "/v1/captures" and request.method == "POST":
            seen["content_type"] = request.headers.get("content-type")
            jid = f"c{len(jobs) + 1}"
            m = extract_capture_zip(request.post_data_buffer, tmp_path / jid, max_files=32, max_total_bytes=64 << 20)
            seen["manifest"] = json.loads(m.read_text())
            exr, png, stats = run_capture(m, width=256)
            jobs[jid] = {"png": png, "stats": stats, "polls": 0}
            return route.fulfill(status=202, content_type="application/json",
                                 body=json.dumps({"id": jid, "status": "queued", "progress": 0}))
        if url.startswith("/v1/captures/"):
            jid, _, rest = url[len("/v1/captures/"):].partition("/")
            job = jobs[jid]
            if rest == "preview":
                return route.fulfill(status=200, content_type="image/png", body=job["png"])
            job["polls"] += 1                          # one "running" answer first, as a real job
            done = job["polls"] > 1
            body = {"id": jid, "status": "done" if done else "running", "progress": 1.0 if done else 0.5,
                    "message": "" if done else "stitching", "asset_id": "env-" + jid if done else None,
                    "stats": job["stats"] if done else None}
            return route.fulfill(status=200, content_type="application/json", body=json.dumps(body))
        return route.fulfill(status=404, body="")

    with pw.sync_playwright() as p:
        b = p.chromium.launch(executable_path=chromium, headless=True,
                              args=["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"])
        try:
            page = b.new_page()
            errors = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.route("http://glint.test/**", handle)
            page.goto("http://glint.test/")
            page.set_input_files("input[type=file]", photos)
            assert page.locator("table.capture-files tr").count() == 1 + len(photos)
            page.locator("table.capture-files input").first.fill("1/250")      # one exposure typed
            page.get_by_text("Upload and stitch").click()
            page.wait_for_selector("img[alt='stitched environment map']:not(.hidden)", timeout=120_000)
            page.wait_for_function("() => document.querySelector('img').naturalWidth > 0")
            assert "done" in page.locator(".capture-panel").inner_text()
            page.get_by_text("Apply to the scene").click()
            assert page.evaluate("() => window.applied") == "env-c1"
            page.screenshot(path=str(artifacts / "web-capture-panel.png"), full_page=True)
        finally:
            b.close()
    assert not errors, errors
    assert seen["content_type"] == "application/zip"
    first = seen["manifest"]["shots"][0]["images"][0]
    assert first == {"file": "shot0_0.jpg", "exposure_s": 0.004}
    assert Image.open(io.BytesIO(jobs["c1"]["png"])).size == (256, 128)
