"""Fisheye geometry: the documented projections, the image circle, yaw and the equirectangular
mapping (docs/design/conventions.md), the C projection kernel against its NumPy reference."""
from __future__ import annotations

import numpy as np
import pytest

from worker import native
from worker.native.kernels import kernels
from worker.capture.fisheye import Lens, yaw_matrix
from worker.capture.stitch import fisheye_map, fisheye_map_numpy, overlap_deg, row_solid_angle


@pytest.mark.parametrize("projection", ["equidistant", "equisolid"])
def test_projection_formulas_and_circle(projection):
    lens = Lens(600, 400, projection, 190.0)
    assert lens.radius == 200.0                                  # the smaller side spans fov
    th = np.radians(np.array([0.0, 10.0, 45.0, 90.0, 95.0]))
    r = lens.radius_of_theta(th)
    f = lens.focal
    expect = f * th if projection == "equidistant" else 2 * f * np.sin(th / 2)
    np.testing.assert_allclose(r, expect)
    assert r[-1] == pytest.approx(200.0)                          # θ_max at the circle's edge
    np.testing.assert_allclose(lens.theta_of_radius(r), th, atol=1e-12)


@pytest.mark.parametrize("projection", ["equidistant", "equisolid"])
def test_pixel_direction_round_trip(projection):
    lens = Lens(640, 480, projection, 200.0)
    rng = np.random.default_rng(1)
    px, py = rng.uniform(0, 640, 500), rng.uniform(0, 480, 500)
    keep = np.hypot(px - 320, py - 240) < lens.radius
    d = lens.pixel_to_camera(px[keep], py[keep])
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
    qx, qy, th = lens.camera_to_pixel(d)
    np.testing.assert_allclose(qx, px[keep], atol=1e-8)
    np.testing.assert_allclose(qy, py[keep], atol=1e-8)
    assert (th <= lens.theta_max + 1e-12).all()


def test_conventions_yaw_and_image_axes():
    """Yaw 0 looks along −Z with +Y up and image right = +X; yaw rotates about +Y (Mitsuba's
    rotate([0,1,0], ψ)), so yaw 90 looks along −X and yaw 180 along +Z."""
    lens = Lens(600, 400, "equidistant", 190.0)
    centre = lens.pixel_to_camera(300.0, 200.0)
    np.testing.assert_allclose(centre, [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(lens.pixel_to_camera(300.0 + 100, 200.0)[1:2], [0], atol=1e-12)
    assert lens.pixel_to_camera(400.0, 200.0)[0] > 0                  # image right = +X
    assert lens.pixel_to_camera(300.0, 100.0)[1] > 0                  # image up = +Y
    np.testing.assert_allclose(yaw_matrix(90) @ [0, 0, -1], [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(yaw_matrix(180) @ [0, 0, -1], [0, 0, 1], atol=1e-12)
    # the world direction −X is the centre of the yaw-90 shot
    px, py, th = lens.world_to_pixel(np.array([-1.0, 0, 0]), 90.0)
    assert (px, py, th) == pytest.approx((300.0, 200.0, 0.0), abs=1e-9)


@pytest.mark.parametrize("projection", ["equidistant", "equisolid"])
def test_pixel_solid_angles_sum_to_the_cap(projection):
    """Σ solid angle over the image circle = 2π(1 − cos θ_max), within pixelation."""
    lens = Lens(800, 800, projection, 190.0)
    total = float(lens.pixel_solid_angle().sum(dtype=np.float64))
    assert total == pytest.approx(2 * np.pi * (1 - np.cos(lens.theta_max)), rel=5e-3)
    assert row_solid_angle(64, 128).sum() * 128 == pytest.approx(4 * np.pi, rel=1e-12)


@pytest.mark.parametrize("projection", ["equidistant", "equisolid"])
def test_equirect_map_matches_design_mapping(projection):
    """The map's pixel (i, j) direction (u = atan2(x, −z)/2π, v = acos(y)/π) projects where the
    lens says, by the C kernel and by the NumPy reference alike."""
    assert native.available(), "C kernels not built (make install)"
    lens = Lens(600, 400, projection, 190.0)
    h, w = 64, 128
    for yaw in (0.0, 180.0, 37.5):
        c = fisheye_map(h, w, lens, yaw, kernels("native"))
        n = fisheye_map(h, w, lens, yaw, kernels("numpy"))
        for a, b in zip(c, n):
            assert np.abs(a - b).max() < 1e-3, f"C and NumPy maps differ by {np.abs(a - b).max()} px"
    mx, my = fisheye_map_numpy(h, w, lens, 0.0)
    # the map's first column at the horizon: u ≈ 0 is the direction −Z (u = atan2(x, −z)/2π)
    i, j = h // 2, 0
    v, u = (i + 0.5) / h, (j + 0.5) / w
    th, ph = v * np.pi, u * 2 * np.pi
    d = np.array([np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)])
    px, py, _ = lens.world_to_pixel(d, 0.0)
    assert (mx[i, j], my[i, j]) == pytest.approx((px - 0.5, py - 0.5), abs=1e-3)
    assert abs(px - 300) < 5 and abs(py - 200) < 5                    # half a map pixel off centre


def test_overlap():
    assert overlap_deg([0, 180], 190) == pytest.approx(10.0)
    assert overlap_deg([0, 120, 240], 150) == pytest.approx(30.0)
    assert overlap_deg([0], 200) == pytest.approx(-160.0)
