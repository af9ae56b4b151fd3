"""The srbf model's static functions and multi-scale bandwidths: closed forms, the paper's model
unchanged for version-1 files, C against NumPy, energy conservation by quadrature.

Time (2 cores, loaded machine): under 1 s each, but the energy test (4-8 s: the independent
quadrature of ``energy_maximum``); the kernel test's first call loads the bunny's cuts (~3 s)."""
import numpy as np
import pytest

from worker import native
from worker.core import brdf
from worker.core import render as R
from worker.core.directions import get_tree
from worker.core.lighting import LeafLighting, node_lighting
from worker.fit.basis import default_basis, paper_basis
from worker.native.kernels import kernels
from worker.scene import GGX, SRBF


def _hemi(n, rng):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _fitted_like(basis, rng, albedo=(0.2, 0.1, 0.05)):
    """A material over the basis with a peak at the normal (fine levels) and a few coarse lobes."""
    c = np.zeros((basis.J, 3))
    fine = basis.bandwidths > basis.bandwidths.min()
    c[fine] = rng.uniform(0, 2.0, (fine.sum(), 1)) * [1.0, 0.8, 0.6]
    coarse = np.nonzero(~fine)[0]
    c[rng.choice(coarse, 12, replace=False)] = rng.uniform(0, 0.3, (12, 3))
    return SRBF.model_validate(basis.to_material(c, albedo))


V1 = {"model": "srbf", "centers": [[0, 0, 1], [0.3, 0, 0.954], [-0.5, 0.5, 0.707]], "bandwidth": 60.0,
      "coefficients": [[1.0, 0.5, 0.2], [0.3, 0.3, 0.3], [0.1, 0.0, 0.2]], "fresnel_f0": 0.4, "albedo": [0.2, 0.1, 0.1]}


def test_version1_files_keep_the_papers_model():
    """A file without the new fields is eq. 11 with one bandwidth, as before they existed."""
    m = SRBF.model_validate(V1)
    assert m.static == "paper" and m.bandwidths is None
    rng = np.random.default_rng(0)
    wi, wo = _hemi(2000, rng), _hemi(2000, rng)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    c = np.asarray(V1["centers"], float)
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    p = np.exp(60.0 * (h @ c.T - 1.0)) @ np.asarray(V1["coefficients"])
    cd = (wi * h).sum(1)
    F = 0.4 + 0.6 * (1 - cd) ** 5
    ref = np.asarray(V1["albedo"]) / np.pi + p * (F / (wi[:, 2] + wo[:, 2] - wi[:, 2] * wo[:, 2]))[:, None]
    np.testing.assert_allclose(brdf.srbf_exact(m, wi, wo), ref, rtol=1e-12)
    pk = brdf.pack(m)
    assert pk.params[4] == 0                                   # the paper's static in the kernel
    # the renderer's refinement is the single-bandwidth rule of before
    sd = 1 / np.sqrt(60.0)
    assert pk.refine_radius == pytest.approx(2 * sd)
    assert pk.extent == pytest.approx(2 * (np.arccos(0.707 / np.linalg.norm([-0.5, 0.5, 0.707])) + 3 * sd), rel=1e-6)
    # a fit over the paper's basis writes no field the paper's model lacks
    assert set(paper_basis().to_material(np.zeros((147, 3)), (0, 0, 0))) == set(V1)


@pytest.mark.parametrize("alpha", [0.05, 0.2, 0.6])
def test_smith_static_with_ggx_distribution_is_ggx(alpha):
    """p = specular·D_GGX(α) with the smith static of the same α is Mitsuba's roughconductor
    (the ggx model, value for value)."""
    rng = np.random.default_rng(1)
    wi, wo = _hemi(5000, rng), _hemi(5000, rng)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    s = brdf.distribution_static(wi[:, 2], wo[:, 2], (wi * h).sum(1), 1.0, "smith", alpha)
    mine = 0.7 * brdf.ggx_D(h[:, 2], alpha) * s
    ref = brdf.evaluate(GGX(alpha=alpha, specular=(0.7, 0.7, 0.7)), wi, wo)[:, 0]
    np.testing.assert_allclose(mine, ref, rtol=2e-6, atol=1e-12)     # ggx packs α as float32


def test_multiscale_material_round_trip_and_render_refinement():
    b = default_basis(static_alpha=0.15)
    m = _fitted_like(b, np.random.default_rng(2))
    again = SRBF.model_validate_json(m.model_dump_json())
    assert again == m and again.static == "smith" and len(again.bandwidths) == b.J
    np.testing.assert_allclose(again.lambdas(), b.bandwidths)
    # the renderer refines for the narrowest level in use, near the mirror direction only
    pk = brdf.pack(m)
    assert pk.refine_radius == pytest.approx(2 / np.sqrt(b.bandwidths.max()))
    assert pk.extent < 0.5
    with pytest.raises(ValueError, match="bandwidths"):
        SRBF.model_validate({**V1, "bandwidths": [60.0, 60.0]})


def test_smith_srbf_is_reciprocal_non_negative_and_conserves_energy():
    b = default_basis(static_alpha=0.1)
    rng = np.random.default_rng(3)
    m = _fitted_like(b, rng, albedo=(0.0, 0.0, 0.0))
    wi, wo = _hemi(4000, rng), _hemi(4000, rng)
    f1, f2 = brdf.evaluate(m, wi, wo), brdf.evaluate(m, wo, wi)
    assert (f1 >= 0).all()
    np.testing.assert_allclose(f1, f2, rtol=1e-9, atol=1e-12)
    # scaled to the energy bound by the rows, the independent quadrature agrees (0.3% tolerance)
    from worker.fit.basis import energy_maximum
    c = np.asarray(m.coefficients)
    k = 1.0 / (b.energy_rows() @ c).max()
    e = energy_maximum(b, c * k)
    assert e.max() <= 1.003, e


@pytest.mark.skipif(not native.available(), reason="C kernels not built")
@pytest.mark.parametrize("static", ["paper", "smith"])
def test_table_kernel_agrees_with_numpy(bunny, static):
    scene, cuts = bunny
    tree = get_tree()
    nl, nw = node_lighting(*LeafLighting(scene.envmap, tree).leaf_radiance(33.0, 1.3), tree)
    b = default_basis(static=static, static_alpha=0.12, fresnel_f0=0.5)
    mats = R.MaterialTable([brdf.pack(_fitted_like(b, np.random.default_rng(4)))])
    rng = np.random.default_rng(5)
    vi = rng.choice(len(scene.mesh.vertices), 300, replace=False).astype(np.int32)
    eye = np.array([0.3, 0.8, 3.0], np.float32)
    wo = eye - scene.mesh.vertices[vi]
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    mat_of = np.zeros(len(vi), np.int32)
    c = R.shade_points_numpy(scene.mesh.normals[vi], wo, vi, mat_of, cuts, nl, nw, tree, mats)
    assert c.max() > 0
    k = kernels("native")
    best = k.simd(-1)
    try:
        for mode in sorted({0, best}):          # the scalar path and the AVX2 one (when the CPU has it)
            assert k.simd(mode) == mode
            a = R.shade_points(scene.mesh.normals[vi], wo, vi, mat_of, cuts, nl, nw, tree, mats, k)
            np.testing.assert_allclose(a, c, rtol=2e-4, atol=1e-6 * c.max(), err_msg=f"simd={mode}")
    finally:
        k.simd(1)
