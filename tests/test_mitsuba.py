"""Accuracy against Mitsuba 3 (scalar_rgb, direct integrator) on real assets.

What runs: the bunny of tests/scenes/bunny.json (2,826 vertices) under the sunset HDRI, at that
scene's camera, 160×120 pixels; the reference is the mean of two independent Mitsuba renders of
512 samples per pixel each (seeds 1 and 2). Relative RMSE over object pixels at least 2 pixels
away from silhouettes. Mitsuba is itself noisy: the two renders' difference estimates the noise
left in their mean, which is reported beside the error (asserted thresholds include it).
Images are saved to test-artifacts/ for inspection.
"""
import numpy as np
import pytest
from scipy.ndimage import binary_erosion

from worker.renderers import FrameRequest

mi = pytest.importorskip("mitsuba")
SPP = 512  # per render; two renders are averaged


def _compare(r, material, mode, artifacts, name):
    from PIL import Image

    from worker.core.tonemap import tonemap
    from worker.mitsuba_ref import render_mitsuba
    from worker.scene import LoadedScene

    scene = r.scene
    spec = scene.spec.model_copy(deep=True)
    spec.objects[0].material = material
    sc = LoadedScene(spec, scene.root, envmap=scene.envmap)
    out = r.render(FrameRequest(camera=spec.camera, materials=[material], shading=mode))
    ours = out.radiance
    a = render_mitsuba(sc, spp=SPP, seed=1)
    b = render_mitsuba(sc, spp=SPP, seed=2)
    ref = 0.5 * (a + b)
    inner = binary_erosion(out.object_id >= 0, iterations=2)
    norm = np.sqrt((ref[inner] ** 2).mean())
    rel = np.sqrt(((ours[inner] - ref[inner]) ** 2).mean()) / norm
    noise = 0.5 * np.sqrt(((a[inner] - b[inner]) ** 2).mean()) / norm  # std of the mean of two
    Image.fromarray(np.concatenate([tonemap(ours), tonemap(ref)], axis=1)).save(artifacts / f"mitsuba-{name}.png")
    print(f"{name}: relative RMSE {rel:.4f} (reference noise {noise:.4f})")
    return rel, noise


@pytest.mark.slow
def test_lambert_bunny_matches_mitsuba(bunny_renderer, artifacts):
    from worker.scene import Lambert

    rel, noise = _compare(bunny_renderer, Lambert(albedo=(0.7, 0.6, 0.5)), "vertex", artifacts, "lambert-bunny")
    # vertex mode; measured 2026-11-23: 3.32% with reference noise 2.53%, i.e. 2.15% once the
    # noise is removed (target 3%)
    assert rel <= 0.04
    assert np.sqrt(max(rel ** 2 - noise ** 2, 0)) <= 0.03


@pytest.mark.slow
def test_ggx_bunny_matches_mitsuba_per_pixel(bunny_renderer, artifacts):
    from worker.scene import GGX

    rel, noise = _compare(bunny_renderer, GGX(alpha=0.25, specular=(0.9, 0.8, 0.6)), "pixel", artifacts, "ggx-bunny")
    # pixel mode; measured 2026-11-23: 3.63% with reference noise 2.57% (2.56% without it; target 8%)
    assert rel <= 0.06


@pytest.mark.slow
def test_default_mode_has_per_pixel_accuracy_on_a_glossy_bunny(bunny_renderer, cache_dir, artifacts):
    """GGX α = 0.15 on the bunny under sunset at 320×240 (faces of ~5 pixels): the default
    (``refined``) mode must be within 1.5× of pixel mode's error against Mitsuba, where Gouraud
    interpolation of vertex shading alone (``vertex``) is not. Reference: two 256-spp renders,
    cached in tests/.cache/mitsuba by content (fit/recovery.py mitsuba_target)."""
    from PIL import Image

    from worker.core.tonemap import tonemap
    from worker.fit.recovery import mitsuba_target
    from worker.scene import GGX, LoadedScene

    r = bunny_renderer
    mat = GGX(alpha=0.15, albedo=(0.1, 0.1, 0.1), specular=(0.8, 0.8, 0.8))
    spec = r.scene.spec.model_copy(deep=True)
    spec.objects[0].material = mat
    spec.camera = spec.camera.model_copy(update={"width": 320, "height": 240})
    sc = LoadedScene(spec, r.scene.root, envmap=r.scene.envmap)
    ref, imgs = mitsuba_target(sc, 256, (1, 2), cache_dir / "mitsuba")
    rel = {}
    for mode in ("vertex", "refined", "pixel"):
        if mode == "refined":       # the default
            assert FrameRequest(camera=spec.camera).shading == mode
        out = r.render(FrameRequest(camera=spec.camera, materials=[mat], shading=mode))
        inner = binary_erosion(out.object_id >= 0, iterations=2)
        norm = np.sqrt((ref[inner] ** 2).mean())
        rel[mode] = float(np.sqrt(((out.radiance[inner] - ref[inner]) ** 2).mean()) / norm)
        Image.fromarray(np.concatenate([tonemap(out.radiance), tonemap(ref)], axis=1)).save(
            artifacts / f"mitsuba-ggx015-bunny-{mode}.png")
    noise = 0.5 * np.sqrt(((imgs[0] - imgs[1])[inner] ** 2).mean()) / norm
    print(f"relative RMSE {rel} (reference noise {noise:.4f})")
    # measured 2026-12-01: vertex 13.0%, refined 5.7%, pixel 4.5% (reference noise 3.9%)
    assert rel["refined"] <= 1.5 * rel["pixel"], rel
    assert rel["vertex"] > 1.5 * rel["pixel"], rel     # the scene tells the modes apart
