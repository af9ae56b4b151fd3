"""The C kernels agree with their NumPy references (same inputs, float tolerance); shading with
every model's kernel branch is checked in tests/models/test_conformance.py."""
import numpy as np
import pytest

from worker import native
from worker.core import render as R
from worker.core.tonemap import tonemap, tonemap_numpy
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
