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
    assert "camera.eye" in msg and "objects.0.material.alpha" in msg
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
    assert bunny.vertices.shape == (2882, 3)      # 2826 in the file, 56 split at creases
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


# --- meshes of every supported kind, with and without normals (written here, not shipped) ---------
_TV = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], np.float64)
_TF = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 4], [1, 4, 3], [2, 3, 4]], np.int64)
# deliberately not what any normal estimator would give, so file normals are recognisable
_TN = np.array([[0, 0, 1], [0, 1, 0], [1, 0, 0], [0.6, 0.8, 0], [0, 0.6, -0.8]], np.float64)


def _ply(path, normals: bool, binary: bool):
    m = trimesh.Trimesh(_TV, _TF, vertex_normals=_TN if normals else None, process=False)
    path.write_bytes(m.export(file_type="ply", encoding="binary" if binary else "ascii", vertex_normal=normals))


def _obj(path, normals: bool):
    lines = [f"v {x} {y} {z}" for x, y, z in _TV]
    if normals:
        lines += [f"vn {x} {y} {z}" for x, y, z in _TN]
        lines += ["f " + " ".join(f"{i + 1}//{i + 1}" for i in f) for f in _TF]
    else:
        lines += ["f " + " ".join(str(i + 1) for i in f) for f in _TF]
    path.write_text("\n".join(lines) + "\n")


def _gltf(path, normals: bool, rotate_y_deg: float = 0.0):
    m = trimesh.Trimesh(_TV, _TF, vertex_normals=_TN if normals else None, process=False)
    s = trimesh.Scene()
    s.add_geometry(m, transform=trimesh.transformations.rotation_matrix(np.radians(rotate_y_deg), [0, 1, 0]))
    if path.suffix == ".glb":
        path.write_bytes(s.export(file_type="glb", include_normals=normals))
    else:
        files = s.export(file_type="gltf", include_normals=normals)   # {name: bytes}, buffers beside
        for name, data in files.items():
            (path.parent / ("x.gltf" if name.endswith(".gltf") else name)).write_bytes(data)


@pytest.mark.parametrize("kind", ["ply-ascii", "ply-binary", "obj", "glb", "gltf", "stl"])
@pytest.mark.parametrize("with_normals", [True, False])
def test_every_mesh_format_with_and_without_normals(tmp_path, kind, with_normals):
    """File normals are used (normalised, copied: trimesh's arrays are read-only) when the file
    has them; otherwise area-weighted face normals of each vertex's smooth wedge, the vertex split
    at creases (worker/creases.py, docs/design/conventions.md). A glTF node rotation applies to
    positions and normals alike."""
    from worker.creases import split_creases

    if kind == "stl" and with_normals:
        pytest.skip("STL stores face normals only")
    ext = {"ply-ascii": "ply", "ply-binary": "ply"}.get(kind, kind)
    path = tmp_path / f"x.{ext}"
    rot = 90.0 if kind in ("glb", "gltf") else 0.0
    if kind.startswith("ply"):
        _ply(path, with_normals, kind.endswith("binary"))
    elif kind == "obj":
        _obj(path, with_normals)
    elif kind in ("glb", "gltf"):
        _gltf(path, with_normals, rot)
    else:
        path.write_bytes(trimesh.Trimesh(_TV, _TF, process=False).export(file_type="stl"))
    m = load_mesh(path)
    R = trimesh.transformations.rotation_matrix(np.radians(rot), [0, 1, 0])[:3, :3]
    assert np.all(np.isfinite(m.normals)) and np.allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-5)
    if kind == "stl":       # STL repeats vertices per face: compare per position
        assert len(m.faces) == len(_TF)
        return
    if with_normals:
        assert np.allclose(m.vertices, _TV @ R.T, atol=1e-5), f"{kind}: positions"
        want = (_TN / np.linalg.norm(_TN, axis=1, keepdims=True)) @ R.T
    else:       # no normals in the file: split at creases, each copy with its wedge's normal
        v, _, n, _, _ = split_creases(_TV, _TF)
        assert np.allclose(m.vertices, v @ R.T, atol=1e-5), f"{kind}: positions"
        want = n @ R.T
    assert np.allclose(m.normals, want, atol=1e-4), f"{kind}: normals\n{m.normals}\nwant\n{want}"


def test_file_normals_of_zero_length_fall_back(tmp_path):
    """A file normal of zero length (an exporter's placeholder) gets the area-weighted normal."""
    from worker.scene import area_weighted_normals

    n = _TN.copy()
    n[2] = 0.0
    path = tmp_path / "z.ply"
    path.write_bytes(trimesh.Trimesh(_TV, _TF, vertex_normals=n, process=False).export(file_type="ply", vertex_normal=True))
    m = load_mesh(path)
    assert np.allclose(m.normals[2], area_weighted_normals(_TV, _TF)[2], atol=1e-5)
