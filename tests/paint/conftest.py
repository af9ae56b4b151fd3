"""Fixtures of the paint tests: real HDRIs (tests/.cache/assets), brute-force references cached
content-addressed in tests/.cache/paint."""
import hashlib
from pathlib import Path

import numpy as np
import pytest
from helpers import cache_lock

ROOT = Path(__file__).resolve().parents[2]
CACHE = ROOT / "tests" / ".cache" / "paint"


@pytest.fixture(scope="session")
def assets():
    """helpers.AssetDir: ``assets / "env" / "sunset.exr"`` fetches that file on first use."""
    from helpers import AssetDir
    return AssetDir()


@pytest.fixture(scope="session")
def cached():
    """cached(name, key_parts, compute) -> np.ndarray (see _cached)."""
    return _cached


def _cached(name: str, key_parts, compute):
    """np.ndarray from tests/.cache/paint/<name>-<sha>.npy, computed once."""
    h = hashlib.sha256()
    for p in key_parts:
        h.update(np.ascontiguousarray(p).tobytes() if isinstance(p, np.ndarray) else repr(p).encode())
    path = CACHE / f"{name}-{h.hexdigest()[:20]}.npy"
    with cache_lock(str(path)):
        if path.is_file():
            return np.load(path)
        val = compute()
        CACHE.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npy")
        np.save(tmp, val)
        tmp.replace(path)
        return val
