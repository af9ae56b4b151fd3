"""Environment lighting integrated over the leaves of the direction tree.

cyber-worlds §V eq. 3: l_k = ∫_{Ω_k} L(ω) dω over each cluster's solid angle. docs/design/conventions.md, precomputed data: the
leaf value is the integral of the map over the leaf's cell, not a point sample, so a sun a few
pixels wide lands, with its full energy, in the leaf that owns it.

How: every map pixel is split into s×s sub-pixels, each assigned (with its exact solid angle) to
the nearest leaf direction (the leaf's Voronoi cell). That gives a sparse (N_leaves × pixels)
matrix, built once per map size. Rotation about +Y by α is a column shift of the equirectangular
map by α·W/2π (fractional shifts interpolate linearly, as Mitsuba's bilinear lookup does), so a
light change costs one roll and a sparse mat-vec, not a rebuild.

Besides l_k, each leaf stores the luminance-weighted sum of its sub-pixel directions. Once per
light change both are summed up the tree (node_lighting), so any cluster's radiance and its
light-weighted centroid direction are one lookup. Rendering evaluates the BRDF at that centroid,
so a sun inside a wide cluster is seen at the sun's direction, not at the cluster's centre.

``light_tables`` gives both per-node tables and the shading kernel's packed form for one
lighting through the kernel backend: ``light_tables_numpy`` (leaf_radiance + node_lighting) is
the reference of the C kernel ``glk_light_tables`` (worker/native/src/lighting.c), which reads
the rotated map in place and makes the four sparse products one pass.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from .directions import DirectionTree

LUMA = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 luminance of linear RGB
MAX_MAP_WIDTH = 2048                       # larger maps are area-averaged first (leaves are ~1°)


def pixel_directions(h: int, w: int, s: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Directions and solid angles of the s×s sub-pixels of an h×w equirectangular map.

    Returns (dirs (h*s, w*s, 3) float64 unit vectors, solid_angle (h*s,) float64 sr per
    sub-pixel of each row). docs/design/conventions.md: u = atan2(x, -z)/2π, v = acos(y)/π.
    """
    hs, ws = h * s, w * s
    theta_edges = np.linspace(0.0, np.pi, hs + 1)
    theta = 0.5 * (theta_edges[:-1] + theta_edges[1:])
    phi = (np.arange(ws) + 0.5) * (2.0 * np.pi / ws)
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    dirs = np.stack(np.broadcast_arrays(st * np.sin(phi), ct, -st * np.cos(phi)), axis=-1)
    solid = (2.0 * np.pi / ws) * (np.cos(theta_edges[:-1]) - np.cos(theta_edges[1:]))
    return dirs, solid


def direction_to_uv(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(…, 3) unit directions -> (u, v) in [0, 1) × [0, 1], docs/design/conventions.md."""
    u = np.mod(np.arctan2(d[..., 0], -d[..., 2]) / (2.0 * np.pi), 1.0)
    v = np.arccos(np.clip(d[..., 1], -1.0, 1.0)) / np.pi
    return u, v


@lru_cache(maxsize=8)
def _assignment(h: int, w: int, tree: DirectionTree):
    """Sparse leaf × pixel matrices: solid angle (sr) and solid angle × direction (x, y, z)."""
    n = tree.n_leaves
    pix_sr = (2 * np.pi / w) * (np.pi / h)
    s = max(1, int(np.ceil(np.sqrt(16.0 * pix_sr / tree.leaf_solid_angle))))
    dirs, solid = pixel_directions(h, w, s)
    _, leaf = cKDTree(tree.leaves.astype(np.float64)).query(dirs.reshape(-1, 3))
    rows = np.arange(h * s)[:, None].repeat(w * s, 1)
    cols = np.arange(w * s)[None, :].repeat(h * s, 0)
    pixel = ((rows // s) * w + cols // s).reshape(-1)
    weight = np.broadcast_to(solid[:, None], rows.shape).reshape(-1)
    d = dirs.reshape(-1, 3)
    mats = [sp.csr_matrix((weight, (leaf, pixel)), shape=(n, h * w))]
    for c in range(3):
        mats.append(sp.csr_matrix((weight * d[:, c], (leaf, pixel)), shape=(n, h * w)))
    for m in mats:
        m.sum_duplicates()
    return mats


def prepare_map(envmap: np.ndarray) -> np.ndarray:
    """Area-average maps wider than MAX_MAP_WIDTH; returns (H, W, 3) float32."""
    h, w, _ = envmap.shape
    if w <= MAX_MAP_WIDTH:
        return np.ascontiguousarray(envmap, dtype=np.float32)
    import cv2

    return cv2.resize(envmap, (MAX_MAP_WIDTH, MAX_MAP_WIDTH // 2), interpolation=cv2.INTER_AREA)


def rotate_map(envmap: np.ndarray, rotation_deg: float) -> np.ndarray:
    """The map as seen in world space after rotating the environment by rotation_deg about +Y
    (Mitsuba: to_world = rotate([0, 1, 0], angle)): world φ reads map φ + α, a column shift."""
    w = envmap.shape[1]
    shift = (rotation_deg / 360.0) * w
    s0 = int(np.floor(shift))
    f = shift - s0
    a = np.roll(envmap, -s0, axis=1)
    if f < 1e-6:
        return a
    return (1.0 - f) * a + f * np.roll(envmap, -s0 - 1, axis=1)


class LeafLighting:
    """Per-leaf integrated radiance for one environment map under rotation and intensity.

    Parameters
    ----------
    envmap : (H, W, 3) float32 linear radiance, W = 2H.
    tree : the direction tree.
    """

    def __init__(self, envmap: np.ndarray, tree: DirectionTree):
        self.map = prepare_map(envmap)
        self.tree = tree
        h, w, _ = self.map.shape
        self._mats = _assignment(h, w, tree)

    def csr(self):
        """The assignment as one CSR pattern with four weights per entry, for the C kernel:
        (indptr (N+1,) int64, pixel index y·W + x (nnz,) int32, weights (nnz, 4) float32 sr and
        sr × direction x, y, z). Built once per LeafLighting."""
        if getattr(self, "_csr", None) is None:
            w_sr, wx, wy, wz = self._mats
            for m in (wx, wy, wz):     # built from the same (leaf, pixel) pairs: one pattern
                if not (np.array_equal(m.indptr, w_sr.indptr) and np.array_equal(m.indices, w_sr.indices)):
                    raise AssertionError("leaf assignment matrices differ in pattern")
            self._csr = (w_sr.indptr.astype(np.int64), w_sr.indices.astype(np.int32),
                         np.ascontiguousarray(np.stack([w_sr.data, wx.data, wy.data, wz.data], 1), np.float32))
        return self._csr

    def leaf_radiance(self, rotation_deg: float = 0.0, intensity: float = 1.0):
        """Returns (l (N, 3) float64 radiance×sr per leaf, ld (N, 3) float64 luminance-weighted
        direction sums per leaf, in units of luminance×sr)."""
        m = rotate_map(self.map, rotation_deg).reshape(-1, 3).astype(np.float64)
        m *= intensity
        w_sr, wx, wy, wz = self._mats
        l = w_sr @ m
        lum = m @ LUMA
        ld = np.stack([wx @ lum, wy @ lum, wz @ lum], axis=1)
        return l, ld


def node_lighting(l: np.ndarray, ld: np.ndarray, tree: DirectionTree):
    """Per tree node, once per light change: (node_l (2N-1, 3) float32 radiance×sr,
    node_w (2N-1, 3) float32 unit light-weighted centroid directions).

    l, ld : (N, 3) per-leaf radiance and luminance-weighted direction sums (leaf_radiance).
    Levels are built bottom-up from pair sums (a node is the union of its two children).
    The centroid falls back to the node's geometric direction when the node is dark or its
    light is spread evenly around it (|Σ lum·ω| ≤ 1e-3 Σ lum). Shading then needs one lookup
    per cluster instead of a normalisation per (point, cluster)."""
    ls, ds = [l], [ld]
    for _ in range(tree.height):
        ls.append(ls[-1].reshape(-1, 2, 3).sum(axis=1))
        ds.append(ds[-1].reshape(-1, 2, 3).sum(axis=1))
    node_l = np.concatenate(ls)
    d = np.concatenate(ds)
    lum = np.abs(node_l @ LUMA)
    dl = np.linalg.norm(d, axis=1)
    use = (dl > 1e-3 * lum) & (dl > 1e-300)
    node_w = np.where(use[:, None], d / np.where(use, dl, 1.0)[:, None], tree.node_dir)
    return node_l.astype(np.float32), node_w.astype(np.float32)


def pack_nodes(node_l: np.ndarray, node_w: np.ndarray) -> np.ndarray:
    """The shading kernel's node records: (2N-1, 8) float32 rows (l_r, l_g, l_b, ω_x, ω_y,
    ω_z, 0, 0), so one record is gathered per cluster (worker/native/src/shade.c)."""
    out = np.zeros((len(node_l), 8), np.float32)
    out[:, 0:3] = node_l
    out[:, 3:6] = node_w
    return out


def light_tables_numpy(lighting: LeafLighting, rotation_deg: float, intensity: float, tree: DirectionTree):
    """Reference of glk_light_tables: (node_l, node_w (2N-1, 3) float32 as node_lighting,
    node8 (2N-1, 8) float32 as pack_nodes) for one rotation (degrees about +Y) and intensity."""
    node_l, node_w = node_lighting(*lighting.leaf_radiance(rotation_deg, intensity), tree)
    return node_l, node_w, pack_nodes(node_l, node_w)


def light_tables(lighting: LeafLighting, rotation_deg: float, intensity: float, tree: DirectionTree,
                 kernels=None):
    """(node_l, node_w, node8) of light_tables_numpy, through the kernel backend."""
    from ..native.kernels import kernels as _kernels

    return (kernels or _kernels()).light_tables(lighting, rotation_deg, intensity, tree)
