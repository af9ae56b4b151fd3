"""Per-pixel shading where vertex shading is wrong: the default (``vertex``) mode's refinement.

Gouraud interpolation of vertex radiance is exact for what varies linearly over a face (the
cut's visibility: inverse-brdf-modeling eq. 22 is linear in v_k, so blending a face's three cuts
by barycentric weight equals interpolating them) and close for what varies slowly with the
normal (the diffuse part). It fails for a glossy lobe whose mirror direction sweeps across a
sizeable part of the lobe inside one face: the highlight peaks between the vertices, and the
interpolation of three samples of it smears or misses it. So a face is refined — its pixels
shaded like pixel mode, each with its own normal and view direction and its face's three cuts
blended by barycentric weight — when the largest angle between its vertices' mirror directions
(k.refine.mirror_spread, src/refine.c) exceeds SPREAD_FRACTION × its material's refine radius
(PackedBRDF.refine_radius: half a GGX lobe's width, 2·atan 2α; infinite for Lambert, which
is never refined). Everything else keeps the vertex shading.

The faces and samples to refine depend on the view and on each object's lobe only, not on the
light or the rest of the material, so they are kept with the view (``Refinement``): a light or
BRDF change re-shades the refined samples, a new view or lobe width picks them again.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# A face is refined when (1) its mirror directions span more than SPREAD_FRACTION × its material's
# refine radius, so the glossy part can vary non-linearly over it, and (2) its vertices' radiance
# differs by more than CONTRAST × the frame's mean vertex radiance, so that the variation is large
# enough to show (a sweep across a dim part of the map changes little). Both chosen on the bunny
# under sunset (GGX α 0.15, 320×240), reported on held-out meshes and maps:
# docs/benchmarks/history/2026-12-01-pixel-accuracy.md
SPREAD_FRACTION = 1.0
CONTRAST = 1.0


@dataclass(eq=False)
class Refinement:
    """The candidate samples of one view under one set of lobes (test 1 above, light-independent):
    key (the per-object refine radii and the fraction it was chosen for), faces (F_c,) int32
    candidate faces, face_verts (F_c, 3) int32 their vertices, rows (n,) int64 the view's sample rows (p·S + s) on them, row_face (n,) int32
    the index into ``faces`` of each row, samples (renderer.Samples of those rows)."""
    key: tuple
    faces: np.ndarray
    face_verts: np.ndarray
    rows: np.ndarray
    row_face: np.ndarray
    samples: object

    def select(self, vert_rgb, scale: float, kernels, contrast: float = CONTRAST) -> np.ndarray:
        """(m,) int64 indices into ``rows`` of the samples to shade per pixel this frame: those on
        candidate faces whose vertex radiance (vert_rgb (V, 3) float32, the frame's) differs by
        more than contrast × scale (the frame's mean vertex radiance, same units)."""
        if len(self.faces) == 0:
            return np.zeros(0, np.int64)
        keep = kernels.refine.face_contrast(self.face_verts, vert_rgb) > np.float32(contrast * scale)
        return np.nonzero(keep[self.row_face])[0]


def candidate_faces(faces_seen, faces, vertices, normals, eye, object_of_face, radius, kernels,
                    fraction: float = SPREAD_FRACTION) -> np.ndarray:
    """(F_c,) int32 the faces of faces_seen (n,) int32 whose mirror spread (radians) exceeds
    fraction × radius[object_of_face] (radius (O,) float32 radians, inf: never)."""
    if len(faces_seen) == 0:
        return np.zeros(0, np.int32)
    lim = np.asarray(radius, np.float64)[object_of_face[faces_seen]] * fraction
    live = np.isfinite(lim)
    fs = faces_seen[live]
    if len(fs) == 0:
        return np.zeros(0, np.int32)
    spread = kernels.refine.mirror_spread(faces[fs], vertices, normals, eye)
    return fs[spread > lim[live]].astype(np.int32)
