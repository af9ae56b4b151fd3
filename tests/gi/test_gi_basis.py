"""The GI basis and projection (polynomial-gi Appendix A-B) against closed forms and brute-force
integrals, the symmetric-term index, and the half-float conversion of the C kernels."""
import numpy as np
import pytest

from worker.core.brdf import evaluate
from worker.renderers.gi import basis, zspace
from worker.renderers.gi.anisotropy import AshikhminShirley, band_coefficients, evaluate_as, gamma
from worker.scene import GGX, SRBF, BlinnPhong, Curve, Lambert, Lobes

MODELS = [GGX(alpha=0.12, specular=(0.8, 0.6, 0.4), albedo=(0.1, 0.2, 0.1)),
          BlinnPhong(exponent=80, specular=(0.5, 0.5, 0.5), albedo=(0.3, 0.2, 0.1)),
          Lobes(exponents=[10, 200], gloss=[0.1, 0.3], directional_diffuse=[(0.1, 0.0, 0.0), (0.0, 0.1, 0.0)], albedo=(0.2, 0.2, 0.2)),
          SRBF(centers=[(0, 0, 1), (0.2, 0, 0.98)], bandwidth=150.0, coefficients=[(1.5, 1.0, 0.5), (0.5, 0.5, 0.5)], fresnel_f0=0.2, albedo=(0.1, 0.1, 0.1)),
          Curve(values=[(6, 6, 6), (2, 2, 2), (0.5, 0.5, 0.5)] + [(0.05, 0.05, 0.05)] * 13, fresnel_f0=0.4, albedo=(0.2, 0.2, 0.2))]


def _directional_albedo(f, theta_o, n=400_000, seed=0):
    """∫ f(ωi, ωo) cos θi dωi by cosine-weighted Monte Carlo (f: (…,3) local directions)."""
    rng = np.random.default_rng(seed)
    u = rng.random((n, 2))
    r, ph = np.sqrt(u[:, 0]), 2 * np.pi * u[:, 1]
    wi = np.stack([r * np.cos(ph), r * np.sin(ph), np.sqrt(1 - u[:, 0])], 1)
    wo = np.broadcast_to([np.sin(theta_o), 0.0, np.cos(theta_o)], wi.shape)
    v = f(wi, wo) * np.pi
    return v.mean(0), v.std(0) / np.sqrt(n)


def test_multiset_index_is_a_bijection():
    for U in (1, 2, 5, 7, 12):
        al = zspace.enumerate_all(U, zspace.MAX_Z)
        z = np.full((len(al), zspace.MAX_Z), zspace.EMPTY, np.int64)
        zc = np.array([len(a) for a in al])
        for i, a in enumerate(al):
            z[i, :len(a)] = a
        assert len(al) == zspace.size(U, zspace.MAX_Z)
        np.testing.assert_array_equal(zspace.index(z, zc, U), np.arange(len(al)))


def test_quadrature_integrates_the_cosine():
    _, _, w, _ = basis.pair_quadrature(64)
    # Σ dωi cos θi over the hemisphere = π at every view angle (1e-4: midpoint rule)
    np.testing.assert_allclose(w.sum(-1) / np.pi, 1.0, atol=1e-4)


@pytest.mark.parametrize("qkind", [0, 1])
@pytest.mark.parametrize("m", MODELS, ids=lambda m: m.model)
def test_projection_is_exact_for_uniform_light(m, qkind):
    """White furnace at every view node: albedo + Σ_j c_j ∫_band q cos = ∫ f cos exactly, for any
    model and quotient (the per-view-angle energy ratio), and both equal a brute-force integral."""
    p = basis.project(m, 64, 1, qkind=qkind)
    wi1, wo1, w1, Es, per, m5, mu, a12, a22 = basis._iso_basis(64, qkind)
    nodes, _ = basis.theta_nodes()
    for k in (0, 7, 13):
        ours = p.first[k, 0] + (p.first[k, 1:] * mu[k][:, None]).sum(0)
        ref, se = _directional_albedo(lambda a, b: evaluate(m, a, b), nodes[k], seed=k)
        # tolerance: 4 standard errors of the reference plus 1.5 % for the quadrature of sharp lobes
        assert np.all(np.abs(ours - ref) <= 4 * se + 0.015 * ref), (m.model, k, ours, ref, se)


@pytest.mark.parametrize("qkind", [0, 1])
def test_single_layer_projection_agrees_with_the_full_quadrature(qkind):
    """``project`` for one layer and a (J, 1, …) series evaluates the BRDF only on the pairs of
    non-zero weight (about half of them); ``project_measure`` over every pair is its reference.
    The first-vertex table agrees to float32 rounding and d to 1e-7 (the reference subtracts a
    float32 albedo/π from the packed BRDF, ~1e-8)."""
    J = 64
    g, wv, starts, has = basis._iso_valid(J, qkind)
    assert 0.3 < len(wv) / (basis.THETA_NODES * 32 * J) < 0.9       # pairs really are skipped
    for m in MODELS + [GGX(alpha=0.02, specular=(1, 1, 1))]:
        p = basis.project(m, J, 1, 1, None, qkind)
        wi1, wo1, w1, *_ = basis._iso_basis(J, qkind)
        E = w1[..., None] * basis._spec_part(m, wi1, wo1)
        first, d, _, _ = basis.project_measure(E, np.asarray(m.albedo, float), J, 1, 1, qkind)
        err = np.abs(p.first - first).max() / np.abs(first).max()
        assert err < 1e-6, (m.model, err)
        assert np.abs(p.d - d).max() < 1e-7, (m.model, p.d, d)


def test_lambert_uses_the_diffuse_slot_only():
    p = basis.project(Lambert(albedo=(0.6, 0.5, 0.4)), 64, 2, J2=16)
    np.testing.assert_allclose(p.first[:, 0], [[0.6, 0.5, 0.4]] * basis.THETA_NODES, rtol=1e-6)
    # bands carry nothing (up to the float32 rounding of the packed albedo)
    assert np.abs(p.first[:, 1:]).max() < 1e-6 and np.abs(p.second[1:]).max() < 1e-6
    np.testing.assert_allclose(p.d, [0.6, 0.5, 0.4], rtol=1e-6)


def test_fresnel_layer_recovers_schlick_exactly():
    """Appendix A eq. 32: a curve with Schlick F0 splits into F0·p and (1 − F0)·p per band
    (bands inside the curve's flat steps; the p(h) table is bilinear at the steps)."""
    p = basis.project(MODELS[4], 64, 2)
    cA, cB = p.first[:, 1:65, 0], p.first[:, 65:129, 0]
    inner = [1, 2, 5, 6, 9, 10]                     # away from the curve's steps at 4, 8, 12
    for k in (3, 8, 12):
        np.testing.assert_allclose(cA[k, inner], 0.4 * np.array([6, 6, 2, 2, 0.5, 0.5]), rtol=0.02)
        np.testing.assert_allclose(cB[k, inner], 0.6 * np.array([6, 6, 2, 2, 0.5, 0.5]), rtol=0.02)


@pytest.mark.parametrize("m", MODELS[:2], ids=lambda m: m.model)
def test_diffuse_equivalent_matches_a_double_integral(m):
    """Appendix B eq. 36: d = (1/π)∬ f cos θi cos θo, against Monte Carlo over (ωi, ωo) pairs."""
    rng = np.random.default_rng(3)
    n = 1_000_000
    def cosine(u):
        r, ph = np.sqrt(u[:, 0]), 2 * np.pi * u[:, 1]
        return np.stack([r * np.cos(ph), r * np.sin(ph), np.sqrt(1 - u[:, 0])], 1)
    v = evaluate(m, cosine(rng.random((n, 2))), cosine(rng.random((n, 2)))) * np.pi   # (π·π/π) per pair
    ref, se = v.mean(0), v.std(0) / np.sqrt(n)
    d = basis.project(m, 64, 1).d
    assert np.all(np.abs(d - ref) <= 4 * se + 0.01 * ref), (d, ref, se)


def test_anisotropic_factor_and_bands():
    """eq. 33-35: quotient · γ^r · normalisation is the Ashikhmin-Shirley lobe; the band
    coefficients are the band averages of γ^r."""
    m = AshikhminShirley(exponent_u=100, exponent_v=400, specular=(1.0, 1.0, 1.0))
    rng = np.random.default_rng(1)
    v = rng.normal(size=(1000, 3)); v[:, 2] = np.abs(v[:, 2]); v /= np.linalg.norm(v, axis=1, keepdims=True)
    w = rng.normal(size=(1000, 3)); w[:, 2] = np.abs(w[:, 2]); w /= np.linalg.norm(w, axis=1, keepdims=True)
    h = (v + w) / np.linalg.norm(v + w, axis=1, keepdims=True)
    e = (100 * h[:, 0] ** 2 + 400 * h[:, 1] ** 2) / (1 - h[:, 2] ** 2)
    ref = np.sqrt(101 * 401) / (8 * np.pi) * h[:, 2] ** e / ((v * h).sum(1) * np.maximum(v[:, 2], w[:, 2]))
    np.testing.assert_allclose(evaluate_as(m, v, w)[:, 0], ref, rtol=1e-9)
    cA, cB = band_coefficients(m, 16)
    g = np.linspace(0, 1, 160001)[1:]
    num = np.array([(g[(g >= j / 16) & (g < (j + 1) / 16)] ** 4).mean() for j in range(16)])
    np.testing.assert_allclose(cA[:, 0], np.sqrt(101 * 401) / (8 * np.pi) * num, rtol=1e-3)
    assert np.abs(cB).max() == 0                   # F0 = 1: no Fresnel layer
    assert np.all((gamma(h, 100) > 0) & (gamma(h, 100) <= 1))


def test_half_floats_match_numpy():
    from worker import native
    from worker.native.kernels import kernels
    if not native.available():
        pytest.skip("C kernels not built")
    gn = kernels("native").gi
    x = np.random.default_rng(0).random(200_000).astype(np.float32) * np.logspace(-12, 4.8, 200_000).astype(np.float32)
    np.testing.assert_array_equal(gn.to_half(x), x.astype(np.float16).view(np.uint16))
    h = x.astype(np.float16)
    np.testing.assert_array_equal(gn.from_half(h.view(np.uint16)), h.astype(np.float32))
