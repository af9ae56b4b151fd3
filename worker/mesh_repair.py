"""Repair of triangle meshes on load: what can be repaired is, what was done is reported, and a
mesh with no usable triangle is refused with a reason.

Fixes, in order (each counted in the report):
- ``nonfinite_vertices``: vertices with a NaN or infinite coordinate; the faces that use them are
  dropped (``faces_on_nonfinite``) rather than refusing the whole file;
- ``degenerate_faces``: faces with a repeated index or (near) zero area;
- ``duplicate_faces``: faces using the same three positions as an earlier face (in any order);
- ``unreferenced_vertices``: vertices no face uses any more, removed.

``duplicate_vertices`` counts vertices that share a position with an earlier one. They are merged
only to find duplicate faces; the output keeps them split, because a split is how a file stores a
crease or a UV seam in its own normals.

Winding is not changed: trimesh.repair.fix_normals needs networkx (not a dependency), and turning
a whole open mesh "outwards" by its signed volume flipped every face of the Stanford bunny.
"""
from __future__ import annotations

import numpy as np

from .errors import GlintError


class MeshRejected(GlintError):
    """No triangle of the mesh survives repair (status 422)."""

    def __init__(self, message: str):
        super().__init__(message, 422)


def _face_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(F, 3) float64 unnormalised face normals (length = 2 × area) of v (V, 3), f (F, 3)."""
    return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])


def repair(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, dict]:
    """Repair a triangle mesh.

    vertices (V, 3) float, faces (F, 3) int (indices already checked to be in range), normals
    (V, 3) float or None (the file's vertex normals, carried through the vertex removal).
    Returns (vertices (V', 3) float64, faces (F', 3) int64, normals (V', 3) or None, report) where
    report maps each fix named in the module docstring to a count, plus ``faces_in`` /
    ``faces_out`` / ``vertices_in`` / ``vertices_out``. Raises MeshRejected when no face survives.
    """
    v, f, carried, rep = repair_carrying(vertices, faces, normals=normals)
    return v, f, carried["normals"], rep


def repair_carrying(vertices: np.ndarray, faces: np.ndarray, **per_vertex: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, dict, dict]:
    """``repair`` carrying any per-vertex arrays (each (V, …) or None: normals, texture
    coordinates) through the vertex removal: (vertices, faces, {name: (V', …) array or None},
    report)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    rep = {"vertices_in": int(len(v)), "faces_in": int(len(f))}

    bad_v = ~np.isfinite(v).all(axis=1)
    rep["nonfinite_vertices"] = int(bad_v.sum())
    keep = ~bad_v[f].any(axis=1)
    rep["faces_on_nonfinite"] = int((~keep).sum())
    f = f[keep]
    vf = np.where(bad_v[:, None], 0.0, v)          # finite copy for the arithmetic below

    # degenerate: hand-written because trimesh's nondegenerate_faces needs a Trimesh whose
    # vertices are all finite and uses an absolute height; the tolerance here is relative to
    # the mesh's size so that millimetre and kilometre models are judged alike
    rep_idx = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    ext = float(np.ptp(vf[~bad_v], axis=0).max()) if (~bad_v).any() else 0.0
    area2 = np.linalg.norm(_face_normals(vf, f), axis=1)
    degen = rep_idx | (area2 <= (1e-10 * ext) ** 2) | ~np.isfinite(area2)
    rep["degenerate_faces"] = int(degen.sum())
    f = f[~degen]

    # duplicate vertices by position (trimesh.grouping.unique_rows hashes rows exactly)
    from trimesh.grouping import unique_rows

    _, inverse = unique_rows(vf)
    inverse = np.asarray(inverse, dtype=np.int64)
    rep["duplicate_vertices"] = int(len(v) - bad_v.sum() - len(np.unique(inverse[~bad_v]))) if len(v) else 0
    fm = inverse[f]                                  # faces on merged positions

    # duplicate faces: same three positions in any order (trimesh.grouping.unique_rows on the
    # sorted rows keeps the first occurrence)
    if len(fm):
        first, _ = unique_rows(np.sort(fm, axis=1))
        first = np.sort(np.asarray(first, dtype=np.int64))
    else:
        first = np.zeros(0, np.int64)
    rep["duplicate_faces"] = int(len(f) - len(first))
    f, fm = f[first], fm[first]

    if not len(f):
        raise MeshRejected(f"no usable triangle: {rep['faces_in']} faces read, "
                           f"{rep['degenerate_faces']} degenerate, {rep['faces_on_nonfinite']} on "
                           f"NaN/infinite vertices, {rep['duplicate_faces']} duplicates")

    used = np.zeros(len(v), bool)
    used[f.ravel()] = True
    rep["unreferenced_vertices"] = int((~used).sum())
    if not used.all():
        remap = np.cumsum(used) - 1
        f = remap[f]
        v = v[used]
        per_vertex = {k: (None if a is None else np.asarray(a)[used]) for k, a in per_vertex.items()}
    rep["vertices_out"] = int(len(v))
    rep["faces_out"] = int(len(f))
    return v, f, per_vertex, rep


def changed(report: dict) -> bool:
    """Whether a repair report records any change to the mesh."""
    return any(report.get(k, 0) for k in ("faces_on_nonfinite", "degenerate_faces", "duplicate_faces",
                                          "unreferenced_vertices"))


def cmd_check(a) -> int:
    """``glint mesh check PATH``: load (and so repair) a mesh, print the repair report as JSON."""
    import json

    from .scene import SceneError, load_mesh

    try:
        m = load_mesh(a.path)
    except SceneError as e:
        raise GlintError(str(e)) from None
    print(json.dumps({"path": str(a.path), "changed": changed(m.repair), "repair": m.repair}))
    return 0


def add_commands(sub) -> None:
    p = sub.add_parser("mesh", help="mesh files: what loading repairs")
    ms = p.add_subparsers(dest="what", required=True)
    c = ms.add_parser("check", help="print what loading PATH repairs (JSON)")
    c.add_argument("path")
    c.set_defaults(fn=cmd_check)
