"""The GI renderer: closed forms (a convex object under a uniform environment), the polynomial
structure of the image in the albedos (eq. 14, 26), exact freezing (eq. 27-28), regions (H(x)),
fixed objects, anisotropy, the renderer seam and chunked precomputation."""
import numpy as np
import pytest

from gi_harness import gi_renderer, scene_with
from worker.renderers import FrameRequest, Lighting, Unsupported, get
from worker.scene import GGX, BlinnPhong, Lambert


def _directional_albedo(f, n, wo, t, b, samples=100_000, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.random((samples, 2))
    r, ph = np.sqrt(u[:, 0]), 2 * np.pi * u[:, 1]
    wi = np.stack([r * np.cos(ph), r * np.sin(ph), np.sqrt(1 - u[:, 0])], 1)
    wo_l = np.array([wo @ t, wo @ b, wo @ n])
    v = f(wi, np.broadcast_to(wo_l, wi.shape))[:, 0] * np.pi
    return v.mean(), v.std() / np.sqrt(samples)


@pytest.mark.parametrize("kind", ["ggx", "anisotropic"])
def test_convex_object_in_a_white_furnace(sphere_scene, kind):
    """Under L = 1 a convex object's radiance is its directional albedo ∫f cos dωi at each pixel
    (no interreflection), for any BRDF: the view-conditioned projection is exact for uniform
    light, so only noise remains. Over 60 pixels: mean relative error within 1.5 % (bias), and
    RMS error within 1.5× the noise of both sides (ours: two seeds at 512 spp; the reference:
    100k cosine samples) plus 1 %."""
    from worker.core.brdf import evaluate, onb
    from worker.renderers.gi.anisotropy import AshikhminShirley, evaluate_as
    if kind == "ggx":
        m = GGX(alpha=0.2, specular=(0.9, 0.9, 0.9))
        sc = sphere_scene(m.model_dump(), {"series": [64], "spp": 512})
        f = lambda a, b: evaluate(m, a, b)
    else:
        m = AshikhminShirley(exponent_u=60, exponent_v=240, specular=(0.9, 0.9, 0.9))
        sc = sphere_scene(Lambert().model_dump(), {"series": [64], "spp": 512, "anisotropic": [
            {"object": "ball", "exponent": 60, "tangent": [0, 1, 0], "material": m.model_dump()}]})
        f = lambda a, b: evaluate_as(m, a, b)
    r0 = gi_renderer(sc, {})
    r1 = gi_renderer(sc, {"seed": 1})
    img0 = r0.draw().reshape(-1, 3)[r0.prim.pixel][:, 0].copy()
    img1 = r1.draw().reshape(-1, 3)[r1.prim.pixel][:, 0].copy()
    ours = 0.5 * (img0 + img1)
    noise = 0.5 * (img0 - img1)                       # one sample of the mean's noise
    rng = np.random.default_rng(5)
    errs, nz = [], []
    for p in rng.choice(len(ours), 60, replace=False):
        n, wo = r0.prim.ns[p], r0.prim.wo[p]
        if kind == "ggx":
            t, b = onb(n)
        else:
            t = np.array([0, 1.0, 0]) - n[1] * n
            if np.linalg.norm(t) < 1e-3:
                continue
            t /= np.linalg.norm(t); b = np.cross(n, t)
        ref, se = _directional_albedo(f, n, wo, t, b, seed=int(p))
        errs.append((ours[p] - ref) / ref)
        nz.append(np.hypot(se, noise[p]) / ref)
    errs, nz = np.array(errs), np.array(nz)
    rms, expected = np.sqrt((errs ** 2).mean()), np.sqrt((nz ** 2).mean())
    assert abs(errs.mean()) < 0.015, f"bias {errs.mean():.4f}"
    assert rms <= 1.5 * expected + 0.01, f"RMS error {rms:.4f}, noise {expected:.4f}"


def test_image_is_a_polynomial_in_the_albedos(sofa_all_editable):
    """Scaling every Lambert albedo by s scales the k-bounce image by s^k (eq. 14)."""
    r = sofa_all_editable
    base = [Lambert(albedo=(0.6, 0.5, 0.4)), Lambert(albedo=(0.7, 0.3, 0.2)), Lambert(albedo=(0.4, 0.5, 0.6)),
            Lambert(albedo=(0.5, 0.5, 0.5))]
    assert r.U == len(base)
    def per_bounce(s):
        for u, m in enumerate(base):
            r.set_unit_material(u, Lambert(albedo=tuple(s * a for a in m.albedo)))
        out, prev = [], 0.0
        for k in range(1, r.N + 1):
            r.max_bounces = k
            img = r.draw().copy()
            out.append(img - prev); prev = img
        r.max_bounces = r.N
        return out
    one, half = per_bounce(1.0), per_bounce(0.5)
    m = r.prim.object_id >= 0
    for k in range(r.N):
        assert np.abs(one[k][m]).max() > 0
        np.testing.assert_allclose(half[k][m], 0.5 ** (k + 1) * one[k][m], rtol=2e-3, atol=1e-4 * np.abs(one[0][m]).max())


def test_freezing_is_exact(sofa_small):
    """The same materials give the same image whichever unit is live (eq. 27-28)."""
    r = sofa_small
    mats = [GGX(alpha=0.15, specular=(0.5, 0.5, 0.5), albedo=(0.3, 0.3, 0.3)), BlinnPhong(exponent=40, specular=(0.2, 0.2, 0.2), albedo=(0.6, 0.2, 0.1)),
            Lambert(albedo=(0.5, 0.6, 0.7))]
    for u, m in enumerate(mats):
        r.set_unit_material(u, m)
    imgs = []
    for u in range(r.U):
        r.freeze(u)
        imgs.append(r.draw().copy())
        assert r.frozen.unit == u
    for img in imgs[1:]:
        np.testing.assert_allclose(img, imgs[0], rtol=1e-3, atol=1e-4 * imgs[0].max())   # half-float F


def test_render_requests(sofa_small):
    r = sofa_small
    spec = r.scene.spec
    mats = [o.material for o in spec.objects]
    out = r.render(FrameRequest(camera=spec.camera, lighting=Lighting(spec.environment.rotation_deg, 2.0), materials=mats))
    half = r.render(FrameRequest(camera=spec.camera, lighting=Lighting(spec.environment.rotation_deg, 1.0), materials=mats))
    np.testing.assert_allclose(out.radiance, 2 * half.radiance, rtol=1e-6)     # linear in intensity
    assert out.radiance.shape == (spec.camera.height, spec.camera.width, 3) and out.object_id.max() == 3
    moved = spec.camera.model_copy(update={"eye": (0.0, 100.0, 300.0)})
    with pytest.raises(Unsupported, match="camera"):
        r.render(FrameRequest(camera=moved, lighting=Lighting(spec.environment.rotation_deg), materials=mats))
    with pytest.raises(Unsupported, match="rotate"):
        r.render(FrameRequest(camera=spec.camera, lighting=Lighting(spec.environment.rotation_deg + 10), materials=mats))
    bad = list(mats); bad[3] = Lambert(albedo=(0.1, 0.1, 0.1))                  # side_wall is "editable": false
    with pytest.raises(Unsupported, match="side_wall"):
        r.render(FrameRequest(camera=spec.camera, lighting=Lighting(spec.environment.rotation_deg), materials=bad))
    renderer, pre = get("gi")
    assert renderer is type(r) and pre.kind == "gi" and renderer.controls == frozenset({"materials", "strokes"})


def test_regions_weight_maps(tmp_path, shared_assets):
    """A region (H(x) from an image) is a unit of its own: with the object's material it changes
    nothing; with another, the direct light changes only where H = 1."""
    from PIL import Image

    from worker.scene import LoadedScene
    img = np.zeros((16, 16), np.uint8); img[:, 8:] = 255            # the floor's half at larger x
    Image.fromarray(img).save(tmp_path / "half.png")
    sc = scene_with("sofa", 32, 24)
    spec = sc.spec.model_copy(deep=True)
    spec.gi = {"series": [64, 1, 1], "spp": 16, "regions": [{"name": "rug", "object": "floor", "weights": str(tmp_path / "half.png"),
                                                             "axis": "y", "material": {"model": "lambert", "albedo": [0.1, 0.6, 0.1]}}]}
    r = gi_renderer(LoadedScene(spec, sc.root, envmap=sc.envmap), {})
    plain = sc.spec.model_copy(deep=True); plain.gi = {"series": [64, 1, 1], "spp": 16}
    ref = gi_renderer(LoadedScene(plain, sc.root, envmap=sc.envmap), {}).draw().copy()
    assert r.layout.names == ["sofa", "floor", "wall", "rug"]
    r.max_bounces = 1
    green = r.draw().copy()
    r.set_unit_material("rug", r.materials[1]); r.max_bounces = 3
    same = r.draw().copy()
    m = r.prim.object_id >= 0
    np.testing.assert_allclose(same[m], ref[m], rtol=1e-3, atol=1e-4 * ref[m].max())
    H, W = r.prim.object_id.shape
    x = np.full(H * W, np.nan); x[r.prim.pixel] = r.prim.pos[:, 0]; x = x.reshape(H, W)
    floor = r.prim.object_id == 1
    right, left = floor & (x > 10), floor & (x < -10)
    assert right.sum() > 20 and left.sum() > 20
    assert (green[right][:, 1] > 2 * green[right][:, 0]).all()           # the rug is green
    assert (green[left][:, 1] < green[left][:, 0]).all()                 # the floor stays orange


def test_chunks_assemble_to_the_same_bytes(shared_assets):
    """Tiles carry their own random streams: computing a part in 3 chunks gives the bytes of
    computing it whole."""
    from worker.renderers.gi import GIPrecomputation
    sc = scene_with("cornell", 24, 24)
    pre = GIPrecomputation()
    opts = {"spp": 256, "series": [16, 1]}         # 128-pixel tiles: 5 of them
    (part,) = pre.parts(sc, opts)
    whole, _ = pre.assemble(sc, part, opts, [pre.compute(sc, part, opts)])
    chunks = pre.chunks(sc, part, opts, 3)
    assert len(chunks) == 3
    split, stats = pre.assemble(sc, part, opts, [pre.compute(sc, part, opts, ch) for ch in chunks[::-1]])
    assert split == whole and stats["pixels"] > 300
