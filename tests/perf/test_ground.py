"""The ground shadow: an invisible shadow catcher that darkens the background by the
ratio of occluded to open-sky irradiance (worker/renderers/cuts/ground.py)."""
from pathlib import Path

import numpy as np
import pytest
import trimesh

from helpers import open_renderer, scene_file

from worker.renderers import FrameRequest
from worker.scene import LoadedScene, parse_scene

ROOT = Path(__file__).resolve().parents[2]


def _sphere_scene(tmp_path, ground):
    trimesh.creation.icosphere(subdivisions=4).export(tmp_path / "sphere.ply")
    spec = parse_scene({"version": 1, "environment": {"map": "unused.exr"},
                        "camera": {"eye": [0, -1.5, 3], "target": [0, -2, 0], "fov_y_deg": 30, "width": 96,
                                   "height": 72},
                        "objects": [{"name": "ball", "mesh": "sphere.ply", "material": {"model": "lambert"}}],
                        **({"ground": ground} if ground is not None else {})})
    return LoadedScene(spec, tmp_path, envmap=np.ones((64, 128, 3), np.float32))


def _plane_hit(cam, eye, dirs, y):
    t = (y - eye[1]) / dirs[:, 1]
    return eye[None, :] + t[:, None] * dirs


def test_sphere_over_a_plane_under_a_uniform_sky(tmp_path, cache_dir):
    """Unit sphere at the origin, plane y = −2, uniform white sky: the open-sky fraction the sphere
    hides from a plane point is the cosine-weighted solid angle of its cap, sin²α·cosβ (α the
    cap's half-angle, β its axis's angle from the normal; the whole cap above the horizon), so
    the background there is 1 − sin²α·cosβ: 0.75 right below the sphere."""
    s = _sphere_scene(tmp_path, {"height": -2.0})
    r = open_renderer(s)
    assert r.ground_available()
    cam = s.spec.camera
    on = r.render(FrameRequest(camera=cam, materials=s.materials))             # the scene's default: on
    off = r.render(FrameRequest(camera=cam, materials=s.materials, ground_shadow=False))
    assert on.info["ground_shadow"] is True and off.info["ground_shadow"] is False
    bg = off.object_id < 0
    np.testing.assert_allclose(off.radiance[bg], 1.0, atol=1e-5)                # no shadow: the sky
    v = r.view(cam)
    p = _plane_hit(cam, np.asarray(cam.eye, np.float64), v.dirs.astype(np.float64), -2.0)
    g = r.data.ground.grid
    inner = max(abs(g.x0), abs(g.z0)) * 0.7                                     # away from the fade
    got = on.radiance.reshape(-1, 3)[:, 1]
    d = np.hypot(p[:, 0], p[:, 2])
    h = 2.0
    dist = np.sqrt(d * d + h * h)
    sin_a, cos_b = 1.0 / dist, h / dist
    want = 1.0 - sin_a ** 2 * cos_b
    sel = bg.reshape(-1) & (p[:, 1] < 0) & (np.abs(p[:, 0]) < inner) & (np.abs(p[:, 2]) < inner)
    assert sel.sum() > 500
    err = np.abs(got[sel] - want[sel])
    below = sel & (d < 0.3)
    assert below.sum() > 0
    # tolerance: 8-bit cut values, leaf cells and the 64×64 grid's bilinear interpolation
    print(f"sphere: max error {err.max():.4f}, mean {err.mean():.4f}, below {got[below].mean():.4f}")
    assert err.max() < 0.02, f"max |shadow − closed form| {err.max():.4f} (mean {err.mean():.4f})"
    assert abs(got[below].mean() - 0.75) < 0.01, f"below the sphere {got[below].mean():.4f}, closed form 0.75"
    half = r.render(FrameRequest(camera=cam, materials=s.materials, ground_intensity=0.5)).radiance.reshape(-1, 3)
    np.testing.assert_allclose(half[sel, 1], 1 - 0.5 * (1 - got[sel]), atol=1e-5)     # intensity blends


def test_scenes_without_ground_are_unchanged(tmp_path, cache_dir):
    """Version-1 files without ``ground`` have no ground part and no shadow, whatever is asked."""
    s = _sphere_scene(tmp_path, None)
    r = open_renderer(s)
    assert not r.ground_available()
    out = r.render(FrameRequest(camera=s.spec.camera, materials=s.materials, ground_shadow=True))
    assert out.info["ground_shadow"] is None
    np.testing.assert_allclose(out.radiance[out.object_id < 0], 1.0, atol=1e-5)


@pytest.mark.slow
def test_bunny_shadow_matches_mitsuba(shared_assets, cache_dir, artifacts):
    """The bunny under a sunny HDRI (stinson-beach, sun 51° up) seen from above: Glint's
    background ratio (shadow on / off) against Mitsuba's ratio of a white diffuse plane's
    radiance with and without the bunny (``direct``: the plane's irradiance, occluded over open,
    which is what the shadow catcher shows). Compared as means over 8×8-pixel blocks (Mitsuba's
    per-pixel ratio has ~6% noise at 256 spp under the sun) away from the bunny, and as the
    shadow's total mass Σ(1 − ratio)."""
    import trimesh
    from PIL import Image

    from worker.core.tonemap import tonemap
    from worker.mitsuba_ref import render_mitsuba
    from worker.renderers import Lighting
    from worker.scene import load_scene

    pytest.importorskip("mitsuba")
    s = load_scene(scene_file("bunny-ground.json"))
    r = open_renderer(s)
    cam, rot = s.spec.camera, s.spec.environment.rotation_deg
    on = r.render(FrameRequest(camera=cam, materials=s.materials, lighting=Lighting(rot)))
    off = r.render(FrameRequest(camera=cam, materials=s.materials, lighting=Lighting(rot), ground_shadow=False))
    ours = on.radiance / np.maximum(off.radiance, 1e-12)

    tmp = cache_dir / "ground-mitsuba"
    tmp.mkdir(exist_ok=True)
    y, h = float(s.mesh.vertices[:, 1].min()), 6.0
    trimesh.Trimesh([[-h, y, -h], [h, y, -h], [h, y, h], [-h, y, h]], [[0, 2, 1], [0, 3, 2]],
                    process=False).export(tmp / "plane.ply")
    base = {"version": 1, "environment": {"map": "unused.exr", "rotation_deg": rot}, "camera": cam.model_dump()}
    plane = {"name": "plane", "mesh": "plane.ply", "material": {"model": "lambert", "albedo": [1, 1, 1]}}
    bunny = {"name": "bunny", "mesh": str(shared_assets / "meshes" / "bunny.ply"), "material": {"model": "lambert"}}
    with_b = render_mitsuba(LoadedScene(parse_scene({**base, "objects": [bunny, plane]}), tmp, envmap=s.envmap),
                            spp=256, seed=1)
    alone = render_mitsuba(LoadedScene(parse_scene({**base, "objects": [plane]}), tmp, envmap=s.envmap),
                           spp=256, seed=2)
    luma = np.array([0.2126, 0.7152, 0.0722])
    bg = on.object_id < 0

    def blocks(x, b=8):
        hh, ww = x.shape[:2]
        return x[:hh // b * b, :ww // b * b].reshape(hh // b, b, ww // b, b, -1).mean((1, 3))

    whole = blocks(bg[..., None].astype(float))[..., 0] == 1
    ref_b = (blocks(with_b) @ luma) / (blocks(alone) @ luma)
    ours_b = blocks(ours) @ luma
    err = np.abs(ref_b - ours_b)[whole]
    mass_ours = (1 - ours @ luma)[bg].sum()
    mass_ref = (1 - (with_b @ luma) / (alone @ luma))[bg].sum()
    pair = np.concatenate([np.where(bg[..., None], ours, 0), np.where(bg[..., None], with_b / np.maximum(alone, 1e-12), 0)], 1)
    Image.fromarray(tonemap(pair.astype(np.float32), 0.0, "linear")).save(artifacts / "ground-shadow-vs-mitsuba.png")
    print(f"ground shadow vs Mitsuba: 8×8 blocks mean |Δ| {err.mean():.4f} (p95 {np.percentile(err, 95):.4f}), "
          f"shadow mass {mass_ours:.0f} vs {mass_ref:.0f}")
    assert whole.sum() > 150
    # measured: mean 0.0030, p95 0.0077; mass 778 vs 751 (3.6%; Mitsuba's noise ~1% of it)
    assert err.mean() < 0.01, f"block mean |ratio − Mitsuba| {err.mean():.4f}"
    assert abs(mass_ours / mass_ref - 1) < 0.08, f"shadow mass {mass_ours:.0f} against Mitsuba's {mass_ref:.0f}"
