"""The coatings industry's measurement geometries, evaluated on any Glint material.

cacad-cosine-lobes §4 (after Westlund & Meyer 2001): a paint is described by a clearcoat gloss
value and a few tristimulus measurements at aspecular angles. This module defines exactly which
geometries those are and how they follow from a BRDF f (1/sr, ``worker.core.brdf.evaluate``).

Local frame: z is the surface normal and the plane of measurement is the xz-plane. The
illuminator is on the −x side; ``wi`` points from the surface towards it.

Multi-angle colour (ASTM E2194, ISO 18314-1; X-Rite MA98 / BYK-mac style instruments)
    Illumination at 45° from the normal. An aspecular angle a is measured in the plane from the
    specular direction towards the illuminator (positive towards the normal), so the detector
    sits at signed polar angle θv = 45° − a on the specular (+x) side: 15° → 30°, 25° → 20°,
    45° → 0° (the normal), 75° → −30°, 110° → −65° (both on the illuminator's side), −15° → 60°
    (beyond the specular direction). E2194 requires 15°, 45°, 110°; 25° and 75° are its optional
    angles and −15° is used by ASTM E2539 instruments. Any a in (−45°, 135°) is accepted.

    Reported value: the bidirectional reflectance factor, the ratio of the radiance reflected in
    that geometry to the radiance reflected by the perfect reflecting diffuser (f = 1/π) under
    the same illumination:  R(a) = π · f(wi, wo(a)), per linear RGB channel (tristimulus values
    in linear RGB instead of CIE XYZ). A perfect white diffuser reads 1 at every angle; a
    metallic flake lobe reads well above 1 near the specular direction. Instrument apertures
    (a few degrees) are neglected: R is the point value.

Specular gloss (ASTM D523 / ISO 2813, 20° geometry for high-gloss automotive finishes)
    Collimated light incident at 20°; the receptor, centred on the specular direction, accepts
    1.80° in the plane of measurement × 3.6° perpendicular to it; the source image is
    0.75° × 2.5°. The reading is the fraction of the incident flux entering the receptor,
        ρ = mean over source directions of ∫_receptor f(wi, wo) cosθo dωo,
    relative to that of the primary standard, polished black glass of refractive index 1.567,
    whose mirror reflection (unpolarised Fresnel reflectance at 20°, 0.04917) all enters the
    receptor and is assigned 100 gloss units:  G = 100 · ρ / R_F(20°; 1.567).
    A mirror-smooth dielectric clearcoat of index 1.5 (R_F(20°) = 0.0401) reads 82 GU;
    automotive clearcoats read 80-95 GU. The integrals use tensor Gauss-Legendre rules (6×6 over
    the source, 4×4 panels of 8×8 nodes over the receptor): exact to 0.5% for cosine lobes up to
    E = 2·10^5 (0.13° wide), tested.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..core.brdf import evaluate
from ..errors import GlintError

ILLUMINATION_DEG = 45.0
ASPECULAR_DEG = (-15.0, 15.0, 25.0, 45.0, 75.0, 110.0)        # default set (E2194 + −15°)
GLOSS_DEG = 20.0
GLOSS_RECEPTOR_DEG = (1.80, 3.6)                               # in plane, perpendicular
GLOSS_SOURCE_DEG = (0.75, 2.5)
GLOSS_STANDARD_N = 1.567                                       # black glass primary standard
LUMA = np.array([0.2126, 0.7152, 0.0722])                      # Rec. 709 Y of linear RGB


class MeasurementError(GlintError):
    """A measurement set that cannot be used (angle out of range, wrong number of channels…)."""


def fresnel_dielectric(cos_i: float, n: float) -> float:
    """Unpolarised Fresnel reflectance of a dielectric of index n (from air)."""
    sin_t2 = (1.0 - cos_i * cos_i) / (n * n)
    cos_t = np.sqrt(max(0.0, 1.0 - sin_t2))
    rs = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    rp = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp)


GLOSS_STANDARD_R = fresnel_dielectric(np.cos(np.radians(GLOSS_DEG)), GLOSS_STANDARD_N)


def in_plane(theta_deg) -> np.ndarray:
    """Unit vectors (…, 3) at signed polar angles θ (degrees) in the xz-plane, +x side positive."""
    t = np.radians(np.asarray(theta_deg, np.float64))
    return np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], axis=-1)


def aspecular_directions(angles_deg, illumination_deg: float = ILLUMINATION_DEG):
    """(wi (3,), wo (K, 3)) local directions of the multi-angle geometry at aspecular angles."""
    a = np.asarray(angles_deg, np.float64)
    view = illumination_deg - a
    if np.any(np.abs(view) >= 89.0):
        bad = a[np.abs(view) >= 89.0]
        raise MeasurementError(f"aspecular angle(s) {bad.tolist()} put the detector at or below the "
                               f"horizon (illumination {illumination_deg}°: use −44° < a < 134°)")
    return in_plane(-illumination_deg), in_plane(view)


def _rotated(center: np.ndarray, alpha: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """Directions offset from an in-plane ``center`` by alpha (in the plane, radians) and beta
    (perpendicular, radians): spherical coordinates about the y axis."""
    th = np.arctan2(center[0], center[2]) + alpha
    cb = np.cos(beta)
    return np.stack([np.sin(th) * cb, np.sin(beta), np.cos(th) * cb], axis=-1)


def _gl(n: int, half_width: float, panels: int = 1):
    """Composite Gauss-Legendre nodes and weights on [−half_width, half_width]."""
    x, w = np.polynomial.legendre.leggauss(n)
    edges = np.linspace(-half_width, half_width, panels + 1)
    xs, ws = [], []
    for a, b in zip(edges[:-1], edges[1:]):
        xs.append(0.5 * (b - a) * x + 0.5 * (a + b))
        ws.append(0.5 * (b - a) * w)
    return np.concatenate(xs), np.concatenate(ws)


@lru_cache(maxsize=4)
def gloss_quadrature(gloss_deg: float = GLOSS_DEG):
    """(wi (S, 3), wo (Q, 3), weights (S, Q)) of the D523 gloss integral: the mean over the source
    aperture of ∫_receptor (·) cosθo dωo, so ρ = Σ weights · f(wi, wo)."""
    sa, sw = _gl(6, np.radians(GLOSS_SOURCE_DEG[0]) / 2)
    sb, swb = _gl(6, np.radians(GLOSS_SOURCE_DEG[1]) / 2)
    ra, rw = _gl(8, np.radians(GLOSS_RECEPTOR_DEG[0]) / 2, panels=4)
    rb, rwb = _gl(8, np.radians(GLOSS_RECEPTOR_DEG[1]) / 2, panels=4)
    A, B = np.meshgrid(sa, sb, indexing="ij")
    wsrc = (sw[:, None] * swb[None, :]).reshape(-1)
    wsrc = wsrc / wsrc.sum()                                   # mean over the source image
    light = _rotated(in_plane(-gloss_deg), A.reshape(-1), B.reshape(-1))
    RA, RB = np.meshgrid(ra, rb, indexing="ij")
    wo = _rotated(in_plane(gloss_deg), RA.reshape(-1), RB.reshape(-1))
    # solid angle element of (alpha, beta) coordinates about the y axis: cos(beta) dα dβ
    wrec = (rw[:, None] * rwb[None, :]).reshape(-1) * np.cos(RB.reshape(-1)) * wo[:, 2]
    return light, wo, wsrc[:, None] * wrec[None, :]


def _eval(material, wi, wo) -> np.ndarray:
    """f (…, 3) 1/sr of a Glint material, or of any object with ``evaluate(wi, wo)`` (the
    published paint models of the database)."""
    if hasattr(material, "evaluate"):
        return material.evaluate(wi, wo)
    return evaluate(material, wi, wo)


def gloss_units(material) -> float:
    """ASTM D523 20° specular gloss (GU) of a material: 100 ρ / R_F(20°; 1.567)."""
    wi, wo, w = gloss_quadrature()
    a, b = np.broadcast_arrays(wi[:, None, :], wo[None, :, :])
    f = _eval(material, a, b)                                  # (S, Q, 3)
    rho = float((w[..., None] * f).sum(axis=(0, 1)) @ LUMA)     # achromatic: luminance
    return 100.0 * rho / GLOSS_STANDARD_R


def reflectance_factors(material, angles_deg=ASPECULAR_DEG) -> np.ndarray:
    """(K, 3) linear RGB reflectance factors R = π f at 45° illumination and aspecular angles."""
    wi, wo = aspecular_directions(angles_deg)
    return np.pi * _eval(material, np.broadcast_to(wi, wo.shape), wo)


def angle_key(a: float) -> str:
    """The JSON key of an aspecular angle: "15", "-15", "12.5"."""
    return f"{a:g}"


def measure(material, angles_deg=ASPECULAR_DEG) -> dict:
    """The industry's measurements of any Glint material:
    ``{"gloss": G (GU), "aspecular": {"15": [r, g, b], …}}`` (reflectance factors, linear RGB)."""
    r = reflectance_factors(material, angles_deg)
    return {"gloss": gloss_units(material),
            "aspecular": {angle_key(a): [float(x) for x in row] for a, row in zip(angles_deg, r)}}


def parse_measurements(m: dict) -> tuple[float, np.ndarray, np.ndarray]:
    """Check a measurement dict; returns (gloss, angles (K,) float64, values (K, 3) float64)."""
    if not isinstance(m, dict) or "aspecular" not in m:
        raise MeasurementError('measurements need "gloss" and "aspecular"')
    try:
        g = float(m.get("gloss", 0.0))
    except (TypeError, ValueError):
        raise MeasurementError(f"gloss must be a number, got {m.get('gloss')!r}") from None
    if not np.isfinite(g) or g < 0 or g > 2000:
        # D523: mirror-like metals read up to ~2000 GU
        raise MeasurementError(f"gloss must be within 0…2000 GU, got {g}")
    asp = m["aspecular"]
    if not isinstance(asp, dict) or not asp:
        raise MeasurementError("aspecular must map angles to [r, g, b]")
    angles, vals = [], []
    for k, v in asp.items():
        try:
            a = float(k)
        except ValueError:
            raise MeasurementError(f"aspecular angle {k!r} is not a number") from None
        arr = np.asarray(v, np.float64)
        if arr.shape != (3,) or not np.isfinite(arr).all() or (arr < 0).any():
            raise MeasurementError(f"aspecular[{k}] must be three non-negative numbers, got {v!r}")
        angles.append(a); vals.append(arr)
    order = np.argsort(angles)
    angles = np.asarray(angles)[order]
    aspecular_directions(angles)                                 # range check
    return g, angles, np.asarray(vals)[order]


def lightness(y: np.ndarray) -> np.ndarray:
    """CIE L* of relative luminance Y (reflectance factor, white = 1)."""
    y = np.asarray(y, np.float64)
    f = np.where(y > (6 / 29) ** 3, np.cbrt(np.maximum(y, 0)), y / (3 * (6 / 29) ** 2) + 4 / 29)
    return 116.0 * f - 16.0


def flop_index(m: dict) -> float | None:
    """X-Rite flop index 2.69 (L*15 − L*110)^1.11 / L*45^0.86 of a measurement dict (luminance of
    the linear RGB factors as Y); None without the 15°, 45° and 110° readings. Solid colours read
    ≲ 2, high-flop silvers 15 or more."""
    asp = m["aspecular"]
    if not all(k in asp for k in ("15", "45", "110")):
        return None
    L = {k: float(lightness(np.asarray(asp[k]) @ LUMA)) for k in ("15", "45", "110")}
    d = max(L["15"] - L["110"], 0.0)
    return float(2.69 * d ** 1.11 / max(L["45"], 1e-6) ** 0.86)


def export_measurements(material_or_measurements, fmt: str = "json") -> str:
    """A design's measurements for paint formulation, as JSON or CSV text.

    Accepts a Glint material (measured first) or a measurement dict. CSV columns: geometry,
    angle_deg, r, g, b, value (gloss in GU on its own row)."""
    import json

    m = material_or_measurements
    if not isinstance(m, dict):
        m = measure(m)
    g, angles, vals = parse_measurements(m)
    fmt = fmt.lower()
    if fmt == "json":
        out = {"gloss": g, "aspecular": {angle_key(a): [float(x) for x in v] for a, v in zip(angles, vals)},
               "geometry": {"illumination_deg": ILLUMINATION_DEG, "gloss": f"ASTM D523 {GLOSS_DEG:g}°",
                            "aspecular": "ASTM E2194 (reflectance factor π·f, linear RGB)"},
               "flop_index": flop_index(m)}
        return json.dumps(out, indent=1) + "\n"
    if fmt == "csv":
        lines = ["geometry,angle_deg,r,g,b,value",
                 f"gloss_D523,{GLOSS_DEG:g},,,,{g:.6g}"]
        for a, v in zip(angles, vals):
            lines.append(f"aspecular_45,{a:g},{v[0]:.6g},{v[1]:.6g},{v[2]:.6g},")
        return "\n".join(lines) + "\n"
    raise MeasurementError(f"unknown export format {fmt!r} (json or csv)")
