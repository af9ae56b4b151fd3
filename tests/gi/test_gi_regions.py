"""Painted regions under global illumination (renderers/gi/renderer.py ``_n_units``,
fit/regions.py ``fit_region_gi``): a region is drawn at the camera hits with its own material,
its weight interpolated from the hit face's corners and taken from its object's own unit; the
session's strokes in region mode fit the region's material through the GI tensors."""
import numpy as np
import pytest

from gi_harness import gi_renderer, middle_row, scene_with
from gi_harness import session_frame as _frame
from gi_harness import session_runtime as _runtime
from worker.models import Regions
from worker.models.regions import Region
from worker.protocol import new_state
from worker.renderers import FrameRequest, Lighting
from worker.scene import GGX

# the live unit's entries are half floats (freeze.py), the frozen part single: the same radiance
# drawn with another unit live differs by up to ~1e-4 of the frame's largest value
TOL = 1e-3


@pytest.fixture(scope="module")
def sofa(shared_assets):
    return gi_renderer(scene_with("sofa", 48, 36), {"spp": 64, "series": [64, 1, 1, 1]})


def _draw(r, mats, bounces=None):
    spec = r.scene.spec
    env = spec.environment
    keep = r.max_bounces
    if bounces is not None:
        r.max_bounces = bounces
    try:
        out = r.render(FrameRequest(camera=spec.camera, lighting=Lighting(env.rotation_deg, env.intensity),
                                    materials=mats))
    finally:
        r.max_bounces = keep
    return out.radiance.astype(np.float64).copy(), out.object_id


def _with_region(r, obj: int, material, weight=None, frac=1.0):
    """The object's scene material with one region of ``material`` over the first ``frac`` of its
    vertices (all at ``weight``, or 1)."""
    n = int((r.scene.object_of_vertex == obj).sum())
    ids = np.arange(int(n * frac))
    w = np.full(len(ids), 1.0 if weight is None else weight)
    base = r.scene.spec.objects[obj].material
    return Regions(base=base, vertex_count=n, regions=[Region(name="r", material=material, vertices=ids.tolist(),
                                                              weights=w.tolist())])


def test_a_region_of_the_base_material_changes_nothing(sofa):
    mats = list(sofa.scene.materials)
    before, _ = _draw(sofa, mats)
    mats[0] = _with_region(sofa, 0, mats[0], weight=0.6, frac=0.5)
    after, _ = _draw(sofa, mats)
    assert np.abs(after - before).max() <= TOL * before.max()


def test_a_region_is_its_material_at_the_first_bounce(sofa):
    """Direct light only (one bounce): a region of weight 1 over the whole object draws as the
    object with the region's material; at weight ½ as the mean of the two frames. With every
    bounce too the half-weight frame is the mean, and the other objects' pixels keep the base's
    (the light the region sends on is its object's own material's)."""
    red = GGX(alpha=0.3, albedo=(0.6, 0.1, 0.1), specular=(0.2, 0.2, 0.2))
    mats = list(sofa.scene.materials)
    base1, ids = _draw(sofa, mats, bounces=1)
    plain = list(mats); plain[0] = red
    red1, _ = _draw(sofa, plain, bounces=1)
    full = list(mats); full[0] = _with_region(sofa, 0, red)
    got1, _ = _draw(sofa, full, bounces=1)
    on = ids == 0
    assert on.sum() > 100
    assert np.abs(got1 - red1)[on].max() <= TOL * red1[on].max()
    assert np.abs(got1 - base1)[on].mean() > 0.05 * base1[on].mean()       # the region is drawn
    half = list(mats); half[0] = _with_region(sofa, 0, red, weight=0.5)
    got_half, _ = _draw(sofa, half, bounces=1)
    assert np.abs(got_half - 0.5 * (base1 + red1))[on].max() <= TOL * red1[on].max()
    # every bounce: the region's BRDF takes all the light arriving at its hits (linear in its
    # weight there too); the light it sends on to other surfaces stays the base's
    base_n, _ = _draw(sofa, mats)
    got_n, _ = _draw(sofa, full)
    half_n, _ = _draw(sofa, half)
    assert np.abs(half_n - 0.5 * (base_n + got_n))[on].max() <= TOL * got_n[on].max()
    assert np.abs(got_n - base_n)[on].mean() > 0.05 * base_n[on].mean()
    assert np.abs(got_n - base_n)[~on].max() <= TOL * base_n.max()


@pytest.mark.parametrize("kind", ["darkening", "colour change"])
def test_strokes_paint_a_region_under_gi(sofa, kind):
    """A stroke in region mode on a GI scene makes a region and fits its material through the
    tensors: the requested change on the painted pixels, nothing far from the stroke, and the
    frame shows what the fit predicted; undo takes it back."""
    rt = _runtime(sofa)
    before, ids = _frame(rt)
    y, x0, x1 = middle_row(ids, 0)
    ev = rt.handle({"seq": 1, "type": "region", "action": "paint", "name": "seat"})
    assert ev[0]["stats"]["painting"] == "seat"
    if kind == "darkening":
        stroke = {"mode": "scale", "scale": 0.5}
    else:
        m = before[y, int(x0):int(x1)].mean(0)
        stroke = {"mode": "color", "color": (m * np.array([1.3, 0.8, 0.6])).tolist()}
    stroke.update({"points": [[x0, y + 0.5], [x1, y + 0.5]], "diameter": 4, "kappa": 0.05})
    assert rt.handle({"seq": 2, "type": "stroke", "stroke": stroke})[0]["rejected"] is False
    fit = rt.fit_if_needed()[0]
    st = fit["stats"]
    assert fit["material"]["model"] == "regions" and st["regions"] == ["seat"], fit
    assert st["achieved"] >= 0.8 and st["spill_far"] <= 0.1, st
    assert any("traced into the tensors" in n for n in fit["notes"]), fit["notes"]
    m = rt.state.materials[0]
    assert isinstance(m, Regions) and m.regions[0].name == "seat"
    after, _ = _frame(rt)
    painted = np.zeros_like(ids, bool)
    painted[y, int(x0) + 1:int(x1) - 1] = True
    painted &= ids == 0
    ratio = after[painted].sum(0) / before[painted].sum(0)
    if kind == "darkening":
        assert np.all(np.abs(ratio - 0.5) < 0.12), ratio
    else:
        assert ratio[0] > ratio[2] + 0.3, ratio
    far = np.ones_like(ids, bool)
    far[max(y - 6, 0):y + 7] = False
    far &= ids == 0
    assert np.abs(after - before)[far].mean() <= 0.02 * before[far].mean()
    rt.handle({"seq": 3, "type": "undo"})
    assert rt.fit_if_needed()[0]["material"]["model"] != "regions"
    again, _ = _frame(rt)
    assert np.abs(again - before).max() <= TOL * before.max()


RED = {"model": "lambert", "albedo": [0.9, 0.04, 0.04]}


def _left_half(r, obj: int, material):
    """The object's material with a region of ``material`` over the vertices left of its middle
    (x below the median), weight 1."""
    from worker.scene import parse_material

    lo, hi = np.searchsorted(r.scene.object_of_vertex, [obj, obj + 1])
    x = r.scene.mesh.vertices[lo:hi, 0]
    ids = np.nonzero(x < np.median(x))[0]
    return Regions(base=r.scene.spec.objects[obj].material, vertex_count=int(hi - lo),
                   regions=[Region(name="left", material=parse_material(material), vertices=ids.tolist(),
                                   weights=[1.0] * len(ids))])


@pytest.fixture(scope="module")
def traced(sofa):
    """The sofa scene with a region over the sofa's left half traced into the tensors."""
    design = _left_half(sofa, 0, RED)
    opts = {"spp": 64, "series": [64, 1, 1, 1], "painted": [{"object": "sofa", "material": design.model_dump(mode="json")}]}
    return gi_renderer(scene_with("sofa", 48, 36), opts), design


def test_a_traced_region_of_the_base_material_is_the_base(sofa, traced):
    """Traced into the tensors, a region holding the object's own material draws what the
    tensors without it draw (the same paths: a unit choice takes its own random number)."""
    r, design = traced
    base_mats = list(sofa.scene.materials)
    before, _ = _draw(sofa, base_mats)
    same = design.model_copy(update={"regions": [design.regions[0].model_copy(update={"material": base_mats[0]})]})
    mats = list(r.scene.materials)
    mats[0] = same
    got, _ = _draw(r, mats)
    assert np.abs(got - before).max() <= TOL * before.max()


def test_a_traced_region_sends_its_own_light(sofa, traced):
    """A red region traced into the tensors: the sofa's pixels are what the first-vertex region
    draws (up to the light the red half sends on to the other half), and the walls and floor
    receive red light off it where the first-vertex region left them the base's."""
    r, design = traced
    mats = list(r.scene.materials)
    mats[0] = design
    got, ids = _draw(r, mats)
    first, _ = _draw(sofa, mats)             # the same design, the region at the camera hits only
    base, _ = _draw(sofa, list(sofa.scene.materials))
    on = ids == 0
    assert np.abs(got[on] - first[on]).mean() < 0.1 * first[on].mean()
    others = (ids >= 1)
    # light off the red half: green falls on the other objects, red hardly
    g = got[others].sum(0) / first[others].sum(0)
    assert g[1] < 0.99 and g[0] > g[1] + 0.01, g
    assert np.abs(first[others] - base[others]).max() <= TOL * base.max()
    # a design other than the traced one: its regions drawn at the camera hits, the traced
    # region's light the sofa's own material's (the base frame where the design has none)
    plain, _ = _draw(r, list(r.scene.materials))
    assert np.abs(plain - base).max() <= TOL * base.max()


def test_painted_options_are_checked(sofa):
    from worker.renderers.gi.options import GIOptionsError, parse_options, unit_layout

    sc = sofa.scene
    design = _left_half(sofa, 0, RED).model_dump(mode="json")
    for bad, msg in (({"object": "nothing", "material": design}, "no object"),
                     ({"object": "sofa", "material": RED}, "not a material with painted regions"),
                     ({"object": "side_wall", "material": design}, "not editable"),
                     ({"object": "floor", "material": design}, "vertices")):
        with pytest.raises(GIOptionsError, match=msg):
            unit_layout(sc, parse_options(sc, {"painted": [bad]}))


def test_strokes_paint_a_traced_region(traced):
    """A session on tensors with the region traced in: a stroke inside the region (its weights
    unchanged) fits the region's material with the traced unit live, its light through the
    tails too (Gauss-Newton steps), and the frame shows the fit's prediction."""
    r, design = traced
    st = new_state(r.scene.spec)
    st.materials[0] = design
    st.base_material = design
    rt = _runtime(r, st)
    before, ids = _frame(rt)
    assert r._region_units[(0, "left")] < r.U                 # the traced unit, not a first-vertex one
    # the pixels whose face lies wholly in the region, and a stroke along the middle of them
    lo = int(np.searchsorted(r.scene.object_of_vertex, 0))
    w = design.regions[0].dense(design.vertex_count)
    full = np.zeros(ids.size, bool)
    on = np.nonzero(r.prim.obj == 0)[0]
    inner = on[(w[r.geo.F[r.prim.face[on]] - lo] >= 1.0).all(1)]
    full[r.prim.pixel[inner]] = True
    full = full.reshape(ids.shape)
    y, x0, x1 = middle_row(full.astype(int), 1)
    rt.handle({"seq": 1, "type": "region", "action": "paint", "name": "left"})
    stroke = {"mode": "scale", "scale": 0.5, "points": [[x0, y + 0.5], [x1, y + 0.5]], "diameter": 2, "kappa": 0.05}
    assert rt.handle({"seq": 2, "type": "stroke", "stroke": stroke})[0]["rejected"] is False
    fit = rt.fit_if_needed()[0]
    assert r._region_units[(0, "left")] < r.U, "the region's weights changed"
    assert not any("traced into the tensors" in n for n in fit.get("notes", [])), fit["notes"]
    assert fit["stats"]["achieved"] >= 0.3 and fit["stats"]["spill_far"] <= 0.3, fit["stats"]
    after, _ = _frame(rt)
    band = full.copy()
    band[:y - 1] = band[y + 2:] = False
    assert after[band].mean() < 0.9 * before[band].mean()


def test_traced_regions_light_the_room_as_mitsuba_does(sofa, traced, tmp_path):
    """The design exported to Mitsuba (blendbsdf weighted by the PLY's per-vertex attribute, a
    path tracer of the same depth): the light the red half sends on to the floor and walls is
    Mitsuba's in the traced tensors, and missing where the region is drawn at the camera hits
    only (green over the other objects, relative to Mitsuba's)."""
    pytest.importorskip("mitsuba")
    import hashlib

    from gi_harness import CACHE
    from helpers import cache_lock
    from worker.export.run import export
    from worker.scene import LoadedScene

    r, design = traced
    spec = r.scene.spec.model_copy(deep=True)
    spec.objects[0].material = design
    scene = LoadedScene(spec, r.scene.root, envmap=r.scene.envmap)
    out = tmp_path / "mi"
    export(scene, "mitsuba", out, mitsuba_spp=256)
    xml = (out / "scene.xml").read_text()
    assert "blendbsdf" in xml and "mesh_attribute" in xml
    # the GI renderer's depth (four bounces: the series' length) and two-sided surfaces
    assert 'name="max_depth" value="5"' in xml and 'type="twosided"' in xml
    key = hashlib.sha256(xml.encode() + b"".join(p.read_bytes() for p in sorted(out.glob("*.ply")))).hexdigest()[:32]
    path = CACHE / "gi-mitsuba" / f"regions-{key}.npy"
    with cache_lock(str(path)):
        if not path.is_file():
            import mitsuba as mi
            mi.set_variant("scalar_rgb")
            s = mi.load_file(str(out / "scene.xml"))
            img = np.stack([np.asarray(mi.render(s, seed=k), np.float32)[..., :3] for k in (1, 2)])
            path.parent.mkdir(parents=True, exist_ok=True)
            np.save(path.with_suffix(".tmp.npy"), img)
            path.with_suffix(".tmp.npy").replace(path)
        ref2 = np.load(path)
    ref = ref2.mean(0)
    mats = list(r.scene.materials)
    mats[0] = design
    got, ids = _draw(r, mats)
    first, _ = _draw(sofa, mats)
    others = ids >= 1
    g_traced = got[others, 1].sum() / ref[others, 1].sum()
    g_first = first[others, 1].sum() / ref[others, 1].sum()
    noise = np.abs(ref2[0][others, 1].sum() - ref2[1][others, 1].sum()) / ref[others, 1].sum()
    print(f"green on the other objects against Mitsuba: traced {g_traced:.4f}, camera hits only {g_first:.4f} "
          f"(Mitsuba's two halves differ by {noise:.4f})")
    assert abs(g_traced - 1.0) < 0.02 and g_first - 1.0 > abs(g_traced - 1.0) + 0.01, (g_traced, g_first, noise)


def test_a_first_vertex_region_linearises_as_the_general_expansion(sofa):
    """A region drawn at the camera hits is linear in its coefficients: the short expansion
    (no terms of its d) equals the general one, and the radiance it predicts is exact."""
    from worker.fit.basis import default_basis
    from worker.renderers.gi import strokes as stm

    mats = list(sofa.scene.materials)
    mats[0] = _with_region(sofa, 0, GGX(alpha=0.3, albedo=(0.6, 0.1, 0.1), specular=(0.2, 0.2, 0.2)), frac=0.5)
    sofa.apply_materials(mats)
    u = sofa._region_units[(0, "r")]
    assert u > sofa.U
    samples = sofa.surface_samples(None, 0)
    smp = sofa._sampled_at(u, samples)
    assert smp.linear
    basis = default_basis()
    m = sofa._mat(u)
    p = sofa.projection(u, m)
    sm = stm.srbf_map(basis, sofa.J, sofa.layers, sofa.J2, sofa._unit_q(u), p.ok)
    ext = stm.extend_map(sm.first, [])
    co = sofa._coefficients(u, m)
    fast = smp.linearise(co, sm, ext)
    smp.linear = False
    slow = smp.linearise(co, sm, ext)
    for a, b in zip(fast, slow):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6 * np.abs(b).max())
    np.testing.assert_allclose(fast[3], smp.radiance(co), rtol=1e-6, atol=1e-9)


def test_one_brdf_strokes_over_a_painted_object_under_gi(sofa):
    """After ``stop``, strokes fit one BRDF for the object again (its regions give way to it, as
    in direct light): the fit's rows and its exact radiance are of the object without its
    regions, so the frame shows what the fit reported."""
    rt = _runtime(sofa)
    before, ids = _frame(rt)
    y, x0, x1 = middle_row(ids, 0)
    rt.handle({"seq": 1, "type": "region", "action": "paint", "name": "seat"})
    dark = {"mode": "scale", "scale": 0.4, "points": [[x0, y + 0.5], [x1, y + 0.5]], "diameter": 4, "kappa": 0.05}
    rt.handle({"seq": 2, "type": "stroke", "stroke": dark})
    assert rt.fit_if_needed()[0]["material"]["model"] == "regions"
    painted, _ = _frame(rt)
    rt.handle({"seq": 3, "type": "region", "action": "stop"})
    up = {**dark, "scale": 1.5, "points": [[x0, y - 2.5], [x1, y - 2.5]]}
    rt.handle({"seq": 4, "type": "stroke", "stroke": up})
    fit = rt.fit_if_needed()[0]
    assert fit["material"]["model"] == "srbf", fit["material"]["model"]
    after, _ = _frame(rt)
    # the frame is the plain srbf's: the same as the object given that material directly
    mats = list(sofa.scene.materials)
    from worker.protocol.state import parse_material
    mats[0] = parse_material(fit["material"])
    direct, _ = _draw(sofa, mats)
    assert np.abs(after - direct).max() <= TOL * direct.max()
    assert fit["stats"]["gap"] is None or fit["stats"]["gap"] < 0.05, fit["stats"]


def test_a_one_brdf_stroke_that_falls_short_under_gi_offers_a_region(sofa):
    """Under GI the light near the mirror directions is not measured (a room's walls light them as
    much as the map), but a one-BRDF stroke that falls short still gets a guidance event after its
    frame: what the one BRDF reached and spread to the rest of the object, and a painted region on
    offer. Taken, the same stroke as a region reaches the change and asks for nothing more."""
    from worker.protocol import server_event

    def dark_of(y, x0, x1):
        return {"mode": "scale", "scale": 0.5, "points": [[x0, y + 0.5], [x1, y + 0.5]], "diameter": 4, "kappa": 0.05}

    rt = _runtime(sofa)
    rt.frame(-1)
    _, ids = _frame(rt)
    y, x0, x1 = middle_row(ids, 0)
    rt.handle({"seq": 1, "type": "stroke", "stroke": dark_of(y, x0, x1)})
    st = rt.fit_if_needed()[0]["stats"]
    rt.frame(1)
    got = [e for e in rt.after_frame() if e["type"] == "guidance"]
    assert st["achieved"] < 0.8, st                     # one BRDF darkens the whole sofa
    assert len(got) == 1, got
    g = got[0]
    assert g["object"] == "sofa" and g["region"] and "painting the stroke as a region" in g["message"], g
    assert g["covered"] is None and g["rotate_to_deg"] is None, g          # the light is not measured
    assert g["achieved"] == st["achieved"] and g["spill"] == st["spill"], (g, st)
    assert f"{st['achieved'] * 100:.0f}%" in g["message"]
    server_event.validate_python(g)
    # the offer taken: the same stroke in region mode
    rt2 = _runtime(sofa)
    rt2.frame(-1)
    rt2.handle({"seq": 1, "type": "region", "action": "paint", "name": "seat"})
    rt2.fit_if_needed()
    rt2.frame(1)
    rt2.after_frame()
    rt2.handle({"seq": 2, "type": "stroke", "stroke": dark_of(y, x0, x1)})
    st2 = rt2.fit_if_needed()[0]["stats"]
    rt2.frame(2)
    assert st2["achieved"] >= 0.8, st2
    assert not [e for e in rt2.after_frame() if e["type"] == "guidance"]


def test_a_grown_region_refreezes_only_the_pixels_it_changed(sofa):
    """A stroke extends a region whose unit is live: the freeze its new weights need computes
    only the pixels whose units changed or that are on the region (the rest of V does not depend
    on its material, and its weights reach only the first vertex of its own pixels), and gives
    what a whole-image freeze gives: the same V, live rows and frame. Back to the layout before
    (a region fit draws the look below the region), its freeze is taken back."""
    red = GGX(alpha=0.3, albedo=(0.6, 0.1, 0.1), specular=(0.2, 0.2, 0.2))
    mats = list(sofa.scene.materials)
    mats[0] = _with_region(sofa, 0, red, frac=0.3)
    sofa.apply_materials(mats)
    u = sofa._region_units[(0, "r")]
    sofa._stash.clear()                                 # (the module's other tests' layouts)
    sofa.frozen = None
    sofa.freeze(u)
    before = sofa.frozen
    P = len(sofa.pu.k0)
    assert sofa.last_freeze_pixels == P
    img_before, _ = _draw(sofa, mats)
    grown = list(mats)
    grown[0] = _with_region(sofa, 0, GGX(alpha=0.2, albedo=(0.1, 0.5, 0.1), specular=(0.3, 0.3, 0.3)), frac=0.45)
    sofa.apply_materials(grown)
    assert sofa._region_units[(0, "r")] == u and sofa.frozen is None
    sofa.freeze(u)
    part = sofa.frozen
    assert 0 < sofa.last_freeze_pixels < 0.9 * P, (sofa.last_freeze_pixels, P)
    img_part, _ = _draw(sofa, grown)
    assert sofa.frozen is part                          # drawn with it, not frozen again
    # back and forth: each layout's freeze is taken back
    kept = list(sofa._stash)                            # (what a failure below needs to say)
    sofa.apply_materials(mats)
    # failed once in CI (the freeze was not found again); the layouts kept and asked for say why
    assert sofa.frozen is before, (kept, sofa._painted_key, sofa.frozen)
    assert np.array_equal(_draw(sofa, mats)[0], img_before) and sofa.frozen is before
    sofa.apply_materials(grown)
    assert sofa.frozen is part
    # against a freeze of every pixel
    sofa._stash.clear()
    sofa.frozen = None
    sofa.freeze(u)
    whole = sofa.frozen
    assert sofa.last_freeze_pixels == P
    img_whole, _ = _draw(sofa, grown)
    assert np.array_equal(part.live, whole.live) and np.array_equal(part.V, whole.V)
    assert np.array_equal(img_part, img_whole)
    # another unit's material changed meanwhile: every pixel again
    other = list(grown)
    other[1] = GGX(alpha=0.5, albedo=(0.2, 0.2, 0.6), specular=(0.1, 0.1, 0.1))
    sofa.apply_materials(other)
    regrown = list(other)
    regrown[0] = _with_region(sofa, 0, red, frac=0.6)
    sofa.apply_materials(regrown)
    sofa.freeze(u)
    assert sofa.last_freeze_pixels == P


def test_kept_freezes_are_bounded(sofa, monkeypatch):
    """At most STASHED_FREEZES layouts' freezes are kept, and while they weigh more than
    STASHED_BYTES the oldest go (the newest stays whatever its size)."""
    from worker.renderers.gi import renderer as gr

    red = GGX(alpha=0.3, albedo=(0.6, 0.1, 0.1), specular=(0.2, 0.2, 0.2))
    sofa._stash.clear()
    for k in range(6):
        mats = list(sofa.scene.materials)
        mats[0] = _with_region(sofa, 0, red, frac=0.2 + 0.1 * k)
        sofa.apply_materials(mats)
        sofa.freeze(sofa._region_units[(0, "r")])
    assert len(sofa._stash) == gr.STASHED_FREEZES
    monkeypatch.setattr(gr, "STASHED_BYTES", 1)
    mats = list(sofa.scene.materials)
    mats[0] = _with_region(sofa, 0, red, frac=0.9)
    sofa.apply_materials(mats)
    assert len(sofa._stash) == 1, [v[0].nbytes for v in sofa._stash.values()]


def test_a_region_in_parts_under_gi(sofa):
    """A highlight across the sofa on a bright matte base (little energy left for one BRDF):
    the region split by mirror direction, a BRDF per part, each part's rows the one-part rows
    times its share of the region's weight at the hit. The frames drawn with the parts are what
    the stacked fit's model predicts there (the parts are units at the first vertex, linear in
    their coefficients), the parts partition the region, and they reach more of the highlight
    than one BRDF for the region."""
    from worker.fit.brush import Stroke
    from worker.fit.fitter import Fitter
    from worker.fit.regions import fit_region_gi
    from worker.scene import Lambert

    fx = Fitter(sofa, "sofa", base_material=Lambert(albedo=(0.7, 0.7, 0.7)), fit_scale=sofa.stroke_fit_scale)
    fx.add_view()
    v = fx.views[0]
    y0 = float(np.median(v.xy[:, 1]))
    row = v.xy[np.abs(v.xy[:, 1] - y0) <= 1.0, 0]
    x0, x1 = float(np.quantile(row, 0.15)), float(np.quantile(row, 0.85))
    C = 2.0 * float(v.base.max())
    fx.add_stroke(Stroke(points=[(x0, y0), (x1, y0)], color=(C, C, C), diameter=6.0, kappa=0.05))
    one = fit_region_gi(fx, name="hl", parts=1)
    two = fit_region_gi(fx, name="hl", parts=2)
    print(f"GI highlight: 1 part {one.achieved:.3f} (gap {one.model_gap:.1e}), "
          f"2 parts {two.achieved:.3f} (gap {two.model_gap:.1e}), spill far {two.spill_far:.3f}")
    assert [g.name for g in two.material.regions] == ["hl/1", "hl/2"]
    a, b = (set(g.vertices) for g in two.regions)
    assert not a & b and a | b == set(one.region.vertices)
    assert two.model_gap <= 2e-3, two.model_gap
    assert two.achieved > one.achieved + 0.03, (one.achieved, two.achieved)
    assert two.spill_far <= 0.1, two.spill_far
    auto = fit_region_gi(fx, name="hl", parts="auto")
    assert auto.tried[0][0] == 1 and auto.achieved >= max(a for _, a in auto.tried) - 0.02, auto.tried
