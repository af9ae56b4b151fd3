"""``glint capture`` and ``glint capture-synth`` as a user runs them."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from PIL import Image

ROOT = Path(__file__).resolve().parents[2]


def _glint(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "worker.cli", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=300)


def test_capture_cli(tmp_path, shared_assets):
    r = _glint("capture-synth", shared_assets / "env" / "apartment.exr", "--out", tmp_path / "c", "--size", "300x200",
               "--brackets", "3", "--jitter", "1", "--json")
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert Path(info["manifest"]).is_file() and len(info["shutter_s"]) == 3
    r = _glint("capture", info["manifest"], "--out", tmp_path / "env.exr", "--preview", tmp_path / "p.png",
               "--width", "256", "--json")
    assert r.returncode == 0, r.stderr
    st = json.loads(r.stdout)
    for key in ("seconds", "dynamic_range_stops", "frame_pixels_removed", "response"):
        assert key in st, key
    assert st["width"] == 256 and st["height"] == 128 and st["photos"] == 6
    assert st["response"]["samples"] > 100 and len(st["response"]["gamma_rgb"]) == 3
    assert "capture" in r.stderr                                       # the progress bar
    assert Image.open(tmp_path / "p.png").size == (256, 128)
    assert (tmp_path / "env.exr").stat().st_size > 1000


def test_capture_cli_errors(tmp_path):
    m = tmp_path / "m.json"
    m.write_text(json.dumps({"version": 1, "projection": "orthographic", "fov_deg": 190,
                             "shots": [{"yaw_deg": 0, "images": [{"file": "a.jpg"}, {"file": "b.jpg"}]}]}))
    r = _glint("capture", m, "--out", tmp_path / "e.exr")
    assert r.returncode == 2
    assert "unknown projection 'orthographic'" in r.stderr
    assert not (tmp_path / "e.exr").exists()
    m.write_text(json.dumps({"version": 1, "projection": "equisolid", "fov_deg": 190,
                             "shots": [{"yaw_deg": 0, "images": [{"file": "a.jpg"}, {"file": "b.jpg"}]}]}))
    r = _glint("capture", m, "--out", tmp_path / "e.exr")
    assert r.returncode == 2 and "shots[0].images[0].file: 'a.jpg' not found" in r.stderr
