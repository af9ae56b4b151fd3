"""Repair of triangle meshes on load: what can be repaired is, what was done is reported, and a
mesh with no usable triangle is refused with a reason.

Fixes, in order (each counted in the report):
- ``nonfinite_vertices``: vertices with a NaN or infinite coordinate; the faces that use them are
  dropped (``faces_on_nonfinite``) rather than refusing the whole file;
- ``degenerate_faces``: faces with a repeated index or (near) zero area;
- ``duplicate_faces``: faces using the same three positions as an earlier face (in any order);
- ``unreferenced_vertices``: vertices no face uses any more, removed;
- winding and orientation (``orient``), for meshes whose normals come from their faces (a file
  without normals): ``winding_flipped_faces``, faces turned so that every edge shared by two
  faces is walked in opposite directions by them (each surface piece coherent, keeping the
  file's winding of most of its area); ``outward_flipped_faces`` (``outward_flipped_components``),
  faces of pieces turned whole because their front sees nothing of the surroundings and their
  back does (an inward-facing piece); ``components`` and ``non_orientable_faces`` (faces of
  pieces no winding makes coherent, left as they are);
- thin surfaces: ``two_sided_components`` / ``two_sided_faces``, open pieces of a mesh of
  several pieces whose two sides both see the surroundings (glass, a panel), which get a back
  (``two_sided_faces_added``, ``back_sheets``), also in a mesh with its own normals;
  ``fold_vertices_split``, vertices whose faces fold back on themselves, split into one per side
  (``split_folds``); ``layer_vertices_moved``, vertices of two layers on the same positions
  facing apart, parted (``separate_layers``); these two for meshes without normals, whose
  vertex normals are then recomputed from the repaired faces.

``duplicate_vertices`` counts vertices that share a position with an earlier one. They are merged
only to find duplicate faces and the faces sharing an edge; the output keeps them split, because
a split is how a file stores a crease or a UV seam in its own normals.

A file's own normals are kept as they are (the renderers shade with them, not with the winding):
``normals_against_faces`` counts the vertices whose file normal points against the repaired
faces around it, which the loader reports but does not change.
"""
from __future__ import annotations

import numpy as np

from .errors import GlintError

# Orientation by exposure (``orient``): the rays decide by a significance test; the first two
# only set how many rays are spent.
EXPOSURE_FACES = 64     # faces sampled per surface piece (area-weighted, fixed seed)
EXPOSURE_RAYS = 16      # cosine-distributed rays per side of each sampled face
SIGMAS = 3.0            # a piece is turned when its back's escapes exceed its front's by 3 σ …
BLIND_FRONT = 0.02      # … and its front sees (next to) nothing: at most 1 ray in 50 escapes. A room
                        # seen from inside (the Cornell box's walls: 17 of 160 front rays leave
                        # through its open side) keeps its winding; the car's inward pieces: 0-1
                        # of up to 1024 (set on fordFocus and the Cornell box, see the history page)
OFFSET = 1e-5           # ray origins off the face, × the mesh's extent (above float32 rounding)
FOLD_DEG = 150.0        # faces at a vertex more than this apart are two sides of a fold: a sheet
                        # folded back on itself is at 180°, a box's corner at 90°, the sharp corner
                        # of a convex solid (tests/test_scene.py's test solid) at 125°
SHEET_GAP = 1e-4        # half the gap between a thin surface's two sides, × the extent: far above
                        # the depth tests' rounding (float32 positions: ~1e-7 of the extent), far
                        # below anything visible (0.4 mm on the 4.4 m fordFocus)


class MeshRejected(GlintError):
    """No triangle of the mesh survives repair (status 422)."""

    def __init__(self, message: str):
        super().__init__(message, 422)


def _face_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(F, 3) float64 unnormalised face normals (length = 2 × area) of v (V, 3), f (F, 3)."""
    return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])


def _edge_pairs(fm: np.ndarray):
    """Faces sharing an edge on merged positions fm (F, 3) int64.

    Returns (a, b, same, boundary): (E,) int64 the two faces of every edge used by exactly two
    faces, (E,) bool whether both walk it in the same direction (incoherent winding), and (F,)
    int64 the number of each face's edges used by it alone (an open border)."""
    from trimesh.grouping import group_rows

    n = len(fm)
    e = np.concatenate([fm[:, [0, 1]], fm[:, [1, 2]], fm[:, [2, 0]]])          # (3F, 2) directed
    fid = np.tile(np.arange(n), 3)
    key = np.sort(e, axis=1)
    two = np.asarray(group_rows(key, require_count=2), np.int64).reshape(-1, 2)
    one = np.asarray(group_rows(key, require_count=1), np.int64).reshape(-1)
    same = e[two[:, 0], 0] == e[two[:, 1], 0]
    return fid[two[:, 0]], fid[two[:, 1]], same, np.bincount(fid[one], minlength=n)


def _exposure(v: np.ndarray, f: np.ndarray, comp: np.ndarray, n_comp: int, area: np.ndarray,
              seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How much of the surroundings each surface piece's two sides see.

    v (V, 3) float64, f (F, 3) int64 (oriented), comp (F,) int64 piece of each face, area (F,)
    float64. Up to EXPOSURE_FACES faces per piece (area-weighted, without replacement) each cast
    EXPOSURE_RAYS cosine-distributed rays about their normal and as many about its opposite, from
    the centroid moved OFFSET × extent off the face, against the whole mesh (Embree occlusion).
    Returns (front, back, rays): (n_comp,) int64 escaping rays on each side and rays per side."""
    from .trace.embree import Tracer

    rng = np.random.default_rng(seed)
    # weighted sampling without replacement: the largest u^(1/w) per piece (Efraimidis-Spirakis)
    key = np.log(rng.random(len(f))) / np.maximum(area, 1e-300)
    order = np.lexsort((-key, comp))
    start = np.searchsorted(comp[order], np.arange(n_comp))
    rank = np.arange(len(order)) - start[comp[order]]
    pick = order[rank < EXPOSURE_FACES]
    tri = v[f[pick]]
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    cen = tri.mean(axis=1)
    ext = float(np.ptp(v, axis=0).max()) or 1.0
    # an orthonormal frame per face (any tangent: the rays are rotationally symmetric)
    helper = np.where(np.abs(nrm[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(nrm, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(nrm, t1)
    k = EXPOSURE_RAYS
    u1, u2 = rng.random((len(pick), k)), rng.random((len(pick), k))
    r, ph = np.sqrt(u1), 2.0 * np.pi * u2
    lx, ly, lz = r * np.cos(ph), r * np.sin(ph), np.sqrt(1.0 - u1)
    tracer = Tracer(v, f)
    esc = []
    for side in (1.0, -1.0):
        n = side * nrm
        d = lx[..., None] * t1[:, None] + ly[..., None] * t2[:, None] + lz[..., None] * n[:, None]
        o = np.repeat(cen + OFFSET * ext * n, k, axis=0)
        free = ~tracer.occluded(o, d.reshape(-1, 3)).reshape(len(pick), k)
        esc.append(np.bincount(comp[pick], weights=free.sum(1), minlength=n_comp).astype(np.int64))
    rays = np.bincount(comp[pick], minlength=n_comp).astype(np.int64) * k
    return esc[0], esc[1], rays


def orient(v: np.ndarray, f: np.ndarray, fm: np.ndarray) -> tuple[np.ndarray, dict]:
    """Coherent winding and outward orientation of every surface piece.

    v (V, 3) float64 finite positions, f (F, 3) int64 faces, fm (F, 3) int64 the same faces on
    merged positions (faces meet across split vertices). A *piece* is a set of faces joined
    through edges used by exactly two faces (an edge of three or more faces joins nothing).

    1. Winding: every shared edge must be walked in opposite directions by its two faces. Each
       face gets two nodes (as is, turned) joined to its neighbours' by that rule; the connected
       components of that graph are the piece's two coherent windings, or one component holding
       both nodes of a face when none exists (a Möbius-like piece: left as it is). Of the two,
       the one agreeing with the file on more of the piece's area is kept.
    2. Outward: a piece is turned whole when its front sees (next to) nothing of the
       surroundings (at most BLIND_FRONT of its rays escape) and its back significantly more
       (``_exposure``; SIGMAS standard deviations of the difference of the two escape counts,
       ≈ √(front + back)). A closed piece's inside sees nothing, so it ends outward; a piece
       seen from both sides, or a room's wall seen from inside through an opening, is left as
       the file winds it.

    Returns (faces (F, 3) int64 repaired, report counts as the module docstring names them)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(f)
    a, b, same, boundary = _edge_pairs(fm)
    ones = np.ones(2 * len(a))
    # node i: face i as is; node n + i: face i turned. A coherent edge joins as-is with as-is
    # (and turned with turned); an incoherent one joins as-is with turned.
    rows = np.concatenate([a, a + n])
    cols = np.concatenate([np.where(same, b + n, b), np.where(same, b, b + n)])
    _, lab = connected_components(coo_matrix((ones, (rows, cols)), shape=(2 * n, 2 * n)), directed=False)
    n_comp, comp = connected_components(coo_matrix((ones[:len(a)], (a, b)), shape=(n, n)), directed=False)
    comp = comp.astype(np.int64)
    non_orientable = lab[:n] == lab[n:]
    fv = v[f]
    area = 0.5 * np.linalg.norm(np.cross(fv[:, 1] - fv[:, 0], fv[:, 2] - fv[:, 0]), axis=1)
    in_a = lab[:n] < lab[n:]            # as-is node in the piece's lower-labelled winding
    area_t = np.bincount(comp, weights=area, minlength=n_comp)
    area_a = np.bincount(comp, weights=area * in_a, minlength=n_comp)
    keep_a = area_a >= area_t - area_a  # the winding of most of the file's area
    flip = (in_a != keep_a[comp]) & ~non_orientable
    out = f.copy()
    out[flip] = out[flip][:, [0, 2, 1]]
    front, back, rays = _exposure(v, out, comp, n_comp, area)
    turn = ((back - front) > SIGMAS * np.sqrt(np.maximum(front + back, 1))) & (front <= BLIND_FRONT * rays)
    turn &= np.bincount(comp, weights=non_orientable, minlength=n_comp) == 0
    turned = turn[comp]
    out[turned] = out[turned][:, [0, 2, 1]]
    lo, hi = np.minimum(front, back), np.maximum(front, back)
    open_piece = np.bincount(comp, weights=boundary, minlength=n_comp) > 0
    # both sides see the surroundings alike: a sheet within an object (glass, a panel) is seen
    # from both. A mesh that is one open sheet and nothing else (a floor, a wall, a backdrop: a
    # scene's surfaces) is seen from its front, and a back would only double its vertices
    two_sided = open_piece & (hi > 0) & (2 * lo >= hi) & (n_comp > 1)
    rep = {"components": int(n_comp), "non_orientable_faces": int(non_orientable.sum()),
           "winding_flipped_faces": int(flip.sum()), "outward_flipped_faces": int(turned.sum()),
           "outward_flipped_components": int(turn.sum()),
           "two_sided_components": int(two_sided.sum()), "two_sided_faces": int(two_sided[comp].sum())}
    return out, rep, two_sided[comp]


def _sheet_normals(v: np.ndarray, fs: np.ndarray, used: np.ndarray) -> np.ndarray:
    """(U, 3) unit area-weighted normals of the faces fs (S, 3) at the vertices ``used``."""
    fv = v[fs]
    fn = np.cross(fv[:, 1] - fv[:, 0], fv[:, 2] - fv[:, 0])
    acc = np.zeros_like(v)
    for k in range(3):
        np.add.at(acc, fs[:, k], fn)
    n = acc[used]
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def split_folds(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices on a fold get one copy per side.

    A vertex whose faces turn back on themselves (a face's normal more than FOLD_DEG from that
    of the vertex's largest face: the two layers of a sheet modelled as a flattened shell that
    share their vertices, the tip of a thin fin) has no one normal: the area-weighted sum of
    opposite normals is short and points anywhere, and the vertex is shaded (and its visibility
    traced) about that direction. Its faces on the far side of the fold move to a copy of it.

    v (V, 3) float64, f (F, 3) int64 (oriented). Returns (vertices (V + C, 3), faces (F, 3),
    src (C,) int64: the original vertex of each copy)."""
    fv = v[f]
    fn = np.cross(fv[:, 1] - fv[:, 0], fv[:, 2] - fv[:, 0])
    area = np.linalg.norm(fn, axis=1)
    un = fn / np.maximum(area[:, None], 1e-300)
    corner_v = f.ravel()
    corner_f = np.repeat(np.arange(len(f)), 3)
    # each vertex's largest face (ties: the first), as the side its index keeps
    order = np.lexsort((-area[corner_f], corner_v))
    first = np.ones(len(order), bool)
    first[1:] = corner_v[order][1:] != corner_v[order][:-1]
    ref = np.zeros((len(v), 3))
    ref[corner_v[order][first]] = un[corner_f[order][first]]
    far = (un[corner_f] * ref[corner_v]).sum(1) < np.cos(np.radians(FOLD_DEG))
    src = np.unique(corner_v[far])
    if not len(src):
        return v, f, src
    new_id = np.full(len(v), -1, np.int64)
    new_id[src] = len(v) + np.arange(len(src))
    out = f.ravel().copy()
    out[far] = new_id[corner_v[far]]
    return np.concatenate([v, v[src]]), out.reshape(-1, 3), src


def separate_layers(v: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, int]:
    """Two layers on the same positions facing apart, given a gap: every vertex with another
    vertex within SHEET_GAP × extent whose normal points the other way (more than FOLD_DEG
    apart: two sides of a sheet, not two faces of a box's corner split at its edges) moves
    SHEET_GAP × extent along its own normal. A depth test between coincident layers otherwise
    picks either at random, and the one facing away from the viewer is shaded black (dark
    speckles over the fordFocus's roof); apart, the layer facing a viewer is the nearer one.

    v (V, 3) float64, n (V, 3) unit normals. Returns (vertices (V, 3), how many moved)."""
    from scipy.spatial import cKDTree

    ext = float(np.ptp(v, axis=0).max()) or 1.0
    gap = SHEET_GAP * ext
    pairs = cKDTree(v).query_pairs(gap, output_type="ndarray")
    if not len(pairs):
        return v, 0
    opp = (n[pairs[:, 0]] * n[pairs[:, 1]]).sum(1) < np.cos(np.radians(FOLD_DEG))
    moved = np.unique(pairs[opp].ravel())
    out = v.copy()
    out[moved] += gap * n[moved]
    return out, int(len(moved))


def back_sheets(v: np.ndarray, f: np.ndarray, sheet: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A back for every two-sided face: a copy of the sheet's faces, wound the other way, on copies
    of their vertices moved 2 × SHEET_GAP × extent behind the sheet (along minus its own area-weighted
    vertex normals).

    The renderers shade one side of a face, the side its vertex normal points to, with the
    visibility seen from that side; a thin open surface (a roof panel modelled as one layer,
    glass) is seen from both. With its back as a face of its own, whichever side the camera sees
    is the nearer face there (the other lies behind it), and it has its own normals and
    visibility: Mitsuba's ``twosided`` in a renderer that has only one side per face.

    v (V, 3) float64, f (F, 3) int64, sheet (F,) bool. Returns (vertices (V + U, 3), faces
    (F + S, 3), used (U,) int64: the original vertex of each added one)."""
    fs = f[sheet]
    used = np.unique(fs)
    n = _sheet_normals(v, fs, used)
    ext = float(np.ptp(v, axis=0).max()) or 1.0
    remap = np.full(len(v), -1, np.int64)
    remap[used] = len(v) + np.arange(len(used))
    return (np.concatenate([v, v[used] - 2.0 * SHEET_GAP * ext * n]),
            np.concatenate([f, remap[fs][:, [0, 2, 1]]]), used)


def repair(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None,
           normals_from_faces: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, dict]:
    """Repair a triangle mesh.

    vertices (V, 3) float, faces (F, 3) int (indices already checked to be in range), normals
    (V, 3) float or None: the file's vertex normals, carried through the vertex removal, or
    (``normals_from_faces``) normals the loader computed from the faces, which are recomputed
    (area-weighted, ``scene.area_weighted_normals``) when winding or orientation turned a face.
    Winding and orientation are repaired (``orient``) unless the normals are the file's.
    Returns (vertices (V', 3) float64, faces (F', 3) int64, normals (V', 3) or None, report) where
    report maps each fix named in the module docstring to a count, plus ``faces_in`` /
    ``faces_out`` / ``vertices_in`` / ``vertices_out``. Raises MeshRejected when no face survives.
    """
    v, f, carried, rep = repair_carrying(vertices, faces, normals=normals, normals_from_faces=normals_from_faces)
    return v, f, carried["normals"], rep


def repair_carrying(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None,
                    normals_from_faces: bool = False, **per_vertex: np.ndarray | None
                    ) -> tuple[np.ndarray, np.ndarray, dict, dict]:
    """``repair`` carrying any other per-vertex arrays (each (V, …) or None, e.g. texture
    coordinates) through the vertex removal and the copies the repair makes (a sheet's back, a
    fold's split vertex: a copy takes its vertex's row): (vertices, faces, {"normals": …, name:
    (V', …) array or None}, report)."""
    per_vertex = {k: (None if a is None else np.asarray(a)) for k, a in per_vertex.items()}

    def copies(src):
        for k, a in per_vertex.items():
            if a is not None:
                per_vertex[k] = np.concatenate([a, a[src]])
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
        if normals is not None:
            normals = np.asarray(normals)[used]
        per_vertex = {k: (None if a is None else a[used]) for k, a in per_vertex.items()}
    own_normals = normals is not None and not normals_from_faces
    f_or, orep, sheet = orient(v, f, fm)
    if not own_normals:
        f = f_or
        rep.update(orep)
    else:
        rep.update({k: orep[k] for k in ("components", "two_sided_components", "two_sided_faces")})
    rep["two_sided_faces_added"] = int(sheet.sum())
    if sheet.any():
        v, f, src = back_sheets(v, f, sheet)
        copies(src)
        if own_normals:
            normals = np.concatenate([np.asarray(normals), -np.asarray(normals)[src]])
    if not own_normals:
        # normals from the faces: split folds, then part coincident layers along those normals
        from .scene import area_weighted_normals

        v, f, src = split_folds(v, f)
        copies(src)
        rep["fold_vertices_split"] = int(len(src))
        nrm = area_weighted_normals(v, f)
        v, rep["layer_vertices_moved"] = separate_layers(v, nrm)
        if normals is not None and (orep["winding_flipped_faces"] or orep["outward_flipped_faces"] or sheet.any()
                                    or len(src) or rep["layer_vertices_moved"]):
            normals = area_weighted_normals(v, f)
    if own_normals:
        # the file's normals are what the renderers shade with; report those that point against
        # every face around their vertex (summed face normals, area-weighted)
        fv = v[f]
        fn = np.cross(fv[:, 1] - fv[:, 0], fv[:, 2] - fv[:, 0])
        acc = np.zeros_like(v)
        for k in range(3):
            np.add.at(acc, f[:, k], fn)
        rep["normals_against_faces"] = int(((acc * np.asarray(normals, np.float64)).sum(1) < 0).sum())
    rep["vertices_out"] = int(len(v))
    rep["faces_out"] = int(len(f))
    return v, f, {"normals": normals, **per_vertex}, rep


def changed(report: dict) -> bool:
    """Whether a repair report records any change to the mesh."""
    return any(report.get(k, 0) for k in ("faces_on_nonfinite", "degenerate_faces", "duplicate_faces",
                                          "unreferenced_vertices", "winding_flipped_faces",
                                          "outward_flipped_faces", "two_sided_faces_added",
                                          "fold_vertices_split", "layer_vertices_moved"))


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
