"""Transfer functions (inverse-brdf-modeling eq. 21): C against NumPy, and against the renderer."""
import numpy as np
import pytest

from worker import native
from worker.fit.transfer import transfer, transfer_numpy
from worker.native.kernels import kernels
from worker.renderers import Lighting


@pytest.mark.skipif(not native.available(), reason="C kernels not built")
def test_c_kernel_matches_numpy(bunny_view, fitter):
    r, view = bunny_view
    g = view.samples
    sel = np.arange(0, view.n, 53)
    node_l, node_w = r.light(Lighting(20.0, 1.4))       # a different light from the view's
    args = (g.normals[sel], g.wo[sel], g.verts[sel], g.bary[sel], r.cuts, node_l, node_w, r.tree, fitter.basis)
    Tc, Ec = transfer(*args, kernels("native"))
    Tn, En = transfer_numpy(*args)
    assert Tc.shape == Tn.shape == (3, len(sel), fitter.basis.J)
    # float32 centres and the tabulated G in C against float64 exp in NumPy
    np.testing.assert_allclose(Tc, Tn, rtol=0, atol=2e-5 * np.abs(Tn).max())
    np.testing.assert_allclose(Ec, En, rtol=1e-5, atol=1e-7)
    assert np.abs(Tn).max() > 0


def test_prediction_matches_the_renderer(fitter):
    """ρ_d E + T c at the fit pixels equals the renderer's pixel-mode radiance with the srbf
    material of coefficients c (the renderer reads p(h) from a 128×256 table: ~1% apart)."""
    from worker.scene import SRBF

    rng = np.random.default_rng(7)
    J = fitter.basis.J
    c = rng.random((J, 3)) * (rng.random((J, 1)) < 0.2) * 2.0
    mat = SRBF.model_validate(fitter.basis.to_material(c, (0.3, 0.2, 0.1)))
    fitter.set_base_material(mat)
    v = fitter.views[0]
    pred = fitter.predicted(c)
    rel = np.sqrt(((pred - v.base) ** 2).mean()) / np.sqrt((v.base ** 2).mean())
    assert rel < 0.01, rel
    # the Lambert part alone: E is exactly the radiance of a white Lambertian surface
    fitter.set_base_material(mat.model_copy(update={"coefficients": [(0.0, 0.0, 0.0)] * J}))
    np.testing.assert_allclose(np.array([0.3, 0.2, 0.1]) * v.E, fitter.views[0].base, rtol=1e-4, atol=1e-6)
