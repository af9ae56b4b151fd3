"""Per-pixel shading where vertex shading is wrong: the default (``vertex``) mode's refinement.

Gouraud interpolation of vertex radiance is exact for what varies linearly over a face (the
cut's visibility: inverse-brdf-modeling eq. 22 is linear in v_k, so blending a face's three cuts
by barycentric weight equals interpolating them) and close for what varies slowly with the
normal (the diffuse part). It fails for a glossy lobe whose mirror direction sweeps across a
sizeable part of the lobe inside one face: the highlight peaks between the vertices, and the
interpolation of three samples of it smears or misses it. So a face is refined — its pixels
shaded like pixel mode, each with its own normal and view direction and its face's three cuts
blended by barycentric weight — when (1) the largest angle between its vertices' mirror
directions (k.refine.mirror_spread, src/refine.c) exceeds SPREAD_FRACTION × its material's refine
radius (PackedBRDF.refine_radius: half the lobe's width, atan 2α for GGX; infinite for Lambert,
which is never refined), and (2) its vertices' radiance differs by more than CONTRAST × the
frame's mean vertex radiance (k.refine.face_contrast). Everything else keeps the vertex shading.

The mirror spread depends on the view only, so it is kept with the view (``Refinement``); the
two tests and the refined samples' normals, positions and view directions are redone every
frame for the few rows they pick, so a light, BRDF or lobe change costs no new view work.
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
    """What one view's refinement needs that does not change with light or material (kept with
    the view): faces (F_s,) int32 the faces seen, face_verts (F_s, 3) int32 their vertices,
    face_object (F_s,) int32 their objects, spread (F_s,) float32 radians their mirror spread
    (k.refine.mirror_spread), row_face (P·S,) int32 the index into ``faces`` of each sample row
    (−1 background)."""
    faces: np.ndarray
    face_verts: np.ndarray
    face_object: np.ndarray
    spread: np.ndarray
    row_face: np.ndarray

    @classmethod
    def of_view(cls, tri, faces, vertices, normals, eye, object_of_face, kernels) -> "Refinement":
        """From a view's per-sample faces tri (P·S,) int32 (−1 background) and the mesh."""
        seen = np.zeros(len(faces) + 1, bool)               # + 1: row −1 lands on the last slot
        seen[tri] = True
        seen[-1] = False
        fs = np.nonzero(seen[:-1])[0].astype(np.int32)
        index = np.full(len(faces) + 1, -1, np.int32)
        index[fs] = np.arange(len(fs), dtype=np.int32)
        fv = np.ascontiguousarray(faces[fs], np.int32)
        spread = kernels.refine.mirror_spread(fv, vertices, normals, eye) if len(fs) else np.zeros(0, np.float32)
        return cls(fs, fv, np.asarray(object_of_face[fs], np.int32), spread, index[tri])

    def select(self, radius, vert_rgb, scale: float, kernels, fraction: float = SPREAD_FRACTION,
               contrast: float = CONTRAST) -> np.ndarray:
        """(m,) int64 the sample rows to shade per pixel this frame: on faces whose mirror spread
        exceeds fraction × radius[object] (radius (O,) float32 radians, inf: never) and whose
        vertex radiance (vert_rgb (V, 3) float32, the frame's) differs by more than contrast ×
        scale (the frame's mean vertex radiance, same units)."""
        cand = np.nonzero(self.spread > np.asarray(radius, np.float32)[self.face_object] * np.float32(fraction))[0]
        if len(cand) == 0:
            return np.zeros(0, np.int64)
        keep = np.zeros(len(self.faces) + 1, bool)          # + 1: background rows (−1) stay unkept
        keep[cand] = kernels.refine.face_contrast(self.face_verts[cand], vert_rgb) > np.float32(contrast * scale)
        return np.nonzero(keep[self.row_face])[0]
