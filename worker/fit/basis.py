"""The SRBF basis of the specular distribution p(h) and its energy rows
(inverse-brdf-modeling §3.2, eq. 11-16).

p(h) = Σ_j c_j G_j(h), G_j(h) = exp(λ_j(h·ξ_j − 1)) (eq. 12), h in the local frame of the
surface (z = normal, tangent frame of ``brdf.onb``), times a static function s(ωi, ωo)
(``brdf.distribution_static``): the paper's F/(cosθi + cosθo − cosθi cosθo) (eq. 11) or the
microfacet form F·G1(ωi)G1(ωo)/(4 cosθi cosθo) with Smith-GGX shadowing (``smith``).

The paper's basis is one level: 147 centres over the hemisphere with σ = π/40 (4.5°, ~12°
apart). A GGX lobe of α = 0.1 has half its peak 3.7° from the normal, narrower than one of these
SRBFs (7.5°), and a sum of non-negative SRBFs is never narrower than its narrowest member. The
default basis adds finer levels in cones around the normal, where an isotropic surface's highlight
lives (microfacet normals cluster around the macro normal): each level halves σ and keeps the
coarse level's spacing-to-σ ratio (``multiscale_centers``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.optimize import brentq

from ..core.brdf import distribution_static

DEFAULT_J = 147                 # the paper's 3×7×7 hemicube pixel count (coarse level)
DEFAULT_SIGMA = np.pi / 40      # the paper's σ (coarse level)
DEFAULT_NL = 192                # the paper's N_l
# finer levels around the normal: (σ as a fraction of the coarse σ, cone half-angle in degrees)
# (chosen from the recovery matrix, BENCHMARKS.md "Paint to BRDF: recovery")
DEFAULT_FINE = ((0.5, 16.0), (0.25, 7.0), (0.125, 3.5))
DEFAULT_STATIC = "smith"
DEFAULT_STATIC_ALPHA = 0.3
# G below this is treated as zero in the transfer functions (C kernel and NumPy reference,
# identically): the dropped tail of an SRBF holds e^−XCUT of its integral (in u = 1 − h·ξ the
# mass is e^−λu du), so predictions fall short of renders by at most that fraction. The energy rows
# and checks integrate the whole SRBF: energy conservation holds for the material as rendered.
G_CUTOFF = 1e-4
XCUT = -np.log(G_CUTOFF)        # λ(1 − h·ξ) beyond which G is zero in the transfer
ROW_TMAX = 36.0                 # λ(1 − h·ξ) covered by the energy rows: e^−36 ≈ 2e-16


def hemisphere_centers(j: int) -> np.ndarray:
    """(J, 3) float64 well-spread unit vectors over the upper hemisphere (z > 0): a spherical
    Fibonacci set, equal-area in z. The paper uses a 3×7×7 hemicube's pixel directions; any
    well-spread set serves, and this one exists for every J."""
    return cap_centers(j, np.pi / 2)


def cap_centers(j: int, theta_max: float) -> np.ndarray:
    """(J, 3) float64 spherical Fibonacci points over the cap θ ≤ theta_max around +z
    (equal-area in z)."""
    i = np.arange(j) + 0.5
    z = 1.0 - i / j * (1.0 - np.cos(theta_max))
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


def multiscale_centers(j: int = DEFAULT_J, sigma: float = DEFAULT_SIGMA, fine=DEFAULT_FINE):
    """Centres (J, 3) and bandwidths λ (J,) of a multi-scale basis: ``j`` centres over the
    hemisphere with σ, then per (factor, cone_deg) of ``fine`` a level of σ·factor over the cap of
    that half-angle, as many centres as keep the coarse level's spacing-to-σ ratio."""
    cen = [hemisphere_centers(j)]
    lam = [np.full(j, bandwidth_from_sigma(sigma))]
    spacing = np.sqrt(2.0 * np.pi / j)                   # mean spacing of the coarse level (rad)
    for factor, cone in fine:
        s = sigma * factor
        cap = 2.0 * np.pi * (1.0 - np.cos(np.radians(cone)))
        n = max(1, round(cap / (spacing * factor) ** 2))
        cen.append(cap_centers(n, np.radians(cone)))
        lam.append(np.full(n, bandwidth_from_sigma(s)))
    return np.concatenate(cen), np.concatenate(lam)


@dataclass(eq=False)
class SRBFBasis:
    """A fixed SRBF basis and static function.

    centers : (J, 3) float64 unit vectors in the local frame (upper hemisphere).
    bandwidth : λ, one for every centre, or (J,) per centre (multi-scale); afterwards
        ``bandwidths`` is always (J,) and ``bandwidth`` the coarsest (smallest) λ.
    fresnel_f0 : Schlick F0 of the static function.
    static, static_alpha : the static function (``brdf.distribution_static``).
    """
    centers: np.ndarray
    bandwidth: float | np.ndarray
    fresnel_f0: float = 1.0
    static: str = "paper"
    static_alpha: float = DEFAULT_STATIC_ALPHA
    _rows: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        c = np.asarray(self.centers, np.float64)
        self.centers = c / np.linalg.norm(c, axis=1, keepdims=True)
        if np.any(self.centers[:, 2] < -1e-9):
            raise ValueError("SRBF centres must lie in the upper hemisphere (z ≥ 0)")
        self.bandwidths = np.broadcast_to(np.asarray(self.bandwidth, np.float64), (len(c),)).copy()
        if np.any(self.bandwidths <= 0):
            raise ValueError("SRBF bandwidths must be positive")
        self.bandwidth = float(self.bandwidths.min())
        if self.static not in ("paper", "smith"):
            raise ValueError(f"unknown static function {self.static!r} (paper or smith)")

    @property
    def J(self) -> int:
        return len(self.centers)

    @property
    def uniform(self) -> bool:
        return bool(np.all(self.bandwidths == self.bandwidths[0]))

    @property
    def cutoff_cos(self) -> np.ndarray:
        """(J,) h·ξ_j below which G_j < G_CUTOFF."""
        return 1.0 - XCUT / self.bandwidths

    @property
    def row_margin(self) -> float:
        """Relative margin the solver keeps below the energy bound for the rows' quadrature error:
        the smith static's integrand is continuous but steep near the horizon for small α (up to
        1.4e-3 of the largest row at α = 0.05 against a 3× finer quadrature; a fit measured 1.1e-3
        over by the independent check with a 1e-3 margin); the paper's jumps from 1 to 0 at the
        horizon as θo → 90° (cosθi/(cosθi + cosθo − …) → 1), which leaves up to ~0.5%."""
        return 3e-3 if self.static == "smith" else 1e-2

    def key(self) -> tuple:
        return (self.centers.tobytes(), self.bandwidths.tobytes(), float(self.fresnel_f0), self.static,
                float(self.static_alpha) if self.static == "smith" else 0.0)

    def static_fn(self, cos_i, cos_o, cos_d):
        return distribution_static(cos_i, cos_o, cos_d, self.fresnel_f0, self.static, self.static_alpha)

    def refinement(self) -> list[tuple[float, float]]:
        """Cluster refinement for the transfer functions of any combination of the basis: one
        (refine radius, extent) pair per level (distinct λ), as ``brdf.srbf_refinement`` for
        that level's centres: a cluster is split when any pair asks for it."""
        from ..core.brdf import srbf_refinement

        out = []
        for lam in np.unique(self.bandwidths):
            sel = self.bandwidths == lam
            r = srbf_refinement(self.centers[sel], lam)
            out.append((r["refine_radius"], r["extent"]))
        return out

    def kernel_tables(self):
        """Lookup structures of the C transfer kernel (cached):

        cell_off (6·C²+1,) int32 and cell_idx (M,) int32: for each cube-map cell of half-vector
        space (``cube_cell``), the centres whose G can exceed the cutoff somewhere in the cell;
        cell_cand (M, 4) float32: those centres' (ξ, λ), in the same order;
        gtab (G_TABLE,) float32: exp(−x) sampled uniformly over x = λ(1 − h·ξ) ∈ [0, XCUT]
        (linear interpolation error < 1e-5 relative, tested against exp).
        """
        if "kernel" not in self._rows:
            self._rows["kernel"] = _kernel_tables(self.centers, self.bandwidths, self.cutoff_cos)
        return self._rows["kernel"]

    def G(self, h_local: np.ndarray) -> np.ndarray:
        """(…, J) basis values at local unit half vectors (…, 3), zero below the cutoff."""
        d = h_local @ self.centers.T
        g = np.exp(self.bandwidths * (d - 1.0))
        return np.where(d >= self.cutoff_cos, g, 0.0)

    def energy_rows(self, n_l: int = DEFAULT_NL) -> np.ndarray:
        """g_j^l (N_l, J) float64 (eq. 15) at the outgoing directions ``outgoing_directions(n_l)``,
        so that Σ_j g_j^l c_j is the specular directional albedo ∫ f_s cosθi dωi at ω_o^l.

        Eq. 15 as printed omits the cosine of eq. 13; energy conservation (eq. 10) needs it, so
        it is included. Quadrature over half vectors around each centre (``_energy_rows``)."""
        if n_l not in self._rows:
            key = (self.key(), n_l)
            if key not in _ROWS_CACHE:
                if len(_ROWS_CACHE) > 16:
                    _ROWS_CACHE.clear()
                _ROWS_CACHE[key] = energy_rows_at(self, outgoing_directions(n_l))
            self._rows[n_l] = _ROWS_CACHE[key]
        return self._rows[n_l]

    def to_material(self, coefficients: np.ndarray, albedo) -> dict:
        """The scene-file ``srbf`` material (docs/design/conventions.md, scene file) for coefficients (J, 3). Fields beyond
        the paper's model (per-centre bandwidths, the static function) are written only when they
        differ from it, so a paper-model fit writes the same file as before they existed."""
        m = {"model": "srbf", "centers": self.centers.round(9).tolist(), "bandwidth": self.bandwidth,
             "coefficients": np.asarray(coefficients, np.float64).tolist(),
             "fresnel_f0": self.fresnel_f0, "albedo": [float(a) for a in albedo]}
        if not self.uniform:
            m["bandwidths"] = self.bandwidths.tolist()
        if self.static != "paper":
            m["static"] = self.static
            m["static_alpha"] = float(self.static_alpha)
        return m

    def matches(self, material) -> bool:
        """Whether an ``srbf`` material is a combination of this basis (same centres, λ, static)."""
        return (len(material.centers) == self.J
                and np.allclose(np.asarray(material.lambdas()), self.bandwidths, rtol=1e-9)
                and np.allclose(np.asarray(material.centers), self.centers, atol=1e-6)
                and material.static == self.static
                and (self.static == "paper" or abs(material.static_alpha - self.static_alpha) < 1e-12))


def default_basis(j: int = DEFAULT_J, sigma: float = DEFAULT_SIGMA, fresnel_f0: float = 1.0,
                  static: str = DEFAULT_STATIC, static_alpha: float = DEFAULT_STATIC_ALPHA,
                  fine=DEFAULT_FINE) -> SRBFBasis:
    """The fitting basis: ``j`` centres of σ over the hemisphere plus the ``fine`` levels
    (``multiscale_centers``), with the given static function."""
    c, lam = multiscale_centers(j, sigma, fine)
    return SRBFBasis(c, lam, fresnel_f0, static, static_alpha)


def paper_basis(j: int = DEFAULT_J, sigma: float = DEFAULT_SIGMA, fresnel_f0: float = 1.0) -> SRBFBasis:
    """inverse-brdf-modeling's basis as published: one level, the static function of eq. 11."""
    return default_basis(j, sigma, fresnel_f0, "paper", fine=())


# rings of energy rows near the horizon (degrees from the normal, azimuths per ring): the
# specular albedo of a microfacet static rises steeply over the last few degrees (1/(cosθo + Λ)
# grows until cosθo ≈ α) and peaks at the horizon itself, between the Fibonacci rows
HORIZON_RINGS = ((84.0, 48), (87.0, 48), (89.0, 48), (90.0, 48))


def _rings(rings) -> np.ndarray:
    out = [np.zeros((0, 3))]
    for deg, n in rings:
        t = np.radians(deg)
        ph = (np.arange(n) + 0.5) * (2.0 * np.pi / n)
        out.append(np.stack([np.sin(t) * np.cos(ph), np.sin(t) * np.sin(ph), np.full(n, np.cos(t))], 1))
    return np.concatenate(out)


def outgoing_directions(n_l: int = DEFAULT_NL, rings=HORIZON_RINGS) -> np.ndarray:
    """(N_l + ring directions, 3) local outgoing directions ω_o^l of eq. 16: a spherical
    Fibonacci set of n_l over the upper hemisphere (the paper's N_l = 192, from the normal down to
    0.15° above the horizon), then ``rings`` near and at the horizon (θo = 90°: the albedo there
    is the limit of a continuous function, and the largest for a microfacet static)."""
    return np.concatenate([hemisphere_centers(n_l), _rings(rings)])


CUBE_CELLS = 32     # cube-map cells per face edge for the kernel's candidate lists
G_TABLE = 4096


def cube_cell(d: np.ndarray) -> np.ndarray:
    """Cube-map cell (…,) int of directions d (…, 3): face·C² + iu·C + iv, faces +x −x +y −y +z −z,
    (u, v) the other two coordinates over the major one, as glk_fit_transfer computes it."""
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
    reach = np.arccos(np.clip(cutoff_cos, -1.0, 1.0))                 # (J,)
    ok = ang <= reach[None, :] + rad[:, None] + 1e-6
    cell_off = np.concatenate([[0], np.cumsum(ok.sum(1))]).astype(np.int32)
    cell_idx = np.nonzero(ok)[1].astype(np.int32)
    x = np.linspace(0.0, XCUT, G_TABLE)
    gtab = np.exp(-x).astype(np.float32)
    # the listed centres packed per cell as (ξx, ξy, ξz, λ) float32: the kernel reads them in order
    cell_cand = np.ascontiguousarray(np.concatenate([centers[cell_idx], lam[cell_idx, None]], 1), np.float32)
    return cell_off, cell_idx, cell_cand, gtab


_ROWS_CACHE: dict = {}   # energy rows are a pure function of the basis: shared between sessions

# quadrature of one SRBF: Gauss-Legendre nodes in t = λ(1 − h·ξ) (weight e^−t), uniform in φ
ROW_NT, ROW_NPHI = 32, 64


@lru_cache(maxsize=4)
def polar_nodes(nt: int, nphi: int):
    """Nodes t/tcut on [0, 1] and weights for ∫_0^tcut e^−t K dt = tcut Σ w e^{−t} K: nt
    Gauss-Legendre nodes on the core [0, 12/36] of the range (all but 6e-6 of the mass) and
    nt/3 on the tail; and the nphi azimuths."""
    x, w = np.polynomial.legendre.leggauss(nt)
    xt, wt = np.polynomial.legendre.leggauss(max(4, nt // 3))
    a = 12.0 / ROW_TMAX
    tn = np.concatenate([0.5 * (x + 1.0) * a, a + 0.5 * (xt + 1.0) * (1.0 - a)])
    tw = np.concatenate([0.5 * w * a, 0.5 * wt * (1.0 - a)])
    return tn, tw, (np.arange(nphi) + 0.5) * (2.0 * np.pi / nphi)


def energy_rows_at(basis: SRBFBasis, wo: np.ndarray, nt: int = ROW_NT, nphi: int = ROW_NPHI,
                   kernels=None) -> np.ndarray:
    """g_j(ωo) (K, J) float64 (``energy_rows_numpy``, its NumPy reference); kernels: the backend
    (worker/native/kernels.py: the C kernel glk_energy_rows in native/src/fit.c when built)."""
    from ..native.kernels import kernels as _kernels

    return (kernels or _kernels()).energy_rows(basis, wo, nt, nphi)


def energy_rows_numpy(basis: SRBFBasis, wo: np.ndarray, nt: int = ROW_NT, nphi: int = ROW_NPHI) -> np.ndarray:
    """g_j(ωo) (K, J) float64: the specular directional albedo of each basis function at local
    outgoing directions wo (K, 3), eq. 15 with eq. 13's cosine:

        g_j(ωo) = ∫ G_j(h) s(ωi, ωo) cosθi dωi = ∫ G_j(h) s cosθi 4(ωo·h) dωh,  ωi = reflect(ωo, h),

    integrated around each centre in polar coordinates: u = 1 − h·ξ_j, dωh = du dφ, so
    ∫ e^{−λu} K(u) du = (1/λ) ∫_0^{ROW_TMAX} e^{−t} K(t/λ) dt by Gauss-Legendre in t (nt nodes)
    and the trapezoid rule in φ (nphi, spectrally accurate for a periodic integrand). Every
    basis function gets the same relative resolution, whatever its width."""
    wo = np.atleast_2d(np.asarray(wo, np.float64))
    tn, tw, ph = polar_nodes(nt, nphi)
    out = np.zeros((len(wo), basis.J))
    co = wo[:, 2:3]
    for lam in np.unique(basis.bandwidths):
        idx = np.nonzero(basis.bandwidths == lam)[0]
        tcut = min(ROW_TMAX, 2.0 * lam)              # u ≤ 2 on the sphere
        t = tn * tcut
        wt = tw * tcut * np.exp(-t) / lam * (2.0 * np.pi / nphi)     # (nt,)
        u = t / lam
        cz, sz = 1.0 - u, np.sqrt(np.maximum(u * (2.0 - u), 0.0))
        loc = np.stack([np.outer(sz, np.cos(ph)), np.outer(sz, np.sin(ph)), np.outer(cz, np.ones_like(ph))], -1)
        loc = loc.reshape(-1, 3)                                        # (n, 3) around +z
        w = np.repeat(wt, nphi)                                         # (n,)
        for s in range(0, len(idx), 8):
            jj = idx[s:s + 8]
            xi = basis.centers[jj]                                      # (b, 3)
            e1, e2 = _perp(xi)
            h = (loc[None, :, 0:1] * e1[:, None] + loc[None, :, 1:2] * e2[:, None]
                 + loc[None, :, 2:3] * xi[:, None])                     # (b, n, 3)
            od = np.einsum("kc,bnc->kbn", wo, h)                        # (K, b, n) ωo·h
            ci = 2.0 * od * h[None, :, :, 2] - co[:, :, None]
            ok = (od > 0) & (ci > 0)
            cic = np.where(ok, ci, 0.0)
            sv = basis.static_fn(cic, np.broadcast_to(co[:, :, None], ci.shape), od)
            out[:, jj] = np.where(ok, sv * cic * 4.0 * od, 0.0) @ w
    return out


def _perp(xi):
    """Two unit vectors (b, 3) each, completing the unit vectors xi (b, 3) to orthonormal frames."""
    a = np.where(np.abs(xi[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(a, xi)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(xi, e1)


def directional_albedo(basis: SRBFBasis, coefficients: np.ndarray, wo_local: np.ndarray,
                       n_near: int = 300, n_far: int = 200, n_phi: int = 240) -> np.ndarray:
    """Specular directional albedo ∫ f_s cosθi dωi (K, 3) of p = Σ c_j G_j at local outgoing
    directions (K, 3), by a quadrature over ωi independent of the energy rows': the midpoint rule
    on a polar grid whose pole is the mirror direction, with n_near rings within 40° of it
    (0.13° apart: the narrowest default SRBF is 1.6° wide in h, 3° in ωi) and n_far rings
    beyond, n_phi azimuths. Directions below the horizon contribute nothing."""
    th = np.concatenate([(np.arange(n_near) + 0.5) * (np.radians(40.0) / n_near),
                         np.radians(40.0) + (np.arange(n_far) + 0.5) * (np.radians(140.0) / n_far)])
    dth = np.concatenate([np.full(n_near, np.radians(40.0) / n_near), np.full(n_far, np.radians(140.0) / n_far)])
    ph = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    T, P = np.meshgrid(th, ph, indexing="ij")
    dw = (np.sin(T) * dth[:, None] * (2.0 * np.pi / n_phi)).reshape(-1)
    loc = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    coefficients = np.asarray(coefficients, np.float64)
    out = []
    for wo in np.atleast_2d(np.asarray(wo_local, np.float64)):
        r = np.array([-wo[0], -wo[1], wo[2]])                          # mirror direction
        e1, e2 = _perp(r[None])
        wi = loc[:, 0:1] * e1 + loc[:, 1:2] * e2 + loc[:, 2:3] * r
        keep = wi[:, 2] > 0
        wi, w = wi[keep], dw[keep]
        hv = wi + wo
        h = hv / np.linalg.norm(hv, axis=1, keepdims=True)
        s = basis.static_fn(wi[:, 2], np.full(len(wi), wo[2]), (wi * h).sum(1))
        acc = np.zeros(3)
        for a in range(0, len(h), 65536):
            d = h[a:a + 65536] @ basis.centers.T
            g = np.exp(basis.bandwidths * (d - 1.0))            # the whole SRBF, as rendered
            acc += (g @ coefficients).T @ (s[a:a + 65536] * wi[a:a + 65536, 2] * w[a:a + 65536])
        out.append(acc)
    return np.array(out)


def check_directions(n: int = 2048) -> np.ndarray:
    """(K, 3) outgoing directions for energy checks: a spherical Fibonacci set of n over the
    hemisphere plus rings of 64 at 80°, 85°, 88°, 89.5°, 89.9° and 90° from the normal, where
    the static function changes fastest (none coincides with an energy row)."""
    return np.concatenate([hemisphere_centers(n), _rings([(d, 64) for d in (80.0, 85.0, 88.0, 89.5, 89.9, 90.0)])
                           @ _rot_z(np.pi / 64)])


def _rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def energy_maximum(basis: SRBFBasis, coefficients: np.ndarray, n_check: int = 2) -> np.ndarray:
    """The largest specular directional albedo per channel (3,) of p = Σ c_j G_j, by the
    independent quadrature (``directional_albedo``) at the n_check directions per channel
    where the energy-row quadrature over ``check_directions()`` (2,432 directions) finds the
    largest values."""
    if "check" not in basis._rows:
        basis._rows["check"] = energy_rows_at(basis, check_directions())
    coefficients = np.asarray(coefficients, np.float64)
    dense = basis._rows["check"] @ coefficients                          # (K, 3)
    pick = np.unique(np.argsort(-dense, axis=0)[:n_check].reshape(-1))
    return directional_albedo(basis, coefficients, check_directions()[pick]).max(axis=0)


def static_alpha_for(material) -> float:
    """The shadowing roughness of the smith static for fits that start from ``material``: a
    GGX's own α (its Smith G is then exact), an smith srbf's static_alpha, else the default."""
    from ..models import GGX, SRBF, Regions

    if isinstance(material, Regions):            # what the strokes paint over is mostly the base
        material = material.base
    if isinstance(material, GGX):
        return float(np.clip(material.alpha, 0.02, 1.0))
    if isinstance(material, SRBF) and material.static == "smith":
        return float(material.static_alpha)
    return DEFAULT_STATIC_ALPHA


def equivalent_roughness(basis: SRBFBasis, coefficients: np.ndarray) -> float:
    """The GGX α whose distribution best matches the fitted p(h) (luminance of (J, 3)
    coefficients), averaged over φh: the α of min Σ_θ sinθ (p̄(θ) − k·D_α(θ))² over a log grid
    from 0.02 to 1, with the best scale k for each α. Smith shadowing is a property of the
    distribution, so this is the roughness the smith static should use for this p."""
    from ..core.brdf import ggx_D, srbf_p

    th = np.radians(np.linspace(0.0, 85.0, 171))
    ph = np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    h = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    lum = np.asarray(coefficients, np.float64) @ np.array([0.2126, 0.7152, 0.0722])
    p = srbf_p(h, basis.centers, basis.bandwidths, lum[:, None])[..., 0].mean(axis=1)
    if not np.any(p > 0):
        return DEFAULT_STATIC_ALPHA
    w = np.sin(th) + 1e-3
    best, err = DEFAULT_STATIC_ALPHA, np.inf
    for a in np.exp(np.linspace(np.log(0.02), 0.0, 97)):
        d = ggx_D(np.cos(th), a)
        k = (w * d * p).sum() / max((w * d * d).sum(), 1e-300)
        e = (w * (p - k * d) ** 2).sum()
        if e < err:
            best, err = float(a), e
    return best
