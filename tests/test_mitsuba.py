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
