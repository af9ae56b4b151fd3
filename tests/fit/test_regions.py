"""Regions from strokes (worker/fit/regions.py) and their rendering (renderers/layers.py):
the stroke changes what it covers, the rest of the object keeps its material."""
import numpy as np
import pytest

from worker.fit.brush import Stroke
from worker.fit.regions import fit_region, footprint_weights, project, region_weight, rendered_effect
from worker.models import GGX, Lambert, Region, Regions
from worker.renderers import FrameRequest


def _frame(r, material, shading="vertex"):
    return r.render(FrameRequest(camera=r.scene.spec.camera, materials=[material], shading=shading)).radiance


@pytest.mark.parametrize("shading", ["vertex", "pixel"])
def test_the_renderer_blends_the_layers_per_vertex(bunny_renderer, shading):
    """Radiance is linear in each layer's: with one weight w everywhere the frame is
    (1 − w)·base + w·region exactly; where no corner of a pixel's triangle is in the region,
    the pixel is the base's."""
    r = bunny_renderer
    n = len(r.scene.mesh.vertices)
    base, top = Lambert(albedo=(0.6, 0.6, 0.6)), GGX(alpha=0.2, albedo=(0.1, 0.2, 0.5))
    a, b = _frame(r, base, shading), _frame(r, top, shading)
    even = Regions(base=base, vertex_count=n, regions=[Region(name="all", material=top, vertices=list(range(n)),
                                                              weights=[0.3] * n)])
    np.testing.assert_allclose(_frame(r, even, shading), 0.7 * a + 0.3 * b, rtol=1e-4, atol=1e-5)
    half = np.arange(n // 2)
    part = Regions(base=base, vertex_count=n, regions=[Region(name="half", material=top, vertices=half.tolist(),
                                                              weights=[1.0] * len(half))])
    c = _frame(r, part, shading).reshape(-1, 3)
    v = r.view(r.scene.spec.camera)
    outside = (v.tri >= 0) & np.all(r.scene.mesh.faces[np.maximum(v.tri, 0)] >= n // 2, axis=1)
    inside = (v.tri >= 0) & np.all(r.scene.mesh.faces[np.maximum(v.tri, 0)] < n // 2, axis=1)
    assert outside.sum() > 100 and inside.sum() > 100
    np.testing.assert_allclose(c[outside], a.reshape(-1, 3)[outside], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(c[inside], b.reshape(-1, 3)[inside], rtol=1e-5, atol=1e-6)


def test_the_renderer_keeps_the_layers_of_alternating_material_lists(bunny_renderer):
    """Sessions sharing a renderer alternate their material lists frame by frame: each list's
    layers (weights, expansion, blend matrix) are kept, for the last LAYERS_KEPT lists, so a
    region frame does not rebuild them; a list dropped is built again and draws the same."""
    from worker.renderers.layers import LAYERS_KEPT

    r = bunny_renderer
    n = len(r.scene.mesh.vertices)
    base, top = Lambert(albedo=(0.6, 0.6, 0.6)), GGX(alpha=0.2, albedo=(0.1, 0.2, 0.5))
    mats = [Regions(base=base, vertex_count=n, regions=[Region(
        name="r", material=top, vertices=list(range(50 * k, 50 * k + 400)), weights=[0.5] * 400)])
        for k in range(LAYERS_KEPT + 1)]
    a, b = r.layers([mats[0]]), r.layers([mats[1]])
    img = _frame(r, mats[1])
    for _ in range(3):                                  # two sessions' frames, alternating
        assert r.layers([mats[1]]) is b and r.layers([mats[0]]) is a
    for m in mats[2:]:                                  # LAYERS_KEPT − 1 more lists: 9 in all
        r.layers([m])
    assert r.layers([mats[0]]) is a                     # used last of the two: kept
    assert r.layers([mats[1]]) is not b                 # the least recently used went
    np.testing.assert_array_equal(_frame(r, mats[1]), img)
    # bounded by bytes too: over LAYERS_BYTES only the newest list's layers stay
    from worker.renderers.layers import LayersCache
    small = LayersCache(r.scene, max_bytes=1)
    for m in mats[:3]:
        got = small.get([m])
    assert len(small) == 1 and small.get([mats[2]]) is got and got.nbytes > 1


def test_projection_inverts_the_camera_rays(bunny_renderer):
    """A surface point a pixel's ray hits projects back onto that pixel's centre."""
    r = bunny_renderer
    cam = r.scene.spec.camera
    s = r.surface_samples(cam, 0)
    xy, front = project(cam, s.positions)
    assert front.all()
    want = np.stack([s.pix % cam.width + 0.5, s.pix // cam.width + 0.5], 1)
    np.testing.assert_allclose(xy, want, atol=2e-3)


def test_footprint_is_the_brush_dilated_by_its_radius(fitter, across):
    st = Stroke(points=across(fitter), color=(1, 1, 1), diameter=12, kappa=0.05)
    d = np.array([0.0, 3.0, 6.0, 9.0, 12.0, 13.0])
    w = region_weight(st, d)
    np.testing.assert_allclose(w[:3], np.exp(-0.05 * d[:3]))
    assert 0 < w[3] < np.exp(-0.05 * 9.0) and w[4] == 0 and w[5] == 0
    fw = footprint_weights(fitter, [st])
    cam = fitter.views[0].camera
    vs = fitter.renderer.vertex_samples(cam, 0)
    xy, _ = project(cam, vs.positions)
    from worker.fit.brush import polyline_distance
    dist = polyline_distance(xy, np.asarray(st.points))
    np.testing.assert_allclose(fw[vs.pix], region_weight(st, dist), atol=1e-6)
    assert (fw > 0).sum() == (dist <= 12.0).sum() - (dist == 12.0).sum()


@pytest.mark.parametrize("kind", ["highlight", "darkening", "colour"])
def test_a_region_changes_what_the_stroke_covers(fitter, across, kind):
    """One BRDF for the object follows a stroke only partly and changes everything else; a
    region follows it and leaves the object beyond one brush diameter as it was, in rendered
    frames (vertex mode, what the studio shows), not only in the fit's prediction."""
    v = fitter.views[0]
    pts = across(fitter, frac=(0.3, 0.6))
    if kind == "highlight":
        C = 2.0 * float(v.base.max())
        st = Stroke(points=pts, color=(C, C, C), diameter=12)
    elif kind == "darkening":
        st = Stroke(points=pts, mode="scale", scale=0.3, diameter=12)
    else:
        st = Stroke(points=pts, color=tuple((v.base.mean(0) * [1.6, 0.8, 0.5]).tolist()), diameter=12)
    fitter.add_stroke(st)
    out = fit_region(fitter, name="seat")
    assert out.material.model == "regions" and out.material.base == fitter.base_material
    assert out.region.name == "seat" and len(out.region.vertices) > 20
    r, cam = fitter.renderer, v.camera
    got = rendered_effect(r, 0, cam, v.lighting, fitter.base_material, out.material, [st])
    one = rendered_effect(r, 0, cam, v.lighting, fitter.base_material, fitter.fit(fit_albedo=True).material, [st])
    print(f"{kind}: region {got['achieved']:.2f} / {got['spill_far']:.3f} (predicted {out.achieved:.2f} / "
          f"{out.spill_far:.3f}); one BRDF {one['achieved']:.2f} / {one['spill_far']:.3f}")
    # measured (bunny, sunset): region 0.88-0.99 achieved, 0.4-1.5% spill beyond D;
    # one BRDF 0.50-0.57 and 10-38%
    assert got["achieved"] >= 0.8, got
    assert got["spill_far"] <= 0.03, got
    assert one["achieved"] < got["achieved"] - 0.2 and one["spill_far"] > 3 * got["spill_far"], (one, got)
    # the fit predicts what the renderer draws
    assert got["achieved"] == pytest.approx(out.achieved, abs=0.06)
    assert got["spill_far"] == pytest.approx(out.spill_far, abs=0.01)


@pytest.mark.parametrize("kind", ["glossy highlight", "paint colour"])
def test_what_a_real_material_gives_is_painted_as_asked(fitter, kind):
    """The benchmark's glossy highlight and paint colour (bench/fitting.py ``glossy_highlight``,
    ``paint_colour``): the brightest stroke along a row that a lacquer of the object's colour
    itself answers (delivers ANSWERED of its one-colour ask, ``own_share``), asking for that
    lacquer's mean radiance there; the base tinted within energy, asking for its mean radiance
    along the standard stroke. A region reaches either."""
    from bench import fitting

    label, st, gain, own = (fitting.glossy_highlight if kind == "glossy highlight" else fitting.paint_colour)(fitter)
    v = fitter.views[0]
    assert label == kind and st is not None
    if kind == "glossy highlight":
        assert gain > 1.2, gain                                       # a highlight: brighter than the base
        assert own >= fitting.ANSWERED, own                           # the lacquer answers it itself
    else:                                                             # redder than the base there
        core = np.asarray(st.color) / v.base.mean(0)
        assert core[0] > core[1] > core[2], core
    fitter.add_stroke(st)
    out = fit_region(fitter, name=kind, parts="auto")
    got = rendered_effect(fitter.renderer, 0, v.camera, v.lighting, fitter.base_material, out.material, [st])
    print(f"{kind} ({gain:.2f}× the base there, the material's own share {own:.2f}): region "
          f"{got['achieved']:.2f} / {got['spill_far']:.3f}")
    # measured: glossy 0.86 / 0.079 (3.35× the base there), paint 0.98 / 0.012; the issue's ≥ 0.8, ≤ 0.10
    assert got["achieved"] >= 0.8 and got["spill_far"] <= 0.10, got


def test_a_material_answers_its_own_radiance_not_one_colour_along_a_stroke(fitter):
    """``own_share`` measures a material as a fit is measured: the radiance a stroke asks for
    (eq. 23) delivers all of it, the base none. One colour a little brighter than the base's mean
    along a stroke asks to darken where the base is brighter than it and to brighten elsewhere: a
    material that adds that mean lift evenly (a lacquer under even light) gets little of it."""
    from bench.fitting import own_share
    from worker.fit.brush import apply_stroke, stroke_weights

    v = fitter.views[0]
    xy, b = v.xy, v.base.astype(np.float64)
    y0 = float(np.median(xy[:, 1]))
    row = xy[np.abs(xy[:, 1] - y0) <= 2 * v.footprint, 0]
    x0, x1 = float(np.quantile(row, 0.25)), float(np.quantile(row, 0.75))
    st = Stroke(points=[(x0, y0), (x1, y0)], color=(1.0, 1.0, 1.0), diameter=12, kappa=0.05)
    w = stroke_weights(st, xy)
    on = w > 0
    st = st.model_copy(update={"color": tuple((1.05 * b[on].mean(0)).tolist())})
    t = apply_stroke(b.copy(), st, w)
    assert own_share(st, xy, b, t) == pytest.approx(1.0)
    assert own_share(st, xy, b, b) == pytest.approx(0.0)
    even = b.copy()
    even[on] += (t - b)[on].mean(0)                   # the ask's mean change, everywhere alike
    share = own_share(st, xy, b, even)
    spread = np.abs(b[on] - b[on].mean(0)).mean() / b[on].mean()
    print(f"the base along the stroke spreads {spread:.2f} of its mean: an even lift gets {share:.3f}")
    assert spread > 0.05 and share < 0.5, (spread, share)


def test_extending_and_adding_regions(fitter, across):
    v = fitter.views[0]
    C = 2.0 * float(v.base.max())
    fitter.add_stroke(Stroke(points=across(fitter, frac=(0.2, 0.4)), color=(C, C, C), diameter=10))
    first = fit_region(fitter, name="a")
    fitter.set_base_material(first.material)
    fitter.history.clear()
    fitter.add_stroke(Stroke(points=across(fitter, frac=(0.5, 0.7)), color=(C, C, C), diameter=10))
    ext = fit_region(fitter, name="a")
    assert ext.extended and [g.name for g in ext.material.regions] == ["a"]
    assert set(first.region.vertices) < set(ext.region.vertices)
    # the base under the region is the first fit's base, not the first fit
    assert ext.material.base == first.material.base
    other = fit_region(fitter, name="b")
    assert not other.extended and [g.name for g in other.material.regions] == ["a", "b"]
    assert other.material.regions[0] == first.region


def test_a_stroke_off_the_object_is_refused(fitter):
    from worker.fit.fitter import FitError

    fitter.add_stroke(Stroke(points=[(1.0, 1.0)], color=(1, 1, 1), diameter=2))
    with pytest.raises(FitError, match="touch no vertex"):
        fit_region(fitter)


def test_a_highlight_the_light_cannot_give_is_explained(fitter, across):
    """Under the sunset the painted pixels' mirror directions see little light: a bright white
    stroke falls short, and the notes say why and what would give it; one brighter than the sun
    above the surface is impossible for any BRDF; a darkening asks for no guidance."""
    pts = across(fitter, frac=(0.3, 0.6))
    fitter.add_stroke(Stroke(points=pts, color=(3.0, 3.0, 3.0), diameter=12))
    out = fit_region(fitter)
    g = out.guidance
    assert out.achieved < 0.8 and g is not None
    assert g["asked"] > g["mirror"] and g["covered"] < 0.8 and g["impossible_share"] < 0.5
    assert 0 <= g["rotate_to_deg"] < 360 and g["covered_at_rotation"] >= g["covered"]
    told = [n for n in out.notes if "little light near the mirror direction" in n]
    assert told and f"covers {g['covered'] * 100:.0f}% of the highlight asked" in told[0], out.notes
    assert "as a region" not in told[0]           # it is a region already
    fitter.history.clear()
    fitter.add_stroke(Stroke(points=pts, color=(500.0, 500.0, 500.0), diameter=12))
    out = fit_region(fitter)
    assert out.guidance["impossible_share"] > 0.5
    assert any(n.startswith("no BRDF can make this highlight here") for n in out.notes), out.notes
    fitter.history.clear()
    fitter.add_stroke(Stroke(points=pts, mode="scale", scale=0.3, diameter=12))
    assert fit_region(fitter).guidance is None


def test_a_region_in_parts_aims_a_lobe_per_part(fitter, across):
    """A highlight across a curved surface: the region's vertices grouped by mirror direction,
    a BRDF each, fitted together (solve_blocks), give more of it than one BRDF for the region;
    the parts partition the region. One part through solve_blocks is solve's fit_albedo problem."""
    from worker.fit import regions as R
    from worker.fit.solve import solve_blocks

    fitter.set_base_material(Lambert(albedo=(0.7, 0.7, 0.7)))       # a bright base: little energy left
    v = fitter.views[0]
    C = 2.0 * float(v.base.max())
    fitter.add_stroke(Stroke(points=across(fitter, frac=(0.25, 0.75)), color=(C, C, C), diameter=6))
    one = fit_region(fitter, name="hl", parts=1)
    two = fit_region(fitter, name="hl", parts=2)
    print(f"highlight: 1 part {one.achieved:.2f}, 2 parts {two.achieved:.2f}")
    assert [g.name for g in two.material.regions] == ["hl/1", "hl/2"]
    a, b = (set(g.vertices) for g in two.regions)
    assert not a & b and a | b == set(one.region.vertices)
    assert two.achieved > one.achieved + 0.04          # measured 0.71 against 0.64
    # extending "hl" replaces both parts
    fitter.set_base_material(two.material)
    again = fit_region(fitter, name="hl", parts=1)
    assert [g.name for g in again.material.regions] == ["hl"] and again.extended
    # the stacked solver with one block is the single solve with the albedo fitted
    fitter.set_base_material(one.material.base)
    w = R.footprint_weights(fitter, fitter.history.strokes)
    off, n_o = R.object_range(fitter.renderer, 0)
    p = R._prepare_view(fitter, 0, v, w, off, fitter.base_material, fitter.base_material, 0.25)
    J = fitter.basis.J
    A = np.zeros((3, len(p["R"]), J + 1), np.float32)
    for c in range(3):
        A[c, :, :J] = p["Pw"] @ p["T"][c].astype(np.float64)
        A[c, :, J] = p["Pw"] @ p["E"][:, c].astype(np.float64)
    blk = solve_blocks(A, p["target"][p["R"]] - p["fixed"], p["weight"], fitter.basis, 1,
                       np.asarray(fitter.base_material.albedo)[None])
    np.testing.assert_allclose(blk.albedo[0], one.solve.albedo, atol=2e-3)
    pred_one = A[:, :, :J].astype(np.float64) @ one.solve.coefficients.T[:, :, None]
    pred_blk = A[:, :, :J].astype(np.float64) @ blk.coefficients[0].T[:, :, None]
    assert np.abs(pred_one - pred_blk).max() < 0.01 * np.abs(pred_one).max()
