"""A precomputation's first look (worker/renderers/cuts/preview.py) is drawn only for scenes
from ``preview_min_vertices``: smaller ones precompute in seconds. The first look itself, in the
studio and through the API: tests/web/test_browser.py::test_studio_follows_the_demo_precomputation."""


def test_small_scenes_need_no_first_look(client, bunny_scene):
    pre = client.get(f"/v1/scenes/{bunny_scene}").json()["precomputation"]
    assert pre["stats"]["vertices"] < 8000 and "preview" not in pre["stats"], pre["stats"]
    r = client.get(f"/v1/precomputations/{pre['id']}/preview")
    assert r.status_code == 404 and "none was drawn" in r.json()["detail"], r.text
    missing = client.get("/v1/precomputations/nosuchid/preview")
    assert missing.status_code == 404 and "nosuchid" in missing.json()["detail"], missing.text
