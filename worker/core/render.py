"""Radiance from cuts, lighting and BRDFs; images through primary rays.

cyber-worlds eq. 3 / inverse-brdf-modeling eq. 22: B(x, ωo) = Σ_k l_k v_k f_r(ω_k, ωo) over the
point's cut, evaluated two ways:

* at vertices (``shade_points``): radiance at the vertices of the triangles the camera sees,
  then barycentric interpolation per pixel. Fast: cost scales with visible vertices.
* inside faces (``shade_blend``): a pixel shades the blend of its three vertices' cuts by
  barycentric weight (equal to blending their shading, the integral being linear in
  visibility) with its own interpolated normal and view direction, as one cluster list over
  the cuts' common refinement. Sharper glossy highlights on coarse meshes. The cut renderer's
  modes (worker/renderers/cuts/renderer.py) combine the two.

``shade_points_numpy`` is the reference of the C kernel ``glk_shade_points``, ``shade_blend_numpy``
of ``glk_shade_blend`` (and likewise
``interpolate_numpy``, ``env_lookup_numpy``); the public functions take the kernel backend
(worker/native/kernels.py), defaulting to the process's.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..native import model_id
from ..native.kernels import kernels as _kernels
from .brdf import PackedBRDF, eval_packed, onb
from .cuts import CutSet
from .directions import DirectionTree

# --- camera -----------------------------------------------------------------------------------


def camera_rays(eye, target, up, fov_y_deg: float, width: int, height: int, samples: int = 1, kernels=None):
    """Primary rays through pixel centres, docs/design/conventions.md (pixel (0, 0) top-left, image right =
    normalize(cross(forward, up))). Returns (origins (H*W*S, 3), dirs (H*W*S, 3)) float32; with
    samples S > 1, the S rays of pixel p are rows p·S … p·S + S − 1, through the sub-pixel
    positions of ``sample_offsets(S)``.

    The unit directions in the camera frame depend only on the field of view, the image size and
    the samples (cached); a view change rotates them into the world with one 3×3 product
    (``rotate_dirs_numpy``, the reference of the C kernel glk_rotate_dirs)."""
    d = camera_dirs(eye, target, up, fov_y_deg, width, height, samples, kernels)
    return np.broadcast_to(np.asarray(eye, np.float32), d.shape).copy(), d


def camera_axes(eye, target, up) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, forward): the camera's unit axes in world space, each (3,) float64."""
    eye = np.asarray(eye, np.float64)
    fwd = np.asarray(target, np.float64) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(up, np.float64))
    right /= np.linalg.norm(right)
    return right, np.cross(right, fwd), fwd


def camera_dirs(eye, target, up, fov_y_deg: float, width: int, height: int, samples: int = 1, kernels=None):
    """The (H*W*S, 3) float32 unit directions of ``camera_rays`` alone (every ray starts at the
    eye: a renderer that traces some of them makes their origins itself)."""
    right, true_up, fwd = camera_axes(eye, target, up)
    basis = np.stack([right, true_up, fwd]).astype(np.float32)       # rows: camera axes in world
    return (kernels or _kernels()).rotate_dirs(_camera_space_dirs(float(fov_y_deg), int(width), int(height),
                                                                   int(samples)), basis)


def pixel_dirs(eye, target, up, fov_y_deg: float, width: int, height: int, pixels, samples: int = 1,
               kernels=None) -> np.ndarray:
    """(n·S, 3) float32 unit world directions of the S sample rays (rows i·S + s, offsets
    ``sample_offsets(S)``) of the pixels pixels (n,) int64 (flat, y·W + x) of a camera: the rows
    of ``camera_dirs`` for those pixels, without making the whole frame's."""
    pix = np.asarray(pixels, np.int64)
    off = sample_offsets(samples)
    d = _image_to_camera((pix % width)[:, None] + 0.5 + off[None, :, 0],          # (n, S)
                         (pix // width)[:, None] + 0.5 + off[None, :, 1], float(fov_y_deg), int(width), int(height))
    right, true_up, fwd = camera_axes(eye, target, up)
    basis = np.stack([right, true_up, fwd]).astype(np.float32)
    return (kernels or _kernels()).rotate_dirs(d, basis)


def rotate_dirs_numpy(dirs, basis) -> np.ndarray:
    """(P, 3) float32 directions dirs (P, 3) in a frame whose axes are the rows of basis (3, 3),
    in the world: dirs @ basis."""
    return (np.asarray(dirs, np.float32) @ np.asarray(basis, np.float32)).astype(np.float32)


def sample_offsets(samples: int) -> np.ndarray:
    """(S, 2) float64 sub-pixel offsets (x right, y down, in pixels from the pixel centre) of the
    anti-aliasing patterns: 1 the centre; 2 a diagonal pair; 4 the rotated grid (RGSS); k² a
    k × k grid. Every pattern is symmetric about the centre, so the mean of a linear function
    over the samples is its value at the centre: inside a triangle, vertex-mode shading with
    S samples equals one sample, and only edges change."""
    s = int(samples)
    if s == 1:
        return np.zeros((1, 2))
    if s == 2:
        return np.array([[-0.25, -0.25], [0.25, 0.25]])
    if s == 4:
        return np.array([[-0.125, -0.375], [0.375, -0.125], [0.125, 0.375], [-0.375, 0.125]])
    k = int(round(np.sqrt(s)))
    if k * k != s or k < 1:
        raise ValueError(f"samples: {s} per pixel is not supported (1, 2, 4, 9, 16 or another square)")
    g = (np.arange(k) + 0.5) / k - 0.5
    return np.stack(np.meshgrid(g, g, indexing="xy"), -1).reshape(-1, 2)


@lru_cache(maxsize=8)
def _camera_space_dirs(fov_y_deg: float, width: int, height: int, samples: int = 1) -> np.ndarray:
    """(H*W*S, 3) float32 unit directions in the camera frame (x right, y up, z forward)."""
    off = sample_offsets(samples)                                      # (S, 2)
    px = (np.arange(width)[None, :, None] + 0.5 + off[None, None, :, 0])    # (1, W, S)
    py = (np.arange(height)[:, None, None] + 0.5 + off[None, None, :, 1])   # (H, 1, S)
    d = _image_to_camera(*np.broadcast_arrays(px, py), fov_y_deg, width, height)
    d.setflags(write=False)
    return d


def _image_to_camera(px, py, fov_y_deg: float, width: int, height: int) -> np.ndarray:
    """(n, 3) float32 unit camera-frame directions (x right, y up, z forward) through image
    points px, py (same shape, float64 pixels from the top-left corner), flattened in C order."""
    t = np.tan(np.radians(fov_y_deg) / 2.0)
    xs = (2.0 * px / width - 1.0) * t * (width / height)
    ys = (1.0 - 2.0 * py / height) * t
    d = np.stack([xs, ys, np.ones_like(xs)], axis=-1).reshape(-1, 3)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d.astype(np.float32)


# --- shading ----------------------------------------------------------------------------------


TABLE_NEUTRAL = 6     # params index of a table material's flag: its channels' tables are equal


def _neutral_table(table: np.ndarray) -> bool:
    """Whether a (TABLE_N, TABLE_N, 3) table's three channels are equal, bit for bit (the
    vector path then reads one of them, with the same result)."""
    t = np.asarray(table, np.float32).reshape(-1, 3)
    return bool(np.array_equal(t[:, 0], t[:, 1]) and np.array_equal(t[:, 0], t[:, 2]))


def texel_quads(table: np.ndarray) -> np.ndarray:
    """(N, N, 4) float32: per texel (i, j) of one channel of a (N, N, 3) table, the four texels
    a bilinear lookup reads, (i, j), (i, j+1), (i+1, j), (i+1, j+1) (clamped at the last row and
    column), so that the vector path loads them as one 16-byte row per lane (shade.c)."""
    t = np.asarray(table, np.float32)[:, :, 0]
    n = t.shape[0]
    i1 = np.minimum(np.arange(n) + 1, n - 1)
    return np.ascontiguousarray(np.stack([t, t[:, i1], t[i1, :], t[i1][:, i1]], -1))


class MaterialTable:
    """Packed materials in the kernel's arrays: kind (M,) int32 (the library's branch id,
    −1 for a model without a C branch: shaded by its NumPy reference), params (M, 72) float32,
    refine, extent (M,) float32 radians (PackedBRDF), tables (concatenated float32),
    table_off (M,) int64 (-1: none)."""

    def __init__(self, packed: list[PackedBRDF]):
        self.packed = packed
        self.kind = np.array([model_id(p.kernel) for p in packed], np.int32)
        self.params = np.stack([p.params for p in packed]).astype(np.float32)
        self.refine = np.array([min(p.refine_radius, 1e9) for p in packed], np.float32)
        self.extent = np.array([min(p.extent, 1e9) for p in packed], np.float32)
        offs, tabs, pos = [], [], 0
        for i, p in enumerate(packed):
            if p.table is None:
                offs.append(-1)
                continue
            offs.append(pos); tabs.append(p.table.reshape(-1)); pos += p.table.size
            # a table whose three channels are equal (a white specular part) is read once for
            # all three by the vector shading path (shade.c sum_table), from its texel quads
            # stored after it
            if p.kernel == "table" and _neutral_table(p.table):
                self.params[i, TABLE_NEUTRAL] = 1.0
                q = texel_quads(p.table)
                tabs.append(q.reshape(-1)); pos += q.size
        self.table_off = np.array(offs, np.int64)
        self.tables = np.concatenate(tabs).astype(np.float32) if tabs else np.zeros(1, np.float32)


def shade_points_numpy(normals, wo, cut_of, mat_of, cuts: CutSet, node_l, node_w, tree: DirectionTree,
                       mats: MaterialTable, chunk: int = 1024) -> np.ndarray:
    """NumPy reference of glk_shade_points.

    normals, wo : (P, 3) float32 unit vectors (shading normal, direction towards the viewer).
    cut_of : (P,) int32 cut (vertex) index per point, -1 for none. mat_of : (P,) int32.
    node_l, node_w : (2N-1, 3) float32 per-node radiance and light-weighted centroid direction
        (lighting.node_lighting).
    Returns (P, 3) float32 outgoing radiance.
    """
    out = np.zeros((len(normals), 3), np.float64)
    for s in range(0, len(normals), chunk):
        e = min(s + chunk, len(normals))
        out[s:e] = _shade_chunk(normals[s:e].astype(np.float64), wo[s:e].astype(np.float64),
                                cut_of[s:e], mat_of[s:e], cuts, node_l, node_w, tree, mats)
    return out.astype(np.float32)


def _cut_entries(cut_of, cuts: CutSet):
    """Every entry of the points' cuts, in leaf order: (pt, h, start, q8) (M,) int64 point index,
    height, first leaf and quantised visibility (int64, q/255)."""
    a = cuts.offsets[cut_of]
    b = cuts.offsets[cut_of + 1]
    cnt = (b - a).astype(np.int64)
    pt = np.repeat(np.arange(len(cut_of)), cnt)
    node = np.concatenate([np.arange(x, y) for x, y in zip(a, b)]) if len(a) else np.zeros(0, np.int64)
    h = cuts.heights[node].astype(np.int64)
    w = np.int64(1) << h
    # start leaf of each node: running sum within each point's cut
    csum = np.cumsum(w)
    first = np.repeat(np.cumsum(cnt) - cnt, cnt)
    start = csum - w - (csum[first] - w[first]) if len(w) else np.zeros(0, np.int64)
    return pt, h, start, cuts.quant[node].astype(np.int64)


def expand_cut_entries(cut_of, cuts: CutSet, tree: DirectionTree, mirror, pairs):
    """The cluster list each point evaluates: its cut's nodes with non-zero visibility, split
    while any (refine radius, extent) pair asks for it (children inherit the parent's
    visibility). The renderer passes one pair per point (its material's), the fitter one scalar
    pair per basis level (fit/transfer.py).

    cut_of : (P,) cut index per point (≥ 0). mirror : (P, 3) float64 mirror directions.
    pairs : [(refine, extent), …], each radians, a scalar or (P,) float64 per point
        (PackedBRDF.refine_radius / extent); a node of radius R at angle a from the mirror
        direction is split when R > refine and a < R + extent.
    Returns (pt, idx, q): (M,) point index, flat tree-node index and visibility in [0, 1].
    """
    pt, h, start, q8 = _cut_entries(cut_of, cuts)
    q = q8.astype(np.float64) / 255.0
    keep = q > 0
    return split_entries(pt[keep], h[keep], start[keep], q[keep], tree, mirror, pairs)


def blend_cut_entries(verts, bary, cuts: CutSet, height: int):
    """The blend of each point's three cuts by barycentric weight, as one entry list (the NumPy
    reference of shade.c collect_blend before its split about the mirror direction).

    The cuts' common refinement: its nodes start at every entry start of the three cuts, and
    the node at a start is the finest of the three entries covering it; its visibility is
    Σ_i w_i q_i/255 with q_i the entry of cut i covering it (B is linear in visibility,
    inverse-brdf-modeling eq. 22, so shading it equals blending the three cuts' shading where
    they agree, and is closer to the integral where one is coarser).

    verts : (P, 3) cut (vertex) indices (≥ 0); bary : (P, 3) weights; height : the tree's H.
    Returns (pt, h, start, q) (M,) int64, int64, int64, float64 with q > 0, in leaf order.
    """
    P = len(verts)
    verts = np.asarray(verts, np.int64)
    parts = [_cut_entries(verts[:, i], cuts) for i in range(3)]
    keys = [pt * (np.int64(1) << height) + st for pt, _, st, _ in parts]     # sorted: by point, then leaf
    allk = np.unique(np.concatenate(keys)) if P else np.zeros(0, np.int64)
    pt = allk >> np.int64(height)
    start = allk & ((np.int64(1) << height) - 1)
    h = np.full(len(allk), 1 << 30, np.int64)
    q = np.zeros(len(allk))
    w = np.asarray(bary, np.float64)
    for i, (k, (_, hi, _, qi)) in enumerate(zip(keys, parts)):
        j = np.searchsorted(k, allk, side="right") - 1          # the entry of cut i covering each start
        h = np.minimum(h, hi[j])
        q += w[pt, i] * qi[j] / 255.0
    keep = q > 0
    return pt[keep], h[keep], start[keep], q[keep]


def split_entries(pt, h, start, q, tree: DirectionTree, mirror, pairs):
    """Cut entries (pt, h, start, q) split while any (refine, extent) pair asks for it
    (expand_cut_entries); returns (pt, idx, q)."""
    pairs = [(np.asarray(r, np.float64), np.asarray(e, np.float64)) for r, e in pairs]
    while True:
        idx = tree.level_offset[h] + (start >> h)
        R = tree.node_radius[idx].astype(np.float64)
        nd = tree.node_dir[idx].astype(np.float64)
        ang = np.arccos(np.clip((nd * mirror[pt]).sum(1), -1.0, 1.0))
        ref = np.zeros(len(pt), bool)
        for r, e in pairs:
            r, e = (r[pt] if r.ndim else r), (e[pt] if e.ndim else e)
            ref |= (R > r) & ((R + e >= np.pi) | (ang < R + e))
        ref &= h > 0
        if not ref.any():
            return pt, idx, q
        k = np.nonzero(ref)[0]
        half = np.int64(1) << (h[k] - 1)
        stay = ~ref
        pt = np.concatenate([pt[stay], pt[k], pt[k]])
        q = np.concatenate([q[stay], q[k], q[k]])
        start = np.concatenate([start[stay], start[k], start[k] + half])
        h = np.concatenate([h[stay], h[k] - 1, h[k] - 1])


GRAZE_COS = 1e-3       # shade.c glint_common.h GRAZE_COS


def facing_view(n, wo) -> np.ndarray:
    """View directions (P, 3) float64 for shading normals n (P, 3) and unit ωo (P, 3): ωo where
    cosθo ≥ GRAZE_COS, else taken just above the normal's horizon (ωo + n(GRAZE_COS − cosθo),
    normalised). Every shaded point is seen, but its shading normal (a vertex's, or one
    interpolated across a face) can face away from the eye at a silhouette: its grazing
    radiance, not none (a black vertex smeared across a silhouette's faces)."""
    n = np.asarray(n, np.float64)
    wo = np.array(wo, np.float64)
    co = (n * wo).sum(1)
    low = co < GRAZE_COS
    if low.any():
        w = wo[low] + n[low] * (GRAZE_COS - co[low])[:, None]
        wo[low] = w / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-30)
    return wo


def cluster_directions(node_w, idx, n):
    """Representative incident directions (M, 3) of clusters idx for points with normals n
    (M, 3): the light-weighted centroid, nudged just above the horizon when a cluster straddling
    it has its centroid below (its visibility already carries the cosine)."""
    wi = node_w[idx].astype(np.float64)
    ci = (wi * n).sum(1)
    low = ci < 1e-3
    wi[low] += n[low] * (1e-3 - ci[low])[:, None]
    wi[low] /= np.linalg.norm(wi[low], axis=1, keepdims=True)
    return wi


def _shade_chunk(n, wo, cut_of, mat_of, cuts, node_l, node_w, tree, mats):
    wo = facing_view(n, wo)
    co = (n * wo).sum(1)
    live = np.nonzero((co > 0) & (cut_of >= 0))[0]
    if len(live) == 0:
        return np.zeros((len(n), 3))
    r = 2.0 * co[live, None] * n[live] - wo[live]                      # mirror directions
    m = mat_of[live]
    p, idx, q = expand_cut_entries(cut_of[live], cuts, tree, r, [(mats.refine[m], mats.extent[m])])
    return _sum_entries(n, wo, live[p], idx, q, mat_of, node_l, node_w, mats)


def _sum_entries(n, wo, pt, idx, q, mat_of, node_l, node_w, mats):
    """(len(n), 3) float64 Σ l_k q_k f_r(ω_k, ωo) per point over cluster entries (pt point index,
    idx tree node, q visibility) (inverse-brdf-modeling eq. 22)."""
    out = np.zeros((len(n), 3))
    l = node_l[idx].astype(np.float64)
    dark = (l <= 0).all(1)
    npt = n[pt]
    wi = cluster_directions(node_w, idx, npt)
    t, bt = onb(npt)
    wi_l = np.stack([(wi * t).sum(1), (wi * bt).sum(1), (wi * npt).sum(1)], 1)
    wop = wo[pt]
    wo_l = np.stack([(wop * t).sum(1), (wop * bt).sum(1), (wop * npt).sum(1)], 1)
    f = np.zeros((len(pt), 3))
    for mi in np.unique(mat_of[pt]):
        sel = mat_of[pt] == mi
        f[sel] = eval_packed(mats.packed[mi], wi_l[sel], wo_l[sel])
    contrib = np.where(dark[:, None], 0.0, l * q[:, None] * f)
    for c in range(3):
        out[:, c] = np.bincount(pt, weights=contrib[:, c], minlength=len(n))
    return out


def shade_blend_numpy(normals, wo, verts, bary, mat_of, cuts: CutSet, node_l, node_w, tree: DirectionTree,
                      mats: MaterialTable, chunk: int = 512) -> np.ndarray:
    """NumPy reference of glk_shade_blend: radiance at points inside faces, each shading the
    blend of its face's three vertex cuts (blend_cut_entries) with its own normal and view
    direction (pixel mode; inverse-brdf-modeling §4.1).

    normals, wo : (P, 3) float32 unit; verts : (P, 3) int32 cut (vertex) indices; bary : (P, 3)
    float32 weights; mat_of : (P,) int32. Returns (P, 3) float32.
    """
    out = np.zeros((len(normals), 3), np.float64)
    verts = np.asarray(verts)
    for s in range(0, len(normals), chunk):
        e = min(s + chunk, len(normals))
        n, w = normals[s:e].astype(np.float64), wo[s:e].astype(np.float64)
        w = facing_view(n, w)
        co = (n * w).sum(1)
        live = np.nonzero((co > 0) & (verts[s:e, 0] >= 0))[0]
        if len(live) == 0:
            continue
        r = 2.0 * co[live, None] * n[live] - w[live]
        m = np.asarray(mat_of[s:e])[live]
        pt, h, st, q = blend_cut_entries(verts[s:e][live], np.asarray(bary[s:e])[live], cuts, tree.height)
        p, idx, q = split_entries(pt, h, st, q, tree, r, [(mats.refine[m], mats.extent[m])])
        out[s:e] = _sum_entries(n, w, live[p], idx, q, np.asarray(mat_of[s:e]), node_l, node_w, mats)
    return out.astype(np.float32)


def shade_blend(normals, wo, verts, bary, mat_of, cuts: CutSet, node_l, node_w, tree: DirectionTree,
                mats: MaterialTable, kernels=None, node8=None, face=None) -> np.ndarray:
    """(P, 3) float32 per-pixel radiance from blended cuts (see shade_blend_numpy). face : (P,)
    int the face of each point when known (the C kernel merges each face's cuts once)."""
    return (kernels or _kernels()).shade_blend(normals, wo, verts, bary, mat_of, cuts, node_l, node_w, tree, mats,
                                               node8=node8, face=face)


def shade_points(normals, wo, cut_of, mat_of, cuts: CutSet, node_l, node_w, tree: DirectionTree,
                 mats: MaterialTable, kernels=None, node8=None) -> np.ndarray:
    """(P, 3) float32 radiance at points (see shade_points_numpy); kernels: the backend;
    node8: the packed node records of (node_l, node_w) (lighting.light_tables), if at hand."""
    return (kernels or _kernels()).shade_points(normals, wo, cut_of, mat_of, cuts, node_l, node_w, tree, mats,
                                                node8=node8)


def seen_vertices(tri, faces, n_vertices: int) -> np.ndarray:
    """(K,) int32 sorted vertices of the faces hit in ``tri`` (any shape, int32, −1: a miss),
    faces (F, 3): by marking (O(P + F), no sort)."""
    fm = np.zeros(len(faces) + 1, bool)
    fm[np.asarray(tri).reshape(-1)] = True         # a miss (−1) marks the extra last entry
    vm = np.zeros(n_vertices, bool)
    vm[faces[np.flatnonzero(fm[:-1])].reshape(-1)] = True
    return np.flatnonzero(vm).astype(np.int32)


def interpolate_numpy(tri, uv, faces, vert_rgb, out):
    """Barycentric interpolation of per-vertex (V, 3) radiance into out (P, 3) where tri ≥ 0
    (NumPy reference of glk_interpolate)."""
    hit = tri >= 0
    f = faces[tri[hit]]
    u, v = uv[hit, 0:1], uv[hit, 1:2]
    out[hit] = (1 - u - v) * vert_rgb[f[:, 0]] + u * vert_rgb[f[:, 1]] + v * vert_rgb[f[:, 2]]
    return out


def interpolate(tri, uv, faces, vert_rgb, out, kernels=None):
    """Barycentric interpolation of per-vertex (V, 3) radiance into out (P, 3) where tri ≥ 0."""
    return (kernels or _kernels()).interpolate(tri, uv, faces, vert_rgb, out)


def env_lookup_numpy(dirs, envmap, rotation_deg: float, intensity: float, mask=None, out=None) -> np.ndarray:
    """Bilinear lookup of the (rotated, scaled) environment along world directions (P, 3)
    (NumPy reference of glk_env_lookup); only where mask (P,) is set, into out (P, 3)."""
    if out is None:
        out = np.zeros((len(dirs), 3), np.float32)
    sel = np.ones(len(dirs), bool) if mask is None else mask.astype(bool)
    d = dirs[sel].astype(np.float64)
    hm, wm, _ = envmap.shape
    u = np.mod(np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi) + rotation_deg / 360.0, 1.0)
    v = np.arccos(np.clip(d[:, 1], -1, 1)) / np.pi
    fx, fy = u * wm - 0.5, v * hm - 0.5
    x0, y0 = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
    ax, ay = (fx - x0)[:, None], (fy - y0)[:, None]
    x1 = (x0 + 1) % wm; x0 = x0 % wm
    y1 = np.clip(y0 + 1, 0, hm - 1); y0 = np.clip(y0, 0, hm - 1)
    a = envmap[y0, x0] * (1 - ax) + envmap[y0, x1] * ax
    b = envmap[y1, x0] * (1 - ax) + envmap[y1, x1] * ax
    out[sel] = (intensity * (a * (1 - ay) + b * ay)).astype(np.float32)
    return out


def env_lookup(dirs, envmap, rotation_deg: float, intensity: float, mask=None, out=None,
               kernels=None) -> np.ndarray:
    """Bilinear lookup of the (rotated, scaled) environment along world directions (P, 3)."""
    return (kernels or _kernels()).env_lookup(dirs, envmap, rotation_deg, intensity, mask, out)


# --- frame assembly ---------------------------------------------------------------------------


def env_coords(dirs, kernels=None, rows=None) -> np.ndarray:
    """(P, 2) float32 equirectangular coordinates (u in [0, 1), v = acos(y)/π) of world
    directions (P, 3), or (n, 2) of dirs[rows] for rows (n,) int64 (a view's background rows,
    without copying them out first), with the environment unrotated
    (docs/design/conventions.md): once per view, so that a light change costs a lookup
    (``background``)."""
    k = kernels or _kernels()
    return k.env_coords(dirs) if rows is None else k.env_coords(dirs, rows)


def env_coords_numpy(dirs) -> np.ndarray:
    """NumPy reference of glk_env_coords (see env_coords)."""
    d = np.asarray(dirs, np.float64)
    u = np.mod(np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi), 1.0)
    v = np.arccos(np.clip(d[:, 1], -1, 1)) / np.pi
    return np.stack([u, v], 1).astype(np.float32)


def background_numpy(sample, dirs, uv0, envmap, rotation_deg: float, intensity: float, out, shadow=None,
                     eye=None):
    """NumPy reference of glk_background: out[sample] = the (rotated, scaled) environment along
    dirs[sample] (dirs (P·S, 3): every row's ray direction), bilinear at the view's coordinates
    uv0 (n, 2) (env_coords), times the ground shadow factor where a ray from eye (3,) goes down
    through the shadow plane.

    shadow : None, or (grid (G, G, 3) float32 factor, (x0, z0, step, y)) with grid node (i, j)
        at (x0 + i·step, y, z0 + j·step); bilinear, 1 outside the grid.
    out : (P·S, 3) float32, written at rows ``sample`` (n,) int64."""
    hm, wm, _ = envmap.shape
    u = np.mod(uv0[:, 0].astype(np.float64) + rotation_deg / 360.0, 1.0)
    v = uv0[:, 1].astype(np.float64)
    fx, fy = u * wm - 0.5, v * hm - 0.5
    x0, y0 = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
    ax, ay = (fx - x0)[:, None], (fy - y0)[:, None]
    x1 = (x0 + 1) % wm; x0 = x0 % wm
    y1 = np.clip(y0 + 1, 0, hm - 1); y0 = np.clip(y0, 0, hm - 1)
    a = envmap[y0, x0] * (1 - ax) + envmap[y0, x1] * ax
    b = envmap[y1, x0] * (1 - ax) + envmap[y1, x1] * ax
    val = intensity * (a * (1 - ay) + b * ay)
    if shadow is not None:
        grid, (gx0, gz0, step, gy) = shadow
        g = grid.shape[0]
        d = np.asarray(dirs, np.float64)[np.asarray(sample, np.int64)]
        e = np.asarray(eye, np.float64)
        fac = np.ones((len(d), 3))
        down = (d[:, 1] < 0) & (e[1] > gy)
        t = np.where(down, (gy - e[1]) / np.where(down, d[:, 1], -1.0), 0.0)
        gx = (e[0] + t * d[:, 0] - gx0) / step
        gz = (e[2] + t * d[:, 2] - gz0) / step
        inside = down & (gx >= 0) & (gz >= 0) & (gx <= g - 1) & (gz <= g - 1)
        i0 = np.minimum(gx[inside].astype(np.int64), g - 2)
        j0 = np.minimum(gz[inside].astype(np.int64), g - 2)
        fa, fb = (gx[inside] - i0)[:, None], (gz[inside] - j0)[:, None]
        gr = grid.astype(np.float64)
        fac[inside] = ((gr[i0, j0] * (1 - fb) + gr[i0, j0 + 1] * fb) * (1 - fa)
                       + (gr[i0 + 1, j0] * (1 - fb) + gr[i0 + 1, j0 + 1] * fb) * fa)
        val = val * fac
    out[sample] = val.astype(np.float32)
    return out


def background(sample, dirs, uv0, envmap, rotation_deg: float, intensity: float, out, shadow=None, eye=None,
               kernels=None):
    """The background samples of a frame (see background_numpy), through the kernel backend."""
    return (kernels or _kernels()).background(sample, dirs, uv0, envmap, rotation_deg, intensity, out, shadow, eye)


def resolve_numpy(tri, uv, faces, vert_rgb, bg, samples: int, out):
    """NumPy reference of glk_resolve: out (P, 3) = per pixel, the mean over its S samples (rows
    p·S + s of tri (P·S,), uv (P·S, 2), bg (P·S, 3)) of the barycentric interpolation of per-vertex
    radiance vert_rgb (V, 3) where tri ≥ 0, else of bg."""
    val = np.array(bg, np.float32, copy=True)
    interpolate_numpy(tri, uv, faces, vert_rgb, val)
    out[:] = val.reshape(-1, samples, 3).mean(1)
    return out


def resolve(tri, uv, faces, vert_rgb, bg, samples: int, out, kernels=None):
    """Per-pixel mean of the samples' interpolated radiance or background (see resolve_numpy)."""
    return (kernels or _kernels()).resolve(tri, uv, faces, vert_rgb, bg, samples, out)
