"""Shading by prefiltered maps (worker/renderers/paint/render.py, C glp_shade) against a brute-force
integration of the same lobes BRDF over a real HDRI, on an unoccluded convex object (a sphere,
intersected analytically so normals are exact)."""
import numpy as np
import pytest

from worker import native
from worker.native.kernels import kernels
from worker.core.brdf import evaluate, to_local
from worker.core.lighting import pixel_directions
from worker.envmap import load_envmap
from worker.paint.basis import default_exponents
from worker.renderers.paint.prefilter import prefilter_all
from worker.renderers.paint.render import lobe_albedo, material_rows, shade, shade_numpy
from worker.scene import Lobes


def sphere_view(n=40, dist=3.2, fov_deg=40.0, grazing_cut=0.15):
    """Unit sphere seen from +z: per hit pixel the normal N and the view direction V (towards the
    eye); pixels whose N·V < grazing_cut (the silhouette) are left out."""
    t = np.tan(np.radians(fov_deg) / 2)
    xs = (2 * (np.arange(n) + 0.5) / n - 1) * t
    X, Y = np.meshgrid(xs, -xs)
    d = np.stack([X, Y, -np.ones_like(X)], -1).reshape(-1, 3)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.array([0.0, 0.0, dist])
    b = d @ o
    disc = b * b - (o @ o - 1.0)
    hit = disc > 0
    tt = -b[hit] - np.sqrt(disc[hit])
    p = o + tt[:, None] * d[hit]
    nrm = p / np.linalg.norm(p, axis=1, keepdims=True)
    v = -d[hit]
    keep = (nrm * v).sum(1) > grazing_cut
    return nrm[keep], v[keep]


def brute_force(mat, env, normals, views):
    """L = Σ_pixels f(ωi, ωo) (ωi·N) L(ωi) Ω over the map's pixel centres above the horizon:
    the same environment the prefilter sees, integrated with the BRDF itself (core.brdf.evaluate)."""
    h, w, _ = env.shape
    dirs, sa = pixel_directions(h, w, 1)
    dirs = dirs.reshape(-1, 3)
    rad = (env * sa[:, None, None]).reshape(-1, 3).astype(np.float64)
    out = np.zeros((len(normals), 3))
    for k, (n, v) in enumerate(zip(normals, views)):
        up = dirs @ n > 0
        wi = to_local(dirs[up], np.broadcast_to(n, (up.sum(), 3)))
        wo = to_local(v[None], n[None])
        f = evaluate(mat, wi, np.broadcast_to(wo, wi.shape))
        out[k] = (f * wi[:, 2:3] * rad[up]).sum(0)
    return out


def designed_paint(exps):
    """A metallic design on the renderer's basis: diffuse, chromatic flake lobes on the wide and
    medium exponents, an achromatic gloss lobe; the sharp lobes are left to the map-level test
    (tests/paint/test_prefilter.py), which resolves them against a supersampled reference."""
    m = len(exps)
    dd = [(0.0, 0.0, 0.0)] * m
    g = [0.0] * m
    wide = [i for i, e in enumerate(exps) if e <= 200]
    for k, i in enumerate(wide):
        dd[i] = (0.25 / (k + 1), 0.2 / (k + 1), 0.12 / (k + 1))
    g[wide[-1]] = 0.04
    return Lobes(exponents=list(exps), gloss=g, directional_diffuse=dd, albedo=(0.04, 0.035, 0.03))


def rel_rmse(a, b):
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b ** 2)))


@pytest.fixture(scope="module")
def setup(assets):
    env = load_envmap(assets / "env" / "sunset.exr")
    exps = default_exponents()
    return env, exps, prefilter_all(env, exps)


def test_prefiltered_render_matches_brute_force(setup, cached):
    env, exps, maps = setup
    mat = designed_paint(exps)
    nrm, v = sphere_view()
    # every third hit pixel (~340, spread over the whole sphere): the brute-force reference costs
    # a full-map integral per pixel, and the RMSE needs no more pixels to resolve the 2% bound
    nrm, v = nrm[::3], v[::3]
    ref = cached("brute-sphere", [env, nrm, v, repr(mat.model_dump()), "v1"], lambda: brute_force(mat, env, nrm, v))
    rows = material_rows([mat], exps)
    mid = np.zeros(len(nrm), np.int32)
    got = shade(nrm, v, mid, rows, maps)                       # default: cosine="vector"
    albedo = shade(nrm, v, mid, rows, maps, cosine="albedo")
    paper = shade(nrm, v, mid, rows, maps, cosine="paper")
    e_vec, e_alb, e_paper = rel_rmse(got, ref), rel_rmse(albedo, ref), rel_rmse(paper, ref)
    msg = (f"relative RMSE over {len(nrm)} sphere pixels: vector maps {e_vec:.4f} (threshold 0.02); "
           f"lobe-albedo cosine {e_alb:.4f}; paper's R·N cosine (eq. 7) {e_paper:.4f}")
    print(msg)
    assert e_vec < 0.02, msg
    # the paper's approximation overestimates the wide lobes by up to (E+2)/(E+1): it is worse
    assert e_paper > e_alb > e_vec, msg


def test_white_furnace_is_exact_with_the_lobe_albedo_factor(setup):
    _, exps, _ = setup
    white = np.ones((64, 128, 3), np.float32)
    maps = prefilter_all(white, exps)
    mat = designed_paint(exps)
    nrm, v = sphere_view(24, grazing_cut=0.02)
    rows = material_rows([mat], exps)
    mid = np.zeros(len(nrm), np.int32)
    # the directional albedo of the BRDF at each pixel's view, by quadrature
    mu = (nrm * v).sum(1)
    expect = np.array(mat.albedo)[None] + sum(
        (mat.gloss[i] + np.array(mat.directional_diffuse[i]))[None] * np.interp(mu, np.linspace(0, 1, 64), lobe_albedo(e))[:, None]
        for i, e in enumerate(exps))
    for mode in ("vector", "albedo"):
        got = shade(nrm, v, mid, rows, maps, cosine=mode)
        assert np.allclose(got, expect, rtol=3e-3), mode


def test_lobe_albedo_table_closed_forms():
    for e in (1.0, 10.0, 1000.0):
        a = lobe_albedo(e)
        assert a[-1] == pytest.approx(1.0, abs=2e-4)          # R = N: the normalised lobe's albedo
    # sharp lobes: A_E(μ) → μ; E = 1 at grazing keeps half its lobe above the horizon
    assert np.allclose(lobe_albedo(5000.0)[1:], np.linspace(0, 1, 64)[1:], atol=0.02)
    # brute-force quadrature of one value
    e, mu = 3.0, 0.4
    n = np.array([np.sqrt(1 - mu * mu), 0, mu]); r = np.array([0, 0, 1.0])
    d, sa = pixel_directions(400, 800, 1)
    d = d.reshape(-1, 3); om = np.repeat(sa, 800)
    q = ((e + 2) / (2 * np.pi) * np.maximum(d @ r, 0) ** e * np.maximum(d @ n, 0) * om).sum()
    assert np.interp(mu, np.linspace(0, 1, 64), lobe_albedo(e)) == pytest.approx(q, rel=2e-3)


@pytest.mark.skipif(not native.available(), reason="C kernels not built")
def test_c_shading_matches_numpy(setup):
    env, exps, maps = setup
    rng = np.random.default_rng(2)
    n = rng.normal(size=(500, 3)); n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = rng.normal(size=(500, 3)); v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = np.where(((n * v).sum(1) < 0)[:, None], -v, v)
    mats = [designed_paint(exps), Lobes(exponents=list(exps), gloss=[0.01] * len(exps),
                                        directional_diffuse=[(0.1, 0.05, 0.0)] * len(exps), albedo=(0.2, 0.2, 0.2))]
    rows = material_rows(mats, exps)
    mid = rng.integers(-1, 2, 500).astype(np.int32)
    vsh = rng.uniform(0.2, 1.0, (500, 18)).astype(np.float32)
    for kw in ({"cosine": "albedo"}, {"cosine": "paper", "fresnel": True},
               {"vsh": vsh, "rotation_deg": 33.0, "intensity": 2.0}, {"rotation_deg": -71.0}):
        a = shade(n, v, mid, rows, maps, kernels=kernels("native"), **kw)
        b = shade(n, v, mid, rows, maps, kernels=kernels("numpy"), **kw)
        assert np.allclose(a, b, rtol=1e-4, atol=1e-6 * np.abs(b).max()), kw
        assert np.array_equal(b, shade_numpy(n, v, mid, rows, maps, **kw))


@pytest.mark.skipif(not native.available(), reason="C kernels not built")
def test_c_background_matches_numpy(setup):
    from worker.renderers.paint.render import background
    env = setup[0]
    uv = np.random.default_rng(3).random((4000, 2)).astype(np.float32)
    for rot, inten in ((0.0, 1.0), (30.0, 2.0), (-271.5, 0.5)):
        a = background(uv, env, rot, inten, kernels("native"))
        b = background(uv, env, rot, inten, kernels("numpy"))
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6 * np.abs(b).max())


def test_rotation_of_the_environment_is_a_lookup_offset(setup):
    """Rotating the light by α (a column shift at lookup, vectors turned into the map's frame)
    equals prefiltering the rotated map."""
    from worker.core.lighting import rotate_map
    env, exps, maps = setup
    mat = designed_paint(exps)
    nrm, v = sphere_view(24)
    rows = material_rows([mat], exps)
    mid = np.zeros(len(nrm), np.int32)
    alpha = 45.0                                       # 64 columns of the 512-wide map: exact shift
    a = shade(nrm, v, mid, rows, maps, rotation_deg=alpha)
    b = shade(nrm, v, mid, rows, prefilter_all(rotate_map(env, alpha), exps))
    assert rel_rmse(a, b) < 2e-3, rel_rmse(a, b)


@pytest.mark.parametrize("backend", ["native", "numpy"])
def test_writing_into_an_image_equals_the_plain_output(setup, backend):
    from worker.renderers.paint.render import background
    if backend == "native" and not native.available():
        pytest.skip("C kernels not built")
    k = kernels(backend)
    env, exps, maps = setup
    nrm, v = sphere_view(16)
    rows = material_rows([designed_paint(exps)], exps)
    mid = np.zeros(len(nrm), np.int32)
    img = np.full((3 * len(nrm), 3), -1.0, np.float32)
    dst = np.arange(len(nrm), dtype=np.int64) * 3 + 1
    shade(nrm, v, mid, rows, maps, out=img, dst=dst, kernels=k, rotation_deg=12.0)
    assert np.allclose(img[dst], shade(nrm, v, mid, rows, maps, kernels=k, rotation_deg=12.0))
    uv = np.random.default_rng(0).random((len(nrm), 2)).astype(np.float32)
    dst0 = dst - 1
    background(uv, env, 30.0, 2.0, k, out=img, dst=dst0)
    assert np.allclose(img[dst0], background(uv, env, 30.0, 2.0, k), rtol=1e-5)
    assert (img[dst + 1] == -1.0).all()                 # nothing else touched
