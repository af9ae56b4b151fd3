"""A field's sample cuts are the ray-traced occlusion at the sample points, stored losslessly."""
import numpy as np
import pytest

from worker.core.cuts import decode_to_leaves
from worker.renderers.cuts.field import Field, FieldError, cone_directions, field_key
from worker.renderers.cuts.grid import GridSpec


def test_sample_cuts_equal_direct_ray_tracing(bunny_case, tree, trace_points):
    f = bunny_case.field
    rng = np.random.default_rng(0)
    ids = rng.choice(f.n_samples, 24, replace=False)
    truth = trace_points(bunny_case.tracer, tree, f.grid.positions(ids))
    for i, t in zip(ids, truth):
        h, q = f.sample_cut(int(i))
        assert (1 << h.astype(np.int64)).sum() == tree.n_leaves          # a cut covers every leaf once
        got = decode_to_leaves(h, q) > 0.5
        # identical, except directions outside the bounding cone, which cannot hit and are not traced
        assert np.array_equal(got, t), f"sample {i}: {np.count_nonzero(got != t)} leaves differ"


def test_cuts_are_lossless_binary_and_clustered_only_where_children_are_equal(bunny_case):
    f = bunny_case.field
    for i in (0, f.n_samples // 2, f.n_samples - 1):
        h, q = f.sample_cut(i)
        assert set(np.unique(q)) <= {0, 255}
        # no two sibling nodes of equal value (they would have been merged)
        starts = np.concatenate([[0], np.cumsum(1 << h.astype(np.int64))[:-1]])
        sib = (h[:-1] == h[1:]) & ((starts[:-1] >> h[:-1]) % 2 == 0)
        assert not np.any(sib & (q[:-1] == q[1:]))


def test_cone_directions_cover_every_hit(bunny_case, tree, trace_points):
    c, r = bunny_case.center, bunny_case.radius
    p = c + np.array([0.0, 0.0, 3.0 * r])
    cone = np.zeros(tree.n_leaves, bool)
    cone[cone_directions(tree, p, c, r)] = True
    blocked = ~trace_points(bunny_case.tracer, tree, p[None])[0]
    assert blocked.any() and not (blocked & ~cone).any()
    assert cone.mean() < 0.05                           # asin(1/3): 2.9% of the sphere


def test_encoding_roundtrip_sizes_and_errors(bunny_case):
    f = bunny_case.field
    blob = f.encode()
    g = Field.decode(blob)
    a, b = f.cuts(), g.cuts()
    assert np.array_equal(a.offsets, b.offsets) and np.array_equal(a.heights, b.heights) and np.array_equal(a.quant, b.quant)
    assert g.key == f.key and g.grid.spec == f.grid.spec
    np.testing.assert_array_equal(g.grid.center, f.grid.center)
    st = f.storage(len(blob))
    # 4-bit height + 1-bit value per node (the paper's representation) against 2-byte indices
    assert st["bytes_raw"] < 0.35 * st["bytes_index_encoded"]
    assert st["bytes_compressed"] < st["bytes_raw"]
    with pytest.raises(FieldError):
        Field.decode(b"not a field")
    with pytest.raises(FieldError):
        Field.decode(blob[:-40])


def test_key_depends_on_mesh_and_grid_only(bunny_case):
    v, fc = bunny_case.vertices, bunny_case.faces
    k = field_key(v, fc, GridSpec(8, 8), 15)
    assert k == bunny_case.field.key
    assert field_key(v, fc, GridSpec(8, 9), 15) != k
    moved = v + np.float32(1.0)
    assert field_key(moved, fc, GridSpec(8, 8), 15) != k          # other geometry, other field
