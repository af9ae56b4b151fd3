"""Reading equirectangular HDR environment maps (OpenEXR and Radiance .hdr).

docs/design/conventions.md: linear radiance, +Y up, u = atan2(x, -z)/2π, v = acos(y)/π, v = 0 the top row.
Lossy EXR compression (DWAB) leaves small negative values: they are clamped to zero. NaN and
infinite values are rejected with a clear error.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import GlintError


class EnvMapError(GlintError):
    """An environment map that cannot be used; the message names the file and the problem."""


def _read_exr(path: Path) -> np.ndarray:
    import OpenEXR

    try:
        with OpenEXR.File(str(path)) as f:
            channels = f.channels()
            if "RGB" in channels:
                rgb = np.asarray(channels["RGB"].pixels)
            else:
                names = [n for n in ("R", "G", "B") if n in channels]
                if len(names) == 3:
                    rgb = np.stack([np.asarray(channels[n].pixels) for n in names], axis=-1)
                elif "Y" in channels:
                    y = np.asarray(channels["Y"].pixels)
                    rgb = np.stack([y, y, y], axis=-1)
                else:
                    raise EnvMapError(f"{path}: EXR has no RGB or Y channels (has {sorted(channels)})")
    except EnvMapError:
        raise
    except Exception as e:  # OpenEXR raises plain exceptions for truncated or foreign files
        raise EnvMapError(f"{path}: not a readable OpenEXR file ({e})") from e
    return np.ascontiguousarray(rgb[..., :3], dtype=np.float32)


def _read_hdr(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH)
    if img is None:
        raise EnvMapError(f"{path}: not a readable Radiance .hdr file")
    return np.ascontiguousarray(img[..., ::-1], dtype=np.float32)  # BGR -> RGB


def validate_radiance(img: np.ndarray, name: str = "environment map") -> np.ndarray:
    """Check an (H, W, 3) radiance image: finite, equirectangular 2:1; clamp negatives to 0."""
    if img.ndim != 3 or img.shape[2] != 3:
        raise EnvMapError(f"{name}: expected an H×W×3 image, got shape {img.shape}")
    h, w, _ = img.shape
    if h < 2 or w != 2 * h:
        raise EnvMapError(f"{name}: equirectangular maps are 2:1 (width = 2·height), got {w}×{h}")
    bad = ~np.isfinite(img)
    if bad.any():
        raise EnvMapError(f"{name}: {int(bad.sum())} NaN or infinite values; fix the file")
    return np.maximum(img, 0.0, dtype=np.float32)


def load_envmap(path: str | Path) -> np.ndarray:
    """Load an environment map as (H, W, 3) float32 linear radiance (W = 2H)."""
    path = Path(path)
    if not path.is_file():
        raise EnvMapError(f"{path}: environment map file not found")
    suffix = path.suffix.lower()
    if suffix == ".exr":
        img = _read_exr(path)
    elif suffix in (".hdr", ".pic", ".rgbe"):
        img = _read_hdr(path)
    else:
        raise EnvMapError(f"{path}: unsupported environment map type {suffix!r} (use .exr or .hdr)")
    return validate_radiance(img, str(path))


def save_exr(path: str | Path, img: np.ndarray) -> None:
    """Write (H, W, 3) float32 linear radiance as a float EXR (ZIP compression)."""
    import OpenEXR

    hdr = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(hdr, {"RGB": np.ascontiguousarray(img, dtype=np.float32)}) as f:
        f.write(str(path))
