"""Strokes under global illumination: the GI frame at a few pixels as a function of the edited
object's SRBF coefficients, and its linearisation for the stroke fitter (worker/fit/fitter.py).

While unit i is edited (every other unit frozen, freeze.py), a pixel's radiance is polynomial in
i's coefficients on the GI basis (polynomial-gi eq. 28-29):

    B(p) = Σ_{k,n} ĉ_k d^n U_{k,n}(p),   U_{k,n}(p) = V_{k,n}(p) + Σ_s c_s(θo(p)) F_{s,k,n}(p)

with c_s the first-vertex coefficients (interpolated between view-angle nodes), d the diffuse
equivalent and ĉ_k the second-vertex coefficients (ĉ_0 = 1). Each of c, d and ĉ is a linear
function of the SRBF coefficients and the diffuse albedo of an ``srbf`` material
(inverse-brdf-modeling eq. 11-12; ``srbf_map`` projects every basis lobe with basis.py's own
projection), so B is a polynomial of degree ≤ N in them. ``Sampled.linearise`` gives its
first-order expansion at a material:

    B(c, ρ) ≈ ρ E + T c + R

the form of the direct-light transfer (inverse-brdf-modeling eq. 21) plus an offset R, which
the fitter solves with its constrained least squares (c ≥ 0, energy bound) and re-linearises at
the solution (Gauss-Newton). Everything here is dense linear algebra on the few thousand fit
pixels (BLAS matrix products and bincount scatters, no per-pixel Python loop): a stroke's cost
is the solver's, not this module's.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .basis import _iso_basis, project_measure

_MAPS: dict = {}
_MAPS_KEPT = 8


@dataclass
class SRBFMap:
    """The GI-basis coefficients of an srbf material as a linear map of x = [c_1 … c_J, ρ_d]
    (one channel; Jc = J + 1 columns, the last one the diffuse albedo).

    first : (3, THETA_NODES, K1, Jc) float64 first-vertex table per channel (the channels
        differ only through the Fresnel layer's split, ``ok``).
    d : (Jc,) diffuse equivalent. second : (1 + J2·J2_NODES, Jc) or None (J2 series)."""
    first: np.ndarray
    d: np.ndarray
    second: np.ndarray | None


def _lobe_measure(basis, J: int, qkind: int) -> np.ndarray:
    """Erho (THETA_NODES, Q, Jb + 1) = w·G_j(h)·s(ωi, ωo) of every basis lobe on the
    projection's quadrature pairs (basis._iso_basis), the measure project() integrates, per
    lobe; the last column (the diffuse albedo's) is zero. One view-angle node at a time, in
    place (6.7M exponentials for the default basis at J = 64)."""
    wi, wo, w, *_ = _iso_basis(J, qkind)
    hv = wi + wo
    h = hv / np.linalg.norm(hv, axis=-1, keepdims=True)
    ci, co = np.clip(wi[..., 2], 0.0, None), np.clip(wo[..., 2], 0.0, None)
    s = basis.static_fn(ci, co, np.clip((wi * h).sum(-1), 0.0, 1.0))
    ws = np.where((wi[..., 2] > 0) & (wo[..., 2] > 0), w * s, 0.0)
    Jb = basis.J
    out = np.zeros(w.shape + (Jb + 1,))
    for k in range(w.shape[0]):
        g = h[k] @ basis.centers.T                                      # srbf_p's sum, lobe by lobe
        g -= 1.0
        g *= basis.bandwidths
        np.exp(g, out=g)
        g *= ws[k][:, None]
        out[k, :, :Jb] = g
    return out


def srbf_map(basis, J: int, layers: int, J2: int, qkind: int, ok: np.ndarray | None = None) -> SRBFMap:
    """The linear map of SRBFMap for an SRBFBasis (worker/fit/basis.py) on the GI basis of
    (J, layers, J2, qkind); ``ok`` (THETA_NODES, J, 3) bool: the Fresnel layer's split of the
    material linearised around (Projection.ok), needed when layers == 2. Cached by content."""
    okb = None if ok is None or layers == 1 else np.ascontiguousarray(ok, bool)
    key = (basis.key(), J, layers, J2, qkind, None if okb is None else okb.tobytes())
    hit = _MAPS.get(key)
    if hit is not None:
        return hit
    mkey = ("measure", basis.key(), J)
    Erho = _MAPS.get(mkey)
    if Erho is None:
        Erho = _lobe_measure(basis, J, qkind)      # the albedo column has no specular part
    Erho = _keep(mkey, Erho)
    Jb = Erho.shape[-1] - 1
    alb = np.zeros(Jb + 1)
    alb[-1] = 1.0
    if layers == 2:
        if okb is None:
            raise ValueError("srbf_map with the Fresnel layer needs the split (ok) of the material")
        per_c = [project_measure(Erho, alb, J, layers, J2, qkind, ok=okb[..., c:c + 1]) for c in range(3)]
        first = np.stack([p[0] for p in per_c])
        d, second = per_c[0][1], per_c[0][2]
    else:
        f, d, second, _ = project_measure(Erho, alb, J, layers, J2, qkind)
        first = np.broadcast_to(f, (3,) + f.shape)
    return _keep(key, SRBFMap(first, d, second))


def _keep(key, value):
    """Cache ``value`` under ``key`` (the latest _MAPS_KEPT entries: a few bases per process)."""
    _MAPS.pop(key, None)
    while len(_MAPS) >= _MAPS_KEPT:
        _MAPS.pop(next(iter(_MAPS)))
    _MAPS[key] = value
    return value


def extend_map(first: np.ndarray, ext: list[np.ndarray]) -> np.ndarray:
    """(3, Kθ, K1, Jc) first-vertex map -> (3, Kθ, K1 + ΣR, Jc) with the denoised tensors' hat
    coefficients (denoise.extend_coefficients, whose maps ``ext`` [(Kθ, R, K1)] are linear)."""
    if not ext:
        return first
    if first.strides[0] == 0:             # one map for the three channels (no Fresnel split)
        f = first[0]
        one = np.concatenate([f, *[np.einsum("krs,ksj->krj", m, f) for m in ext]], axis=1)
        return np.broadcast_to(one, (3,) + one.shape)
    return np.concatenate([first, *[np.einsum("krs,cksj->ckrj", m, first) for m in ext]], axis=2)


@dataclass
class Coefficients:
    """One material's GI coefficients for unit i: C1 (Kθ, K1, 3) first-vertex table (extended
    with hat components when denoised), d (3,), ck (K2, 3) second-vertex factors (ck[0] = 1)."""
    C1: np.ndarray
    d: np.ndarray
    ck: np.ndarray


class Sampled:
    """The frozen tensors of unit i (freeze.Frozen) at N sample pixels, ready to evaluate B and
    its linearisation at any material of unit i.

    V (N, K2, NP, 3) float64 the frozen part; entries of F^i scaled by the pixel's scale and
    weight h: row (n,) int64 sample, slot, kk, pw (n,) int64, val (n, 3) float64; k0 (N,)
    int64, t (N,) float64 the view-angle interpolation."""

    def __init__(self, fz, pu, hit: np.ndarray, h_all: np.ndarray, K1: int):
        self.N = len(hit)
        self.K1, self.K2, self.NP = K1, fz.K2, fz.NP
        self.V = fz.V[hit].astype(np.float64)
        self.k0 = pu.k0[hit].astype(np.int64)
        self.t = pu.t[hit].astype(np.float64)
        pos = np.searchsorted(fz.live, hit)
        pos = np.minimum(pos, max(len(fz.live) - 1, 0))
        on = (len(fz.live) > 0) & (fz.live[pos] == hit) if len(fz.live) else np.zeros(self.N, bool)
        rows, q = np.nonzero(on)[0], pos[on]
        w = (h_all[hit[rows]] * fz.scale[q]).astype(np.float64)
        if fz.dense is not None:
            F = fz.dense_full(q, K1)                                                 # (nq, NPe, 3, K1)
            r, n, s = np.nonzero(np.any(F != 0, axis=2))
            self.row = rows[r].astype(np.int64)
            self.slot, self.kk, self.pw = s.astype(np.int64), np.zeros(len(r), np.int64), n.astype(np.int64)
            self.val = F[r, n, :, s] * w[r, None]
        else:
            cnt = fz.offsets[q + 1] - fz.offsets[q]
            # every entry of the sampled live pixels: each pixel's range, concatenated
            idx = np.repeat(fz.offsets[q] - (np.cumsum(cnt) - cnt), cnt) + np.arange(int(cnt.sum()))
            r = np.repeat(np.arange(len(q)), cnt)
            key = fz.entries[idx, 0].astype(np.int64)
            s, rest = np.divmod(key, fz.K2 * fz.NP)
            self.kk, self.pw = np.divmod(rest, fz.NP)
            self.slot = s
            self.row = rows[r].astype(np.int64)
            self.val = fz.entries[idx, 1:].copy().view(np.float16).astype(np.float64) * w[r, None]

        # per entry: its first-vertex cell at the pixel's lower view-angle node, and the weight
        # of the upper node (gathers of every evaluation)
        self._cell0 = None
        self._et = self.t[self.row][:, None]
        # a unit that no tail holds (a painted region drawn at the camera hits: every live entry
        # and the frozen part at power 0 of its d, one second-vertex factor): B is linear in its
        # first-vertex coefficients, B = V + Σ_s c_s F_s, and ``linearise`` skips the terms of d
        self.linear = bool(self.K2 == 1 and (len(self.pw) == 0 or int(self.pw.max()) == 0)
                           and not np.any(self.V[:, :, 1:]))

    # --- evaluation ------------------------------------------------------------------------------

    def _slot_coeffs(self, C1: np.ndarray) -> np.ndarray:
        """(n, 3) first-vertex coefficient of every entry at its pixel's view angle."""
        K1 = C1.shape[1]
        if self._cell0 is None or self._cell0[0] != K1:
            self._cell0 = (K1, self.k0[self.row] * K1 + self.slot)
        flat = C1.reshape(-1, 3)
        c0 = self._cell0[1]
        lo, hi = flat[c0], flat[c0 + K1]
        hi -= lo
        hi *= self._et
        hi += lo
        return hi

    def _U(self, co: Coefficients) -> np.ndarray:
        """U (N, K2, NP, 3) = V + Σ_s c_s F_s (module docstring)."""
        U = self.V.copy()
        if len(self.row):
            v = self.val * self._slot_coeffs(co.C1.astype(np.float64))
            cell = (self.row * self.K2 + self.kk) * self.NP + self.pw
            flat = U.reshape(-1, 3)
            for c in range(3):
                flat[:, c] += np.bincount(cell, weights=v[:, c], minlength=flat.shape[0])
        return U

    def _powers(self, co: Coefficients):
        d = np.asarray(co.d, np.float64)
        n = np.arange(self.NP)[:, None]
        dp = d[None, :] ** n                                                  # (NP, 3) d^n
        ndp = np.where(n > 0, n * d[None, :] ** np.maximum(n - 1, 0), 0.0)     # (NP, 3) n d^(n−1)
        return dp, ndp

    def radiance(self, co: Coefficients) -> np.ndarray:
        """(N, 3) float64 B at the samples (eq. 28-29, as freeze.frame_numpy)."""
        dp, _ = self._powers(co)
        ck = np.asarray(co.ck, np.float64)
        return np.einsum("pknc,kc,nc->pc", self._U(co), ck, dp)

    def linearise(self, co: Coefficients, m: SRBFMap, ext_first: np.ndarray):
        """First-order expansion of B around the material whose coefficients are ``co``:
        (T (3, N, Jb) float32, E (N, 3) float32, R (N, 3) float64, B0 (N, 3) float64) with
        B ≈ ρE + Tc + R near it; ext_first (3, Kθ, K1, Jc) the (extended) first-vertex map."""
        N, K1 = self.N, ext_first.shape[2]
        Jc = ext_first.shape[3]
        dp, ndp = self._powers(co)
        ck = np.asarray(co.ck, np.float64)
        if not self.linear:
            U = self._U(co)
            B0 = np.einsum("pknc,kc,nc->pc", U, ck, dp)
        # ∂B/∂c_s(node): M (N, K1, 3) = Σ_{k,n} ĉ_k d^n F_{s,k,n}, split between the two nodes
        M = np.zeros((N * K1, 3))
        if len(self.row):
            wv = self.val * ck[self.kk] * dp[self.pw]
            cell = self.row * K1 + self.slot
            for c in range(3):
                M[:, c] = np.bincount(cell, weights=wv[:, c], minlength=N * K1)
        M = M.reshape(N, K1, 3)
        if self.linear:
            # B = R + Σ_s c_s M_s exactly: R the frozen part, no d or ĉ terms
            R = self.V[:, 0, 0, :].copy()
            C1 = co.C1.astype(np.float64)
            C1r = C1[self.k0] * (1.0 - self.t)[:, None, None] + C1[self.k0 + 1] * self.t[:, None, None]
            B0 = R + (M * C1r).sum(1)
        else:
            dd = np.einsum("pknc,kc,nc->pc", U, ck, ndp)                       # ∂B/∂d
            dck = np.einsum("pknc,nc->pkc", U, dp)                             # ∂B/∂ĉ_k
        Tx = np.zeros((3, N, Jc), np.float32)
        # single precision products (T is float32 for the solver anyway); one product for the
        # three channels when their map is the same (no Fresnel split)
        X = ext_first.astype(np.float32)
        same = ext_first.strides[0] == 0
        M32 = M.astype(np.float32)
        for k in np.unique(self.k0):
            sel = np.nonzero(self.k0 == k)[0]
            t = self.t[sel, None, None].astype(np.float32)
            lo, hi = (1.0 - t) * M32[sel], t * M32[sel]                        # (n, K1, 3)
            if same:
                n = len(sel)
                lo2 = lo.transpose(2, 0, 1).reshape(3 * n, K1)
                hi2 = hi.transpose(2, 0, 1).reshape(3 * n, K1)
                Tx[:, sel] = (lo2 @ X[0, k] + hi2 @ X[0, k + 1]).reshape(3, n, Jc)
            else:
                for c in range(3):
                    Tx[c, sel] = lo[:, :, c] @ X[c, k] + hi[:, :, c] @ X[c, k + 1]
        if self.linear:
            return np.ascontiguousarray(Tx[:, :, :-1]), Tx[:, :, -1].T.copy(), R, B0
        for c in range(3):
            Tx[c] += dd[:, c, None] * m.d[None, :]
            if m.second is not None and self.K2 > 1:
                Tx[c] += dck[:, 1:, c] @ m.second
        # J·g0: the Jacobian applied to the material's own coefficients
        first = self._first_part(co)
        jg0 = first + dd * np.asarray(co.d)[None, :] + (dck[:, 1:] * ck[None, 1:]).sum(1)
        R = B0 - jg0
        return np.ascontiguousarray(Tx[:, :, :-1]), Tx[:, :, -1].T.copy(), R, B0

    def _first_part(self, co: Coefficients) -> np.ndarray:
        """(N, 3) Σ_s c_s ∂B/∂c_s: the part of B linear in the first-vertex coefficients."""
        out = np.zeros((self.N, 3))
        if len(self.row):
            dp, _ = self._powers(co)
            ck = np.asarray(co.ck, np.float64)
            v = self.val * self._slot_coeffs(co.C1.astype(np.float64)) * ck[self.kk] * dp[self.pw]
            for c in range(3):
                out[:, c] = np.bincount(self.row, weights=v[:, c], minlength=self.N)
        return out
