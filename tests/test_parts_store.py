"""Precomputed parts in a data directory's blob store (worker.blobs.PartStore), and the folder of
parts several data directories on one machine share (Settings.shared_parts): a part one of them
computed is copied by the others, not computed again."""
import json

import pytest
from helpers import scene_file


@pytest.fixture(scope="module")
def small_scene(shared_assets, tmp_path_factory):
    """A subdivided icosahedron (162 vertices) beside the bunny under sunset: its cuts take
    about a second to trace."""
    import trimesh

    from worker.scene import load_scene

    folder = tmp_path_factory.mktemp("small")
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.4)
    mesh.apply_translation([0.5, 0.1, 0.0])
    mesh.export(folder / "ball.ply")
    spec = json.loads(scene_file("bunny.json").read_text())
    spec["environment"]["map"] = str(shared_assets / "env" / "sunset.exr")
    spec["objects"][0].update(name="ball", mesh=str(folder / "ball.ply"))
    (folder / "scene.json").write_text(json.dumps(spec))
    return load_scene(folder / "scene.json")


def test_a_part_computed_by_one_data_directory_is_copied_by_another(tmp_path, small_scene, caplog):
    from worker.blobs import BlobStore, PartStore
    from worker.renderers import get
    from worker.renderers.base import ensure, load

    sc = small_scene
    _, pre = get("cuts")
    shared = tmp_path / "shared"
    first = PartStore(BlobStore(tmp_path / "a"), shared)
    done = ensure(pre, sc, first)
    assert done["computed"] == 1, done
    (key, _), = done["parts"].items()
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
