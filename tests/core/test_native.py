"""The C kernels agree with their NumPy references (same inputs, float tolerance)."""
import numpy as np
import pytest

from worker import native
from worker.core import render as R
from worker.core.brdf import pack
from worker.core.directions import get_tree
from worker.core.lighting import LeafLighting, node_lighting
from worker.core.tonemap import tonemap, tonemap_numpy
from worker.native.kernels import kernels
from worker.scene import GGX, SRBF, BlinnPhong, Curve, Lambert, Lobes

pytestmark = pytest.mark.skipif(not native.available(), reason="C kernels not built")

MATS = [Lambert(albedo=(0.7, 0.5, 0.3)), GGX(alpha=0.08, specular=(0.9, 0.8, 0.6), albedo=(0.1, 0.1, 0.1)),
        BlinnPhong(exponent=200, specular=(0.5, 0.5, 0.5), albedo=(0.2, 0.2, 0.2)),
        Lobes(exponents=[10, 300], gloss=[0.1, 0.2], directional_diffuse=[(0.1, 0.0, 0.0), (0.0, 0.1, 0.0)], albedo=(0.3, 0.3, 0.3)),
        SRBF(centers=[(0, 0, 1), (0.3, 0, 0.95)], bandwidth=100.0, coefficients=[(1.0, 0.5, 0.2), (0.3, 0.3, 0.3)], albedo=(0.1, 0.1, 0.1)),
        Curve(values=[(3, 3, 3), (1, 1, 1), (0.1, 0.1, 0.1), (0, 0, 0)], albedo=(0.2, 0.2, 0.2))]


@pytest.mark.parametrize("k", range(len(MATS)))
def test_shade_points_agree(bunny, k):
    scene, cuts = bunny
    tree = get_tree()
    nl, nw = node_lighting(*LeafLighting(scene.envmap, tree).leaf_radiance(33.0, 1.3), tree)
    rng = np.random.default_rng(k)
    vi = rng.choice(len(scene.mesh.vertices), 300, replace=False).astype(np.int32)
    n = scene.mesh.normals[vi]
    eye = np.array([0.3, 0.8, 3.0], np.float32)
    wo = eye - scene.mesh.vertices[vi]; wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    mats = R.MaterialTable([pack(MATS[k])])
    mat_of = np.zeros(len(vi), np.int32)
    a = R.shade_points(n, wo, vi, mat_of, cuts, nl, nw, tree, mats, kernels("native"))
    b = R.shade_points_numpy(n, wo, vi, mat_of, cuts, nl, nw, tree, mats)
    assert a.max() > 0
    np.testing.assert_allclose(a, b, rtol=2e-4, atol=1e-6 * b.max())


def test_interpolate_env_lookup_tonemap_agree(bunny):
    scene, _ = bunny
    cam = scene.spec.camera
    o, d = R.camera_rays(cam.eye, cam.target, cam.up, cam.fov_y_deg, cam.width, cam.height)
    from worker.trace.embree import Tracer
    tri, uv, _ = Tracer(scene.mesh.vertices, scene.mesh.faces).first_hit(o, d)
    vert = np.random.default_rng(0).random((len(scene.mesh.vertices), 3)).astype(np.float32)
    a = R.interpolate(tri, uv, scene.mesh.faces, vert, np.zeros((len(tri), 3), np.float32), kernels("native"))
    b = R.interpolate(tri, uv, scene.mesh.faces, vert, np.zeros((len(tri), 3), np.float32), kernels("numpy"))
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
    mask = tri < 0
    e1 = R.env_lookup(d, scene.envmap, 71.0, 0.7, mask=mask, kernels=kernels("native"))
    e2 = R.env_lookup(d, scene.envmap, 71.0, 0.7, mask=mask, kernels=kernels("numpy"))
    np.testing.assert_allclose(e1, e2, rtol=1e-4, atol=1e-5)
    x = (np.random.default_rng(1).random((1000, 3)) * 4).astype(np.float32)
    for curve in ("linear", "aces", "neutral"):
        diff = np.abs(tonemap(x, 0.5, curve).astype(int) - tonemap_numpy(x, 0.5, curve).astype(int))
        assert diff.max() <= 1  # rounding of the last bit


def test_coarsen_agrees(bunny):
    from worker.core.cuts import coarsen

    _, cuts = bunny
    for tau in (2.0, 8.0):
        a = coarsen(cuts, tau, kernels("native"))
        b = coarsen(cuts, tau, kernels("numpy"))
        np.testing.assert_array_equal(a.offsets, b.offsets)
        np.testing.assert_array_equal(a.heights, b.heights)
        assert np.abs(a.quant.astype(int) - b.quant.astype(int)).max() <= 1     # rounding of equal means
