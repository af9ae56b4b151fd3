"""Crease-aware normals (worker/creases.py): a mesh file without normals gets one normal per
smooth wedge of faces around each vertex; smooth surfaces and files with their own normals are
left as they were."""
import numpy as np
import trimesh

from worker.creases import CREASE_DEG, split_creases
from worker.scene import area_weighted_normals, load_mesh


def _face_unit_normals(v, f):
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def test_a_box_without_normals_loads_with_flat_faces(tmp_path):
    """A box's 12 edges are 90° creases: each of its 8 corners becomes 3 vertices, and every
    face is shaded with its own normal (with one averaged normal per corner, each face was
    shaded as if it bulged, 55° off at its corners)."""
    box = trimesh.creation.box(extents=(2.0, 1.0, 3.0))
    path = tmp_path / "box.obj"
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in box.vertices) +
                    "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in box.faces))
    m = load_mesh(path)
    assert len(m.vertices) == 24 and len(m.faces) == 12
    fn = _face_unit_normals(m.vertices.astype(np.float64), m.faces)
    for k in range(3):
        np.testing.assert_allclose(m.normals[m.faces[:, k]], fn, atol=1e-6)
    rep = m.repair["creases"]
    assert rep["sharp_edges"] == 12 and rep["vertices_split"] == 16 and rep["crease_deg"] == CREASE_DEG
    # positions are kept: every copy sits on a corner of the box
    assert set(map(tuple, np.round(m.vertices, 6))) == set(map(tuple, np.round(box.vertices, 6)))


def test_a_smooth_mesh_keeps_its_vertices_and_normals():
    """No edge of a fine sphere is a crease: vertices, faces and the area-weighted normals are
    exactly those of the plain average (the split is a no-op, in the same order)."""
    s = trimesh.creation.icosphere(subdivisions=3)
    v, f, n, _, rep = split_creases(s.vertices, s.faces)
    assert rep["vertices_split"] == 0 and rep["sharp_edges"] == 0
    np.testing.assert_array_equal(f, s.faces)
    np.testing.assert_array_equal(v, s.vertices)
    np.testing.assert_allclose(n, area_weighted_normals(s.vertices, s.faces), atol=1e-12)


def test_a_sharp_edge_in_a_smooth_fan_splits_only_there():
    """Two smooth strips meeting at a 90° ridge: the ridge's vertices get one copy per side, the
    others stay shared, and the surface stays connected along each smooth strip."""
    # a folded sheet: x in [0, 2] on the floor (y = 0), then up the wall (x = 2, y in [0, 2])
    xs, zs = np.linspace(0, 2, 5), np.linspace(0, 1, 3)
    floor = [(x, 0.0, z) for x in xs for z in zs]
    wall = [(2.0, y, z) for y in xs[1:] for z in zs]
    v = np.array(floor + wall)
    idx = {tuple(p): i for i, p in enumerate(map(tuple, v))}
    f = []
    cols = [[(x, 0.0, z) for z in zs] for x in xs] + [[(2.0, y, z) for z in zs] for y in xs[1:]]
    for a, b in zip(cols[:-1], cols[1:]):
        for j in range(len(zs) - 1):
            f.append((idx[a[j]], idx[a[j + 1]], idx[b[j]]))
            f.append((idx[a[j + 1]], idx[b[j + 1]], idx[b[j]]))
    v2, f2, n2, _, rep = split_creases(v, np.array(f))
    assert rep["vertices_split"] == len(zs)          # the ridge's three vertices, one copy each
    assert rep["sharp_edges"] == len(zs) - 1                             # the ridge
    assert rep["open_edges"] == 2 * (len(cols) - 1) + 2 * (len(zs) - 1)   # the sheet's boundary
    up = np.abs(n2 @ np.array([0.0, 1.0, 0.0]))
    side = np.abs(n2 @ np.array([1.0, 0.0, 0.0]))
    # every vertex normal is the floor's or the wall's, none in between
    assert np.all((up > 1 - 1e-9) | (side > 1 - 1e-9))


def test_regions_painted_before_the_split_follow_the_copies(tmp_path):
    """A regions material painted on an object as it loaded before crease splitting (its
    vertex_count is the file's) keeps working: every copy of a vertex takes that vertex's
    weight, in the renderer's layers, in exports and in a new region's fit; a material painted
    on a mesh of any other size is still refused."""
    import pytest

    from worker.models import GGX, Lambert
    from worker.models.regions import Region, Regions, RegionsError, fit_mesh, layer_weights

    box = trimesh.creation.box()
    v, f, n, source, rep = split_creases(box.vertices, box.faces)
    assert len(v) == 24 and sorted(np.bincount(source)) == [3] * 8
    old = Regions(base=Lambert(albedo=(0.5, 0.5, 0.5)), vertex_count=8,
                  regions=[Region(name="corner", material=GGX(alpha=0.2), vertices=[0, 5], weights=[1.0, 0.25])])
    new = fit_mesh(old, 24, source)
    assert new.vertex_count == 24 and fit_mesh(old, 24, source) is new          # kept on the material
    w = new.regions[0].dense(24)
    np.testing.assert_allclose(w, np.where(source == 0, 1.0, np.where(source == 5, 0.25, 0.0)))
    _, a = layer_weights(old, 24, source)
    np.testing.assert_allclose(a[1], w)
    with pytest.raises(RegionsError, match="painted on a mesh of 8 vertices, but the object has 24"):
        layer_weights(old, 24)                       # no source: another mesh
    with pytest.raises(RegionsError):
        fit_mesh(old.model_copy(update={"vertex_count": 9}), 24, source)
