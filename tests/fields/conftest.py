"""Fixtures for the cut-field tests: real meshes (bunny, table), a floor and a box of the tests'
own, fields traced on a coarse grid (TEST_GRID, 8 shells × 8² per face: a fresh clone traces
each in seconds; BENCHMARKS.md measures the default 24 × 24²), and scenes with a movable object.
Everything traced is cached content-addressed under tests/.cache/cuts, where the cut renderer's
precomputation finds the same fields by the same keys.

Ground truth everywhere is Embree ray tracing of the same meshes (worker.trace.embree)."""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from fields_kit import SceneKit, box_mesh
from helpers import cache_lock
from fields_kit import floor as _floor_mesh

from worker.artifacts import DirStore
from worker.core.directions import get_tree
from worker.renderers.cuts.field import Field, field_key, trace_field
from worker.renderers.cuts.grid import GridSpec
from worker.scene import load_mesh
from worker.trace.embree import Tracer

TEST_GRID = GridSpec(8, 8)


@pytest.fixture(scope="session")
def tree():
    return get_tree()


def cached_field(cache_dir, vertices, faces, spec: GridSpec) -> Field:
    """The field of a mesh, from tests/.cache/cuts/<content key> or traced and stored there."""
    store = DirStore(cache_dir, "cuts")
    key = field_key(vertices, faces, spec, get_tree().height)
    with cache_lock("field", key):
        blob = store.get(key)
        if blob is not None:
            try:
                return Field.decode(blob)
            except ValueError:
                store.discard(key)
        f = trace_field(vertices, faces, spec, key=key)
        store.put(key, f.encode())
        return f


class MeshCase:
    def __init__(self, path, spec, cache_dir):
        m = load_mesh(path)
        self.vertices, self.faces, self.normals = m.vertices, m.faces, m.normals
        self.field = cached_field(cache_dir, m.vertices, m.faces, spec).attach(m.vertices, m.faces)
        self.tracer = Tracer(m.vertices, m.faces)
        self.center, self.radius = self.field.grid.center, self.field.grid.radius


@pytest.fixture(scope="session")
def bunny_case(shared_assets, cache_dir):
    """Bunny (unit size, closed, 2,826 vertices) with the tests' field grid."""
    return MeshCase(shared_assets / "meshes" / "bunny.ply", TEST_GRID, cache_dir)


@pytest.fixture(scope="session")
def table_case(shared_assets, cache_dir):
    """table (cm, 784 vertices, a top on four legs and stretchers) with the tests' field grid."""
    return MeshCase(shared_assets / "meshes" / "table" / "table.obj", TEST_GRID, cache_dir)


@pytest.fixture(scope="session")
def trace_points():
    return _trace_points


@pytest.fixture(scope="session")
def floor_mesh():
    """floor(half, n, y=0) -> (vertices, faces): a square floor of side 2·half, n × n quads."""
    return _floor_mesh


def _trace_points(tracer, tree, points) -> np.ndarray:
    """(P, N) bool free directions from each point (P, 3), rays from the points themselves."""
    out = np.empty((len(points), tree.n_leaves), bool)
    for i, p in enumerate(np.asarray(points, np.float32)):
        out[i] = ~tracer.occluded(np.broadcast_to(p, (tree.n_leaves, 3)), tree.leaves)
    return out


@pytest.fixture(scope="session")
def room(shared_assets, tmp_path_factory):
    """cm: a 3 m floor of 10 cm quads, the ``table`` (static) and the bunny scaled to 72 cm
    standing on the floor in front of it (movable), under the sunset HDRI with the sun low
    behind; the tests' field grid; a 160 × 120 camera."""
    d = tmp_path_factory.mktemp("room")
    v, f = _floor_mesh(150.0, 30)
    trimesh.Trimesh(v, f, process=False).export(d / "floor.ply")
    bunny = load_mesh(shared_assets / "meshes" / "bunny.ply")
    lift = -40.0 * float(bunny.vertices[:, 1].min())
    m = shared_assets / "meshes"
    spec = {
        "version": 1,
        "environment": {"map": str(shared_assets / "env" / "sunset.exr"), "rotation_deg": 140.0},
        "camera": {"eye": [0, 180, 320], "target": [0, 30, 0], "fov_y_deg": 40, "width": 160, "height": 120},
        "cuts": {"field_grid": {"shells": TEST_GRID.shells, "face": TEST_GRID.face}},
        "objects": [
            {"name": "floor", "mesh": str(d / "floor.ply"), "material": {"model": "lambert", "albedo": [0.6, 0.6, 0.6]}},
            {"name": "table", "mesh": str(m / "table" / "table.obj"), "transform": {"translate": [-120, 0, -90]},
             "material": {"model": "ggx", "alpha": 0.3, "specular": [0.2, 0.2, 0.2], "albedo": [0.45, 0.3, 0.18]}},
            {"name": "bunny", "mesh": str(m / "bunny.ply"), "movable": True,
             "transform": {"scale": 40.0, "translate": [20.0, lift, 40.0]},
             "material": {"model": "ggx", "alpha": 0.3, "specular": [0.3, 0.3, 0.3], "albedo": [0.4, 0.4, 0.45]}},
        ],
    }
    return SceneKit(d, spec)


@pytest.fixture(scope="session")
def crate(tmp_path_factory, shared_assets):
    """A small, fast scene: a 2 m floor of 20 cm quads and a 40 × 30 × 50 cm box resting on it
    (movable), fields on a 4 × 4² grid: for the service and the renderer's bookkeeping."""
    d = tmp_path_factory.mktemp("crate")
    v, f = _floor_mesh(100.0, 10)
    trimesh.Trimesh(v, f, process=False).export(d / "floor.ply")
    bv, bf = box_mesh((40.0, 30.0, 50.0), 3)
    trimesh.Trimesh(bv, bf, process=False).export(d / "box.ply")
    spec = {
        "version": 1,
        "environment": {"map": str(shared_assets / "env" / "sunset.exr"), "rotation_deg": 140.0},
        "camera": {"eye": [0, 150, 250], "target": [0, 15, 0], "fov_y_deg": 40, "width": 320, "height": 240},
        "cuts": {"field_grid": {"shells": 4, "face": 4}},
        "objects": [
            {"name": "floor", "mesh": str(d / "floor.ply"), "material": {"model": "lambert", "albedo": [0.6, 0.6, 0.6]}},
            {"name": "box", "mesh": str(d / "box.ply"), "movable": True, "transform": {"translate": [-20.0, 15.0, 0.0]},
             "material": {"model": "lambert", "albedo": [0.7, 0.3, 0.2]}},
        ],
    }
    return SceneKit(d, spec)


@pytest.fixture(scope="session")
def crate_scene(crate, client, shared_assets):
    """Scene id of the crate scene (a floor and a movable box) uploaded and precomputed."""
    spec = json.loads(json.dumps(crate.spec))
    ids = {}
    for path in {spec["objects"][0]["mesh"], spec["objects"][1]["mesh"]}:
        r = client.post("/v1/assets/meshes", params={"filename": Path(path).name}, content=Path(path).read_bytes())
        assert r.status_code == 201, r.text
        ids[path] = r.json()["id"]
    env = client.post("/v1/assets/envmaps", params={"filename": "sunset.exr"},
                      content=(shared_assets / "env" / "sunset.exr").read_bytes())
    assert env.status_code == 201, env.text
    spec["environment"]["map"] = env.json()["id"]
    for o in spec["objects"]:
        o["mesh"] = ids[o["mesh"]]
    sc = client.post("/v1/scenes", json=spec, params={"name": "crate"})
    assert sc.status_code == 201, sc.text
    sid = sc.json()["id"]
    pre = client.post(f"/v1/scenes/{sid}/precompute")
    assert pre.status_code == 202, pre.text
    for _ in range(600):
        p = client.get(f"/v1/precomputations/{pre.json()['id']}").json()
        if p["status"] in ("done", "failed"):
            break
        time.sleep(0.5)
    assert p["status"] == "done", p
    return sid
