"""Write a square floor mesh (PLY, +Y normals from the winding): ``python scripts/make_floor.py
OUT.ply --half 200 --cells 80`` gives a 4 m floor (cm) of 5 cm quads, as bench/floor-4m.ply.

A floor for vertex shading must be tessellated: the cut renderer shades vertices and
interpolates, so a two-triangle floor shows no contact shadow at all."""
import argparse

import numpy as np
import trimesh


def floor(half: float, cells: int, y: float = 0.0):
    g = np.linspace(-half, half, cells + 1)
    x, z = np.meshgrid(g, g, indexing="ij")
    v = np.stack([x.ravel(), np.full(x.size, y), z.ravel()], 1).astype(np.float32)
    i = np.arange(cells)[:, None] * (cells + 1) + np.arange(cells)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + cells + 1, i.ravel() + cells + 2
    f = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int32)
    return v, f


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("out")
    p.add_argument("--half", type=float, default=200.0, help="half side (mesh units)")
    p.add_argument("--cells", type=int, default=80, help="quads per side")
    a = p.parse_args()
    v, f = floor(a.half, a.cells)
    trimesh.Trimesh(v, f, process=False).export(a.out)
