"""The cameras of a turntable: the scene camera orbited about its target.

A published object is shown from ``A`` azimuths (evenly spaced, starting at the scene camera's)
at each of a few elevations, all at the scene camera's distance, field of view and up vector,
so the viewer can swap frames as the shopper drags (azimuth with the horizontal drag, elevation
with the vertical one). World space is +Y up (docs/design/conventions.md); azimuth is measured about +Y from
+Z towards +X, elevation above the XZ plane, both in degrees.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MAX_ELEVATION_DEG = 80.0     # the orbit's pole: beyond it "up" and the view direction nearly meet


@dataclass(frozen=True)
class Orbit:
    """The scene camera as an orbit: target (3,), distance, azimuth and elevation (degrees)."""
    target: tuple[float, float, float]
    distance: float
    azimuth_deg: float
    elevation_deg: float

    def eye(self, azimuth_deg: float, elevation_deg: float) -> list[float]:
        """The eye at (azimuth, elevation) on this orbit: [x, y, z] (world units)."""
        a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
        d = self.distance
        t = self.target
        return [t[0] + d * math.cos(e) * math.sin(a), t[1] + d * math.sin(e), t[2] + d * math.cos(e) * math.cos(a)]


def orbit_of(camera) -> Orbit:
    """The orbit of a scene camera (scene.Camera or its dict form)."""
    c = camera if isinstance(camera, dict) else camera.model_dump()
    eye, target = np.asarray(c["eye"], np.float64), np.asarray(c["target"], np.float64)
    d = eye - target
    r = float(np.linalg.norm(d))
    az = math.degrees(math.atan2(d[0], d[2]))
    el = math.degrees(math.asin(max(-1.0, min(1.0, d[1] / r))))
    return Orbit(tuple(float(x) for x in target), r, az, el)


def default_elevations(camera) -> list[float]:
    """The scene camera's elevation and one 20° above it (capped below the pole), rounded to
    0.1°: what a shopper sees first, and a look from above."""
    el = orbit_of(camera).elevation_deg
    return [round(el, 1), round(min(el + 20.0, MAX_ELEVATION_DEG), 1)]


def azimuths(camera, n: int) -> list[float]:
    """n azimuths (degrees, in [0, 360)), evenly spaced from the scene camera's."""
    a0 = orbit_of(camera).azimuth_deg
    return [round((a0 + 360.0 * i / n) % 360.0, 4) for i in range(n)]


def turntable_camera(camera, azimuth_deg: float, elevation_deg: float, width: int, height: int) -> dict:
    """The scene camera moved to (azimuth, elevation) on its orbit, at width × height pixels
    (scene.Camera's dict form)."""
    c = camera if isinstance(camera, dict) else camera.model_dump(mode="json")
    o = orbit_of(c)
    return {"eye": o.eye(azimuth_deg, elevation_deg), "target": list(o.target), "up": list(c.get("up", (0, 1, 0))),
            "fov_y_deg": c["fov_y_deg"], "width": int(width), "height": int(height)}
