"""The turntable's cameras, the frames' content keys and the 1× frame from the 2× one
(worker/publish), without the service."""
import numpy as np
import pytest

from worker.publish.frames import downsample2, swatch
from worker.publish.keys import file_key, frame_key, scene_inputs
from worker.publish.turntable import azimuths, default_elevations, orbit_of, turntable_camera

CAM = {"eye": [0.0, 3.6, 3.6], "target": [0.0, 0.0, 0.0], "up": [0, 1, 0], "fov_y_deg": 50, "width": 160, "height": 120}


def test_the_turntable_orbits_the_scene_camera():
    o = orbit_of(CAM)
    assert o.distance == pytest.approx(3.6 * 2 ** 0.5) and o.elevation_deg == pytest.approx(45.0)
    azs = azimuths(CAM, 72)
    assert len(azs) == 72 and azs[0] == pytest.approx(0.0) and azs[1] == pytest.approx(5.0)
    # the first view is the scene camera itself, at twice its size for the 2× set
    c = turntable_camera(CAM, azs[0], o.elevation_deg, 320, 240)
    assert np.allclose(c["eye"], CAM["eye"]) and (c["width"], c["height"]) == (320, 240)
    # a quarter turn: the eye is at +X, same height and distance
    c = turntable_camera(CAM, 90.0, 45.0, 160, 120)
    assert np.allclose(c["eye"], [3.6, 3.6, 0.0], atol=1e-9)
    assert default_elevations(CAM) == [45.0, 65.0]
    assert default_elevations({**CAM, "eye": [0, 10, 0.1]})[1] == 80.0     # capped below the pole


def test_frame_keys_follow_what_the_pixels_depend_on():
    scene = {"renderer": "cuts", "parts": {"k1": "sha-a"}, "files": {"m": {"sha256": "mesh-sha"}},
             "spec": {"objects": [{"name": "bunny", "mesh": "m", "material": {"model": "lambert"}}], "ground": None}}
    red, blue = {"model": "lambert", "albedo": [0.6, 0.1, 0.1]}, {"model": "lambert", "albedo": [0.1, 0.1, 0.6]}
    env = {"sha256": "env", "rotation_deg": 0.0, "intensity": 1.0}
    render = {"samples": 1, "shading": "vertex", "tone": "neutral", "exposure": 0.0, "ground_shadow": True}
    enc = {"avif_quality": 60}
    k = frame_key(scene_inputs(scene, "bunny", red), env, CAM, render, enc)
    assert k == frame_key(scene_inputs(scene, "bunny", dict(red)), dict(env), dict(CAM), dict(render), dict(enc))
    changed = [frame_key(scene_inputs(scene, "bunny", blue), env, CAM, render, enc),
               frame_key(scene_inputs(scene, "bunny", red), {**env, "rotation_deg": 90.0}, CAM, render, enc),
               frame_key(scene_inputs(scene, "bunny", red), env, {**CAM, "eye": [0, 3.6, 3.7]}, render, enc),
               frame_key(scene_inputs(scene, "bunny", red), env, CAM, {**render, "ground_shadow": False}, enc),
               frame_key(scene_inputs(scene, "bunny", red), env, CAM, render, {"avif_quality": 70}),
               frame_key(scene_inputs({**scene, "parts": {"k1": "sha-b"}}, "bunny", red), env, CAM, render, enc)]
    assert len(set(changed + [k])) == 7
    assert file_key(k, "avif1") != file_key(k, "avif2") and len(file_key(k, "meta")) == 64


def test_the_1x_frame_is_the_mean_of_the_2x_frame():
    rng = np.random.default_rng(1)
    hi = rng.random((8, 12, 3), dtype=np.float32)
    lo = downsample2(hi)
    assert lo.shape == (4, 6, 3) and lo.dtype == np.float32
    assert np.allclose(lo[1, 2], hi[2:4, 4:6].reshape(-1, 3).mean(0))
    rgb = np.zeros((4, 6, 3), np.uint8)
    rgb[:2] = (200, 10, 20)
    mask = np.zeros((4, 6), bool)
    mask[:2] = True
    assert swatch(rgb, mask) == ([200, 10, 20], 0.5)
    # away from the outline and from a highlight: an object inside a grey background
    rgb = np.full((12, 12, 3), 128, np.uint8)
    mask = np.zeros((12, 12), bool)
    mask[2:10, 2:10] = True
    rgb[mask] = (180, 20, 20)
    rgb[2, 2:10] = (150, 80, 80)          # the anti-aliased outline's mix with the background
    rgb[5, 5] = (255, 255, 255)           # a highlight
    assert swatch(rgb, mask) == ([180, 20, 20], 64 / 144)
