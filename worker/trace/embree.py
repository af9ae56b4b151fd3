"""Ray tracing through embreex (Embree 4): occlusion queries and first hits.

docs/design/conventions.md, measured facts: the raw OCCLUDED query returns 0 for blocked and -1 for free; Embree's tnear is
0, so callers offset origins off the surface. Calls release the GIL, so Python threads scale.
"""
from __future__ import annotations

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh


class Tracer:
    """Embree scene over one triangle mesh.

    vertices : (V, 3) float, faces : (F, 3) int.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.scene = rtcore_scene.EmbreeScene()
        self._mesh = TriangleMesh(self.scene, np.ascontiguousarray(vertices, np.float32),
                                  np.ascontiguousarray(faces, np.int32))

    def occluded(self, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """(R,) bool: True where the ray (origin, unit dir) hits anything at t > 0."""
        r = self.scene.run(np.ascontiguousarray(origins, np.float32),
                           np.ascontiguousarray(dirs, np.float32), query="OCCLUDED")
        return np.asarray(r) == 0

    def first_hit(self, origins: np.ndarray, dirs: np.ndarray):
        """Nearest hits: (prim (R,) int32, -1 for a miss; uv (R, 2) float32 Embree barycentrics,
        hit = (1−u−v)·v0 + u·v1 + v·v2; t (R,) float32)."""
        r = self.scene.run(np.ascontiguousarray(origins, np.float32),
                           np.ascontiguousarray(dirs, np.float32), output=1)
        uv = np.stack([r["u"], r["v"]], axis=1).astype(np.float32)
        return r["primID"].astype(np.int32), uv, r["tfar"].astype(np.float32)
