"""Model-specific BRDF checks (the generic ones, for every registered model, are in
tests/models/test_conformance.py): Lambert's white furnace, the srbf table against its exact sum,
GGX value for value against Mitsuba 3's roughconductor."""
import numpy as np
import pytest

from worker.core import brdf
from worker.scene import GGX, SRBF, Lambert


def _hemi(n, rng):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2])
    return v


def _srbf():
    rng = np.random.default_rng(3)
    c = _hemi(12, rng)
    c[:, 2] += 0.5
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    return SRBF(centers=[tuple(x) for x in c], bandwidth=60.0,
                coefficients=[tuple(x) for x in rng.uniform(0, 0.05, size=(12, 3))], fresnel_f0=0.5, albedo=(0.2, 0.2, 0.2))


def _albedo(m, wo, n=400_000, seed=1):
    """Directional albedo ∫ f(ωi, ωo) cosθi dωi by cosine-weighted Monte Carlo (per RGB)."""
    rng = np.random.default_rng(seed)
    u1, u2 = rng.random(n), rng.random(n)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    wi = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u1)], 1)
    f = brdf.evaluate(m, wi, np.broadcast_to(wo, wi.shape))
    return (f * np.pi).mean(0)     # pdf = cos/π


def test_lambert_white_furnace_is_exactly_albedo():
    a = _albedo(Lambert(albedo=(1, 1, 1)), np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(a, 1.0, atol=1e-12)


def test_srbf_table_matches_exact_sum():
    m = _srbf()
    rng = np.random.default_rng(5)
    wi, wo = _hemi(3000, rng), _hemi(3000, rng)
    exact = brdf.srbf_exact(m, wi, wo)
    table = brdf.evaluate(m, wi, wo)
    # bilinear table at 128×256 over the hemisphere: within 2% of the peak value
    assert np.abs(exact - table).max() < 0.02 * exact.max()


def test_ggx_matches_mitsuba_roughconductor():
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    for alpha in (0.1, 0.25, 0.6):
        m = GGX(alpha=alpha, specular=(0.9, 0.7, 0.5))
        b = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": alpha, "material": "none",
                          "specular_reflectance": {"type": "rgb", "value": [0.9, 0.7, 0.5]}})
        rng = np.random.default_rng(int(alpha * 100))
        wi, wo = _hemi(300, rng), _hemi(300, rng)
        ours = brdf.evaluate(m, wi, wo)
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(0, 0, 1)
        ctx = mi.BSDFContext()
        for k in range(len(wi)):
            si.wi = mi.Vector3f(*wo[k])           # Mitsuba's si.wi is towards the viewer
            v = b.eval(ctx, si, mi.Vector3f(*wi[k]))  # includes cosθ towards the light
            ref = np.array([v[0], v[1], v[2]]) / wi[k, 2]
            np.testing.assert_allclose(ours[k], ref, rtol=2e-4, atol=1e-6)
