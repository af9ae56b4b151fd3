import numpy as np
from scipy.spatial import cKDTree

from worker.core.directions import N_LEAVES, get_tree


def test_count_unit_and_near_uniform():
    t = get_tree()
    assert t.leaves.shape == (N_LEAVES, 3) == (32768, 3)
    assert np.allclose(np.linalg.norm(t.leaves, axis=1), 1.0, atol=1e-6)
    d, _ = cKDTree(t.leaves).query(t.leaves, k=2)
    nn = d[:, 1]
    # near-uniform: nearest-neighbour spacing varies by only a few percent
    assert nn.std() / nn.mean() < 0.03
    assert nn.min() > 0.9 * nn.mean()
    # mean direction of a uniform set is ~0
    assert np.linalg.norm(t.leaves.mean(axis=0)) < 1e-3


def test_subtrees_are_spatially_coherent():
    t = get_tree()
    for h in (4, 8, 12):
        r = t.node_radius[t.level_offset[h]:t.level_offset[h + 1]]
        # a node of 2^h leaves covers 2^h·4π/N sr; a compact cap of that area has this radius
        cap = np.arccos(1 - 2.0 ** h * 2 / N_LEAVES)
        assert np.median(r) < 2.0 * cap, (h, np.median(r), cap)
    # node_index maps (height, first leaf) to the flat arrays
    assert t.node_index(np.array([0]), np.array([5]))[0] == 5
    assert t.node_index(np.array([15]), np.array([0]))[0] == len(t.node_dir) - 1
