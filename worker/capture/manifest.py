"""The capture manifest, version 1: which photos, which lens, which exposures.

A capture is one or more fisheye *shots* taken from the same point, each a bracket of JPEG
photos at different exposures (cyber-worlds §IV: two shots, front and back, with the phone's
auto exposure bracketing). The manifest (README, "Capture manifest")::

    {"version": 1, "projection": "equidistant", "fov_deg": 190,
     "shots": [{"yaw_deg": 0,   "images": [{"file": "front_0.jpg", "exposure_s": 0.004}, ...]},
               {"yaw_deg": 180, "images": [{"file": "back_0.jpg"}, ...]}]}

Exposure of each photo, relative (the unit the HDR merge divides by):
``t · (ISO / 100) / N²`` with t the shutter time in seconds (``exposure_s``, else the JPEG's
EXIF ExposureTime), ISO and N (f-number) from EXIF. ISO and N are folded in only when every
photo of the capture has them; a factor that some photos lack is left out for all of them, so
exposures always stay comparable. Photos are read upright (EXIF Orientation applied).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from ..errors import GlintError

MAX_IMAGE_PIXELS = 64_000_000   # per photo, checked from the header before decoding (bombs)


class CaptureError(GlintError):
    """A capture that cannot be processed; the message names the manifest field or file."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class CaptureImage(_Strict):
    file: str = Field(min_length=1)
    exposure_s: float | None = Field(None, gt=0.0, allow_inf_nan=False)


class CaptureShot(_Strict):
    yaw_deg: float = Field(allow_inf_nan=False)
    images: list[CaptureImage]


class CaptureManifest(_Strict):
    """Capture manifest version 1 (README, "Capture manifest")."""
    version: Literal[1]
    projection: Literal["equidistant", "equisolid"]
    fov_deg: float = Field(gt=0.0, le=360.0, allow_inf_nan=False)
    shots: list[CaptureShot] = Field(min_length=1)

    @field_validator("shots")
    @classmethod
    def _brackets(cls, shots: list[CaptureShot]) -> list[CaptureShot]:
        for i, s in enumerate(shots):
            if len(s.images) < 2:
                raise ValueError(f"shot {i} (yaw {s.yaw_deg:g}°) has {len(s.images)} image(s): "
                                 "a bracket needs at least 2 exposures")
        return shots


def _format_validation(e: ValidationError, source: str) -> str:
    lines = [f"{source}: invalid capture manifest"]
    for err in e.errors():
        loc = ".".join(str(p) for p in err["loc"])
        msg = err["msg"]
        if err["type"] == "literal_error" and err["loc"] and err["loc"][-1] == "projection":
            msg = f"unknown projection {err.get('input')!r}; use 'equidistant' (r = f·θ) or 'equisolid' (r = 2f·sin(θ/2))"
        lines.append(f"  {loc}: {msg}" if loc else f"  {msg}")
    return "\n".join(lines)


def parse_manifest(data: dict | str | bytes, source: str = "manifest") -> CaptureManifest:
    try:
        if isinstance(data, (str, bytes)):
            return CaptureManifest.model_validate_json(data)
        return CaptureManifest.model_validate(data)
    except ValidationError as e:
        raise CaptureError(_format_validation(e, source)) from None


# --- photos and their exposures ---------------------------------------------------------------


@dataclass
class Photo:
    """One bracketed photo, resolved: path, size (upright), exposure facts."""
    path: Path
    field: str                       # "shots[i].images[j]", for messages
    width: int
    height: int
    shutter_s: float | None          # exposure_s or EXIF ExposureTime
    shutter_source: str              # "manifest" | "exif"
    f_number: float | None
    iso: float | None
    exposure: float = 0.0            # relative exposure, filled by resolve()


@dataclass
class Capture:
    """A manifest with its photos resolved and checked. ``shots[i]`` lists shot i's photos in
    order of increasing exposure."""
    manifest: CaptureManifest
    root: Path
    shots: list[list[Photo]]
    width: int
    height: int
    exposure_notes: list[str] = field(default_factory=list)


_EXIF_IFD = 0x8769
_EXPOSURE_TIME, _F_NUMBER, _ISO = 0x829A, 0x829D, 0x8827
_ORIENTATION = 0x0112


def _num(v) -> float | None:
    """An EXIF number (rational, int, or a tuple of them) as a positive finite float, else None."""
    if isinstance(v, (tuple, list)):
        v = v[0] if v else None
    try:
        f = float(v)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return f if math.isfinite(f) and f > 0 else None


def read_photo_facts(path: Path) -> tuple[int, int, float | None, float | None, float | None]:
    """(width, height upright, ExposureTime s, FNumber, ISO) from the header, without decoding
    the pixels."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            w, h = im.size
            exif = im.getexif()
    except UnidentifiedImageError:
        raise CaptureError(f"{path.name}: not an image Pillow can read (JPEG expected)") from None
    except OSError as e:
        raise CaptureError(f"{path.name}: unreadable image ({e})") from None
    if w * h > MAX_IMAGE_PIXELS:
        raise CaptureError(f"{path.name}: {w}×{h} is more than {MAX_IMAGE_PIXELS // 1_000_000} Mpx per photo", status=413)
    if exif.get(_ORIENTATION) in (5, 6, 7, 8):   # rotated by 90°: read upright
        w, h = h, w
    sub = exif.get_ifd(_EXIF_IFD)
    get = lambda tag: _num(sub.get(tag, exif.get(tag)))   # noqa: E731  (some writers put them in IFD0)
    return w, h, get(_EXPOSURE_TIME), get(_F_NUMBER), get(_ISO)


def _inside(path: Path, root: Path) -> bool:
    try:
        path.resolve().relative_to(root.resolve())
        return True
    except ValueError:
        return False


def resolve(manifest: CaptureManifest, base: Path, root: Path | None = None) -> Capture:
    """Find every photo (paths relative to ``base``, the manifest's folder), read its size and
    EXIF, and compute relative exposures.

    root : when given (the service), photos must lie inside it, symlinks resolved.
    Raises CaptureError naming the field or file: missing files, inconsistent sizes, photos
    without any exposure information, a bracket whose exposures are all equal."""
    shots: list[list[Photo]] = []
    size: tuple[int, int, str] | None = None
    for i, shot in enumerate(manifest.shots):
        photos = []
        for j, img in enumerate(shot.images):
            fld = f"shots[{i}].images[{j}]"
            rel = Path(img.file)
            if rel.is_absolute() and root is not None:
                raise CaptureError(f"{fld}.file: {img.file!r} is an absolute path; name files relative to the manifest")
            path = base / rel
            if root is not None and not _inside(path, root):
                raise CaptureError(f"{fld}.file: {img.file!r} points outside the capture folder")
            if not path.is_file():
                raise CaptureError(f"{fld}.file: {img.file!r} not found (missing bracket?)")
            w, h, t, n, iso = read_photo_facts(path)
            if size is None:
                size = (w, h, img.file)
            elif (w, h) != size[:2]:
                raise CaptureError(f"{fld}.file: {img.file} is {w}×{h} but {size[2]} is {size[0]}×{size[1]}; "
                                   "all photos of a capture must come from the same camera and lens at one size")
            if img.exposure_s is not None:
                shutter, src = img.exposure_s, "manifest"
            elif t is not None:
                shutter, src = t, "exif"
            else:
                raise CaptureError(f"{fld}: {img.file} has no exposure information: give exposure_s in the "
                                   "manifest (seconds) or keep the photo's EXIF ExposureTime")
            photos.append(Photo(path, fld, w, h, shutter, src, n, iso))
        shots.append(photos)
    assert size is not None
    everyone = [p for s in shots for p in s]
    notes = []
    use_n = all(p.f_number for p in everyone)
    use_iso = all(p.iso for p in everyone)
    if not use_n and any(p.f_number for p in everyone):
        notes.append("FNumber ignored: not every photo has it")
    if not use_iso and any(p.iso for p in everyone):
        notes.append("ISO ignored: not every photo has it")
    for p in everyone:
        e = p.shutter_s
        if use_iso:
            e *= p.iso / 100.0
        if use_n:
            e /= p.f_number ** 2
        p.exposure = e
    for i, photos in enumerate(shots):
        ex = sorted(p.exposure for p in photos)
        if ex[-1] <= ex[0] * (1 + 1e-6):
            raise CaptureError(f"shots[{i}]: all {len(photos)} photos have the same exposure ({photos[0].shutter_s:g} s): "
                               "bracketing needs different exposures")
        photos.sort(key=lambda p: p.exposure)
    return Capture(manifest, base, shots, size[0], size[1], notes)


def load_capture(path: str | Path, root: str | Path | None = None) -> Capture:
    """Read, validate and resolve a manifest file (photos relative to its folder)."""
    path = Path(path)
    if not path.is_file():
        raise CaptureError(f"{path}: capture manifest not found")
    try:
        raw = path.read_bytes()
        json.loads(raw)
    except (OSError, ValueError) as e:
        raise CaptureError(f"{path.name}: not a JSON file ({e})") from None
    m = parse_manifest(raw, path.name)
    return resolve(m, path.parent, Path(root) if root is not None else None)
