"""Checking an upload by reading it: what the service stores only once it is known to load.

``inspect_upload(path, kind, limits)`` reads a mesh, environment map or image the way a worker
will (so a file that passes here renders later), checks sizes before decoding where the format
allows (decompression bombs), and returns the asset's metadata. The service runs it in a child
process with a time limit (server/inspect.py): parsing a 256 MB OBJ or a 33-megapixel EXR never
blocks the API process.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import GlintError


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) read from the header alone, before any decoding."""
    suf = path.suffix.lower()
    if suf == ".exr":
        import OpenEXR

        try:
            dw = OpenEXR.File(str(path), header_only=True).header()["dataWindow"]
        except Exception as e:
            raise GlintError(f"not a readable OpenEXR file ({e})") from None
        (x0, y0), (x1, y1) = dw
        return int(x1 - x0 + 1), int(y1 - y0 + 1)
    if suf == ".hdr":
        with open(path, "rb") as f:
            head = f.read(4096)
        if not (head.startswith(b"#?RADIANCE") or head.startswith(b"#?RGBE")):
            raise GlintError("not a Radiance .hdr file")
        for line in head.split(b"\n"):
            parts = line.split()
            if len(parts) == 4 and parts[0] in (b"-Y", b"+Y") and parts[2] in (b"+X", b"-X"):
                return int(parts[3]), int(parts[1])
        raise GlintError("Radiance .hdr header has no resolution line")
    if suf == ".npy":
        try:
            arr = np.load(path, mmap_mode="r", allow_pickle=False)
        except Exception as e:
            raise GlintError(f"not a readable .npy array ({e})") from None
        if arr.ndim != 3:
            raise GlintError(f"an image array must be H×W×3, got shape {arr.shape}")
        return int(arr.shape[1]), int(arr.shape[0])
    from PIL import Image

    try:
        with Image.open(path) as im:
            return im.size
    except Exception as e:
        raise GlintError(f"not a readable image ({e})") from None


def inspect_upload(path: str | Path, kind: str, limits: dict) -> dict:
    """Metadata of an upload of ``kind`` ("mesh", "envmap", "image"), or GlintError (status 413
    for what is too large, 422 for what cannot be read). Messages name "the upload", not the
    temporary path."""
    path = Path(path)
    try:
        if kind == "mesh":
            from .scene import load_mesh

            m = load_mesh(path)
            if len(m.faces) > limits.get("max_mesh_faces", 8_000_000):
                raise GlintError(f"{len(m.faces)} triangles is more than the limit of {limits['max_mesh_faces']}", 413)
            lo, hi = m.vertices.min(0), m.vertices.max(0)
            return {"vertices": int(len(m.vertices)), "faces": int(len(m.faces)), "bounds": [lo.tolist(), hi.tolist()],
                    "repair": m.repair}
        w, h = image_size(path)
        if kind == "envmap":
            from .envmap import load_envmap

            cap = limits.get("max_envmap_pixels", 8192 * 4096)
            if w * h > cap:
                raise GlintError(f"{w}×{h} pixels is more than the limit of {cap}", 413)
            img = load_envmap(path)
            return {"width": int(img.shape[1]), "height": int(img.shape[0]), "mean_radiance": float(img.mean())}
        if kind == "image":
            from .fit.files import load_target

            if w * h > limits.get("max_image_pixels", 64_000_000):
                raise GlintError(f"{w}×{h} pixels is too large for a target image", 413)
            img = load_target(path)
            return {"width": int(img.shape[1]), "height": int(img.shape[0])}
    except GlintError as e:
        raise type(e)(str(e).replace(str(path), "the upload"), e.status) from None
    raise GlintError(f"unknown asset kind {kind!r}", 400)
