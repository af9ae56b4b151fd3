"""Per-vertex fields (painted region weights) baked into textures through a mesh's own texture
coordinates, for the glTF export.

Glint blends a regions material per vertex and interpolates linearly across each face; a texture
holds the same field when every texel belongs to one face: each face's texels take the
barycentric interpolation of its corners' values. That needs texture coordinates that give each
face a place of its own in the texture. Many real meshes' do not: a wood grain that repeats
(coordinates beyond [0, 1], wrapped) or mirrored parts sharing one image put several faces on the
same texels, and a texture cannot hold two weights there. ``bake`` therefore measures the overlap
and says so; the caller falls back to per-vertex attributes.

Coordinates here are glTF's: origin at the image's top left (``u``, ``1 − v`` of OBJ's and
trimesh's), wrapped (the glTF sampler's default REPEAT).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_OVERLAP = 0.01       # covered texels that two faces claim, above which a bake is refused
CHUNK = 500_000          # texel candidates rasterised at once (~150 bytes of temporaries each)


@dataclass
class Bake:
    """values (K, S, S) float32 in texels, row 0 at the top; covered (S, S) bool, texels inside
    a face; overlap: the fraction of covered texels inside more than one face (0 … 1); error: the
    largest difference between the texture (bilinear, as a GPU samples it) and the per-vertex
    field interpolated at every face's centroid."""
    values: np.ndarray
    covered: np.ndarray
    overlap: float
    error: float


def gltf_uv(uvs: np.ndarray) -> np.ndarray:
    """(V, 2) texture coordinates with the origin at the bottom left (OBJ, trimesh) -> glTF's
    (top left): (u, 1 − v)."""
    out = np.array(uvs, np.float32)
    out[:, 1] = 1.0 - out[:, 1]
    return out


def _rasterise(uv: np.ndarray, faces: np.ndarray, size: int):
    """Texels whose centres lie inside each face: (face (N,) int64, texel y (N,), x (N,) int64
    wrapped into the image, barycentrics (N, 3) float64). uv (V, 2) glTF coordinates."""
    t = uv.astype(np.float64)[faces] * size - 0.5          # (F, 3, 2): texel centres at integers
    lo = np.ceil(t.min(1)).astype(np.int64)                 # the centres inside each face's box
    hi = np.floor(t.max(1)).astype(np.int64)
    wh = np.maximum(hi - lo + 1, 0)
    n = wh[:, 0] * wh[:, 1]
    # runs of faces whose boxes hold about CHUNK candidate texels together
    cuts = np.searchsorted(np.cumsum(n), np.arange(CHUNK, int(n.sum()), CHUNK))
    for sel in np.split(np.arange(len(faces)), np.unique(cuts)):
        cnt = n[sel]
        if not cnt.sum():
            continue
        fi = np.repeat(sel, cnt)
        k = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        x = lo[fi, 0] + k % wh[fi, 0]
        y = lo[fi, 1] + k // wh[fi, 0]
        a, b, c = t[fi, 0], t[fi, 1], t[fi, 2]
        d = (b[:, 1] - c[:, 1]) * (a[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (a[:, 1] - c[:, 1])
        ok = np.abs(d) > 1e-12                              # faces of zero area in UV cover nothing
        d = np.where(ok, d, 1.0)
        l0 = ((b[:, 1] - c[:, 1]) * (x - c[:, 0]) + (c[:, 0] - b[:, 0]) * (y - c[:, 1])) / d
        l1 = ((c[:, 1] - a[:, 1]) * (x - c[:, 0]) + (a[:, 0] - c[:, 0]) * (y - c[:, 1])) / d
        l2 = 1.0 - l0 - l1
        inside = ok & (l0 >= -1e-9) & (l1 >= -1e-9) & (l2 >= -1e-9)
        yield (fi[inside], np.mod(y[inside], size), np.mod(x[inside], size),
               np.stack([l0, l1, l2], 1)[inside])


def bake(uvs: np.ndarray, faces: np.ndarray, values: np.ndarray, size: int = 1024) -> Bake:
    """Bake per-vertex values into textures.

    uvs (V, 2) float glTF texture coordinates (gltf_uv), faces (F, 3) int, values (K, V) float
    (the fields, e.g. K region weights in 0 … 1), size: the texture's side in texels. Texels
    outside every face take the value of the nearest covered texel, so that filtering and mipmaps
    near a face's edge do not pull in black."""
    from scipy.ndimage import distance_transform_edt

    faces = np.asarray(faces, np.int64)
    values = np.asarray(values, np.float32).reshape(len(values), -1)
    span = np.ptp(np.asarray(uvs, np.float64)[faces], axis=1).max() if len(faces) else 0.0
    if not np.isfinite(span) or span >= 1.0:
        # a face as wide as the texture covers some texels twice once wrapped: no bake
        return Bake(np.zeros((len(values), 0, 0), np.float32), np.zeros((0, 0), bool), 1.0, float("inf"))
    out = np.zeros((len(values), size, size), np.float32)
    count = np.zeros((size, size), np.int32)
    # a texel centre on an edge two faces share lies inside both: overlap counts only the claims
    # of centres strictly inside a face
    strict = np.zeros((size, size), np.int32)
    for fi, y, x, bary in _rasterise(uvs, faces, size):
        corners = values[:, faces[fi]]                       # (K, N, 3)
        out[:, y, x] = (corners * bary[None].astype(np.float32)).sum(2)
        np.add.at(count, (y, x), 1)
        interior = (bary > 1e-6).all(1)
        np.add.at(strict, (y[interior], x[interior]), 1)
    covered = count > 0
    overlap = float((strict > 1).sum() / max(1, covered.sum()))
    if covered.any() and not covered.all():
        _, (iy, ix) = distance_transform_edt(~covered, return_indices=True)
        out = out[:, iy, ix]
    # what a viewer reads back at each face's centroid, against the field there
    c = uvs.astype(np.float64)[faces].mean(1) * size - 0.5
    x0, y0 = np.floor(c[:, 0]).astype(np.int64), np.floor(c[:, 1]).astype(np.int64)
    fx, fy = c[:, 0] - x0, c[:, 1] - y0
    got = np.zeros((len(values), len(faces)), np.float64)
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            got += out[:, np.mod(y0 + dy, size), np.mod(x0 + dx, size)] * (wy * wx)
    want = values[:, faces].mean(2)
    err = float(np.abs(got - want).max()) if len(faces) else 0.0
    return Bake(out, covered, overlap, err)


def png(channel: np.ndarray) -> bytes:
    """An 8-bit greyscale PNG of one (S, S) field in 0 … 1 (quantised to 1/255)."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.round(np.clip(channel, 0.0, 1.0) * 255).astype(np.uint8), "L").save(buf, "PNG", optimize=True)
    return buf.getvalue()
