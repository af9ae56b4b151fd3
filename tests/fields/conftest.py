"""Fixtures for the cut-field tests: real meshes (bunny, table, oakTable), fields traced once and
cached content-addressed under tests/.cache/fields (first run: about a minute), a floor.

Ground truth everywhere is Embree ray tracing of the same meshes (worker.trace.embree)."""
from __future__ import annotations

import numpy as np
import pytest

from worker.core.directions import get_tree
from worker.renderers.cuts.field import Field, field_key, trace_field
from worker.renderers.cuts.grid import GridSpec
from worker.scene import load_mesh
from worker.trace.embree import Tracer


@pytest.fixture(scope="session")
def tree():
    return get_tree()


def cached_field(cache_dir, vertices, faces, spec: GridSpec) -> Field:
    """The field of a mesh, from tests/.cache/fields/<content key> or traced and stored."""
    key = field_key(vertices, faces, spec, get_tree().height)
    p = cache_dir / "fields" / key
    if p.is_file():
        try:
            return Field.decode(p.read_bytes())
        except ValueError:
            p.unlink()
    f = trace_field(vertices, faces, spec, key=key)
    p.parent.mkdir(parents=True, exist_ok=True)
    from worker.atomic import atomic_write

    atomic_write(p, f.encode())
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
    """Bunny (unit size, closed) with a small field: 8 shells × 8² per face."""
    return MeshCase(shared_assets / "meshes" / "bunny.ply", GridSpec(8, 8), cache_dir)


@pytest.fixture(scope="session")
def oaktable_case(shared_assets, cache_dir):
    """oakTable (cm) with a 16 × 16² field: dense enough for accuracy statistics."""
    return MeshCase(shared_assets / "meshes" / "oakTable" / "oakTable.obj", GridSpec(16, 16), cache_dir)


@pytest.fixture(scope="session")
def trace_points():
    return _trace_points


@pytest.fixture(scope="session")
def floor_mesh():
    return _floor_mesh


def _trace_points(tracer, tree, points) -> np.ndarray:
    """(P, N) bool free directions from each point (P, 3), rays from the points themselves."""
    out = np.empty((len(points), tree.n_leaves), bool)
    for i, p in enumerate(np.asarray(points, np.float32)):
        out[i] = ~tracer.occluded(np.broadcast_to(p, (tree.n_leaves, 3)), tree.leaves)
    return out


def _floor_mesh(half: float, n: int, y: float = 0.0):
    """A square floor of side 2·half at height y, n × n quads (vertices (n+1)², normals +Y)."""
    g = np.linspace(-half, half, n + 1)
    x, z = np.meshgrid(g, g, indexing="ij")
    v = np.stack([x.ravel(), np.full(x.size, y), z.ravel()], 1).astype(np.float32)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + n + 1, i.ravel() + n + 2
    f = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int32)
    return v, f
