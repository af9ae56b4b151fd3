"""Fisheye lens geometry: pixels ↔ directions for the two projections of the capture manifest.

Image circle: its diameter is the smaller image side and spans ``fov_deg``; it is centred on
the image. A pixel at distance r (pixels) from the centre sees the direction at angle θ from the
optical axis with
    equidistant  r = f·θ              f = R / θ_max
    equisolid    r = 2f·sin(θ/2)      f = R / (2 sin(θ_max/2))
where R = min(W, H)/2 and θ_max = fov/2. Image right is camera +X, image up camera +Y, and the
lens looks along camera −Z. A shot at yaw 0 is the camera frame itself (looks along world −Z, +Y
up, docs/design/conventions.md); a shot at yaw ψ is rotated by ψ about +Y (right-handed, Mitsuba's
``rotate([0, 1, 0], ψ)``), so yaw 90 looks along −X and yaw 180 along +Z.

Pixel coordinates are continuous with pixel (i, j)'s centre at (i + 0.5, j + 0.5) and (0, 0)
the top-left corner.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np


@lru_cache(maxsize=4)
def _radius_grid(width: int, height: int) -> np.ndarray:
    x = np.arange(width, dtype=np.float32) + 0.5 - 0.5 * width
    y = np.arange(height, dtype=np.float32) + 0.5 - 0.5 * height
    r = np.sqrt(x[None, :] ** 2 + y[:, None] ** 2)
    r.setflags(write=False)
    return r


def yaw_matrix(yaw_deg: float) -> np.ndarray:
    """(3, 3) float64 rotation about +Y by yaw_deg (camera → world)."""
    a = np.radians(yaw_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@dataclass(frozen=True)
class Lens:
    width: int
    height: int
    projection: str      # "equidistant" | "equisolid"
    fov_deg: float

    @property
    def radius(self) -> float:
        """R, the image circle's radius in pixels."""
        return 0.5 * min(self.width, self.height)

    @property
    def theta_max(self) -> float:
        return np.radians(self.fov_deg) / 2.0

    @property
    def focal(self) -> float:
        """f in pixels per radian (the angular resolution at the centre, both projections)."""
        if self.projection == "equidistant":
            return self.radius / self.theta_max
        return self.radius / (2.0 * np.sin(self.theta_max / 2.0))

    @property
    def centre(self) -> tuple[float, float]:
        return 0.5 * self.width, 0.5 * self.height

    def radius_of_theta(self, theta: np.ndarray) -> np.ndarray:
        if self.projection == "equidistant":
            return self.focal * theta
        return 2.0 * self.focal * np.sin(theta / 2.0)

    def theta_of_radius(self, r: np.ndarray) -> np.ndarray:
        if self.projection == "equidistant":
            return r / self.focal
        return 2.0 * np.arcsin(np.clip(r / (2.0 * self.focal), 0.0, 1.0))

    def pixels_per_radian(self, theta: np.ndarray) -> np.ndarray:
        """dr/dθ: radial resolution at θ (pixels per radian)."""
        if self.projection == "equidistant":
            return np.full_like(np.asarray(theta, np.float64), self.focal)
        return self.focal * np.cos(np.asarray(theta) / 2.0)

    # -- per-pixel maps -------------------------------------------------------------------------
    def pixel_radius(self) -> np.ndarray:
        """(H, W) float32 distance of each pixel centre from the circle's centre, in pixels
        (cached, read-only)."""
        return _radius_grid(self.width, self.height)

    def circle_mask(self) -> np.ndarray:
        """(H, W) bool: pixel centres inside the image circle (θ ≤ θ_max)."""
        return self.pixel_radius() <= self.radius

    def pixel_to_camera(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Continuous pixel coordinates → (…, 3) float64 unit directions in the camera frame."""
        cx, cy = self.centre
        dx, dy = np.asarray(px, np.float64) - cx, cy - np.asarray(py, np.float64)
        r = np.hypot(dx, dy)
        th = self.theta_of_radius(r)
        s = np.where(r > 0, np.sin(th) / np.maximum(r, 1e-12), 0.0)
        return np.stack([dx * s, dy * s, -np.cos(th)], axis=-1)

    def camera_to_pixel(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(…, 3) unit camera-frame directions → (px, py, θ) float64; θ > θ_max is outside."""
        d = np.asarray(d, np.float64)
        th = np.arccos(np.clip(-d[..., 2], -1.0, 1.0))
        rho = np.hypot(d[..., 0], d[..., 1])
        r = self.radius_of_theta(th)
        s = np.where(rho > 1e-12, r / np.maximum(rho, 1e-12), 0.0)
        cx, cy = self.centre
        return cx + d[..., 0] * s, cy - d[..., 1] * s, th

    def world_to_pixel(self, d: np.ndarray, yaw_deg: float):
        """World directions → (px, py, θ) in the shot taken at yaw_deg."""
        return self.camera_to_pixel(np.asarray(d, np.float64) @ yaw_matrix(yaw_deg))

    def pixel_solid_angle(self) -> np.ndarray:
        """(H, W) float32 solid angle (sr) of each pixel inside the circle (0 outside):
        sinθ/(r·dr/dθ) per unit pixel area (cached, read-only)."""
        return _solid_angle(self)

    def _pixel_solid_angle(self) -> np.ndarray:
        r = self.pixel_radius().astype(np.float64)
        th = self.theta_of_radius(r)
        rr = np.maximum(r, 0.5)
        sa = np.sin(np.maximum(th, 1e-9)) / (rr * self.pixels_per_radian(th))
        sa[r < 0.5] = 1.0 / self.focal ** 2
        return np.where(r <= self.radius, sa, 0.0)


@lru_cache(maxsize=2)
def _solid_angle(lens: Lens) -> np.ndarray:
    sa = lens._pixel_solid_angle().astype(np.float32)
    sa.setflags(write=False)
    return sa
