"""glint gi precompute / render / bench through the command line, on a small copy of the sofa
scene (tensors cached in tests/.cache/gi)."""
import json

import numpy as np
import pytest

from gi_harness import CACHE, SCENES
from worker.cli import main


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory, shared_assets):
    import helpers    # its scene_file fetches the scene's assets (this fixture has that name too)

    s = json.loads(helpers.scene_file("gi/sofa.json").read_text())
    for o in s["objects"]:
        o["mesh"] = str((SCENES / o["mesh"]).resolve())
    s["environment"]["map"] = str((SCENES / s["environment"]["map"]).resolve())
    s["camera"]["width"], s["camera"]["height"] = 32, 24
    s["gi"] = {"series": [64, 1, 1], "spp": 16}
    p = tmp_path_factory.mktemp("gi-cli") / "sofa.json"
    p.write_text(json.dumps(s))
    return p


def test_precompute_json(scene_file, capsys):
    assert main(["gi", "precompute", str(scene_file), "--store", str(CACHE), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for k in ("seconds", "pixels", "bounces", "series", "spp", "bytes", "bytes_per_bounce"):
        assert k in out, k
    assert out["bounces"] == 3 and out["series"] == [64, 1, 1] and out["spp"] == 16
    assert len(out["bytes_per_bounce"]) == 3 and out["bytes"] >= sum(out["bytes_per_bounce"])
    assert 0 < out["pixels"] <= 32 * 24
    # --series sets the bounces; --bounces pads or truncates the series
    assert main(["gi", "precompute", str(scene_file), "--store", str(CACHE), "--series", "64,1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["bounces"] == 2


def test_render_with_material_override(scene_file, tmp_path):
    mat = tmp_path / "glossy.json"
    mat.write_text(json.dumps({"model": "ggx", "alpha": 0.1, "specular": [0.8, 0.8, 0.8], "albedo": [0.05, 0.05, 0.05]}))
    base = ["gi", "render", str(scene_file), "--store", str(CACHE)]
    assert main(base + ["--out", str(tmp_path / "a.png"), "--raw", str(tmp_path / "a.npy")]) == 0
    assert main(base + ["--out", str(tmp_path / "b.png"), "--raw", str(tmp_path / "b.npy"), "--material", f"floor={mat}"]) == 0
    a, b = np.load(tmp_path / "a.npy"), np.load(tmp_path / "b.npy")
    assert a.shape == (24, 32, 3) and a.dtype == np.float32 and (tmp_path / "a.png").stat().st_size > 0
    assert np.abs(a - b).max() > 0.01 * a.max()          # the floor changed (and what it lights)
    assert main(base + ["--out", str(tmp_path / "c.png"), "--material", "side_wall=" + str(mat)]) == 2   # fixed
    assert main(base + ["--out", str(tmp_path / "c.png"), "--material", "nothing=" + str(mat)]) == 2
    assert main(base + ["--out", str(tmp_path / "c.png"), "--series", "64,3"]) == 2                     # 3 ∤ 64


def test_bench_json(scene_file, capsys):
    # the benchmark is the composed command's (bench/gi.py), not the renderer's
    from glint.cli import main as glint_main

    assert glint_main(["gi", "bench", str(scene_file), "--store", str(CACHE), "--object", "floor", "--frames", "3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for k in ("ms_freeze", "ms_per_frame", "fps", "width", "height"):
        assert k in out, k
    assert out["width"] == 32 and out["height"] == 24 and out["fps"] > 0 and out["live_pixels"] > 0


def test_fit_regions_and_render_them(scene_file, tmp_path, capsys):
    """glint fit --regions on a GI scene: a region made by the strokes and fitted through the
    tensors; glint gi render --material draws it (it drew the base before)."""
    from gi_harness import gi_renderer
    from worker.scene import load_scene

    sc = load_scene(scene_file)
    ids = gi_renderer(sc, dict(sc.spec.gi)).prim.object_id
    ys, xs = np.nonzero(ids == 0)
    y = float(np.median(ys)) + 0.5
    row = xs[np.abs(ys + 0.5 - y) < 1]
    x0, x1 = float(np.quantile(row, 0.3)) + 0.5, float(np.quantile(row, 0.7)) + 0.5
    strokes = tmp_path / "strokes.json"
    strokes.write_text(json.dumps({"version": 1, "fit_scale": 1.0, "strokes": [
        {"points": [[x0, y], [x1, y]], "mode": "scale", "scale": 0.4, "diameter": 3}]}))
    mat = tmp_path / "m.json"
    assert main(["fit", str(scene_file), "--object", "sofa", "--strokes", str(strokes), "--regions", "--region-name",
                 "seat", "--out", str(mat), "--cuts", str(CACHE), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["model"] == "regions" and res["regions"][0]["name"] == "seat", res
    assert res["achieved"] > 0.8 and res["spill_far"] < 0.05, res
    base = ["gi", "render", str(scene_file), "--store", str(CACHE)]
    assert main(base + ["--out", str(tmp_path / "a.png"), "--raw", str(tmp_path / "a.npy")]) == 0
    assert main(base + ["--out", str(tmp_path / "b.png"), "--raw", str(tmp_path / "b.npy"), "--material", f"sofa={mat}"]) == 0
    a, b = np.load(tmp_path / "a.npy"), np.load(tmp_path / "b.npy")
    changed = np.abs(b - a).max(axis=2) > 1e-3 * a.max()
    assert 0 < changed.sum() < 0.5 * (ids == 0).sum() and b[changed].mean() < 0.8 * a[changed].mean()
    assert not changed[ids != 0].any()          # the light off the region is the sofa's own (renderer.py)
    # traced into the tensors, the darkened region also sends less light on to the floor and walls
    assert main(base + ["--out", str(tmp_path / "c.png"), "--raw", str(tmp_path / "c.npy"), "--material", f"sofa={mat}",
                        "--trace-regions", f"sofa={mat}"]) == 0
    c = np.load(tmp_path / "c.npy")
    others = (ids >= 0) & (ids != 0)
    assert c[others].sum() < 0.999 * b[others].sum()
    assert np.abs(c - b)[ids == 0].mean() < 0.1 * b[ids == 0].mean()
    assert main(base + ["--out", str(tmp_path / "d.png"), "--trace-regions", "sofa=" + str(tmp_path / "none.json")]) == 2
