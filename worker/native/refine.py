"""The refinement kernel (src/refine.c) behind the backend's ``refine`` family:
``k.refine.mirror_spread`` (per face, the largest angle between its vertices' mirror directions),
``k.refine.face_contrast`` (per face, the spread of its vertices' radiance) and
``k.refine.edge_pixels`` (the pixels next to another surface: renderers/cuts/edges.py),
the same arrays in and out in both backends; the NumPy reference is ``mirror_spread_numpy`` here
(tests/core/test_refine.py checks they agree). The cut renderer shades per pixel only the faces
whose spread exceeds a fraction of their material's lobe (worker/renderers/cuts/refine.py).
"""
from __future__ import annotations

import numpy as np

from . import bind, c, f32p, f64, i32, i32p, i64, lib, u8p


def mirror_spread_numpy(faces, vertices, normals, eye) -> np.ndarray:
    """(F,) float32 radians: per face of faces (F, 3) int32, the largest angle between the mirror
    directions r_i = 2 (n_i·o_i) n_i − o_i of its vertices, o_i the unit direction from vertex
    x_i (vertices (V, 3) float32) to eye (3,), n_i from normals (V, 3) float32 (normalised here)."""
    f = np.asarray(faces, np.int64)
    x = np.asarray(vertices, np.float64)[f]                     # (F, 3, 3)
    n = np.asarray(normals, np.float64)[f]
    n /= np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-30)
    o = np.asarray(eye, np.float64) - x
    o /= np.maximum(np.linalg.norm(o, axis=2, keepdims=True), 1e-30)
    r = 2.0 * (n * o).sum(2, keepdims=True) * n - o

    def ang(a, b):
        return np.arccos(np.clip((r[:, a] * r[:, b]).sum(1), -1.0, 1.0))

    return np.maximum(np.maximum(ang(0, 1), ang(1, 2)), ang(0, 2)).astype(np.float32)


def face_contrast_numpy(faces, vert_rgb) -> np.ndarray:
    """(F,) float32: per face of faces (F, 3) int32, max over channels of (max − min) of its
    vertices' radiance vert_rgb (V, 3) float32."""
    r = np.asarray(vert_rgb, np.float32)[np.asarray(faces, np.int64)]   # (F, 3 vertices, 3 channels)
    return (r.max(1) - r.min(1)).max(1).astype(np.float32)


# (dy, dx) of the neighbour each pixel is compared with: right, down, down-right, down-left;
# the symmetric half of the 8-neighbourhood (a pair marks both of its pixels)
_PAIRS = ((0, 1), (1, 0), (1, 1), (1, -1))


def edge_pixels_numpy(tri: np.ndarray, faces: np.ndarray, object_of_face: np.ndarray, height: int,
                      width: int) -> np.ndarray:
    """NumPy reference of glk_edge_pixels (renderers/cuts/edges.py edge_pixels): (n,) int64 flat
    indices of the pixels of a one-sample hit buffer tri (H·W,) int32 (−1 background) next to
    another surface (8-neighbourhood: background against the mesh, another object's face, or a
    face sharing no vertex with its own); faces (F, 3) int32, object_of_face (F,) int32.
    Vectorised over the pixel grid, ~30 ms at 1280×960."""
    t = np.asarray(tri, np.int32).reshape(height, width)
    mark = np.zeros((height, width), bool)
    for dy, dx in _PAIRS:
        ys_a = slice(0, height - dy)
        ys_b = slice(dy, height)
        xs_a = slice(max(0, -dx), width - max(0, dx))
        xs_b = slice(max(0, dx), width - max(0, -dx))
        a, b = t[ys_a, xs_a], t[ys_b, xs_b]
        diff = a != b
        if not diff.any():
            continue
        ia, ib = a[diff], b[diff]
        cut = (ia < 0) | (ib < 0)                  # one side background (both: equal, not here)
        both = np.nonzero(~cut)[0]
        if len(both):
            fa, fb = ia[both], ib[both]
            va, vb = faces[fa], faces[fb]
            share = (va[:, :, None] == vb[:, None, :]).any(axis=(1, 2))
            cut[both] = ~share | (object_of_face[fa] != object_of_face[fb])
        e = np.zeros(a.shape, bool)
        e[diff] = cut
        mark[ys_a, xs_a] |= e
        mark[ys_b, xs_b] |= e
    return np.flatnonzero(mark).astype(np.int64)


class NumpyRefine:
    """The reference of the refinement kernel."""
    name = "numpy"

    def edge_pixels(self, tri, faces, object_of_face, height, width):
        return edge_pixels_numpy(tri, faces, object_of_face, height, width)

    def mirror_spread(self, faces, vertices, normals, eye):
        return mirror_spread_numpy(faces, vertices, normals, eye)

    def face_contrast(self, faces, vert_rgb):
        return face_contrast_numpy(faces, vert_rgb)


class NativeRefine:
    """Typed wrapper of glk_mirror_spread (refine.c; OpenMP over faces)."""
    name = "native"

    def __init__(self):
        if lib is None:
            raise RuntimeError("the C kernels are not built (make build)")
        self._spread = bind("glk_mirror_spread", None, F=i64, faces=i32p, vx=f32p, vn=f32p, ex=f64, ey=f64, ez=f64,
                            out=f32p)
        self._contrast = bind("glk_face_contrast", None, F=i64, faces=i32p, vert_rgb=f32p, out=f32p)
        self._edges = bind("glk_edge_pixels", None, H=i32, W=i32, tri=i32p, faces=i32p, obj=i32p, out=u8p)

    def edge_pixels(self, tri, faces, object_of_face, height, width):
        """(n,) int64 flat pixel indices (see edge_pixels_numpy)."""
        out = np.empty(int(height) * int(width), np.uint8)
        self._edges(int(height), int(width), c(tri, np.int32), c(faces, np.int32).reshape(-1, 3),
                    c(object_of_face, np.int32), out)
        return np.flatnonzero(out).astype(np.int64)

    def mirror_spread(self, faces, vertices, normals, eye):
        """(F,) float32 (see mirror_spread_numpy)."""
        fc = c(faces, np.int32).reshape(-1, 3)
        out = np.empty(len(fc), np.float32)
        e = [float(v) for v in eye]
        self._spread(len(fc), fc, c(vertices, np.float32), c(normals, np.float32), *e, out)
        return out

    def face_contrast(self, faces, vert_rgb):
        """(F,) float32 (see face_contrast_numpy)."""
        fc = c(faces, np.int32).reshape(-1, 3)
        out = np.empty(len(fc), np.float32)
        self._contrast(len(fc), fc, c(vert_rgb, np.float32), out)
        return out
