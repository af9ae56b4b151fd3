"""Synthetic captures of real HDRIs (worker/capture/synth.py), cached content-addressed under
tests/.cache/capture: the key hashes the HDRI's bytes, the parameters and the generator's
source, so a change to any of them makes a new capture."""
from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import cache_lock

ROOT = Path(__file__).resolve().parents[2]
CAPTURE_SRC = ROOT / "worker" / "capture"


def load_small_hdri(name: str) -> np.ndarray:
    """A test HDRI (tests/.cache/assets/env, fetched on first use) at 512×256 (area-averaged when larger)."""
    import cv2

    from worker.envmap import load_envmap

    from helpers import asset_file

    env = load_envmap(asset_file(f"env/{name}"))
    if env.shape[1] != 512:
        env = cv2.resize(env, (512, 256), interpolation=cv2.INTER_AREA)
    return env


class Captures:
    def __init__(self, cache: Path):
        self.cache = cache / "capture"

    def get(self, hdri: str, **params) -> dict:
        """Folder of a synthetic capture: {'dir', 'manifest', 'frame' (bool mask), 'truth'}."""
        from PIL import Image

        from worker.capture.synth import synthesize

        h = hashlib.sha256()
        from helpers import asset_file

        h.update(asset_file(f"env/{hdri}").read_bytes())
        h.update(json.dumps(params, sort_keys=True).encode())
        for f in ("synth.py", "fisheye.py"):
            h.update((CAPTURE_SRC / f).read_bytes())
        d = self.cache / f"{Path(hdri).stem}-{h.hexdigest()[:16]}"
        with cache_lock(str(d)):
            if not (d / "truth.json").is_file():
                tmp = d.with_name(d.name + ".tmp")
                shutil.rmtree(tmp, ignore_errors=True)
                synthesize(load_small_hdri(hdri), tmp, **params)
                shutil.rmtree(d, ignore_errors=True)
                tmp.rename(d)
        return {"dir": d, "manifest": d / "manifest.json", "frame": np.asarray(Image.open(d / "frame.png")) > 0,
                "truth": json.loads((d / "truth.json").read_text())}


@pytest.fixture(scope="session")
def captures(cache_dir) -> Captures:
    return Captures(cache_dir)


@pytest.fixture(scope="session")
def small_hdri():
    """load_small_hdri(name) -> (256, 512, 3) float32 radiance."""
    return load_small_hdri
