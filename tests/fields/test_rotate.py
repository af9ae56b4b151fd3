"""Field cuts re-expressed over a rotated frame's leaves: the leaf map, C against NumPy, and
against ray tracing of the rotated mesh."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from worker.core.cuts import decode_to_leaves
from worker import native
from worker.native.kernels import kernels
from worker.renderers.cuts.combine import RotatedSamples
from worker.renderers.cuts.rotate import (
    LeafMap,
    coarse_cut_numpy,
    nearest_leaves,
    rotation_part,
)
from worker.trace.embree import Tracer


def rot_y(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def rot_x(deg):
    a = np.radians(deg)
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


def test_leaf_map_is_the_nearest_leaf(tree):
    assert np.array_equal(LeafMap(tree, np.eye(3)).perm, np.arange(tree.n_leaves))
    # through the cube-map table, the leaves themselves map to themselves
    assert np.array_equal(nearest_leaves(tree, tree.leaves), np.arange(tree.n_leaves))
    q = rot_y(33.0) @ rot_x(-20.0)
    lm = LeafMap(tree, q)
    src = tree.leaves.astype(np.float64) @ q                  # receiver leaves in the source frame
    _, exact = cKDTree(tree.leaves.astype(np.float64)).query(src)
    # the table plus neighbour refinement finds the nearest leaf (ties aside)
    d = np.where(lm.perm != exact)[0]
    a_tab = (src[d] * tree.leaves[lm.perm[d]]).sum(1)
    a_ex = (src[d] * tree.leaves[exact[d]]).sum(1)
    assert len(d) <= 3 and np.allclose(a_tab, a_ex, atol=1e-6), len(d)
    # the inverse map lists every receiver leaf once, under its source leaf
    assert np.array_equal(np.sort(lm.inv_idx), np.arange(tree.n_leaves))
    for l in (0, 1234, 30000):
        got = lm.inv_idx[lm.inv_off[l]:lm.inv_off[l + 1]]
        assert set(got) == set(np.nonzero(lm.perm == l)[0])


def test_rotation_part_refuses_shear_and_mirror():
    m = np.eye(4); m[:3, :3] = 2.5 * rot_y(10)
    q, s = rotation_part(m)
    assert abs(s - 2.5) < 1e-12 and np.allclose(q, rot_y(10))
    with pytest.raises(ValueError):
        rotation_part(np.diag([1.0, 2.0, 1.0, 1.0]))
    with pytest.raises(ValueError):
        rotation_part(np.diag([-1.0, 1.0, 1.0, 1.0]))


@pytest.mark.skipif(not native.available(), reason="C kernels not built")
@pytest.mark.parametrize("hmin", [0, 3])
@pytest.mark.parametrize("q", [np.eye(3), rot_y(71.0), rot_y(-15.0) @ rot_x(40.0)], ids=["identity", "yaw", "tilt"])
def test_c_rotation_agrees_with_numpy(bunny_case, tree, hmin, q):
    f = bunny_case.field
    lm = LeafMap(tree, q)
    ids = np.random.default_rng(hmin).choice(f.n_samples, 60, replace=False)
    a, b = RotatedSamples(f, lm, hmin, kernels("native")), RotatedSamples(f, lm, hmin, kernels("numpy"))
    assert a.ensure(ids) == 60 and b.ensure(ids) == 60
    assert a.ensure(ids) == 0                                   # kept: nothing recomputed
    for i in ids:
        ha, qa = a.cut(i); hb, qb = b.cut(i)
        for x, y in zip(a.nodes(i), b.nodes(i)):
            assert np.array_equal(x, y)
        assert np.array_equal(ha, hb) and np.array_equal(qa, qb)
        assert (1 << ha.astype(np.int64)).sum() == tree.n_leaves
        assert ha.min() >= hmin or len(ha) == 1


def test_identity_rotation_keeps_cuts_and_coarse_cuts_keep_fractions(bunny_case, tree):
    f = bunny_case.field
    ids = np.arange(0, f.n_samples, 97)
    exact = RotatedSamples(f, LeafMap(tree, np.eye(3)), 0)
    coarse = RotatedSamples(f, LeafMap(tree, np.eye(3)), 3)
    exact.ensure(ids); coarse.ensure(ids)
    for i in ids:
        h, q = f.sample_cut(int(i))
        he, qe = exact.cut(i)
        assert np.array_equal(h, he) and np.array_equal(q, qe)
        hc, qc = coarse.cut(i)
        leaves = decode_to_leaves(h, q) / 255.0
        frac = leaves.reshape(-1, 8).mean(1)
        got = decode_to_leaves(hc, qc).reshape(-1, 8)[:, 0] / 255.0
        np.testing.assert_allclose(got, frac, atol=0.5 / 255 + 1e-7)
    # the NumPy builder on a toy leaf array
    free = np.ones(1 << 15, bool); free[100:103] = False; free[4096:8192] = False
    h, q = coarse_cut_numpy(free, 3)
    assert (1 << h.astype(np.int64)).sum() == 1 << 15
    assert 12 in h and (h >= 3).all() and set(np.unique(q)) == {0, 159, 255}   # 5/8 free → 159


def test_rotated_samples_match_ray_tracing_the_rotated_mesh(bunny_case, tree, trace_points):
    """Sample s of the field of a rotated, translated bunny, read at its world position, against
    rays traced there through the transformed mesh: they differ only at shadow boundaries."""
    f = bunny_case.field
    q = rot_y(57.0) @ rot_x(12.0)
    t = np.array([0.4, -0.2, 1.1])
    world = (bunny_case.vertices.astype(np.float64) @ q.T + t).astype(np.float32)
    tracer = Tracer(world, bunny_case.faces)
    rng = np.random.default_rng(3)
    ids = rng.choice(np.arange(f.grid.per_shell * 3, f.n_samples), 20, replace=False)   # outside the body
    truth = trace_points(tracer, tree, f.grid.positions(ids) @ q.T + t)
    pool = RotatedSamples(f, LeafMap(tree, q), 0)
    pool.ensure(ids)
    kd = cKDTree(tree.leaves)
    _, nb = kd.query(tree.leaves, k=9)
    wrong_total = blocked_total = 0
    for i, tr in zip(ids, truth):
        h, qq = pool.cut(i)
        got = decode_to_leaves(h, qq) > 0.5
        wrong = np.nonzero(got != tr)[0]
        # every disagreeing leaf has a neighbour on the other side of the true shadow boundary
        boundary = (tr[nb[wrong]] != tr[wrong][:, None]).any(1)
        assert boundary.all(), f"sample {i}: {np.count_nonzero(~boundary)} leaves off the boundary"
        wrong_total += len(wrong); blocked_total += np.count_nonzero(~tr)
    assert wrong_total < 0.08 * blocked_total, (wrong_total, blocked_total)


def test_c_nearest_leaves_agree_with_numpy(tree):
    rng = np.random.default_rng(4)
    d = rng.normal(size=(20000, 3)); d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = np.concatenate([d, tree.leaves.astype(np.float64) @ (rot_y(12.5) @ rot_x(3.0))])
    assert np.array_equal(nearest_leaves(tree, d, kernels("native")), nearest_leaves(tree, d, kernels("numpy")))
