"""Precomputed parts in a data directory's blob store (worker.blobs.PartStore), and the folder of
parts several data directories on one machine share (Settings.shared_parts): a part one of them
computed is copied by the others, not computed again."""
import pytest
from helpers import scene_file


@pytest.fixture(scope="module")
def bunny_scene_loaded(shared_assets):
    from worker.scene import load_scene

    return load_scene(scene_file("bunny.json"))


def test_a_part_computed_by_one_data_directory_is_copied_by_another(tmp_path, bunny_scene_loaded, caplog):
    from worker.blobs import BlobStore, PartStore
    from worker.renderers import get
    from worker.renderers.base import ensure, load

    sc = bunny_scene_loaded
    _, pre = get("cuts")
    shared = tmp_path / "shared"
    first = PartStore(BlobStore(tmp_path / "a"), shared)
    done = ensure(pre, sc, first)
    assert done["computed"] == 1, done
    (key, info), = done["parts"].items()
    assert (shared / key).read_bytes() == first.get(key)         # written to the shared folder too

    second = PartStore(BlobStore(tmp_path / "b"), shared)
    again = ensure(pre, sc, second)
    assert again["computed"] == 0 and again["parts"][key]["cached"], again
    # the second directory has its own verified copy: its blob and key, the same bytes
    assert second.sha(key) == first.sha(key) and (tmp_path / "b" / "keys" / key).is_file()
    (shared / key).unlink()
    assert second.get(key) == first.get(key)
    assert load(pre, sc, second).cuts.n_vertices == len(sc.mesh.vertices)

    # without the shared folder a third directory does not have it
    alone = PartStore(BlobStore(tmp_path / "c"))
    assert alone.sha(key) is None

    # a shared folder that cannot be written (here a file stands where it should be) costs the
    # copy, not the part
    blocked = tmp_path / "blocked"
    blocked.write_text("not a folder")
    fourth = PartStore(BlobStore(tmp_path / "d"), blocked)
    fourth.put(key, first.get(key))
    assert fourth.get(key) == first.get(key) and "not written to the shared folder" in caplog.text
