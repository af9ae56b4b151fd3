"""Helpers of the cut-field tests (a module, not conftest: conftest names are ambiguous across
folders): meshes of the tests' own, reference cuts of a few vertices, scene files to edit."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from worker.core.cuts import CutSet, build_cuts
from worker.core.directions import get_tree
from worker.renderers.cuts.precompute import ray_offsets, vertex_visibility
from worker.scene import load_scene
from worker.trace.embree import Tracer


def floor(half: float, n: int, y: float = 0.0):
    """A square floor of side 2·half at height y, n × n quads: (vertices (n+1)² float32, faces
    int32 wound so that the normals point up). As scripts/make_floor.py."""
    g = np.linspace(-half, half, n + 1)
    x, z = np.meshgrid(g, g, indexing="ij")
    v = np.stack([x.ravel(), np.full(x.size, y), z.ravel()], 1).astype(np.float32)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + n + 1, i.ravel() + n + 2
    f = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int32)
    return v, f


def reference_cuts(mesh, ids, tau: float = 1.0) -> CutSet:
    """Cuts of the given vertices of a (world-space, whole-scene) mesh traced against all of it,
    as the static precomputation traces them (same origin offset), without tracing the rest."""
    tree = get_tree()
    tracer = Tracer(mesh.vertices, mesh.faces)
    eps = ray_offsets(mesh.vertices, mesh.faces)
    parts = []
    for s in range(0, len(ids), 64):
        b = np.asarray(ids[s:s + 64])
        vis, _ = vertex_visibility(tracer, tree, mesh.vertices[b], mesh.normals[b], eps[b])
        parts.append(build_cuts(vis, tau))
    return CutSet.concat(parts)


def box_mesh(size=(1.0, 1.0, 1.0), n: int = 4):
    """A closed box (centre at the origin) with n × n quads per face and its own vertices per
    face (sharp edges: every vertex normal is its face's)."""
    verts, faces = [], []
    sx, sy, sz = (0.5 * np.asarray(size, np.float64))
    g = np.linspace(-1.0, 1.0, n + 1)
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u, v = [a for a in range(3) if a != axis]
            U, V = np.meshgrid(g, g, indexing="ij")
            p = np.zeros((n + 1, n + 1, 3))
            p[..., axis] = sign
            p[..., u], p[..., v] = U, V
            base = sum(len(x) for x in verts)
            verts.append(p.reshape(-1, 3) * [sx, sy, sz])
            i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
            a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + n + 1, i.ravel() + n + 2
            f = np.concatenate([np.stack([a, c, d], 1), np.stack([a, d, b], 1)])
            # outward winding: flip where the (u, v, axis) frame is left-handed for this sign
            nrm = np.cross(verts[-1][f[0, 1]] - verts[-1][f[0, 0]], verts[-1][f[0, 2]] - verts[-1][f[0, 0]])
            if nrm[axis] * sign < 0:
                f = f[:, ::-1]
            faces.append(f + base)
    return np.concatenate(verts).astype(np.float32), np.concatenate(faces).astype(np.int32)


@dataclass
class SceneKit:
    """Scene files with a movable object, written to a folder: ``write(name, edit)`` writes
    the base spec changed by edit(spec) and returns its path; ``load(name, edit)`` loads it."""
    root: Path
    spec: dict

    def write(self, name: str, edit=None) -> Path:
        spec = json.loads(json.dumps(self.spec))
        if edit is not None:
            edit(spec)
        p = self.root / f"{name}.json"
        p.write_text(json.dumps(spec, indent=1))
        return p

    def load(self, name: str = "scene", edit=None):
        return load_scene(self.write(name, edit))


