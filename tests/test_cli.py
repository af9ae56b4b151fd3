"""The glint command line, run as a user would (subprocess)."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SCENE = str(ROOT / "tests" / "scenes" / "bunny.json")


def glint(*args, check=True):
    r = subprocess.run([sys.executable, "-m", "worker.cli", *args], capture_output=True, text=True, cwd=ROOT, timeout=600)
    if check:
        assert r.returncode == 0, r.stderr
    return r


def test_precompute_render_bench(tmp_path, cache_dir, bunny):
    out = json.loads(glint("precompute", SCENE, "--out", str(cache_dir), "--json").stdout)
    for k in ("seconds", "vertices", "directions", "mean_cut_size", "bytes_height_encoded", "bytes_index_encoded"):
        assert k in out
    assert out["vertices"] == 2826 and out["directions"] == 32768
    assert out["bytes_height_encoded"] < out["bytes_index_encoded"]
    png, raw = tmp_path / "b.png", tmp_path / "b.npy"
    glint("render", SCENE, "--out", str(png), "--raw", str(raw), "--cuts", str(cache_dir))
    img = np.load(raw)
    assert img.shape == (120, 160, 3) and img.dtype == np.float32 and img.max() > 0
    from PIL import Image
    assert Image.open(png).size == (160, 120)
    b = json.loads(glint("bench", "render", SCENE, "--frames", "4", "--json", "--cuts", str(cache_dir)).stdout)
    for k in ("ms_per_frame", "fps", "width", "height", "vertices"):
        assert k in b
    assert b["width"] == 160 and b["fps"] > 0


def test_bad_scene_is_a_clear_error(tmp_path):
    p = tmp_path / "s.json"
    p.write_text(json.dumps({"version": 1, "environment": {"map": "x.exr"}, "camera": {"eye": "up", "target": [0, 0, 0]}, "objects": []}))
    r = glint("render", str(p), "--out", str(tmp_path / "x.png"), check=False)
    assert r.returncode == 2
    assert "camera.eye" in r.stderr and "objects" in r.stderr and "Traceback" not in r.stderr
