"""The C kernels agree with their NumPy references (same inputs, float tolerance); shading with
every model's kernel branch is checked in tests/models/test_conformance.py."""
import numpy as np
import pytest

from worker import native
from worker.core import render as R
from worker.core.tonemap import CURVES, tonemap, tonemap_numpy
from worker.native.kernels import kernels

pytestmark = pytest.mark.skipif(not native.available(), reason="C kernels not built")


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
    big = (np.random.default_rng(3).random((480, 640, 3)) ** 3 * 6).astype(np.float32)
    for curve in ("linear", "aces", "neutral"):
        diff = np.abs(tonemap(x, 0.5, curve).astype(int) - tonemap_numpy(x, 0.5, curve).astype(int))
        assert diff.max() <= 1  # rounding of the last bit
        # a frame's worth goes through the cached table (kernels.TONEMAP_LUT_MIN): within a level
        # of the curve, and off by one at few values (a bucket straddling a level's edge)
        diff = np.abs(tonemap(big, 0.5, curve).astype(int) - tonemap_numpy(big, 0.5, curve).astype(int))
        assert diff.max() <= 1 and (diff > 0).mean() < 0.03, (curve, diff.max(), (diff > 0).mean())
        assert (0.5, CURVES[curve]) in kernels("native")._luts          # the table was the path taken


def test_tonemap_pair_agrees_and_its_half_is_the_linear_block_mean():
    from worker.core.tonemap import half_mean, tonemap_pair

    rng = np.random.default_rng(2)
    x = (rng.random((30, 46, 3)) ** 3 * 3).astype(np.float32)      # dark to over-exposed
    x[4:8, 10:20] = 0.0
    for curve in ("linear", "aces", "neutral"):
        a2, a1 = tonemap_pair(x, -0.3, curve, kernels("native"))
        b2, b1 = tonemap_pair(x, -0.3, curve, kernels("numpy"))
        assert a2.shape == (30, 46, 3) and a1.shape == (15, 23, 3) and a1.dtype == np.uint8
        assert np.abs(a2.astype(int) - b2.astype(int)).max() <= 1      # the OETF table's rounding
        assert np.abs(a1.astype(int) - b1.astype(int)).max() <= 1
        # the half frame is tone-mapped from the mean radiance, not the mean of the bytes
        lin = tonemap_numpy(x.reshape(15, 2, 23, 2, 3).mean(axis=(1, 3)), -0.3, curve).astype(int)
        disp = b2.reshape(15, 2, 23, 2, 3).mean(axis=(1, 3))
        assert np.abs(b1 - lin).max() <= 1 and np.abs(b1 - disp).max() > 5
    np.testing.assert_allclose(half_mean(x)[3, 7], x[6:8, 14:16].reshape(-1, 3).mean(0), rtol=1e-6)
    with pytest.raises(ValueError):
        tonemap_pair(x[:29], 0.0, "neutral")


def test_coarsen_agrees(bunny):
    from worker.core.cuts import coarsen

    _, cuts = bunny
    for tau in (2.0, 8.0):
        a = coarsen(cuts, tau, kernels("native"))
        b = coarsen(cuts, tau, kernels("numpy"))
        np.testing.assert_array_equal(a.offsets, b.offsets)
        np.testing.assert_array_equal(a.heights, b.heights)
        assert np.abs(a.quant.astype(int) - b.quant.astype(int)).max() <= 1     # rounding of equal means
