"""Tone mapping for display: exposure (stops), a named tone curve, then the sRGB transfer
function, to 8-bit. Radiance stays linear float32 everywhere else (docs/design/conventions.md).

Curves: ``linear`` (clip at 1), ``aces`` (Narkowicz's fit of the ACES filmic curve),
``neutral`` (identity up to 0.8, then a smooth shoulder to 1: keeps product colours and
mid-tones exact while rolling off highlights). NumPy reference of glk_tonemap.
"""
from __future__ import annotations

import numpy as np

CURVES = {"linear": 0, "aces": 1, "neutral": 2}
MID_GREY = 0.18            # the linear reflectance a display shows as middle grey
LUMA = np.array([0.2126, 0.7152, 0.0722])
EV_RANGE = (-20.0, 20.0)   # the display messages' exposure bounds


def auto_exposure(radiance: np.ndarray, mask: np.ndarray | None = None) -> float | None:
    """The exposure (stops) that shows the median luminance of ``radiance`` (…, 3) linear,
    over ``mask`` (boolean, its leading shape; None: every pixel), as middle grey (MID_GREY);
    None when nothing lit is selected. The capture preview is exposed the same way
    (worker/capture/pipeline.py preview_png), so a map shown at this exposure matches it."""
    lum = np.asarray(radiance, np.float64) @ LUMA
    if mask is not None:
        lum = lum[mask]
    lum = lum[np.isfinite(lum)]
    if lum.size == 0:
        return None
    med = float(np.median(lum))
    if med <= 0:
        return None
    return float(np.clip(np.log2(MID_GREY / med), *EV_RANGE))


def apply_curve(x: np.ndarray, curve: str) -> np.ndarray:
    x = np.maximum(x, 0.0)
    if curve == "aces":
        return np.clip((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)
    if curve == "neutral":
        k = 0.8
        t = np.maximum(x - k, 0.0)
        return np.where(x <= k, x, k + (1 - k) * t / (t + (1 - k)))
    if curve == "linear":
        return np.minimum(x, 1.0)
    raise ValueError(f"unknown tone curve {curve!r}; choose one of {sorted(CURVES)}")


def srgb_oetf(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(np.maximum(c, 0.0031308), 1 / 2.4) - 0.055)


def tonemap_numpy(rgb: np.ndarray, exposure: float = 0.0, curve: str = "neutral") -> np.ndarray:
    """(…, 3) float linear radiance -> (…, 3) uint8 sRGB."""
    c = srgb_oetf(apply_curve(rgb.astype(np.float64) * 2.0 ** exposure, curve))
    return np.clip(np.rint(c * 255.0), 0, 255).astype(np.uint8)


def tonemap(rgb: np.ndarray, exposure: float = 0.0, curve: str = "neutral", kernels=None) -> np.ndarray:
    """(…, 3) float linear radiance -> (…, 3) uint8 sRGB; kernels: the backend."""
    if curve not in CURVES:
        raise ValueError(f"unknown tone curve {curve!r}; choose one of {sorted(CURVES)}")
    from ..native.kernels import kernels as _kernels

    return (kernels or _kernels()).tonemap(rgb, exposure, curve)


def half_mean(rgb: np.ndarray) -> np.ndarray:
    """(2H, 2W, 3) float32 linear radiance -> (H, W, 3) float32, the mean of each 2 × 2 block
    (the pixel's mean radiance over its footprint), summed in the C kernel's order."""
    h, w = rgb.shape[0] // 2, rgb.shape[1] // 2
    r = np.asarray(rgb, np.float32)[:2 * h, :2 * w]
    return ((r[0::2, 0::2] + r[0::2, 1::2]) + (r[1::2, 0::2] + r[1::2, 1::2])) * np.float32(0.25)


def tonemap_pair_numpy(rgb: np.ndarray, exposure: float = 0.0, curve: str = "neutral"):
    """NumPy reference of glk_tonemap_pair: a (2H, 2W, 3) float32 linear frame -> (its (2H, 2W, 3)
    uint8 sRGB image, the (H, W, 3) uint8 sRGB image of its 2 × 2 block means in linear radiance)."""
    return tonemap_numpy(rgb, exposure, curve), tonemap_numpy(half_mean(rgb), exposure, curve)


def tonemap_pair(rgb: np.ndarray, exposure: float = 0.0, curve: str = "neutral", kernels=None):
    """(2H, 2W, 3) float32 linear frame -> (2H × 2W uint8 sRGB, H × W uint8 sRGB of its 2 × 2 block
    means); see tonemap_pair_numpy. kernels: the backend."""
    if curve not in CURVES:
        raise ValueError(f"unknown tone curve {curve!r}; choose one of {sorted(CURVES)}")
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] % 2 or rgb.shape[1] % 2:
        raise ValueError(f"tonemap_pair: a (2H, 2W, 3) frame, not {rgb.shape}")
    from ..native.kernels import kernels as _kernels

    return (kernels or _kernels()).tonemap_pair(rgb, exposure, curve)
