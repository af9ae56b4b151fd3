"""Where a visibility cut field is sampled: concentric spheres around an object's bounding sphere,
each covered by an equi-angular cube map (cyber-worlds §V.A.1, Fig. 4; §V.A.4 for the lookup).

Shell k (0 ≤ k < K) has radius ρ_k = ρ_0 q^k (geometric spacing, ρ_0 = rho_min·r,
ρ_{K−1} = rho_max·r): the occluded set seen from a point changes over a distance proportional
to the point's distance from the object, so cells of equal relative size (Δρ/ρ = q − 1, and an
angular width of about (π/2)/n) make the interpolation error about the same on every shell.

Each shell is sampled at the (n+1)² corners of every cube face, mapped to the sphere by the
equi-angular map d = normalise(a + tan(πu/4) t_u + tan(πv/4) t_v), u, v ∈ [−1, 1]. Corners on
face edges are shared, so a shell has 6n² + 2 distinct points and bilinear interpolation inside
a face is continuous across faces. Trilinear interpolation (§V.A.4: "eight sample points
neighbor to the vertex") blends the 2 × 4 corners of the cell holding the point, linearly in
log ρ between shells and in (u, v) within a face. Cell (k, face, i, j) has index
((k·6 + face)·n + i)·n + j.

``lookup_numpy`` is the NumPy reference of the C kernel ``glf_lookup`` (fields.c).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

# face f: major axis a, tangents (t_u, t_v); +X, −X, +Y, −Y, +Z, −Z
FACE_AXES = np.array([
    [[1, 0, 0], [0, 0, -1], [0, 1, 0]],
    [[-1, 0, 0], [0, 0, 1], [0, 1, 0]],
    [[0, 1, 0], [1, 0, 0], [0, 0, -1]],
    [[0, -1, 0], [1, 0, 0], [0, 0, 1]],
    [[0, 0, 1], [1, 0, 0], [0, 1, 0]],
    [[0, 0, -1], [-1, 0, 0], [0, 1, 0]],
], np.float64)


@dataclass(frozen=True)
class GridSpec:
    """Sampling density of a field (dimensionless; the defaults are justified in BENCHMARKS.md).

    shells : K concentric spheres. face : n, cube-face cells per side (6n² + 2 points per shell).
    rho_min, rho_max : innermost and outermost radii in units of the bounding radius r.
    """
    shells: int = 24
    face: int = 24
    rho_min: float = 0.25
    rho_max: float = 8.0

    def __post_init__(self):
        if self.shells < 2 or self.face < 1 or not (0 < self.rho_min < self.rho_max):
            raise ValueError(f"invalid field grid {self}")

    def tag(self) -> str:
        return f"K{self.shells}n{self.face}r{self.rho_min:g}-{self.rho_max:g}"


def face_directions(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Unique unit directions of the cube-face corner grid and the (6, n+1, n+1) int32 table of
    their indices (shared edge and corner points appear once: 6n² + 2 directions, float64)."""
    g = np.tan(np.pi / 4 * np.linspace(-1.0, 1.0, n + 1))
    a, tu, tv = FACE_AXES[:, 0], FACE_AXES[:, 1], FACE_AXES[:, 2]
    d = a[:, None, None, :] + g[None, :, None, None] * tu[:, None, None, :] + g[None, None, :, None] * tv[:, None, None, :]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    flat = d.reshape(-1, 3)
    key = np.round(flat * 1e9).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)                      # keep the first-seen order (face by face)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    dirs = flat[first[order]]
    table = rank[inverse.reshape(-1)].reshape(6, n + 1, n + 1).astype(np.int32)
    return dirs, table


@dataclass(frozen=True, eq=False)
class FieldGrid:
    """Sample points of one object's field, in the object's local frame.

    center : (3,) float64 bounding-sphere centre; radius : r (local units).
    """
    center: np.ndarray
    radius: float
    spec: GridSpec

    @cached_property
    def _faces(self):
        return face_directions(self.spec.face)

    @property
    def directions(self) -> np.ndarray:
        """(M, 3) float64 unit directions of one shell's points, M = 6n² + 2."""
        return self._faces[0]

    @property
    def face_table(self) -> np.ndarray:
        """(6, n+1, n+1) int32 index into ``directions`` of every face corner."""
        return self._faces[1]

    @property
    def per_shell(self) -> int:
        return len(self.directions)

    @property
    def n_samples(self) -> int:
        return self.spec.shells * self.per_shell

    @property
    def n_cells(self) -> int:
        """Cells between consecutive shells: (K − 1) · 6n²."""
        return (self.spec.shells - 1) * 6 * self.spec.face ** 2

    @cached_property
    def radii(self) -> np.ndarray:
        """(K,) float64 shell radii, geometric from rho_min·r to rho_max·r."""
        s = self.spec
        return self.radius * s.rho_min * (s.rho_max / s.rho_min) ** (np.arange(s.shells) / (s.shells - 1))

    @property
    def log_q(self) -> float:
        s = self.spec
        return float(np.log(s.rho_max / s.rho_min) / (s.shells - 1))

    def positions(self, ids: np.ndarray | None = None) -> np.ndarray:
        """(S, 3) float64 local positions of samples (all, or the given ids)."""
        ids = np.arange(self.n_samples) if ids is None else np.asarray(ids)
        k, m = np.divmod(ids, self.per_shell)
        return self.center + self.radii[k][:, None] * self.directions[m]

    def params(self) -> np.ndarray:
        """(9,) float64 packed for the C kernel: cx, cy, cz, ρ_0, ρ_max, log q, K, n, r."""
        s = self.spec
        return np.array([*self.center, self.radii[0], self.radii[-1], self.log_q, s.shells, s.face, self.radius],
                        np.float64)


def lookup_numpy(grid: FieldGrid, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Trilinear interpolation stencil of local points (P, 3).

    Returns (cells (P,) int32 cell index, weights (P, 8) float32 summing to 1 over the cell's
    corners in ``cell_corners`` order, inside (P,) bool: the point is within the outermost
    shell). Points inside the innermost shell take the innermost cells in their direction
    (clamped). Reference of glf_lookup."""
    p = np.asarray(points, np.float64) - grid.center
    rho = np.linalg.norm(p, axis=1)
    K, n = grid.spec.shells, grid.spec.face
    inside = rho <= grid.radii[-1] * (1 + 1e-9)
    s = np.log(np.maximum(rho, 1e-300) / grid.radii[0]) / grid.log_q
    s = np.clip(s, 0.0, K - 1.0)
    k0 = np.minimum(np.floor(s).astype(np.int64), K - 2)
    ts = s - k0
    ax = np.abs(p)
    major = np.argmax(ax, axis=1)
    sign = p[np.arange(len(p)), major] < 0
    face = 2 * major + sign
    fa = FACE_AXES[face]
    am = np.maximum((p * fa[:, 0]).sum(1), 1e-300)
    u = (4 / np.pi) * np.arctan((p * fa[:, 1]).sum(1) / am)
    v = (4 / np.pi) * np.arctan((p * fa[:, 2]).sum(1) / am)
    gu = np.clip((u + 1) * 0.5 * n, 0.0, n)
    gv = np.clip((v + 1) * 0.5 * n, 0.0, n)
    i0 = np.minimum(np.floor(gu).astype(np.int64), n - 1)
    j0 = np.minimum(np.floor(gv).astype(np.int64), n - 1)
    a, b = gu - i0, gv - j0
    w = np.empty((len(p), 8), np.float64)
    c = 0
    for dk in (0, 1):
        wk = ts if dk else 1 - ts
        for di in (0, 1):
            wi = a if di else 1 - a
            for dj in (0, 1):
                w[:, c] = wk * wi * (b if dj else 1 - b)
                c += 1
    cells = ((k0 * 6 + face) * n + i0) * n + j0
    return cells.astype(np.int32), w.astype(np.float32), inside


def cell_corners(grid: FieldGrid, cells: np.ndarray) -> np.ndarray:
    """(C, 8) int32 sample ids of cells' corners, ordered (shell, u, v) = (0,0,0), (0,0,1), … (1,1,1)."""
    n = grid.spec.face
    cells = np.asarray(cells, np.int64)
    j0 = cells % n
    i0 = (cells // n) % n
    face = (cells // (n * n)) % 6
    k0 = cells // (6 * n * n)
    out = np.empty((len(cells), 8), np.int64)
    c = 0
    for dk in (0, 1):
        for di in (0, 1):
            for dj in (0, 1):
                out[:, c] = (k0 + dk) * grid.per_shell + grid.face_table[face, i0 + di, j0 + dj]
                c += 1
    return out.astype(np.int32)
