"""Sample grid of a field: cube-map shells, trilinear stencils, C lookup against NumPy."""
from types import SimpleNamespace

import numpy as np
import pytest

from worker import native
from worker.native.kernels import kernels
from worker.renderers.cuts.combine import lookup
from worker.renderers.cuts.grid import (
    FieldGrid,
    GridSpec,
    cell_corners,
    face_directions,
    lookup_numpy,
)


@pytest.mark.parametrize("n", [1, 4, 24])
def test_cube_map_shell_has_6n2_plus_2_unit_points(n):
    d, table = face_directions(n)
    assert len(d) == 6 * n * n + 2
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert table.shape == (6, n + 1, n + 1) and set(np.unique(table)) == set(range(len(d)))
    # equi-angular: neighbouring points on a face are at most ~(π/2)/n apart
    if n > 1:
        step = np.degrees(np.arccos(np.clip((d[table[:, :-1, :]] * d[table[:, 1:, :]]).sum(-1), -1, 1)))
        assert step.max() < 90.0 / n * 1.25 and step.min() > 90.0 / n * 0.6


def test_stencil_reproduces_samples_and_interpolates_positions():
    g = FieldGrid(np.array([0.3, -1.0, 2.0]), 1.7, GridSpec(6, 5, 0.25, 8.0))
    cells, w, inside = lookup_numpy(g, g.positions())
    assert inside.all() and cells.min() >= 0 and cells.max() < g.n_cells
    ids = cell_corners(g, cells)
    assert np.array_equal(ids[np.arange(len(ids)), np.argmax(w, 1)], np.arange(g.n_samples))
    np.testing.assert_allclose(w.max(1), 1.0, atol=1e-6)
    rng = np.random.default_rng(0)
    x = g.center + rng.normal(size=(2000, 3)) * 4
    cells, w, inside = lookup_numpy(g, x)
    ids = cell_corners(g, cells)
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-6)
    assert (w >= 0).all()
    # the stencil's weighted sample positions lie near the point (within one cell)
    rho = np.linalg.norm(x - g.center, axis=1)
    ok = inside & (rho > g.radii[0])
    est = np.einsum("pk,pkc->pc", w, g.positions(ids.reshape(-1)).reshape(-1, 8, 3))
    rel = np.linalg.norm(est - x, axis=1)[ok] / rho[ok]
    cell = np.exp(g.log_q) - 1 + np.pi / 2 / g.spec.face
    assert rel.max() < cell, (rel.max(), cell)


@pytest.mark.skipif(not native.available(), reason="C kernels not built")
def test_c_lookup_agrees_with_numpy_including_culling():
    g = FieldGrid(np.array([10.0, 40.0, -5.0]), 60.0, GridSpec(24, 24))
    rng = np.random.default_rng(1)
    x = (g.center + rng.normal(size=(5000, 3)) * 250).astype(np.float32)
    n = rng.normal(size=(5000, 3)); n = (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(np.float32)
    a = np.radians(37.0)
    m = np.eye(4)
    m[:3, :3] = 1.2 * np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    m[:3, 3] = [30, -2, 11]
    clearance = rng.uniform(0, 300, g.n_samples).astype(np.float32)      # any values will do here
    f = SimpleNamespace(grid=g, clearance=clearance)
    i1, w1, t1 = lookup(f, m, x, n, kernels("native"))
    i2, w2, t2 = lookup(f, m, x, n, kernels("numpy"))
    assert np.array_equal(t1, t2) and 0 < np.count_nonzero(t1) < len(t1)
    culled = i2 < 0
    assert 0.05 < culled.mean() < 0.95          # both kinds of points occur
    assert np.array_equal(i1, i2)
    np.testing.assert_allclose(w1, w2, atol=1e-6)
    # culling: outside the outermost shell, or the bounding sphere below the horizon
    xl = x.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    nl = n.astype(np.float64) @ m[:3, :3].T
    nl /= np.linalg.norm(nl, axis=1, keepdims=True)
    expect = (np.linalg.norm(xl - g.center, axis=1) > g.radii[-1]) | ((nl * (g.center - xl)).sum(1) < -g.radius)
    assert np.array_equal(culled, expect)
