"""SRBF basis: the bandwidth relation, energy rows (eq. 15) and the C kernel's lookup tables."""
import numpy as np
import pytest

from worker.fit.basis import (DEFAULT_NL, G_CUTOFF, bandwidth_from_sigma, cube_cell, default_basis,
                              directional_albedo, hemisphere_centers, outgoing_directions)


def test_centres_cover_the_upper_hemisphere():
    c = hemisphere_centers(147)
    assert c.shape == (147, 3)
    np.testing.assert_allclose(np.linalg.norm(c, axis=1), 1.0, atol=1e-12)
    assert (c[:, 2] > 0).all()
    # well spread: no direction of the hemisphere is farther than one mean spacing from a centre
    d = hemisphere_centers(5000)
    nearest = np.arccos(np.clip(d @ c.T, -1, 1)).min(axis=1)
    spacing = np.sqrt(2 * np.pi / 147)
    assert nearest.max() < spacing


@pytest.mark.parametrize("sigma", [np.pi / 40, 0.2, 0.5])
def test_bandwidth_matches_the_variance_relation(sigma):
    lam = bandwidth_from_sigma(sigma)
    # σ² = E[1 − h·ξ] under |G|² = exp(2λ(h·ξ − 1)), by quadrature over the angle from ξ
    th = np.linspace(0, np.pi, 400_001)
    w = np.exp(2 * lam * (np.cos(th) - 1)) * np.sin(th)
    var = (w * (1 - np.cos(th))).sum() / w.sum()
    assert var == pytest.approx(sigma ** 2, rel=1e-4)
    if sigma == np.pi / 40:
        assert lam == pytest.approx(81.06, abs=0.01)


def test_bad_sigma_is_refused():
    with pytest.raises(ValueError):
        bandwidth_from_sigma(0.0)


def test_energy_rows_are_directional_albedos():
    """Σ_j g_j^l c_j equals the specular directional albedo ∫ f_s cosθi dωi computed by an
    independent θ-φ quadrature over ωi (the rows integrate over half vectors)."""
    b = default_basis(fresnel_f0=0.3)
    g = b.energy_rows()
    assert g.shape == (DEFAULT_NL, 147) and (g >= 0).all()
    rng = np.random.default_rng(3)
    c = rng.random((147, 3)) * (rng.random((147, 1)) < 0.15)
    pick = [0, 40, 100, 160, 191]
    ref = directional_albedo(b, c, outgoing_directions()[pick])
    np.testing.assert_allclose(g[pick] @ c, ref, rtol=2e-3)


def test_kernel_candidate_lists_are_conservative():
    """Every centre whose G reaches the cutoff at a half vector is listed for its cell."""
    b = default_basis()
    cell_off, cell_idx, gtab = b.kernel_tables()
    rng = np.random.default_rng(0)
    h = rng.normal(size=(20000, 3)); h[:, 2] = np.abs(h[:, 2])
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    cells = cube_cell(h)
    need = (h @ b.centers.T) >= b.cutoff_cos
    for i in range(len(h)):
        listed = set(cell_idx[cell_off[cells[i]]:cell_off[cells[i] + 1]].tolist())
        assert set(np.nonzero(need[i])[0].tolist()) <= listed
    # and the table reproduces exp within 1e-5 relative
    d = np.linspace(b.cutoff_cos, 1.0, 100_003)
    x = (d - b.cutoff_cos) * (len(gtab) - 1) / (1 - b.cutoff_cos)
    i0 = np.minimum(x.astype(int), len(gtab) - 2)
    approx = gtab[i0] + (gtab[i0 + 1] - gtab[i0]) * (x - i0)
    exact = np.exp(b.bandwidth * (d - 1))
    assert np.max(np.abs(approx - exact) / exact) < 1e-5
    assert gtab[0] == pytest.approx(G_CUTOFF, rel=1e-4)
