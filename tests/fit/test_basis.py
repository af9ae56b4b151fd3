"""SRBF basis: the bandwidth relation, energy rows (eq. 15) and the C kernel's lookup tables."""
import numpy as np
import pytest

from worker import native
from worker.fit.basis import (G_CUTOFF, XCUT, bandwidth_from_sigma, cube_cell, default_basis, directional_albedo,
                              energy_rows_at, energy_rows_numpy, hemisphere_centers, multiscale_centers,
                              outgoing_directions, paper_basis)


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
    independent quadrature over ωi (the rows integrate over half vectors around each centre),
    for both static functions, at rows from the normal to the horizon (4-6 s: the independent
    quadrature, for two bases)."""
    rng = np.random.default_rng(3)
    for b in (paper_basis(fresnel_f0=0.3), default_basis(fresnel_f0=0.5, static_alpha=0.15)):
        g = b.energy_rows()
        wo = outgoing_directions()
        assert g.shape == (len(wo), b.J) and (g >= 0).all()
        c = rng.random((b.J, 3)) * (rng.random((b.J, 1)) < 0.15)
        pick = [0, 40, 100, 160, 191, len(wo) - 60, len(wo) - 1]     # the last is on the horizon
        ref = directional_albedo(b, c, wo[pick])
        np.testing.assert_allclose(g[pick] @ c, ref, rtol=3e-3)


@pytest.mark.skipif(not native.available(), reason="C kernels not built")
@pytest.mark.parametrize("static", ["paper", "smith"])
def test_energy_rows_c_kernel_matches_numpy(static):
    """glk_energy_rows against its NumPy reference, both statics (~1 s each)."""
    from worker.native.kernels import kernels

    b = default_basis(static=static, static_alpha=0.2)
    wo = outgoing_directions()[::7]
    got = energy_rows_at(b, wo, kernels=kernels("native"))
    np.testing.assert_allclose(got, energy_rows_numpy(b, wo), rtol=1e-10, atol=1e-14)


def test_kernel_candidate_lists_are_conservative():
    """Every centre whose G reaches the cutoff at a half vector is listed for its cell."""
    b = default_basis()
    cell_off, cell_idx, cell_cand, gtab = b.kernel_tables()
    np.testing.assert_allclose(cell_cand[:, :3], b.centers[cell_idx], atol=1e-7)
    np.testing.assert_allclose(cell_cand[:, 3], b.bandwidths[cell_idx], rtol=1e-7)
    rng = np.random.default_rng(0)
    h = rng.normal(size=(20000, 3)); h[:, 2] = np.abs(h[:, 2])
    h[:5000] = h[:5000] * [0.05, 0.05, 1.0]                  # many near the normal, where fine levels are
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    cells = cube_cell(h)
    need = (h @ b.centers.T) >= b.cutoff_cos
    for i in range(len(h)):
        listed = set(cell_idx[cell_off[cells[i]]:cell_off[cells[i] + 1]].tolist())
        assert set(np.nonzero(need[i])[0].tolist()) <= listed
    # and the table reproduces exp(−x) within 1e-5 relative
    x = np.linspace(0.0, XCUT, 100_003)
    f = x * (len(gtab) - 1) / XCUT
    i0 = np.minimum(f.astype(int), len(gtab) - 2)
    approx = gtab[i0] + (gtab[i0 + 1] - gtab[i0]) * (f - i0)
    assert np.max(np.abs(approx - np.exp(-x)) / np.exp(-x)) < 1e-5
    assert gtab[-1] == pytest.approx(G_CUTOFF, rel=1e-4)


def test_multiscale_levels():
    """Finer levels sit in cones around the normal, keep the coarse spacing-to-σ ratio and
    halve σ each (λ ≈ 1/(2σ²) quadruples)."""
    c, lam = multiscale_centers(147, np.pi / 40, ((0.5, 16.0), (0.25, 7.0)))
    levels = np.unique(lam)
    assert len(levels) == 3 and (c[:, 2] > 0).all()
    np.testing.assert_allclose(levels[1:] / levels[:-1], 4.0, rtol=0.02)
    fine = lam == levels[-1]
    assert np.degrees(np.arccos(c[fine, 2])).max() <= 7.0
    # spacing: nearest-neighbour angle within a level scales with σ
    def spacing(sel):
        a = np.arccos(np.clip(c[sel] @ c[sel].T, -1, 1)) + np.eye(sel.sum()) * 9
        return np.median(a.min(1))
    assert spacing(lam == levels[0]) / spacing(fine) == pytest.approx(4.0, rel=0.25)
