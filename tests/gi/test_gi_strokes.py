"""Strokes under global illumination (worker/renderers/gi/strokes.py, worker/fit/fitter.py):
the GI renderer's expansion of the frame in the edited object's srbf coefficients is its
first-order Taylor expansion (checked against the exact frame by finite differences, on the
dense, the sparse (J2 series, Fresnel layer) and the denoised tensor layouts), and a stroke
painted in a GI scene moves the frame's pixels where it was painted, with little spill."""
import numpy as np
import pytest

from gi_harness import gi_renderer, scene_with
from worker.errors import GlintError
from worker.fit.basis import default_basis
from worker.fit.brush import Stroke
from worker.fit.fitter import Fitter
from worker.renderers.base import FrameRequest, Lighting
from worker.renderers.gi import GIData, GIRenderer
from worker.renderers.gi.options import parse_options, unit_layout
from worker.renderers.gi.renderer import denoise_tensors, region_images
from worker.renderers.gi.trace import make_setup
from worker.scene import SRBF, Lambert


def _lighting(r):
    env = r.scene.spec.environment
    return Lighting(env.rotation_deg, env.intensity)


def _identity_denoised(shared_assets):
    """The sofa at 32×24 with its tensors "denoised" by the identity: the hat components of the
    indirect light (denoise.py) without OIDN's cost."""
    sc = scene_with("sofa", 32, 24)
    opts = {"spp": 16, "series": [64, 1, 1, 1]}
    raw = gi_renderer(sc, opts)
    o = parse_options(sc, opts)
    S = make_setup(sc, o, unit_layout(sc, o), region_images(sc, o))
    bounces, meta = denoise_tensors(sc, S, raw.data.bounces, denoiser=lambda img, a, n: img)
    d = raw.data
    return GIRenderer(sc, GIData({**d.meta, "denoise": meta}, d.pixel, d.obj, bounces, d.opts))


LAYOUTS = {
    "dense": lambda a: gi_renderer(scene_with("sofa", 48, 36), {"spp": 64, "series": [64, 1, 1, 1]}),
    "sparse-fresnel": lambda a: gi_renderer(scene_with("cornell", 24, 24),
                                            {"spp": 16, "series": [16, 4, 1, 1], "fresnel": True}),
    "denoised": _identity_denoised,
}


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_the_expansion_is_the_frames_taylor_expansion(shared_assets, layout):
    """Around a glossy srbf material m0 (random lobes of the fitting basis), ρE + Tc + R equals
    the exact radiance at m0 within 5e-4 of the largest (the expansion sums the lobes exactly,
    the renderer evaluates the material's p(h) table: 1.3e-4 measured on the sofa), shade_samples equals the drawn frame at the
    object's pixels (1e-5), and for a step ε·δ the expansion's error relative to the change falls
    in proportion to ε (second order): a Jacobian with a wrong term would leave a constant share."""
    r = LAYOUTS[layout](shared_assets)
    obj = 0
    smp = r.surface_samples(None, obj)
    assert len(smp) >= 40
    basis = default_basis()
    lt = _lighting(r)
    rng = np.random.default_rng(1)
    c0 = np.zeros((basis.J, 3))
    c0[rng.choice(basis.J, 12, replace=False)] = rng.uniform(0.0, 0.06, (12, 3))
    alb = np.array([0.45, 0.35, 0.25])
    m0 = SRBF.model_validate(basis.to_material(c0, alb))
    T, E, R = r.linearise(smp, basis, lt, m0, obj)
    B0 = r.shade_samples(smp, m0, obj, lt)
    at = alb * E + np.einsum("cnj,jc->nc", T, c0) + R
    assert np.abs(at - B0).max() <= 5e-4 * np.abs(B0).max(), np.abs(at - B0).max()
    mats = list(r.scene.materials)
    mats[obj] = m0
    img = r.render(FrameRequest(r.scene.spec.camera, lt, mats)).radiance.reshape(-1, 3)
    frame = img[r.prim.pixel[smp.hit]]
    assert np.abs(frame - B0).max() <= 1e-5 * np.abs(B0).max(), np.abs(frame - B0).max()
    dc = np.zeros_like(c0)
    dc[rng.choice(basis.J, 6, replace=False)] = 0.03
    share = {}
    for eps in (0.8, 0.2):
        m1 = SRBF.model_validate(basis.to_material(c0 + eps * dc, alb + eps * 0.15))
        B1 = r.shade_samples(smp, m1, obj, lt)
        lin = (alb + eps * 0.15) * E + np.einsum("cnj,jc->nc", T, c0 + eps * dc) + R
        share[eps] = np.abs(lin - B1).mean() / np.abs(B1 - B0).mean()
    assert share[0.2] < 0.4 * share[0.8], share          # 0.25 for an exact Jacobian
    assert share[0.8] < 0.05, share


@pytest.fixture(scope="module")
def sofa(shared_assets):
    return gi_renderer(scene_with("sofa", 48, 36), {"spp": 64, "series": [64, 1, 1, 1]})


def test_a_stroke_under_gi_changes_the_frame_where_it_is_painted(sofa):
    """A dark grey matte sofa; a stroke across its middle asks for 1.2× the radiance there. The
    GI frame drawn with the fitted material (all four bounces) delivers at least 60% of the
    requested change on the painted pixels (0.76 measured) and changes the unpainted ones by at
    most 15% of their radiance (0.11: the sofa has one BRDF, and the band is a sixth of its
    pixels at this resolution), the fitter's own figures are those of the frame (it judges a fit by the
    exact radiance, not by its expansion), and Gauss-Newton stopped on its tolerance."""
    r = sofa
    base = Lambert(albedo=(0.2, 0.2, 0.2))
    fx = Fitter(r, "sofa", base_material=base, fit_scale=r.stroke_fit_scale)
    fx.add_view()
    v = fx.views[0]
    y0 = float(np.median(v.xy[:, 1]))
    row = v.xy[np.abs(v.xy[:, 1] - y0) <= 1.0, 0]
    x0, x1 = float(np.quantile(row, 0.2)), float(np.quantile(row, 0.8))
    fx.add_stroke(Stroke(points=[(x0, y0), (x1, y0)], mode="scale", scale=1.2, diameter=6.0, kappa=0.05))
    out = fx.fit()
    (target, painted), = fx.targets()[0]
    assert painted.sum() >= 20 and (~painted).sum() >= 100
    mats = list(r.scene.materials)
    mats[0] = base
    before = r.render(FrameRequest(r.scene.spec.camera, _lighting(r), mats)).radiance.reshape(-1, 3).copy()
    mats[0] = out.material
    after = r.render(FrameRequest(r.scene.spec.camera, _lighting(r), mats)).radiance.reshape(-1, 3)
    pix = r.prim.pixel[v.samples.hit]
    b, a = before[pix], after[pix]
    ask = target[painted] - b[painted]
    achieved = float(((a[painted] - b[painted]) * ask).sum() / (ask * ask).sum())
    spill = float(np.sqrt(((a[~painted] - b[~painted]) ** 2).mean() / (b[~painted] ** 2).mean()))
    assert achieved >= 0.6, (achieved, out.notes)
    assert spill <= 0.15, spill
    assert abs(out.achieved - achieved) < 1e-3 and abs(out.spill - spill) < 1e-3, (out.achieved, achieved, out.spill, spill)
    assert out.gap is not None and out.gap <= 2e-3 and 1 <= out.steps <= 4, (out.steps, out.gap)
    # interreflections: the floor under the sofa changed too, though nothing was painted there
    floor = r.prim.pixel[r.prim.obj == 1]
    assert np.abs(after[floor] - before[floor]).max() > 1e-4


def test_the_fit_grid_is_bounded_at_large_views(sofa, monkeypatch):
    """A view larger than GIRenderer.FIT_PIXELS fits on every other (third…) pixel: a stroke
    paints 4× the pixels at 640×480 as at 320×240, and the fitter bounds only the unpainted
    rows. Here the bound is set to a quarter of the 48×36 view: the scale is 1/2 and the view
    has a quarter of the object's rows; under the bound the scale stays 1."""
    assert sofa.stroke_fit_scale == 1.0
    monkeypatch.setattr(GIRenderer, "FIT_PIXELS", 24 * 18)
    r = GIRenderer(sofa.scene, sofa.data)
    assert r.stroke_fit_scale == pytest.approx(0.5)
    small, full = Fitter(r, "sofa", fit_scale=r.stroke_fit_scale), Fitter(sofa, "sofa", fit_scale=sofa.stroke_fit_scale)
    small.add_view(); full.add_view()
    n, N = len(small.views[0].pix), len(full.views[0].pix)
    assert 0.2 * N <= n <= 0.3 * N, (n, N)


def test_strokes_on_a_fixed_object_are_refused(sofa):
    fx = Fitter(sofa, "side_wall", fit_scale=1.0)
    with pytest.raises(GlintError, match="fixed"):
        fx.add_view()


def test_strokes_are_painted_in_the_precomputed_view(sofa):
    cam = sofa.scene.spec.camera.model_copy(update={"eye": (0.0, 100.0, 250.0)})
    fx = Fitter(sofa, "sofa", fit_scale=1.0)
    with pytest.raises(GlintError, match="camera is fixed"):
        fx.add_view(cam)
