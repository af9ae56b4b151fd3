"""Paint to BRDF (inverse-brdf-modeling eq. 17-19, 23): recovering known materials, strokes that
add and remove highlights, energy conservation, the unpainted-pixel weight, several views."""
import numpy as np
import pytest

from helpers import render

from worker.fit.basis import energy_maximum
from worker.fit.brush import Stroke, stroke_weights
from worker.fit.fitter import FitError
from worker.scene import GGX, Lambert

TARGET_GGX = GGX(alpha=0.25, specular=(0.6, 0.5, 0.4), albedo=(0.2, 0.2, 0.2))


def _constraints_hold(fx, out, tol=1e-7):
    """c ≥ 0; every energy row ≤ 1 − ρ_d in its own channel; and an independent quadrature at the
    directions where a ten times denser set of directions finds the largest albedo agrees."""
    c = out.solve.coefficients
    bound = 1 - fx.albedo
    assert (c >= 0).all()
    assert (out.solve.energy <= bound + tol).all(), (out.solve.energy, bound)
    e = energy_maximum(fx.basis, c)
    assert (e <= bound + 1e-4).all(), (e, bound)


def _rel(a, b, mask):
    return float(np.sqrt(((a[mask] - b[mask]) ** 2).mean()) / np.sqrt((b[mask] ** 2).mean()))


def test_recovers_ggx_rendered_by_glint(fitter, artifacts):
    from PIL import Image

    from worker.core.tonemap import tonemap

    r = fitter.renderer
    target, _ = render(r, TARGET_GGX)
    fitter.set_base_material(Lambert(albedo=TARGET_GGX.albedo))     # ρ_d from the designer
    out = fitter.fit_targets([target])
    _constraints_hold(fitter, out)
    again, oid = render(r, out.material)
    obj = oid == 0
    rel = _rel(again, target, obj)
    Image.fromarray(np.concatenate([tonemap(target), tonemap(again)], 1)).save(artifacts / "fit-ggx-glint.png")
    print(f"ggx → srbf, Glint target: relative RMSE {rel:.4f} over {obj.sum()} pixels; "
          f"solve {out.solve.seconds * 1e3:.1f} ms; energy max {out.solve.energy_max:.3f}")
    assert rel < 0.02          # measured 0.0026 (0.035 with the paper's static and basis)
    assert out.solve.residual_rel < 0.05


@pytest.mark.slow
def test_recovers_ggx_rendered_by_mitsuba(fitter, artifacts, cache_dir):
    """The target comes from an independent renderer: the fit sees Mitsuba's noise and its
    exact visibility, and still lands close (two 256-spp renders averaged, cached by content),
    re-rendered as the designer sees it: the default mode's settled frame (refined, 4 samples at
    edges)."""
    pytest.importorskip("mitsuba")
    import copy

    from PIL import Image
    from scipy.ndimage import binary_erosion

    from worker.core.tonemap import tonemap
    from worker.fit.recovery import mitsuba_target

    r = fitter.renderer
    spec = r.scene.spec.model_copy(deep=True)
    spec.objects[0].material = TARGET_GGX
    sc = copy.copy(r.scene)
    sc.spec = spec
    target, _ = mitsuba_target(sc, 256, (3, 4), cache_dir / "mitsuba")
    fitter.set_base_material(Lambert(albedo=TARGET_GGX.albedo))
    out = fitter.fit_targets([target])
    _constraints_hold(fitter, out)
    from worker.jobs.lod import STILL_ANTIALIAS, STILL_SAMPLES
    from worker.renderers import FrameRequest

    res = r.render(FrameRequest(camera=r.scene.spec.camera, materials=[out.material], samples=STILL_SAMPLES,
                                antialias=STILL_ANTIALIAS))
    assert res.info["samples"] == STILL_SAMPLES and FrameRequest(camera=None).shading == "refined"
    again, oid = res.radiance, res.object_id
    inner = binary_erosion(oid == 0, iterations=2)
    rel = _rel(again, target, inner)
    per_pixel = _rel(render(r, out.material)[0], target, inner)
    Image.fromarray(np.concatenate([tonemap(target), tonemap(again)], 1)).save(artifacts / "fit-ggx-mitsuba.png")
    print(f"ggx → srbf, Mitsuba target: relative RMSE {rel:.4f} in the default mode (per pixel, one sample: "
          f"{per_pixel:.4f})")
    assert rel < 0.08


def test_white_stroke_paints_a_highlight(fitter, across):
    v = fitter.views[0]
    base = v.base.copy()
    C = 2.0 * float(base.max())
    notes = fitter.add_stroke(Stroke(points=across(fitter), color=(C, C, C), diameter=8, kappa=0.1))
    assert notes == []
    (target, painted), = fitter.targets()[0]
    out = fitter.fit()
    _constraints_hold(fitter, out)
    # the outcome's figures are the projection of the change onto the request, and the
    # relative change of the unpainted pixels
    pred = fitter.predicted(out.solve.coefficients)
    ask = target[painted] - base[painted]
    assert out.achieved == pytest.approx(((pred[painted] - base[painted]) * ask).sum() / (ask * ask).sum(), rel=1e-9)
    assert out.spill == pytest.approx(_rel(pred, base, ~painted), rel=1e-9)
    assert out.energy == pytest.approx(out.solve.energy.tolist()) and len(out.energy_bound) == 3
    print(f"stroke: {painted.sum()} pixels, achieved {out.achieved:.2f}, spill {out.spill:.3f}, notes {out.notes}")
    assert out.achieved > 0.35         # measured 0.51 with the default weight 0.25 (0.22 at the paper's 1)
    assert out.spill < 0.4             # measured 0.31
    # the renderer shows it: the painted pixels are brighter in the new frame
    r = fitter.renderer
    before = render(r, fitter.base_material)[0].reshape(-1, 3)[v.pix]
    after = render(r, out.material)[0].reshape(-1, 3)[v.pix]
    asked = ask.mean()
    assert after[painted].mean() > before[painted].mean() + 0.3 * asked


def test_strokes_without_colour_fit_a_white_specular_part(fitter, across):
    """White, grey and scaling strokes ask for no colour: the fit keeps one specular part for
    the three channels (solve ``neutral``), which satisfies the energy rows of the darkest
    channel's bound; a coloured stroke is fitted per channel. Forced per channel, the white
    stroke's lobes differ between channels (the light's colour differs), the tint that showed as
    pink and cyan bands."""
    from worker.fit.brush import achromatic

    C = 2.0 * float(fitter.views[0].base.max())
    pts = across(fitter)
    white = Stroke(points=pts, color=(C, C, C), diameter=8, kappa=0.1)
    assert achromatic([white]) and achromatic([Stroke(points=pts, mode="scale", scale=0.3)])
    assert not achromatic([Stroke(points=pts, color=(C, 0.5 * C, C))]) and not achromatic([])
    fitter.add_stroke(white)
    out = fitter.fit()
    c = out.solve.coefficients
    assert np.ptp(c, axis=1).max() == 0.0 and c.max() > 0, c.max()
    _constraints_hold(fitter, out)
    per = fitter.fit(neutral=False).solve.coefficients
    spread = float(np.abs(per - per.mean(axis=1, keepdims=True)).sum() / np.abs(per).sum())
    assert spread > 0.01, spread                   # per channel, the lobes do differ
    fitter.history.clear()
    fitter.add_stroke(Stroke(points=pts, color=(C, 0.6 * C, 0.3 * C), diameter=8, kappa=0.1))
    coloured = fitter.fit().solve.coefficients
    assert np.ptp(coloured, axis=1).max() > 0


def test_a_neutral_solve_is_the_per_channel_one_when_the_channels_agree():
    """With the same rows in every channel and a grey target, one coefficient vector for the
    three channels is what the per-channel solve finds: neutral only ties what is free to
    differ, also with the albedo fitted."""
    from worker.fit.basis import default_basis
    from worker.fit.solve import FitRows, solve

    b = default_basis()
    rng = np.random.default_rng(3)
    T1 = (rng.random((400, b.J)) * 0.02).astype(np.float32)
    T = np.stack([T1] * 3)
    E = np.full((400, 3), 0.3, np.float32)
    tgt = np.repeat(rng.random((400, 1)) * 0.5 + 0.2, 3, axis=1)
    rows = [FitRows(T, E, tgt, np.ones(400))]
    for fa in (False, True):
        a = solve(rows, b, (0.4, 0.4, 0.4), fit_albedo=fa)
        n = solve(rows, b, (0.4, 0.4, 0.4), fit_albedo=fa, neutral=True)
        # equal to the solvers' tolerance (their active sets grow along different paths)
        assert np.allclose(n.coefficients, a.coefficients, atol=1e-4 * a.coefficients.max()), fa
        assert np.allclose(n.albedo, a.albedo, atol=1e-6) and n.residual_rms == pytest.approx(a.residual_rms, rel=1e-6)


def test_unpainted_weight_keeps_untouched_regions(fitter, across):
    """The paper's limitation (§5): unpainted regions change too. Weighting them keeps them:
    the change falls as the weight rises, at the price of a weaker stroke."""
    base = fitter.views[0].base.copy()
    C = 2.0 * float(base.max())
    fitter.add_stroke(Stroke(points=across(fitter), color=(C, C, C), diameter=8, kappa=0.1))
    rows = [(uw, fitter.fit(unpainted_weight=uw)) for uw in (0.1, 1.0, 4.0)]
    for uw, o in rows:
        print(f"unpainted weight {uw}: spill {o.spill:.3f}, achieved {o.achieved:.2f}")
    sp = [o.spill for _, o in rows]
    ach = [o.achieved for _, o in rows]
    assert sp[0] > sp[1] > sp[2] and ach[0] > ach[1] > ach[2]
    assert sp[2] < 0.5 * sp[1]         # measured 0.040 against 0.132


def test_fitting_the_albedo_lets_a_matte_object_darken(fitter, across):
    """The specular part only adds light: with ρ_d given, a darkening stroke on a Lambertian
    object achieves nothing; fitting ρ_d too (energy rows Σ g c + ρ_d ≤ 1) achieves it."""
    fitter.add_stroke(Stroke(points=across(fitter), mode="scale", scale=0.3, diameter=12, kappa=0.0))
    fixed = fitter.fit()
    free = fitter.fit(fit_albedo=True)
    print(f"darkening: achieved {fixed.achieved:.2f} with ρ_d given, {free.achieved:.2f} with ρ_d fitted "
          f"({np.round(free.material.albedo, 3).tolist()}); spill {free.spill:.3f}")
    assert abs(fixed.achieved) < 0.02
    assert free.achieved > 0.3                                  # measured 0.61
    assert max(free.material.albedo) < max(fitter.albedo)
    c = free.solve.coefficients
    rows = fitter.basis.energy_rows() @ c + np.asarray(free.material.albedo)
    assert (c >= 0).all() and rows.max() <= 1.0 + 1e-7


def test_negative_stroke_removes_a_highlight(fitter):
    fitter.set_base_material(TARGET_GGX)
    v = fitter.views[0]
    base = v.base.copy()
    lum = base.mean(1)
    hot = int(np.argmax(lum))                                  # the brightest highlight pixel
    x, y = v.xy[hot]
    fitter.add_stroke(Stroke(points=[(x - 3.0, y), (x + 3.0, y)], color=(-1.0, -1.0, -1.0), diameter=10, kappa=0.0))
    (target, painted), = fitter.targets()[0]
    diffuse = (fitter.albedo * v.E)[painted].mean()
    before = base[painted].mean() - diffuse                     # highlight above the diffuse level
    left = {}
    for uw in (1.0, 0.1):
        out = fitter.fit(unpainted_weight=uw)
        _constraints_hold(fitter, out)
        left[uw] = (fitter.predicted(out.solve.coefficients)[painted].mean() - diffuse) / before
        print(f"unpainted weight {uw}: {left[uw]:.2f} of the highlight over diffuse is left")
    assert left[1.0] < 0.7     # measured 0.59: the highlight's half vectors light unpainted pixels too
    assert left[0.1] < 0.3


def test_unconstrained_can_break_energy_conservation(fitter, across):
    C = 50.0 * float(fitter.views[0].base.max())
    fitter.add_stroke(Stroke(points=across(fitter), color=(C, C, C), diameter=16, kappa=0.0))
    bound = float((1 - fitter.albedo).min())
    con = fitter.fit(constrained=True)
    unc = fitter.fit(constrained=False)
    print(f"energy rows max: constrained {con.solve.energy_max:.3f}, unconstrained {unc.solve.energy_max:.3f} (bound {bound})")
    assert con.solve.energy_max <= bound + 1e-7
    assert unc.solve.energy_max > bound
    assert unc.solve.residual_rms < con.solve.residual_rms


def test_undo_redo_refit(fitter, across):
    empty = fitter.fit().solve.coefficients
    assert np.abs(empty).max() < 1e-5, np.abs(empty).max()   # no strokes on a Lambertian: nothing to add (peaks are ~1-30)
    C = 2.0 * float(fitter.views[0].base.max())
    fitter.add_stroke(Stroke(points=across(fitter), color=(C, C, C)))
    painted = fitter.fit().solve.coefficients
    fitter.undo()
    np.testing.assert_allclose(fitter.fit().solve.coefficients, empty, atol=1e-5)   # QP tolerance, warm-started
    fitter.redo()
    np.testing.assert_allclose(fitter.fit().solve.coefficients, painted, rtol=1e-6, atol=1e-8)


def test_strokes_off_the_object_are_noted(fitter):
    notes = fitter.add_stroke(Stroke(points=[(1.0, 1.0), (3.0, 1.0)], color=(5, 5, 5), diameter=2))
    assert notes and "touches no pixel" in notes[0]
    out = fitter.fit()
    assert out.painted == 0 and out.notes
    with pytest.raises(FitError, match="view 3"):
        fitter.add_stroke(Stroke(points=[(1.0, 1.0)], view=3))


def test_several_views_stack_rows(fitter, across):
    cam = fitter.renderer.scene.spec.camera
    side = cam.model_copy(update={"eye": [2.4, 0.6, 2.2]})
    i = fitter.add_view(side)
    C = 2.0 * float(fitter.views[0].base.max())
    fitter.add_stroke(Stroke(points=across(fitter, view=i), color=(C, C, C), diameter=8, view=i))
    out = fitter.fit()
    assert out.pixels == fitter.views[0].n + fitter.views[1].n
    assert out.painted > 0
    # the stroke painted in the side view brightens it there
    v = fitter.views[i]
    (t, p) = fitter.targets()[0][i]
    assert (fitter.predicted(out.solve.coefficients, i)[p] - v.base[p]).mean() > 0


def test_bad_targets_are_refused(fitter):
    with pytest.raises(FitError, match="aspect"):
        fitter.fit_targets([np.zeros((100, 100, 3), np.float32)])
    with pytest.raises(FitError, match="NaN"):
        fitter.fit_targets([np.full((120, 160, 3), np.nan, np.float32)])
    with pytest.raises(FitError, match="target"):
        fitter.fit_targets([np.zeros((120, 160, 3)), np.zeros((120, 160, 3))])


def test_edge_rows_become_the_mean_over_their_pixel(fitter):
    """For a target image made elsewhere (a pixel's mean over its area), the rows at the edge
    pixels the settled frame samples (silhouettes, occlusions, creases) become the mean of the
    transfer rows of AREA_SAMPLES samples over the pixel; the other rows stay; the Gram follows;
    a pixel whose samples are partly off the object is left out of a target's rows."""
    from worker.fit.fitter import AREA_SAMPLES
    from worker.fit.solve import gram

    r = fitter.renderer
    v = fitter.views[0]
    cam = v.camera
    T0, E0 = v.T.copy(), v.E.copy()
    n = fitter.antialias_rows(0)
    px = np.floor(v.xy[:, 1]).astype(np.int64) * cam.width + np.floor(v.xy[:, 0]).astype(np.int64)
    edge = r.edge_mask(cam).reshape(-1)[px]
    changed = (v.T != T0).any(axis=(0, 2)) | (v.E != E0).any(axis=1)
    assert n > 20 and changed.sum() <= n, (n, int(changed.sum()))   # self-occlusions, not only outlines
    assert not (changed & ~edge).any()
    assert (v.mixed & edge).any() and not (v.mixed & ~edge).any()
    # a row against its samples' transfer, computed apart
    i = np.nonzero(changed)[0][len(np.nonzero(changed)[0]) // 2]
    smp = r.area_samples(cam, fitter.obj, px[i:i + 1], AREA_SAMPLES)
    assert len(smp) == AREA_SAMPLES
    T, E = r.transfer(smp, fitter.basis, v.lighting)
    np.testing.assert_allclose(v.T[:, i], T.mean(axis=1), rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(v.E[i], E.mean(axis=0), rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(v.gram, gram(v.T), rtol=1e-6, atol=1e-9 * np.abs(v.gram).max())
    assert fitter.antialias_rows(0) == 0                                  # once per row
    _, valid = fitter.target_rows(0, np.ones((cam.height, cam.width, 3), np.float32))
    assert not (valid & v.mixed).any() and valid.any()
    # a glint narrower than a pixel in the target: its row (and its neighbours') too
    inner = np.nonzero(~v.averaged)[0]
    k = inner[len(inner) // 2]
    img = np.full((cam.height, cam.width, 3), 0.2, np.float32)
    img[px[k] // cam.width, px[k] % cam.width] = 3.0
    steep = fitter.steep_rows(0, img)
    assert steep[k] and 1 <= steep.sum() <= 5, int(steep.sum())
    assert not fitter.steep_rows(0, np.full_like(img, 0.2)).any()
    assert fitter.antialias_rows(0, extra=steep) == int((steep & ~edge).sum()) >= 1
    assert v.averaged[k] and (v.T[:, k] != T0[:, k]).any()


def test_a_target_fit_averages_its_edge_rows(fitter):
    """fit_targets (glint fit --target, the REST fit job) makes the edge rows area means first;
    a bad target is refused before that work."""
    v = fitter.views[0]
    with pytest.raises(FitError, match="aspect"):
        fitter.fit_targets([np.zeros((100, 100, 3), np.float32)])
    assert v.averaged is None
    fitter.fit_targets([np.full((v.camera.height, v.camera.width, 3), 0.2, np.float32)])
    assert v.averaged.any() and v.mixed.any()


def test_a_partial_view_extends_to_the_full_view(fitter, across):
    """Quick views: a view built for a few pixels, then extended under a stroke and
    completed, holds exactly the rows of the view built at once (transfer, Gram, base)."""
    from worker.fit.fitter import painted_select, quick_select

    full = fitter.views[0]
    st = Stroke(points=across(fitter), color=(1, 1, 1), diameter=8)
    quick = fitter.build_view(select=quick_select(st, rows=60))
    assert quick.partial and quick.n_object == full.n and quick.n < full.n / 4, (quick.n, full.n)
    # every pixel the stroke paints is built; unbuilt ones are unpainted
    w = stroke_weights(st, quick.cand_xy[quick.unbuilt], quick.footprint)
    assert not np.any(w > 0)
    st2 = Stroke(points=across(fitter, dy=8.0), color=(1, 1, 1), diameter=8)
    added = fitter.extend_view(quick, painted_select(st2))
    assert added > 0 and not np.any(stroke_weights(st2, quick.cand_xy[quick.unbuilt], quick.footprint) > 0)
    fitter.extend_view(quick)
    assert not quick.partial and quick.n == full.n
    order = np.argsort(quick.pix)
    np.testing.assert_array_equal(quick.pix[order], full.pix)
    np.testing.assert_allclose(quick.T[:, order], full.T, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(quick.base[order], full.base, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(quick.gram, full.gram, rtol=1e-4, atol=1e-6 * float(np.abs(full.gram).max()))


def _fits_close_to(fitter, ref, fq, st, what: str) -> None:
    """fq (a fitter on a quick view) fitted to stroke st predicts, on fitter's full view,
    within 5% RMS of ref (the full fit), achieving at least half as much of the stroke."""
    fq.add_stroke(st)
    out = fq.fit()
    a = fitter.predicted(out.solve.coefficients)
    b = fitter.predicted(ref.solve.coefficients)
    rel = float(np.sqrt(((a - b) ** 2).mean()) / np.sqrt((b ** 2).mean()))
    assert rel < 0.05, f"{what} fit differs from the full fit by {rel:.3f} (relative RMS over the view)"
    assert out.achieved > 0.5 * ref.achieved, (out.achieved, ref.achieved)


def test_a_quick_view_fits_close_to_the_full_one(fitter, across):
    """A stroke fitted on a quick view (painted pixels plus a sparse grid, unpainted rows
    weighted for the unbuilt ones) predicts, on the full view, nearly what the full fit does
    (measured 2.7% relative RMS, achieved share 0.506 against 0.503)."""
    from worker.fit.fitter import Fitter, quick_select

    C = 2.0 * float(fitter.views[0].base.max())
    st = Stroke(points=across(fitter), color=(C, C, C), diameter=8)
    fitter.add_stroke(st)
    ref = fitter.fit()
    fq = Fitter(fitter.renderer, "bunny", base_material=fitter.base_material, fit_scale=1.0)
    fq.views.append(fq.build_view(select=quick_select(st, rows=300)))
    assert fq.views[0].partial
    _fits_close_to(fitter, ref, fq, st, "quick-view")


def test_a_quick_view_on_coarse_cuts_fits_close_to_the_full_one(fitter, across):
    """A session's quick view is built on the drag level's cuts (half the transfer's
    cost). Its base rendering is on the same cuts, so nothing unpainted looks changed to the
    fit; the fit predicts, on the full view, nearly what the full fit does."""
    from worker.fit.fitter import Fitter, quick_select

    C = 2.0 * float(fitter.views[0].base.max())
    st = Stroke(points=across(fitter), color=(C, C, C), diameter=8)
    fitter.add_stroke(st)
    ref = fitter.fit()
    fq = Fitter(fitter.renderer, "bunny", base_material=fitter.base_material, fit_scale=1.0)
    fq.views.append(fq.build_view(select=quick_select(st, rows=300), coarse=True))
    v = fq.views[0]
    assert v.coarse and v.provisional
    full_rows = fitter.views[0]
    idx = np.searchsorted(full_rows.pix, v.pix)
    # the rows differ (other cuts), but by a few per cent only
    dT = float(np.linalg.norm(v.T - full_rows.T[:, idx]) / np.linalg.norm(full_rows.T[:, idx]))
    dB = float(np.linalg.norm(v.base - full_rows.base[idx]) / np.linalg.norm(full_rows.base[idx]))
    assert 0 < dT < 0.08 and dB < 0.05, (dT, dB)
    # rows added under a later stroke are on the same cuts
    fq.extend_view(v)
    assert not v.partial and v.coarse and v.provisional
    np.testing.assert_allclose(v.base, fq._shade_base(v), rtol=1e-6)
    _fits_close_to(fitter, ref, fq, st, "coarse quick-view")
