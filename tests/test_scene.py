import json

import numpy as np
import pytest
import trimesh

from worker.scene import SceneError, Transform, load_mesh, load_scene, parse_scene


def test_bad_fields_are_named():
    with pytest.raises(SceneError) as e:
        parse_scene({"version": 1, "environment": {"map": "x.exr"}, "camera": {"eye": [0, 0], "target": [0, 0, 0]},
                     "objects": [{"name": "a", "mesh": "m.obj", "material": {"model": "ggx", "alpha": -1}}]})
    msg = str(e.value)
    assert "camera.eye" in msg and "objects.0.material.ggx.alpha" in msg
    with pytest.raises(SceneError, match="unique"):
        parse_scene({"environment": {"map": "x"}, "camera": {"eye": [0, 0, 1], "target": [0, 0, 0]},
                     "objects": [{"name": "a", "mesh": "m"}, {"name": "a", "mesh": "m"}]})


def test_missing_files_and_bad_json(tmp_path):
    p = tmp_path / "s.json"
    p.write_text("{not json")
    with pytest.raises(SceneError, match="not valid JSON"):
        load_scene(p)
    p.write_text(json.dumps({"version": 1, "environment": {"map": "none.exr"}, "camera": {"eye": [0, 0, 1], "target": [0, 0, 0]},
                             "objects": [{"name": "a", "mesh": "none.obj"}]}))
    with pytest.raises(SceneError, match=r"objects\[0\].*none.obj.*not found"):
        load_scene(p)
    (tmp_path / "fake.obj").write_bytes(b"\x89PNG this is not a mesh")
    with pytest.raises(SceneError, match="fake.obj"):
        load_mesh(tmp_path / "fake.obj")


def test_nan_environment_rejected(tmp_path):
    from worker.envmap import EnvMapError, load_envmap, save_exr

    img = np.ones((8, 16, 3), np.float32)
    img[2, 3, 1] = np.nan
    save_exr(tmp_path / "bad.exr", img)
    with pytest.raises(EnvMapError, match="NaN"):
        load_envmap(tmp_path / "bad.exr")


def test_real_formats_load(shared_assets, tmp_path):
    box = load_mesh(shared_assets / "meshes" / "cornell-box.obj")           # OBJ with groups
    assert len(box.faces) >= 32
    bunny = load_mesh(shared_assets / "meshes" / "bunny.ply")
    assert bunny.vertices.shape == (2826, 3)
    tm = trimesh.Trimesh(bunny.vertices, bunny.faces, process=False)
    for ext in ("glb", "stl"):
        tm.export(tmp_path / f"b.{ext}")
        m = load_mesh(tmp_path / f"b.{ext}")
        assert len(m.faces) == len(bunny.faces)
        assert np.allclose(np.linalg.norm(m.normals, axis=1), 1, atol=1e-5)
    from worker.envmap import load_envmap
    hdr = load_envmap(shared_assets / "env" / "stinson-beach.hdr")
    assert hdr.shape == (512, 1024, 3) and hdr.min() >= 0


def test_transform_order_scale_rotate_translate():
    m = Transform(scale=2.0, rotate_deg=(0, 90, 0), translate=(1, 0, 0)).matrix()
    p = m @ np.array([1.0, 0, 0, 1])
    # x=1 → scaled to 2 → rotated +90° about Y (x → -z) → translated by +x
    np.testing.assert_allclose(p[:3], [1, 0, -2], atol=1e-12)


def test_lobes_diffuse_is_albedo_and_old_files_load():
    """Every model names its diffuse weight ``albedo``; version 1 files that said ``diffuse`` for
    lobes still load, and dump the new name."""
    from worker.scene import Lobes

    old = Lobes.model_validate({"model": "lobes", "exponents": [10], "gloss": [0.1],
                                "directional_diffuse": [[0.1, 0.1, 0.1]], "diffuse": [0.2, 0.3, 0.4]})
    assert old.albedo == (0.2, 0.3, 0.4)
    assert "albedo" in old.model_dump() and "diffuse" not in old.model_dump()
    assert Lobes(exponents=[10], gloss=[0.1], directional_diffuse=[(0, 0, 0)], albedo=(0.5, 0.5, 0.5)).albedo == (0.5, 0.5, 0.5)
