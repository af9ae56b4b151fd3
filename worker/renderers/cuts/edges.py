"""Anti-aliasing where the image is discontinuous: the ``edges`` sampling of the cut renderer.

Inside one smooth piece of surface, vertex and refined shading vary continuously across pixels:
one sample at the pixel centre is the mean over the pixel to first order (the sample patterns
are symmetric about the centre, render.sample_offsets), so S samples there change nothing but
the cost. What aliases is where the surface seen changes abruptly between neighbouring pixels:
silhouettes against the background, one object in front of another, a part of an object in
front of another part of it, and creases (whose faces carry split vertices). ``edge_pixels``
finds them from the one-sample hit buffer; the renderer then takes S samples at those pixels
only. On the held-out couch at 1280×960 they are a few percent of the pixels, so an
anti-aliased frame costs about a one-sample one instead of S× its primary hits, background
and refined shading.

Two neighbouring pixels (8-neighbourhood) are across an edge when one sees the mesh and the
other the background, or they see faces of different objects, or faces that share no vertex
(a face and its neighbours share a vertex, so a smooth surface never triggers; split crease
vertices and occlusion do). The test is O(P) over the pixel grid, once per
view (a publication renders four frames per camera): the C kernel glk_edge_pixels (refine.c), with
native/refine.py ``edge_pixels_numpy`` its vectorised reference and ``edge_pixels_reference``
here the definition.

The other place one sample is not the pixel's mean is where refined shading (refine.py) is
curved at the pixel scale: a sharp highlight inside a refined face, and the boundary of a
refined face with one that is not (the interpolation misses the highlight the refined face
shows). ``steep_pixels`` picks, per frame, the refined pixels and their neighbours whose
one-sample radiance departs from the mean of their neighbours (the second difference, which a
linear ramp does not have) by more than STEEP × their object's mean vertex radiance (the
refinement's own unit, refine.object_scale), and those get the S samples too.
"""
from __future__ import annotations

import numpy as np

# A refined pixel (or a neighbour of one) is supersampled when its largest channel differs from
# the mean of its two neighbours along a row or a column by more than STEEP × its object's mean
# vertex radiance. Chosen on the bunny under sunset (GGX α 0.05, 0.15, 0.3 at 320×240, against
# a 4×4-supersampled reference: 0.05 / 0.1 / 0.25 gave 1.09 / 1.13 / 1.28× the error of four
# samples everywhere at α 0.05 with 5,570 / 3,632 / 1,396 pixels; the first difference instead
# picked 2× the pixels for the same error); reported on held-out meshes and maps in
# docs/benchmarks/index.md (anti-aliasing)
STEEP = 0.1

def edge_pixels(tri: np.ndarray, faces: np.ndarray, object_of_face: np.ndarray, height: int,
                width: int, kernels=None) -> np.ndarray:
    """(n,) int64 flat indices (row-major, y·W + x) of the pixels next to an edge of the surface
    seen, from a one-sample view's face per pixel tri (H·W,) int32 (−1 background); faces (F, 3)
    int32 vertex ids, object_of_face (F,) int32; through the kernel backend (C glk_edge_pixels,
    refine.c; native/refine.py ``edge_pixels_numpy`` is its reference)."""
    from ...native.kernels import kernels as _kernels

    return (kernels or _kernels()).refine.edge_pixels(tri, faces, object_of_face, height, width)


def edge_pixels_reference(tri, faces, object_of_face, height: int, width: int) -> np.ndarray:
    """Loop reference of ``edge_pixels`` (the definition, pixel by pixel; for tests)."""
    t = np.asarray(tri).reshape(height, width)
    out = []
    for y in range(height):
        for x in range(width):
            a = int(t[y, x])
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    yy, xx = y + dy, x + dx
                    if (dy or dx) and 0 <= yy < height and 0 <= xx < width:
                        b = int(t[yy, xx])
                        if a == b:
                            continue
                        if a < 0 or b < 0 or object_of_face[a] != object_of_face[b] \
                                or not set(faces[a].tolist()) & set(faces[b].tolist()):
                            out.append(y * width + x)
                            break
                else:
                    continue
                break
    return np.asarray(out, np.int64)


def steep_pixels(img: np.ndarray, rows: np.ndarray, exclude: np.ndarray, obj: np.ndarray, scale: np.ndarray,
                 height: int, width: int, steep: float | None = None) -> np.ndarray:
    """(k,) int64 flat indices of the refined pixels rows (m,) int64 (one-sample frame: pixel
    ids) and their 4-neighbours, not in exclude (n,) int64 (the edge pixels, supersampled
    already), whose largest channel of img (H·W, 3) float32 differs from the mean of its two
    neighbours along a row or a column by more than steep (default STEEP) × scale[object]
    (scale (O,) float32, refine.object_scale; obj (H, W) int32 object per pixel)."""
    steep = STEEP if steep is None else steep
    r = np.asarray(rows, np.int64)
    y, x = np.divmod(r, width)
    # the refined pixels and their neighbours: where a refined face meets one that is not, the
    # two shadings differ (the interpolation misses the highlight the refined face shows)
    p = np.unique(np.concatenate([r, y * width + np.minimum(x + 1, width - 1), y * width + np.maximum(x - 1, 0),
                                  np.minimum(y + 1, height - 1) * width + x, np.maximum(y - 1, 0) * width + x]))
    if len(exclude):
        p = p[~np.isin(p, exclude, assume_unique=True)]
    if not len(p):
        return p
    rgb = np.asarray(img, np.float32).reshape(-1, 3)
    y, x = np.divmod(p, width)
    here = rgb[p].max(1)              # gathered: the whole frame's max costs ~40 ms at 1280×960
    lum = lambda yy, xx: rgb[yy * width + xx].max(1)                       # noqa: E731
    # the second difference: what one sample at the centre of a symmetric pattern misses (a
    # linear ramp's mean over the pattern is its centre value)
    xl, xr = np.maximum(x - 1, 0), np.minimum(x + 1, width - 1)
    yu, yd = np.maximum(y - 1, 0), np.minimum(y + 1, height - 1)
    best = np.maximum(np.abs(here - 0.5 * (lum(y, xl) + lum(y, xr))),
                      np.abs(here - 0.5 * (lum(yu, x) + lum(yd, x))))
    o = np.asarray(obj).reshape(-1)[p]
    thr = np.float32(steep) * np.asarray(scale, np.float32)[np.maximum(o, 0)]
    return p[(best > thr) & (o >= 0)]
