"""Crease-aware vertex normals for meshes whose file stores none.

A vertex shared by faces meeting at a sharp edge (a chair's leg, a couch's seat) has no one
normal: the area-weighted average points between the faces, so its hemisphere dips below both
of them. Glint traces a vertex's visibility over that hemisphere (its cut) and interpolates
shading across the faces, so each face along the edge was shaded with a normal it does not have
and the edge drew dark (the adjacent face counted as an occluder).

``split_creases`` gives each vertex one copy per *wedge*: the faces around it joined through
edges whose dihedral angle (between the two face normals) is at most ``CREASE_DEG``. Each copy
has the area-weighted normal of its wedge. A smooth surface (every edge below the angle) keeps
its vertices, in order; a box gets flat faces. This is the auto-smooth of modelling tools,
applied only where the file gives no normals (docs/design/conventions.md, vertex normals); a
file's own normals, and its own splits (a crease or a UV seam stored as separate vertices), are
kept. On the held-out couch it removed 25-44% of the vertex mode's error against Mitsuba
(docs/benchmarks/history/2026-12-06-creases.md).

Written here rather than taken from trimesh: ``trimesh.graph.smooth_shade`` cuts the mesh into
disconnected patches of faces (and merges large coplanar facets by an area rule), which also
separates faces that meet at a crease elsewhere in an otherwise smooth fan; here each vertex is
split within its own fan, so the surface stays connected wherever it is smooth.
"""
from __future__ import annotations

import numpy as np

# the largest dihedral angle (degrees) across which faces share a vertex normal; chosen on the
# tuning meshes of docs/benchmarks/history/2026-12-06-creases.md, reported on held-out ones
CREASE_DEG = 45.0


def split_creases(vertices: np.ndarray, faces: np.ndarray, angle_deg: float | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
    """Split vertices along sharp edges.

    vertices (V, 3) float, faces (F, 3) int (in range, no degenerate faces: after
    mesh_repair.repair). Returns (vertices (V', 3) float64, faces (F, 3) int64, normals (V', 3)
    float64 unit, source (V',) int64 the input vertex each output vertex copies, report {"crease_deg", "sharp_edges" (two faces sharper than the angle),
    "open_edges" (boundary or non-manifold edges: their faces never share a normal there),
    "vertices_split"}) with V' ≥ V;
    angle_deg : default CREASE_DEG (180 keeps one normal per vertex, the plain average): vertex
    copies keep their position; faces keep their order and winding. O(F log F) (one sort of the
    edges, one connected-components pass over the 3F face corners)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    angle_deg = CREASE_DEG if angle_deg is None else float(angle_deg)
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    n_f = len(f)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])     # length = 2 × area
    ln = np.linalg.norm(fn, axis=1)
    fu = fn / np.maximum(ln, 1e-300)[:, None]

    # half-edges: face i's edge k runs from corner k to corner (k+1) % 3
    ka = np.tile(np.array([0, 1, 2]), n_f)
    kb = (ka + 1) % 3
    hf = np.repeat(np.arange(n_f), 3)
    va, vb = f[hf, ka], f[hf, kb]
    lo, hi = np.minimum(va, vb), np.maximum(va, vb)
    key = lo * (len(v) + 1) + hi
    order = np.argsort(key, kind="stable")
    ks = key[order]
    # edges used by exactly two faces can be smooth (a boundary, or a non-manifold edge, is a
    # crease by definition: its faces do not form one surface there)
    starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    counts = np.diff(np.r_[starts, len(ks)])
    two = starts[counts == 2]
    a, b = order[two], order[two + 1]
    fa, fb = hf[a], hf[b]
    smooth = (fu[fa] * fu[fb]).sum(1) >= np.cos(np.radians(angle_deg))
    sharp = int(len(a) - smooth.sum())
    open_edges = int((counts != 2).sum())
    a, b, fa, fb = a[smooth], b[smooth], fa[smooth], fb[smooth]
    # join, at both ends of each smooth edge, the two faces' corners of the same vertex
    rows, cols = [], []
    for ends_a in (ka, kb):
        ca = ends_a[a]                                # corner of face fa at this end
        vert = f[fa, ca]
        cb = np.where(f[fb, ka[b]] == vert, ka[b], kb[b])
        rows.append(fa * 3 + ca)
        cols.append(fb * 3 + cb)
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    g = coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(3 * n_f, 3 * n_f))
    n_wedges, wedge = connected_components(g, directed=False)
    corner_vertex = f.reshape(-1)
    # number the wedges in the order of their vertices (then of their first corner), so that a
    # mesh with no crease keeps its vertices exactly, and split copies sit beside each other
    first = np.full(n_wedges, 3 * n_f, np.int64)
    np.minimum.at(first, wedge, np.arange(3 * n_f))
    rank = np.empty(n_wedges, np.int64)
    rank[np.lexsort((first, corner_vertex[first]))] = np.arange(n_wedges)
    wedge = rank[wedge]
    # corners of one wedge share one vertex (edges join corners of the same vertex only)
    new_faces = wedge.reshape(-1, 3).astype(np.int64)
    new_v = np.zeros((n_wedges, 3))
    new_v[wedge] = v[corner_vertex]
    nrm = np.zeros((n_wedges, 3))
    for k in range(3):
        np.add.at(nrm, new_faces[:, k], fn)
    nl = np.linalg.norm(nrm, axis=1, keepdims=True)
    nrm = np.where(nl > 0, nrm / np.maximum(nl, 1e-300), [0.0, 1.0, 0.0])
    report = {"crease_deg": float(angle_deg), "sharp_edges": sharp, "open_edges": open_edges,
              "vertices_split": int(n_wedges - len(np.unique(corner_vertex)))}
    source = np.zeros(n_wedges, np.int64)
    source[wedge] = corner_vertex
    return new_v, new_faces, nrm, source, report
