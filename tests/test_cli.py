"""The glint command line, run as a user would (subprocess)."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SCENE = str(ROOT / "tests" / "scenes" / "bunny.json")


def glint(*args, check=True):
    r = subprocess.run([sys.executable, "-m", "glint", *args], capture_output=True, text=True, cwd=ROOT, timeout=600)
    if check:
        assert r.returncode == 0, r.stderr
    return r


def test_precompute_render_bench(tmp_path, cache_dir, bunny):
    out = json.loads(glint("precompute", SCENE, "--out", str(cache_dir), "--json").stdout)
    for k in ("seconds", "vertices", "directions", "mean_cut_size", "bytes_height_raw", "bytes_index_raw",
              "bytes_height_deflated", "bytes_index_deflated", "saving_raw", "saving_deflated"):
        assert k in out
    assert out["vertices"] == 2882 and out["directions"] == 32768
    # like against like: 4-bit heights beat 16-bit indices raw by ~1.5 of 3 bytes a node; deflated,
    # the bunny's cuts are 33% smaller (README: cut storage); both must hold on any mesh
    assert out["saving_raw"] > 0.45, out
    assert out["saving_deflated"] > 0.2, out
    png, raw = tmp_path / "b.png", tmp_path / "b.npy"
    glint("render", SCENE, "--out", str(png), "--raw", str(raw), "--cuts", str(cache_dir))
    img = np.load(raw)
    assert img.shape == (120, 160, 3) and img.dtype == np.float32 and img.max() > 0
    from PIL import Image
    assert Image.open(png).size == (160, 120)
    b = json.loads(glint("bench", "render", SCENE, "--frames", "4", "--json", "--cuts", str(cache_dir)).stdout)
    for k in ("ms_per_frame", "fps", "width", "height", "vertices", "ms_per_frame_drag", "fps_drag", "width_drag",
              "tau", "tau_drag", "refined_samples"):
        assert k in b
    assert b["width"] == 160 and b["width_drag"] == 160 and b["tau_drag"] == 16.0   # 160 px: no half resolution
    aa = json.loads(glint("bench", "antialias", SCENE, "--views", "1", "--width", "160", "--height", "120", "--json",
                          "--cuts", str(cache_dir)).stdout)["samplings"]
    # edge sampling: nearly four samples' error at a fraction of their pixels
    assert aa["4-edges"]["rel_rmse_pct"] < 0.6 * aa["1-full"]["rel_rmse_pct"], aa
    assert aa["4-edges"]["rel_rmse_pct"] < 1.2 * aa["4-full"]["rel_rmse_pct"], aa
    assert 0 < aa["4-edges"]["edge_pixels"] < 0.25 * 160 * 120, aa


def test_bad_scene_is_a_clear_error(tmp_path):
    p = tmp_path / "s.json"
    p.write_text(json.dumps({"version": 1, "environment": {"map": "x.exr"}, "camera": {"eye": "up", "target": [0, 0, 0]}, "objects": []}))
    r = glint("render", str(p), "--out", str(tmp_path / "x.png"), check=False)
    assert r.returncode == 2
    assert "camera.eye" in r.stderr and "objects" in r.stderr and "Traceback" not in r.stderr


def test_fit_to_a_target_and_render_it(tmp_path, cache_dir, bunny):
    """glint fit --target (a GGX render) writes an srbf material that glint render accepts."""
    scene = json.loads(Path(SCENE).read_text())
    scene["objects"][0]["material"] = {"model": "ggx", "alpha": 0.3, "specular": [0.5, 0.5, 0.5], "albedo": [0.3, 0.3, 0.3]}
    for o in scene["objects"]:
        o["mesh"] = str((ROOT / "tests" / "scenes" / o["mesh"]).resolve())
    scene["environment"]["map"] = str((ROOT / "tests" / "scenes" / scene["environment"]["map"]).resolve())
    ggx = tmp_path / "ggx.json"
    ggx.write_text(json.dumps(scene))
    target = tmp_path / "target.npy"
    glint("render", str(ggx), "--out", str(tmp_path / "t.png"), "--raw", str(target), "--cuts", str(cache_dir), "--per-pixel")
    mat = tmp_path / "material.json"
    res = json.loads(glint("fit", SCENE, "--object", "bunny", "--target", str(target), "--out", str(mat),
                           "--fit-scale", "0.5", "--cuts", str(cache_dir), "--json").stdout)
    for k in ("seconds_transfer", "seconds_solve", "pixels", "basis", "residual_rms", "energy_max"):
        assert k in res
    from worker.fit.basis import default_basis, outgoing_directions
    J = default_basis().J
    assert res["basis"] == J and res["pixels"] > 1000 and res["constrained"]
    # ρ_d is the scene material's (Lambert 0.7), not the target's 0.3: a poor fit, but a valid one
    assert res["energy_max"] <= res["energy_bound"] + 1e-7
    m = json.loads(mat.read_text())
    assert m["model"] == "srbf" and len(m["coefficients"]) == J
    raw = tmp_path / "again.npy"
    glint("render", SCENE, "--material", f"bunny={mat}", "--out", str(tmp_path / "a.png"), "--raw", str(raw), "--cuts", str(cache_dir))
    assert np.load(raw).max() > 0
    b = json.loads(glint("bench", "fit", SCENE, "--fit-scale", "1", "--repeat", "2", "--json", "--cuts", str(cache_dir)).stdout)
    assert b["ms_transfer"] > 0 and b["ms_solve"] > 0 and b["basis"] == J and b["energy_rows"] == len(outgoing_directions())


def test_fit_strokes_file_and_bad_input(tmp_path, cache_dir, bunny):
    strokes = tmp_path / "strokes.json"
    strokes.write_text(json.dumps({"version": 1, "albedo": [0.3, 0.3, 0.3], "fit_scale": 1.0, "strokes": [
        {"points": [[70, 60], [90, 62]], "color": [3, 3, 3], "diameter": 8},
        {"points": [[2, 2]], "color": [3, 3, 3], "diameter": 2}]}))
    mat = tmp_path / "m.json"
    r = glint("fit", SCENE, "--object", "bunny", "--strokes", str(strokes), "--out", str(mat), "--cuts", str(cache_dir), "--json")
    res = json.loads(r.stdout)
    assert res["painted"] > 0 and any("touches no pixel" in n for n in res["notes"])
    unc = json.loads(glint("fit", SCENE, "--object", "bunny", "--strokes", str(strokes), "--out", str(mat),
                           "--cuts", str(cache_dir), "--unconstrained", "--json").stdout)
    assert not unc["constrained"]
    # user errors: one clear line, exit 2, no traceback
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"strokes": [{"points": [[0, 0]], "diameter": "big"}]}))
    for args in (["--strokes", str(bad)], ["--strokes", str(tmp_path / "missing.json")],
                 ["--target", str(strokes)], ["--strokes", str(strokes), "--target", str(strokes)]):
        r = glint("fit", SCENE, "--object", "bunny", *args, "--out", str(mat), "--cuts", str(cache_dir), check=False)
        assert r.returncode == 2 and "Traceback" not in r.stderr and "error" in r.stderr, r.stderr
    r = glint("fit", SCENE, "--object", "teapot", "--strokes", str(strokes), "--out", str(mat), "--cuts", str(cache_dir), check=False)
    assert r.returncode == 2 and "teapot" in r.stderr


def test_fit_regions_and_render_them(tmp_path, cache_dir, bunny_renderer):
    """glint fit --regions writes a regions material and reports what the strokes got; glint
    render --material draws it; a material painted on another mesh is refused."""
    strokes = tmp_path / "strokes.json"
    strokes.write_text(json.dumps({"version": 1, "fit_scale": 1.0, "strokes": [
        {"points": [[60, 60], [95, 64]], "mode": "scale", "scale": 0.3, "diameter": 12}]}))
    mat = tmp_path / "m.json"
    res = json.loads(glint("fit", SCENE, "--object", "bunny", "--strokes", str(strokes), "--regions", "--region-name",
                           "belly", "--out", str(mat), "--cuts", str(cache_dir), "--json").stdout)
    assert res["model"] == "regions" and res["regions"][0]["name"] == "belly" and res["regions"][0]["vertices"] > 20
    assert res["achieved"] > 0.8 and res["spill_far"] < 0.03 and res["spill"] < res["achieved"]
    m = json.loads(mat.read_text())
    assert m["model"] == "regions" and m["base"] == {"model": "lambert", "albedo": [0.7, 0.7, 0.7]}
    assert m["vertex_count"] == 2882 and m["regions"][0]["material"]["model"] == "srbf"
    from worker.renderers import FrameRequest

    sc = bunny_renderer.scene
    a = bunny_renderer.render(FrameRequest(camera=sc.spec.camera, materials=sc.materials)).radiance
    painted = tmp_path / "b.npy"
    glint("render", SCENE, "--out", str(tmp_path / "b.png"), "--raw", str(painted), "--material", f"bunny={mat}",
          "--cuts", str(cache_dir))
    b = np.load(painted)
    changed = np.abs(b - a).max(axis=2) > 1e-4
    # a darkening across the middle: a band changes, darker, most of the bunny does not
    assert 100 < changed.sum() < 0.3 * (a.max(axis=2) > 0).sum() and b[changed].mean() < a[changed].mean()
    # extending it from the command line: the region grows, one region still
    res2 = json.loads(glint("fit", SCENE, "--object", "bunny", "--strokes", str(strokes), "--regions", "--region-name",
                            "belly", "--base", str(mat), "--out", str(tmp_path / "m2.json"), "--cuts", str(cache_dir),
                            "--json").stdout)
    assert res2["regions"][0]["extended"] and res2["regions"][0]["vertices"] == res["regions"][0]["vertices"]
    m["vertex_count"] = 3000
    (tmp_path / "other.json").write_text(json.dumps(m))
    r = glint("render", SCENE, "--out", str(tmp_path / "c.png"), "--material", f"bunny={tmp_path / 'other.json'}",
              "--cuts", str(cache_dir), check=False)
    assert r.returncode == 2 and "3000 vertices, but the object has 2882" in r.stderr and "Traceback" not in r.stderr
    r = glint("fit", SCENE, "--object", "bunny", "--target", str(painted), "--regions", "--out", str(mat),
              "--cuts", str(cache_dir), check=False)
    assert r.returncode == 2 and "--regions goes with --strokes" in r.stderr
