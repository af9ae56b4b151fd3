"""The glTF material fit (worker/export/approx.py) against closed forms: the sample set's
quadrature, the glTF BRDF's energy, a glTF material fitted to itself, and extensions kept only
when they lower the error."""
import numpy as np

from worker.export.approx import (
    GltfMaterial,
    GltfPBR,
    Samples,
    approximate,
    approximate_ggx,
    default_samples,
    gltf_brdf,
    sheen_albedo,
    sheen_lobe,
)
from worker.models import GGX, Lambert


def _albedo(f, smp):
    """(V, 3) directional albedo ∫ f cosθi dωi per view by the sample weights."""
    return ((smp.w * np.maximum(smp.wi[..., 2], 0))[..., None] * f).sum(1)


def test_the_quadrature_integrates_cosine_and_a_sharp_lobe():
    smp = default_samples()
    # ∫ cosθ dω = π for every view, from the mixture of cosine and lobe samples
    e = (smp.w * np.maximum(smp.wi[..., 2], 0)).sum(1) / np.pi
    assert np.abs(e - 1).max() < 0.02, e
    # the directional albedo of a sharp GGX lobe (α 0.05) against a dense midpoint quadrature in
    # the half-vector's own polar grid: the cosine samples alone would miss it
    m = GGX(alpha=0.05, specular=(1.0, 1.0, 1.0))
    got = _albedo(m.evaluate(smp.wi, smp.wo), smp)[:, 0]
    nt, nph = 2000, 256
    t = (np.arange(nt) + 0.5) * (np.pi / 2) / nt
    ph = (np.arange(nph) + 0.5) * 2 * np.pi / nph
    T, P = np.meshgrid(t, ph, indexing="ij")
    wi = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    dw = np.sin(T) * (np.pi / 2 / nt) * (2 * np.pi / nph)
    for v in (0, 7, 15):
        wo = smp.wo[v, 0]
        ref = (m.evaluate(wi, np.broadcast_to(wo, wi.shape))[..., 0] * wi[..., 2] * dw).sum()
        assert abs(got[v] - ref) < 0.03 * ref, (v, got[v], ref)


def test_gltf_brdf_closed_forms():
    smp = default_samples()
    # a rough white dielectric with specular 0 is Lambertian: f = baseColor/π
    f = gltf_brdf(GltfMaterial((0.6, 0.5, 0.4), 0.0, 0.7, specular=0.0, specular_color=(1, 1, 1)), smp.wi, smp.wo)
    ok = (smp.wi[..., 2] > 0)
    np.testing.assert_allclose(f[ok], np.broadcast_to(np.array([0.6, 0.5, 0.4]) / np.pi, f[ok].shape), rtol=1e-12)
    # single scattering loses energy: a white metal at roughness 0.5 reflects 0.8-0.95 (Kulla-Conty 2017 fig. 2)
    a = _albedo(gltf_brdf(GltfMaterial((1, 1, 1), 1.0, 0.5), smp.wi, smp.wo), smp)[:, 0]
    assert 0.8 < a.min() and a.max() < 0.95, a
    # reciprocity, sheen and clearcoat included
    m = GltfMaterial((0.3, 0.2, 0.1), 0.2, 0.4, 0.8, (1.5, 1.2, 1.0), 0.5, 0.2, (0.4, 0.3, 0.2), 0.5)
    np.testing.assert_allclose(gltf_brdf(m, smp.wi, smp.wo), gltf_brdf(m, smp.wo, smp.wi), rtol=1e-9, atol=1e-12)
    # the sheen albedo table against the sample set's own quadrature of the lobe
    for r in (0.3, 0.8):
        lobe = sheen_lobe(np.maximum(smp.wi[..., 2], 0), smp.wo[..., 2],
                          ((smp.wi + smp.wo) / np.linalg.norm(smp.wi + smp.wo, axis=-1, keepdims=True))[..., 2], r * r)
        e = (smp.w * np.maximum(smp.wi[..., 2], 0) * lobe).sum(1)
        np.testing.assert_allclose(sheen_albedo(smp.wo[:, 0, 2], r), e, rtol=0.05, atol=0.005)


def test_a_gltf_material_fits_itself_and_keeps_only_the_extension_it_uses():
    truth = GltfMaterial((0.5, 0.2, 0.1), 0.0, 0.35, specular=0.7, specular_color=(2.0, 1.5, 1.0))
    a = approximate(GltfPBR(gltf=truth.__dict__))
    assert a.rel_rmse < 0.01, a.public()
    assert a.material.extensions == ["KHR_materials_specular"], a.public()
    np.testing.assert_allclose(a.material.base_color, truth.base_color, atol=0.02)
    assert abs(a.material.roughness - truth.roughness) < 0.02
    # (the dielectric's F0 is weakly determined beside a bright diffuse base: not compared)
    # the candidates it tried, each no better by the margin than what it kept
    assert a.candidates["base"] > a.rel_rmse and len(a.candidates) == 4


def test_glints_ggx_is_close_and_lambert_exact_for_mitsuba():
    smp = Samples.make(n_views=8, n_cos=96, n_lobe=32)
    g = GGX(alpha=0.2, specular=(0.5, 0.4, 0.3), albedo=(0.3, 0.3, 0.3))
    assert approximate_ggx(g, smp).exact and approximate_ggx(Lambert(), smp).exact
    # over Mitsuba's blend bound (max specular + max albedo > 1): the closest ggx within it
    big = GGX(alpha=0.2, specular=(0.8, 0.8, 0.8), albedo=(0.5, 0.5, 0.5))
    b = approximate_ggx(big, smp)
    assert not b.exact and max(b.material.specular) + max(b.material.albedo) <= 1.0 + 1e-9
    assert 0.0 < b.rel_rmse < 0.4, b


def test_a_dark_glossy_dielectric_fits_as_one_not_as_a_metal():
    """Black lacquer (a sharp 5% specular over a 2% diffuse) has an almost exact glTF form (a
    dielectric, roughness √α, KHR_materials_specular), but the core fit alone ends as a metal,
    from which the specular extension cannot move: the extension is tried from a dielectric too."""
    lacquer = GGX(alpha=0.08, specular=(0.05, 0.05, 0.05), albedo=(0.02, 0.02, 0.02))
    a = approximate(lacquer)
    assert a.rel_rmse < 0.02, f"black lacquer fits at {a.rel_rmse:.1%} relative BRDF RMSE (bound 2%): {a.public()}"
    assert a.material.metallic < 0.1 and abs(a.material.roughness - 0.08 ** 0.5) < 0.03, a.public()
    assert "KHR_materials_specular" in a.material.extensions, a.public()
