"""File forms of fitting inputs: STROKES.json and target images (``glint fit``).

STROKES.json, version 1::

    {"version": 1,
     "views": [{"camera": {...scene camera...}, "rotation_deg": 0, "intensity": 1}],   # optional
     "strokes": [{"points": [[x, y], ...], "color": [4, 4, 4], "diameter": 24, "kappa": 0.05,
                  "mode": "color", "scale": 1.0, "view": 0}],
     "albedo": [0.3, 0.3, 0.3], "fresnel_f0": 1.0, "unpainted_weight": 1.0, "fit_scale": 0.25}

Without ``views`` the scene's camera and lighting form view 0. Every field but ``strokes`` is
optional. Targets are linear radiance: .npy (H, W, 3) float, .exr or .hdr; a .png is read as
8-bit sRGB and linearised (its tone curve is assumed to be the plain sRGB transfer).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Literal

import numpy as np
from PIL import Image
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from ..envmap import EnvMapError
from ..scene import Camera, Color, SceneError
from .brush import Stroke

MAX_TARGET_PIXELS = 64_000_000


class ViewSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    camera: Camera | None = None
    rotation_deg: float | None = None
    intensity: float | None = Field(None, ge=0.0)


class StrokeFile(BaseModel):
    model_config = ConfigDict(extra="forbid")
    version: Literal[1] = 1
    views: list[ViewSpec] = Field(default_factory=list, max_length=64)
    strokes: list[Stroke] = Field(max_length=100_000)
    albedo: Color | None = None
    fresnel_f0: float | None = Field(None, ge=0.0, le=1.0)
    unpainted_weight: float | None = Field(None, ge=0.0)
    fit_scale: float | None = Field(None, gt=0.0, le=1.0)


def load_strokes(path: str | Path) -> StrokeFile:
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: stroke file not found")
    try:
        return StrokeFile.model_validate(json.loads(path.read_text()))
    except json.JSONDecodeError as e:
        raise SceneError(f"{path}: not valid JSON ({e.msg} at line {e.lineno})") from e
    except ValidationError as e:
        first = e.errors()[0]
        where = ".".join(str(x) for x in first["loc"])
        raise SceneError(f"{path}: {where}: {first['msg']}") from e


def srgb_to_linear(u8: np.ndarray) -> np.ndarray:
    x = u8.astype(np.float64) / 255.0
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def load_target(path: str | Path) -> np.ndarray:
    """(H, W, 3) float32 linear radiance from .npy, .exr, .hdr or .png (sRGB)."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: target image not found")
    suf = path.suffix.lower()
    if suf == ".npy":
        try:
            img = np.load(path, allow_pickle=False)
        except Exception as e:
            raise SceneError(f"{path}: not a readable .npy array ({e})") from e
    elif suf in (".exr", ".hdr"):
        try:
            img = _read_radiance(path)
        except EnvMapError as e:
            raise SceneError(str(e)) from e
    elif suf == ".png":
        img = srgb_to_linear(np.asarray(_open_image(path).convert("RGB")))
    else:
        raise SceneError(f"{path}: unsupported target type {suf!r} (use .npy, .exr, .hdr or .png)")
    img = np.asarray(img)
    if img.ndim != 3 or img.shape[2] < 3 or not np.issubdtype(img.dtype, np.number):
        raise SceneError(f"{path}: a target must be an H×W×3 image, got shape {img.shape}")
    img = img[:, :, :3].astype(np.float32)
    if not np.all(np.isfinite(img)):
        raise SceneError(f"{path}: target has NaN or infinite values")
    return img


def load_mask(path: str | Path) -> np.ndarray:
    """(H, W) bool from an image file: non-zero pixels are used."""
    img = np.asarray(_open_image(Path(path)).convert("L"))
    return img > 0


def _open_image(path: Path) -> Image.Image:
    if not path.is_file():
        raise SceneError(f"{path}: image not found")
    try:
        im = Image.open(path)
        if im.width * im.height > MAX_TARGET_PIXELS:
            raise SceneError(f"{path}: {im.width}×{im.height} is larger than {MAX_TARGET_PIXELS} pixels")
        im.load()
        return im
    except SceneError:
        raise
    except Exception as e:  # Pillow raises many types for foreign or truncated files
        raise SceneError(f"{path}: not a readable image ({e})") from e


def _read_radiance(path: Path) -> np.ndarray:
    """EXR/HDR reading without the environment map's 2:1 check."""
    from ..envmap import _read_exr, _read_hdr

    img = _read_exr(path) if path.suffix.lower() == ".exr" else _read_hdr(path)
    return np.maximum(img, 0.0)   # lossy EXR leaves small negatives (docs/design/conventions.md)

