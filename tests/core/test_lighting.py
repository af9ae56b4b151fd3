import numpy as np

from worker.core.directions import get_tree
from worker.core.lighting import LeafLighting, node_lighting, pixel_directions


def _map_integral(m):
    _, sr = pixel_directions(*m.shape[:2])
    return (m * sr[:, None, None]).sum(axis=(0, 1))


def test_solid_angles_sum_to_sphere():
    _, sr = pixel_directions(64, 128, 3)
    assert abs(sr.sum() * 128 * 3 - 4 * np.pi) < 1e-9


def test_leaf_integrals_conserve_energy_real_map(shared_assets):
    from worker.envmap import load_envmap

    m = load_envmap(shared_assets / "env" / "sunset.exr")
    lt = LeafLighting(m, get_tree())
    for rot in (0.0, 37.5, 180.0):
        l, _ = lt.leaf_radiance(rot, 2.0)
        # rotation moves light around but keeps every watt (tolerance: float64 round-off)
        np.testing.assert_allclose(l.sum(0), 2.0 * _map_integral(m), rtol=1e-6)


def test_uniform_map_gives_equal_leaves():
    m = np.ones((128, 256, 3), np.float32)
    t = get_tree()
    l, ld = LeafLighting(m, t).leaf_radiance()
    # Voronoi cells of a near-uniform set: each leaf within 15% of 4π/N, total exact
    assert np.allclose(l.sum(0), 4 * np.pi)
    assert np.abs(l[:, 0] / t.leaf_solid_angle - 1).max() < 0.15
    node_l, node_w = node_lighting(l, ld, t)
    assert np.isclose(node_l[-1, 0], 4 * np.pi, rtol=1e-6)           # the root holds everything
    np.testing.assert_allclose(np.linalg.norm(node_w, axis=1), 1, atol=1e-5)


def test_rotation_moves_a_small_source_to_the_expected_direction():
    t = get_tree()
    h, w = 128, 256
    m = np.zeros((h, w, 3), np.float32)
    m[64, 10] = 1000.0                      # a 'sun' near the horizon
    d, _ = pixel_directions(h, w)
    sun = d[64, 10]
    lt = LeafLighting(m, t)
    for rot in (0.0, 90.0, 200.0):
        l, ld = lt.leaf_radiance(rot)
        k = np.argmax(l[:, 0])
        # world direction: the map's direction rotated by +rot about +Y (Mitsuba's rotate)
        a = np.radians(rot)
        r = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        expect = r @ sun
        centroid = ld[k] / np.linalg.norm(ld[k])
        assert np.degrees(np.arccos(np.clip(centroid @ expect, -1, 1))) < 1.0
