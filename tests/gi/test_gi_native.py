"""The GI C kernels agree with their NumPy references: exactly (to float rounding) given the same
random numbers, and statistically for independent random streams."""
import numpy as np
import pytest

from gi_harness import gi_renderer, scene_with
from worker import native
from worker.native.kernels import kernels
from worker.renderers.gi.options import parse_options, unit_layout
from worker.renderers.gi.renderer import region_images
from worker.renderers.gi.trace import make_setup, trace_tile
from worker.scene import GGX, BlinnPhong

pytestmark = pytest.mark.skipif(not native.available(), reason="C kernels not built")


def _tiles_agree(a, b, rtol):
    for k, (x, y) in enumerate(zip(a, b), start=1):
        # same entries (pixel counts, slots, tails) and values to float rounding
        np.testing.assert_array_equal(x[0], y[0], err_msg=f"bounce {k} counts")
        np.testing.assert_array_equal(x[1], y[1], err_msg=f"bounce {k} slots")
        np.testing.assert_array_equal(x[2], y[2], err_msg=f"bounce {k} tails")
        va = x[3].astype(np.float64) * np.repeat(x[4], x[0])[:, None]
        vb = y[3].astype(np.float64) * np.repeat(y[4], y[0])[:, None]
        assert np.abs(va - vb).max() <= rtol * np.abs(va).max(), f"bounce {k}"


@pytest.mark.parametrize("name,opts", [
    ("cornell", {"series": [64, 1, 1, 1]}),
    ("cornell", {"series": [16, 4, 1], "fresnel": True}),
    ("sofa", {"series": [32, 8, 1], "quotient": "microfacet"}),    # a fixed object, J2 series
])
def test_path_tracer_kernels_agree(shared_assets, name, opts):
    """gi_sample + gi_emit + gi_compact (hash tables) against sample_numpy + emit_numpy + compact
    (dense) on one tile of real paths with the same random numbers: identical entries, values
    within 1e-6 relative (float accumulation order, half-float rounding at the same places)."""
    sc = scene_with(name, 14, 14)
    o = parse_options(sc, {"spp": 8, **opts})
    S = make_setup(sc, o, unit_layout(sc, o), region_images(sc, o))
    a, ra = trace_tile(S, 0, kernels("numpy"))
    b, rb = trace_tile(S, 0, kernels("native"))
    assert ra == rb and ra > 500
    _tiles_agree(a, b, 1e-6)


def _box_denoised(r, sc, o):
    """r's tensors denoised as denoise.py does, with a 3×3 box filter in place of OIDN (the
    layout, hat components in slots K1…, is what matters here), on r's own backend."""
    from scipy.ndimage import uniform_filter
    from worker.renderers.gi import GIData, GIRenderer
    from worker.renderers.gi.renderer import denoise_tensors
    op = parse_options(sc, o)
    S = make_setup(sc, op, unit_layout(sc, op), region_images(sc, op))
    box = lambda img, a, n: uniform_filter(img, size=(3, 3, 1), mode="constant")
    b, meta = denoise_tensors(sc, S, r.data.bounces, denoiser=box)
    d = r.data
    return GIRenderer(sc, GIData({**d.meta, "denoise": meta}, d.pixel, d.obj, b, d.opts), kernels=r.k)


@pytest.mark.parametrize("opts", [{"series": [64, 1, 1, 1]}, {"series": [16, 4, 1, 1], "fresnel": True},
                                  {"series": [64, 1, 1, 1], "spp": 1}, {"series": [64, 1, 1, 1], "denoised": True}])
def test_freeze_and_frame_kernels_agree(shared_assets, opts):
    """gi_freeze / gi_frame(_dense) against freeze_numpy / frame_numpy for every unit made live:
    the frozen sums within 1e-6, live half floats within one unit of the last place, frames
    within 1e-4 relative (half-float rounding of F). Denoised tensors give the dense layout
    blocks of different slot ranges per power (hat components only beyond power 0)."""
    sc = scene_with("cornell", 24, 24)
    opts = dict(opts)
    denoised = opts.pop("denoised", False)
    o = {"spp": 16, **opts}
    rn, rc = gi_renderer(sc, o, "numpy"), gi_renderer(sc, o, "native")
    if denoised:
        rn, rc = _box_denoised(rn, sc, o), _box_denoised(rc, sc, o)
    for r in (rn, rc):
        r.set_unit_material(0, GGX(alpha=0.1, specular=(0.5, 0.4, 0.3), albedo=(0.2, 0.3, 0.1)))
        r.set_unit_material(2, BlinnPhong(exponent=60, specular=(0.3, 0.3, 0.3), albedo=(0.5, 0.1, 0.1)))
    layouts = set()
    for i in range(rn.U):
        rn.freeze(i); rc.freeze(i)
        a, b = rn.frozen, rc.frozen
        np.testing.assert_allclose(a.V, b.V, rtol=1e-6, atol=1e-6 * np.abs(a.V).max())
        np.testing.assert_array_equal(a.live, b.live)
        if a.dense is not None:
            assert b.dense is not None and a.dense.shape == b.dense.shape
            np.testing.assert_array_equal(a.lo, b.lo)
            np.testing.assert_array_equal(a.width, b.width)
            assert np.abs(a.dense.astype(np.int64) - b.dense.astype(np.int64)).max() <= 1
            layouts.add("dense")
            if denoised:
                # powers ≥ 1 reach only the hat components (slots ≥ K1 of the raw tensors)
                assert a.NPe >= 2 and (a.lo[1:] >= rn.data.meta["K1"]).all(), (a.lo, a.width)
                assert a.width[1:].sum() < a.width[0], a.width
        else:
            np.testing.assert_array_equal(a.offsets, b.offsets)
            np.testing.assert_array_equal(a.key, b.key)
            assert np.abs(a.entries[:, 1:].astype(np.int64) - b.entries[:, 1:].astype(np.int64)).max() <= 1
            layouts.add("sparse")
        ia, ib = rn.draw().copy(), rc.draw().copy()
        assert np.abs(ia - ib).max() <= 1e-4 * np.abs(ia).max(), i
    assert layouts and (not denoised or "dense" in layouts), layouts


def test_freeze_kernels_agree_where_units_share_pixels(shared_assets, tmp_path):
    """A region (H(x)) shares the floor's pixels with it: a live pixel there also carries the
    other unit's frozen coefficients, so gi_freeze's V of the dense layout (taken from the
    live cells as the blocks are written) is not zero there. Against freeze_numpy: V within
    1e-6 (measured 4e-7), frames within 1e-5 (measured 1.3e-6), dense layout for every unit."""
    from PIL import Image

    from worker.scene import LoadedScene
    img = np.zeros((16, 16), np.uint8); img[:, 8:] = 255
    Image.fromarray(img).save(tmp_path / "half.png")
    sc = scene_with("sofa", 32, 24)
    spec = sc.spec.model_copy(deep=True)
    spec.gi = {"series": [64, 1, 1], "spp": 128, "regions": [{
        "name": "rug", "object": "floor", "weights": str(tmp_path / "half.png"), "axis": "y",
        "material": {"model": "lambert", "albedo": [0.1, 0.6, 0.1]}}]}
    reg = LoadedScene(spec, sc.root, envmap=sc.envmap)
    rn, rc = gi_renderer(reg, {}, "numpy"), gi_renderer(reg, {}, "native")
    shared = (rn.pu.units >= 0).sum(1) > 1
    assert shared.sum() > 20
    for r in (rn, rc):
        r.set_unit_material(1, GGX(alpha=0.1, specular=(0.5, 0.4, 0.3), albedo=(0.2, 0.3, 0.1)))
    for i in range(rn.U):
        rn.freeze(i); rc.freeze(i)
        a, b = rn.frozen, rc.frozen
        assert a.dense is not None and b.dense is not None, i
        np.testing.assert_allclose(a.V, b.V, rtol=1e-6, atol=1e-6 * np.abs(a.V).max())
        ia, ib = rn.draw().copy(), rc.draw().copy()
        assert np.abs(ia - ib).max() <= 1e-5 * np.abs(ia).max(), i


def test_independent_streams_agree_statistically(shared_assets):
    """Tensors of seed 0 drawn by the C kernels and of seed 1 drawn by the NumPy freeze and
    frame references differ only by noise: their relative RMSE is within 30 % of that between
    two C runs with seeds 0 and 2. (The tensors are traced by the process's backend, and cached:
    the NumPy tracer is too slow for this scene; it is checked against C on one tile above and
    end to end on a tiny scene in tests/core/test_backend.py.)"""
    sc = scene_with("sofa", 24, 18)
    o = {"spp": 32, "series": [64, 1, 1]}
    c0 = gi_renderer(sc, {**o, "seed": 0}).draw().copy()
    c2 = gi_renderer(sc, {**o, "seed": 2}).draw().copy()
    r = gi_renderer(sc, {**o, "seed": 1}, "numpy")
    n1 = r.draw().copy()
    m = r.prim.object_id >= 0
    def rel(a, b): return np.sqrt(((a[m] - b[m]) ** 2).mean()) / np.sqrt((a[m] ** 2).mean())
    cross, same = rel(c0, n1), rel(c0, c2)
    assert cross <= 1.3 * same, (cross, same)
    assert abs(n1[m].mean() / c0[m].mean() - 1) < 0.02


def test_freeze_of_some_pixels_agrees_and_keeps_the_rest(shared_assets):
    """gi_freeze over a list of pixels (a region's grown footprint, every live pixel among them)
    writes V there as a whole freeze does, and leaves V's other rows as the caller's; the NumPy
    reference the same."""
    from worker.renderers.gi import freeze as fzm

    rc = gi_renderer(scene_with("sofa", 32, 24), {"series": [64, 1, 1], "spp": 64}, "native")
    rn = gi_renderer(scene_with("sofa", 32, 24), {"series": [64, 1, 1], "spp": 64}, "numpy")
    i, nb = 0, rc.max_bounces
    P = len(rc.pu.k0)
    rng = np.random.default_rng(3)
    live = np.nonzero((rc.pu.units == i).any(1))[0]
    pixels = np.union1d(live, rng.choice(P, P // 5, replace=False)).astype(np.int64)
    assert len(live) > 20 and len(pixels) < P
    outs = []
    for r in (rc, rn):
        _, C1, d, second = r._tables(r.materials)
        tables = fzm.tail_tables(i, nb, r.U, r.J2, d, second)
        whole = r.k.gi.freeze(r.data.bounces[:nb], tables, r.pu, C1, i, r.K1, r.K2, r.N)
        V0 = rng.standard_normal(whole.V.shape).astype(np.float32)
        part = r.k.gi.freeze(r.data.bounces[:nb], tables, r.pu, C1, i, r.K1, r.K2, r.N, pixels, V0)
        rest = np.setdiff1d(np.arange(P), pixels)
        assert np.array_equal(part.V[rest], V0[rest])
        assert np.array_equal(part.V[pixels], whole.V[pixels]) and np.array_equal(part.live, whole.live)
        outs.append(part)
    a, b = outs
    np.testing.assert_allclose(a.V[pixels], b.V[pixels], rtol=1e-6, atol=1e-6 * np.abs(b.V).max())
