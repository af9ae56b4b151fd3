import math

import numpy as np
import pytest

from worker.core import cuts
from worker.core.directions import get_tree


def _values(n_vertices=6, seed=0):
    """Cosine-weighted visibility with random occluding caps: realistic, not toy-uniform."""
    t = get_tree()
    rng = np.random.default_rng(seed)
    nrm = rng.normal(size=(n_vertices, 3)); nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    v = np.maximum(nrm @ t.leaves.T, 0).astype(np.float32)
    for i in range(n_vertices):
        c = rng.normal(size=3); c /= np.linalg.norm(c)
        v[i, t.leaves @ c > rng.uniform(0.3, 0.9)] = 0
    return v


@pytest.mark.parametrize("tau", [0.25, 1.0, 4.0])
def test_numpy_and_c_agree_and_error_is_bounded(tau):
    v = _values()
    a = cuts.build_cuts_numpy(v, tau)
    b = cuts.build_cuts(v, tau)
    assert np.array_equal(a.offsets, b.offsets)
    assert np.array_equal(a.heights, b.heights)
    assert np.array_equal(a.quant, b.quant)
    for i in range(len(v)):
        h, val = a.cut(i)
        assert (1 << h.astype(np.int64)).sum() == 32768       # a cut partitions the leaves
        rec = cuts.decode_to_leaves(h, val)
        # per node L1 error ≤ tau, plus 8-bit quantisation (≤ 0.5/255 per leaf)
        starts = cuts.node_starts(h)
        for s, hh in zip(starts[::50], h[::50]):
            seg = slice(s, s + (1 << int(hh)))
            err = np.abs(v[i, seg] - v[i, seg].mean()).sum()
            assert err <= tau + 1e-9
        # the whole cut: L1 error ≤ τ per node plus the 8-bit quantisation of every leaf
        total = np.abs(rec - v[i]).sum()
        bound = tau * len(h) + 0.5 / 255 * len(rec)
        assert total <= bound, f"cut {i}: L1 error {total:.2f} over the bound {bound:.2f} ({len(h)} nodes)"


def test_encode_roundtrip_and_height_encoding_is_smaller():
    cs = cuts.build_cuts(_values(20, 1), 1.0)
    blob = cuts.encode(cs)
    back = cuts.decode(blob)
    assert np.array_equal(back.offsets, cs.offsets)
    assert np.array_equal(back.heights, cs.heights)
    assert np.array_equal(back.quant, cs.quant)
    assert len(blob) < 0.5 * cuts.index_encoded_bytes(cs)
    with pytest.raises(ValueError):
        cuts.decode(b"not a cut")


def test_product_and_interpolation_of_cuts_match_leaf_level_operations():
    v = _values(3, 2)
    cs = cuts.build_cuts(v, 0.5)
    c = [cs.cut(i) for i in range(3)]
    leaves = [cuts.decode_to_leaves(*x) for x in c]
    h, val = cuts.combine(c, math.prod)
    np.testing.assert_allclose(cuts.decode_to_leaves(h, val), leaves[0] * leaves[1] * leaves[2], atol=1e-6)
    w = (0.2, 0.5, 0.3)
    h, val = cuts.combine(c, lambda x: sum(a * b for a, b in zip(w, x)))
    np.testing.assert_allclose(cuts.decode_to_leaves(h, val), sum(a * b for a, b in zip(w, leaves)), atol=1e-6)
    # the result is no finer than needed: each node is the smallest operand node
    assert len(h) <= sum(len(x[0]) for x in c)


def test_coarsen_keeps_a_valid_cut_and_only_merges_within_tau():
    from worker.core.cuts import build_cuts_numpy, coarsen, decode_to_leaves

    rng = np.random.default_rng(5)
    H = 10
    # piecewise-constant visibility with noise: many small nodes at τ = 0.5
    base = np.repeat(rng.random((6, 16)), (1 << H) // 16, axis=1)
    vals = np.clip(base + 0.02 * rng.normal(size=base.shape), 0, 1).astype(np.float32)
    fine = build_cuts_numpy(vals, 0.5)
    fine.height = H
    same = coarsen(fine, 0.0)              # τ = 0 merges only equal siblings: same leaves
    for v in range(6):
        a = decode_to_leaves(*fine.cut(v), height=H)
        b = decode_to_leaves(*same.cut(v), height=H)
        np.testing.assert_allclose(a, b, atol=1e-6)
    coarse = coarsen(fine, 8.0)
    assert coarse.sizes().sum() < 0.5 * fine.sizes().sum()
    for v in range(6):
        h, q = coarse.cut(v)
        assert (np.int64(1) << h.astype(np.int64)).sum() == 1 << H     # every leaf once
        a = decode_to_leaves(*fine.cut(v), height=H)
        b = decode_to_leaves(h, q, height=H)
        # the L1 error of each merged node is bounded by τ (between-children part) + the
        # quantisation of the merged value
        assert np.abs(a - b).sum() <= 8.0 * len(h) + (1 << H) / 255.0
