"""Shared fixtures. Precomputed cuts are cached in tests/.cache (content-addressed by geometry),
so only the first run pays for tracing."""
import os
from pathlib import Path

import pytest

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "assets"
CACHE = ROOT / "tests" / ".cache"
ARTIFACTS = ROOT / "test-artifacts"


@pytest.fixture(scope="session")
def shared_assets() -> Path:
    if not SHARED.is_dir():
        pytest.fail(f"real test assets not found at {SHARED} (../shared/assets beside the repository)")
    return SHARED


@pytest.fixture(scope="session")
def cache_dir() -> Path:
    CACHE.mkdir(parents=True, exist_ok=True)
    return CACHE


@pytest.fixture(scope="session")
def artifacts() -> Path:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    return ARTIFACTS


@pytest.fixture(scope="session")
def bunny(shared_assets, cache_dir):
    """(LoadedScene, CutSet) of tests/scenes/bunny.json, cuts cached."""
    from worker.engine import load_or_precompute
    from worker.scene import load_scene

    scene = load_scene(ROOT / "tests" / "scenes" / "bunny.json")
    cuts, _, _ = load_or_precompute(scene, cache_dir)
    return scene, cuts
