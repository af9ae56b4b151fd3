"""A first start: the studio shows the precomputation's first look (worker/renderers/cuts/
preview.py) while the demo scene precomputes, then the session's frames; the first look is
close to the final frame. The demo is the bunny here, with ``preview_min_vertices`` 0 (the
default draws it for scenes from 8000 vertices: the bunny has 2826 and precomputes in seconds)."""
import io
import json

import httpx
import numpy as np
from PIL import Image

from helpers import GlintServer, scene_file

CANVAS_RGB = """() => {
  const c = document.getElementById('view'), d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  let s = 0, s2 = 0, n = 0;
  for (let k = 0; k < d.length; k += 4 * 97) { const v = (d[k] + d[k + 1] + d[k + 2]) / 765; s += v; s2 += v * v; n++; }
  return Math.sqrt(Math.max(0, s2 / n - (s / n) ** 2));
}"""


def _png(c, body):
    r = c.post("/v1/renders", json=body)
    assert r.status_code == 200, r.text
    return np.asarray(Image.open(io.BytesIO(r.content)).convert("RGB"), np.float64) / 255


def test_the_studio_shows_a_first_look_while_the_demo_precomputes(tmp_path, shared_assets, browser, artifacts):
    spec = json.loads(scene_file("bunny.json").read_text())
    spec["environment"]["map"] = str(shared_assets / "env" / "sunset.exr")
    spec["objects"][0]["mesh"] = str(shared_assets / "meshes" / "bunny.ply")
    demo = tmp_path / "demo.json"
    demo.write_text(json.dumps(spec))
    srv = GlintServer(tmp_path / "data", workers=1, demo=True,
                      env={"GLINT_PREVIEW_MIN_VERTICES": "0", "GLINT_DEMO_SCENE": str(demo)})
    errors: list[str] = []
    try:
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(srv.base + "/")
        # the first look comes while the precomputation runs, before any frame of a session
        page.wait_for_function("() => document.getElementById('view').dataset.preview === '1'", timeout=60_000)
        assert page.evaluate("() => document.getElementById('view').dataset.frame") is None
        assert "first look" in page.locator("#status").inner_text()
        spread = page.evaluate(CANVAS_RGB)
        page.screenshot(path=str(artifacts / "web-first-look-1-preview.png"))
        assert spread > 0.02, f"the first look on the canvas is flat (spread {spread:.3f})"
        with httpx.Client(base_url=srv.base, timeout=120) as c:
            st = c.get("/v1/status").json()["demo"]
            assert st["state"] == "precomputing" and st["preview"], st
        # then the demo opens by itself and its frames replace the first look
        page.wait_for_function("() => document.getElementById('view').dataset.frame !== undefined", timeout=300_000)
        page.wait_for_function("() => document.getElementById('view').dataset.preview === undefined", timeout=10_000)
        page.screenshot(path=str(artifacts / "web-first-look-2-frame.png"))
        page.close()
        with httpx.Client(base_url=srv.base, timeout=120) as c:
            sid = c.get("/v1/status").json()["demo"]["scene_id"]
            p = c.get(f"/v1/scenes/{sid}").json()["precomputation"]
            assert p["status"] == "done", p
            info, cam = p["stats"]["preview"], spec["camera"]
            # the coarse tree: at most 256 rays per vertex (the full precomputation traces up to 32 768)
            assert 0 < info["rays"] <= 256 * p["stats"]["vertices"], info
            assert (info["width"], info["height"]) == (cam["width"], cam["height"]), info
            r = c.get(f"/v1/precomputations/{p['id']}/preview")
            assert r.status_code == 200 and r.headers["content-type"] == "image/jpeg", r.text
            first = np.asarray(Image.open(io.BytesIO(r.content)).convert("RGB"), np.float64) / 255
            # against the final frame, on the object's pixels (where a black bunny differs from it)
            final = _png(c, {"scene_id": sid})
            black = _png(c, {"scene_id": sid, "materials": {"bunny": {"model": "lambert", "albedo": [0, 0, 0]}}})
    finally:
        srv.stop()
    assert not errors, errors
    obj = np.abs(final - black).max(axis=2) > 0.05
    assert obj.mean() > 0.05, f"the bunny covers {obj.mean():.1%} of the frame"
    mean_err = abs(first[obj].mean() - final[obj].mean()) / final[obj].mean()
    pix_err = np.abs(first[obj] - final[obj]).mean() / final[obj].mean()
    print(f"first look: {info}; precomputation {p['stats']['seconds']:.1f} s; against the final frame "
          f"mean {mean_err:.2%}, per pixel {pix_err:.2%}")
    assert mean_err < 0.03 and pix_err < 0.06, (f"first look vs final frame over {obj.sum()} object pixels: "
                                               f"mean {mean_err:.1%} (bound 3%), per pixel {pix_err:.1%} (bound 6%)")
