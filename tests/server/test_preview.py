"""A precomputation's first look (worker/renderers/cuts/preview.py): drawn at its start from 256
directions per vertex for scenes above ``preview_min_vertices``, served while it runs and after,
and close to the final frame."""
import io
import json
import time
from pathlib import Path

import httpx
import numpy as np
from PIL import Image

from helpers import GlintServer

ROOT = Path(__file__).resolve().parents[2]


def _png(c, body):
    r = c.post("/v1/renders", json=body)
    assert r.status_code == 200, r.text
    return np.asarray(Image.open(io.BytesIO(r.content)).convert("RGB"), np.float64) / 255


def test_small_scenes_need_no_first_look(client, bunny_scene):
    pre = client.get(f"/v1/scenes/{bunny_scene}").json()["precomputation"]
    assert pre["stats"]["vertices"] < 8000 and "preview" not in pre["stats"], pre["stats"]
    r = client.get(f"/v1/precomputations/{pre['id']}/preview")
    assert r.status_code == 404 and "none was drawn" in r.json()["detail"], r.text
    missing = client.get("/v1/precomputations/nosuchid/preview")
    assert missing.status_code == 404 and "nosuchid" in missing.json()["detail"], missing.text


def test_the_first_look_is_the_scene_from_few_directions(tmp_path, shared_assets):
    srv = GlintServer(tmp_path, workers=1, env={"GLINT_PREVIEW_MIN_VERTICES": "0"})
    try:
        c = httpx.Client(base_url=srv.base, timeout=120)
        ids = {}
        for kind, name in (("meshes", "bunny.ply"), ("envmaps", "sunset.exr")):
            sub = "meshes" if kind == "meshes" else "env"
            r = c.post(f"/v1/assets/{kind}", params={"filename": name}, content=(shared_assets / sub / name).read_bytes())
            assert r.status_code == 201, r.text
            ids[kind] = r.json()["id"]
        spec = json.loads((ROOT / "tests" / "scenes" / "bunny.json").read_text())
        spec["environment"]["map"], spec["objects"][0]["mesh"] = ids["envmaps"], ids["meshes"]
        sid = c.post("/v1/scenes", json=spec).json()["id"]
        pid = c.post(f"/v1/scenes/{sid}/precompute").json()["id"]
        first_seen = None
        for _ in range(600):
            p = c.get(f"/v1/precomputations/{pid}").json()
            if first_seen is None and "preview" in p["stats"]:
                first_seen = p["status"]
            if p["status"] in ("done", "failed"):
                break
            time.sleep(0.2)
        assert p["status"] == "done", p
        # shown while the precomputation runs, not only after it
        assert first_seen in ("queued", "running"), first_seen
        info, cam = p["stats"]["preview"], spec["camera"]
        # the coarse tree: at most 256 rays per vertex (the full precomputation traces up to 32 768)
        assert 0 < info["rays"] <= 256 * p["stats"]["vertices"], info
        assert (info["width"], info["height"]) == (cam["width"], cam["height"]), info
        r = c.get(f"/v1/precomputations/{pid}/preview")
        assert r.status_code == 200, r.text
        assert r.headers["content-type"] == "image/jpeg"
        first = np.asarray(Image.open(io.BytesIO(r.content)).convert("RGB"), np.float64) / 255
        # against the final frame, on the object's pixels (where a black bunny differs from it)
        final = _png(c, {"scene_id": sid})
        black = _png(c, {"scene_id": sid, "materials": {"bunny": {"model": "lambert", "albedo": [0, 0, 0]}}})
        c.close()
    finally:
        srv.stop()
    obj = np.abs(final - black).max(axis=2) > 0.05
    assert obj.mean() > 0.05, f"the bunny covers {obj.mean():.1%} of the frame"
    mean_err = abs(first[obj].mean() - final[obj].mean()) / final[obj].mean()
    pix_err = np.abs(first[obj] - final[obj]).mean() / final[obj].mean()
    print(f"first look: {info}; precomputation {p['stats']['seconds']:.1f} s; against the final frame "
          f"mean {mean_err:.2%}, per pixel {pix_err:.2%}")
    assert mean_err < 0.03 and pix_err < 0.06, (f"first look vs final frame over {obj.sum()} object pixels: "
                                               f"mean {mean_err:.1%} (bound 3%), per pixel {pix_err:.1%} (bound 6%)")
