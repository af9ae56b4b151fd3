"""The SRBF basis of the specular distribution p(h) and its energy rows
(inverse-brdf-modeling §3.2, eq. 11-16).

p(h) = Σ_j c_j G(h·ξ_j, λ), G(x, λ) = exp(λ(x − 1)) (eq. 12), h in the local frame of the
surface (z = normal, tangent frame of ``brdf.onb``). The static function is
s(ωi, ωo) = F(ωi·h) / (cosθi + cosθo − cosθi cosθo) with Schlick's F (eq. 11).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.optimize import brentq

from ..core.brdf import distribution_static, srbf_refinement
from ..core.directions import get_tree

DEFAULT_J = 147                 # the paper's 3×7×7 hemicube pixel count
DEFAULT_SIGMA = np.pi / 40      # the paper's σ
DEFAULT_NL = 192                # the paper's N_l
# G below this is treated as zero (in the transfer kernels and here, identically): it bounds
# the dropped part of any basis function to 1e-5 of its peak.
G_CUTOFF = 1e-5


def hemisphere_centers(j: int) -> np.ndarray:
    """(J, 3) float64 well-spread unit vectors over the upper hemisphere (z > 0): a spherical
    Fibonacci set, equal-area in z. The paper uses a 3×7×7 hemicube's pixel directions; any
    well-spread set serves (issue 3), and this one exists for every J."""
    i = np.arange(j) + 0.5
    z = 1.0 - i / j
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = i * (np.pi * (3.0 - np.sqrt(5.0)))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def bandwidth_from_sigma(sigma: float) -> float:
    """λ from the paper's relation σ² = 1 − (coth(2λ) − 1/(2λ)) (§5, after Narcowich and Ward
    1996). The paper prints 'cosh'; coth is the one that makes sense: it is E[1 − h·ξ] under the
    density |G|² ∝ exp(2λ(h·ξ − 1)) on the sphere (Narcowich-Ward's variance of G), so σ is the
    angular spread of G² (≈ 1/√(2λ)), tested against quadrature."""
    if not 0.0 < sigma < 1.0:
        raise ValueError(f"sigma must be in (0, 1) radians-ish for a useful SRBF, got {sigma}")
    target = sigma * sigma

    def f(lam):
        x = 2.0 * lam
        coth = 1.0 / np.tanh(x)
        return 1.0 - (coth - 1.0 / x) - target
    # 1 − (coth 2λ − 1/(2λ)) falls from 2/3 (λ → 0) to 1/(2λ) (λ → ∞)
    return float(brentq(f, 1e-6, 1e7, xtol=1e-10, rtol=1e-12))


@dataclass(eq=False)
class SRBFBasis:
    """A fixed SRBF basis.

    centers : (J, 3) float64 unit vectors in the local frame (upper hemisphere).
    bandwidth : λ (dimensionless).
    fresnel_f0 : Schlick F0 of the static function.
    """
    centers: np.ndarray
    bandwidth: float
    fresnel_f0: float = 1.0
    _rows: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        c = np.asarray(self.centers, np.float64)
        self.centers = c / np.linalg.norm(c, axis=1, keepdims=True)
        if np.any(self.centers[:, 2] < -1e-9):
            raise ValueError("SRBF centres must lie in the upper hemisphere (z ≥ 0)")

    @property
    def J(self) -> int:
        return len(self.centers)

    @property
    def cutoff_cos(self) -> float:
        """h·ξ below which G < G_CUTOFF."""
        return 1.0 + np.log(G_CUTOFF) / self.bandwidth

    def refinement(self) -> dict:
        """Cluster refinement for shading any combination of the basis (brdf.srbf_refinement)."""
        return srbf_refinement(self.centers, self.bandwidth)

    def kernel_tables(self):
        """Lookup structures of the C transfer kernel (cached):

        cell_off (6·C²+1,) int32 and cell_idx (…,) int32: for each cube-map cell of half-vector
        space (``cube_cell``), the centres whose G can exceed the cutoff somewhere in the cell;
        gtab (G_TABLE,) float32: G sampled uniformly in h·ξ over [cutoff_cos, 1] (linear
        interpolation error < 1e-6 relative at the default λ, measured in tests against exp).
        """
        if "kernel" not in self._rows:
            self._rows["kernel"] = _kernel_tables(self.centers, self.bandwidth, self.cutoff_cos)
        return self._rows["kernel"]

    def G(self, h_local: np.ndarray) -> np.ndarray:
        """(…, J) basis values at local unit half vectors (…, 3), zero below the cutoff."""
        d = h_local @ self.centers.T
        g = np.exp(self.bandwidth * (d - 1.0))
        return np.where(d >= self.cutoff_cos, g, 0.0)

    def energy_rows(self, n_l: int = DEFAULT_NL) -> np.ndarray:
        """g_j^l (N_l, J) float64 (eq. 15) at the outgoing directions ``outgoing_directions(n_l)``,
        so that Σ_j g_j^l c_j is the specular directional albedo ∫ f_s cosθi dωi at ω_o^l.

        Eq. 15 as printed omits the cosine of eq. 13; energy conservation (eq. 10) needs it, so
        it is included. Quadrature over half vectors (dωi = 4 (ωo·h) dωh) on the 2^15 near-uniform
        directions of the cut tree: ~0.02 rad spacing against the SRBF's ≥ 0.05 rad width."""
        if n_l not in self._rows:
            key = (self.centers.tobytes(), self.bandwidth, self.fresnel_f0, n_l)
            if key not in _ROWS_CACHE:
                if len(_ROWS_CACHE) > 16:
                    _ROWS_CACHE.clear()
                _ROWS_CACHE[key] = _energy_rows(self.centers, self.bandwidth, self.fresnel_f0, n_l)
            self._rows[n_l] = _ROWS_CACHE[key]
        return self._rows[n_l]

    def to_material(self, coefficients: np.ndarray, albedo) -> dict:
        """The scene-file ``srbf`` material (DESIGN.md §3) for coefficients (J, 3)."""
        return {"model": "srbf", "centers": self.centers.round(9).tolist(), "bandwidth": self.bandwidth,
                "coefficients": np.asarray(coefficients, np.float64).tolist(),
                "fresnel_f0": self.fresnel_f0, "albedo": [float(a) for a in albedo]}


def default_basis(j: int = DEFAULT_J, sigma: float = DEFAULT_SIGMA, fresnel_f0: float = 1.0) -> SRBFBasis:
    return SRBFBasis(hemisphere_centers(j), bandwidth_from_sigma(sigma), fresnel_f0)


def outgoing_directions(n_l: int = DEFAULT_NL) -> np.ndarray:
    """(N_l, 3) local outgoing directions ω_o^l of eq. 16: a spherical Fibonacci set over the
    upper hemisphere, from the normal down to 0.15° above the horizon (grazing angles, where
    Fresnel raises the albedo, are covered)."""
    return hemisphere_centers(n_l)


CUBE_CELLS = 16     # cube-map cells per face edge for the kernel's candidate lists
G_TABLE = 4096


def cube_cell(d: np.ndarray) -> np.ndarray:
    """Cube-map cell (…,) int of directions d (…, 3): face·C² + iu·C + iv, faces +x −x +y −y +z −z,
    (u, v) the other two coordinates over the major one, as glk_transfer computes it."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    ax, ay, az = np.abs(x), np.abs(y), np.abs(z)
    zf = (az >= ax) & (az >= ay)
    xf = ~zf & (ax >= ay)
    face = np.where(zf, np.where(z > 0, 4, 5), np.where(xf, np.where(x > 0, 0, 1), np.where(y > 0, 2, 3)))
    major = np.where(zf, az, np.where(xf, ax, ay))
    u = np.where(zf, x, np.where(xf, y, x)) / major
    v = np.where(zf, y, z) / major
    iu = np.clip(((u + 1.0) * (CUBE_CELLS / 2)).astype(np.int64), 0, CUBE_CELLS - 1)
    iv = np.clip(((v + 1.0) * (CUBE_CELLS / 2)).astype(np.int64), 0, CUBE_CELLS - 1)
    return face * CUBE_CELLS * CUBE_CELLS + iu * CUBE_CELLS + iv


def _cell_geometry():
    """Per cube cell: centre direction (6C², 3) and angular radius (max angle to its corners;
    a gnomonic cell is a convex spherical quadrilateral, so no point is farther than a corner)."""
    C = CUBE_CELLS
    edges = np.linspace(-1.0, 1.0, C + 1)
    mids = 0.5 * (edges[:-1] + edges[1:])

    def to_dir(face, u, v):
        one = np.ones_like(u)
        s = 1.0 if face % 2 == 0 else -1.0
        if face < 2:
            d = np.stack([s * one, u, v], -1)
        elif face < 4:
            d = np.stack([u, s * one, v], -1)
        else:
            d = np.stack([u, v, s * one], -1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    cen, rad = [], []
    for face in range(6):
        U, V = np.meshgrid(mids, mids, indexing="ij")
        c = to_dir(face, U, V).reshape(-1, 3)
        r = np.zeros(len(c))
        for du in (0, 1):
            for dv in (0, 1):
                Uc, Vc = np.meshgrid(edges[du:C + du], edges[dv:C + dv], indexing="ij")
                k = to_dir(face, Uc, Vc).reshape(-1, 3)
                r = np.maximum(r, np.arccos(np.clip((c * k).sum(1), -1.0, 1.0)))
        cen.append(c); rad.append(r)
    return np.concatenate(cen), np.concatenate(rad)


def _kernel_tables(centers, lam, cutoff_cos):
    cen, rad = _cell_geometry()
    ang = np.arccos(np.clip(cen @ centers.T, -1.0, 1.0))              # (cells, J)
    reach = np.arccos(np.clip(cutoff_cos, -1.0, 1.0))
    ok = ang <= reach + rad[:, None] + 1e-6
    cell_off = np.concatenate([[0], np.cumsum(ok.sum(1))]).astype(np.int32)
    cell_idx = np.nonzero(ok)[1].astype(np.int32)
    d = np.linspace(cutoff_cos, 1.0, G_TABLE)
    gtab = np.exp(lam * (d - 1.0)).astype(np.float32)
    return cell_off, cell_idx, gtab


_ROWS_CACHE: dict = {}   # energy rows are a pure function of the basis: shared between sessions


@lru_cache(maxsize=1)
def _quadrature_halfvectors():
    """Upper-hemisphere quadrature nodes (M, 3) and equal weights dω (sr) from the cut tree."""
    leaves = get_tree().leaves.astype(np.float64)
    leaves /= np.linalg.norm(leaves, axis=1, keepdims=True)
    return leaves[leaves[:, 2] > 0], 4.0 * np.pi / len(leaves)


def _energy_rows(centers, lam, f0, n_l):
    h, dw = _quadrature_halfvectors()
    wo = outgoing_directions(n_l)
    gm = np.exp(lam * (h @ centers.T - 1.0))
    gm[h @ centers.T < 1.0 + np.log(G_CUTOFF) / lam] = 0.0           # (M, J)
    od = wo @ h.T                                                    # (N_l, M) ωo·h
    wi_z = 2.0 * od * h[None, :, 2] - wo[:, 2:3]                     # cosθi of ωi = reflect(ωo, h)
    ok = (od > 0) & (wi_z > 0)
    co = np.broadcast_to(wo[:, 2:3], od.shape)
    s = distribution_static(np.where(ok, wi_z, 0.0), co, od, f0)     # F(ωi·h)/(…); ωi·h = ωo·h
    w = np.where(ok, s * wi_z * 4.0 * od * dw, 0.0)
    return w @ gm


def directional_albedo(basis: SRBFBasis, coefficients: np.ndarray, wo_local: np.ndarray,
                       n_samples: int = 400) -> np.ndarray:
    """Specular directional albedo ∫ f_s cosθi dωi (…, 3) of p = Σ c_j G_j at local outgoing
    directions (K, 3), by an independent quadrature over ωi on a θ-φ grid (for tests)."""
    th = (np.arange(n_samples) + 0.5) * (np.pi / 2) / n_samples
    ph = (np.arange(2 * n_samples) + 0.5) * np.pi / n_samples
    T, P = np.meshgrid(th, ph, indexing="ij")
    wi = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    dw = (np.sin(T) * (np.pi / 2 / n_samples) * (np.pi / n_samples)).reshape(-1)
    out = []
    for wo in np.atleast_2d(wo_local):
        hv = wi + wo
        h = hv / np.linalg.norm(hv, axis=1, keepdims=True)
        cd = (wi * h).sum(1)
        s = distribution_static(wi[:, 2], wo[2], cd, basis.fresnel_f0)
        p = np.exp(basis.bandwidth * (h @ basis.centers.T - 1.0)) @ coefficients
        out.append(((p * (s * wi[:, 2] * dw)[:, None])).sum(0))
    return np.array(out)
