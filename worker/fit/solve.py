"""Linearly constrained least squares for the SRBF coefficients (inverse-brdf-modeling eq. 17-19).

Per RGB channel c:

    minimise   Σ_i w_i (B_i − ρ_d E(x_i) − Σ_j c_j T_j(x_i))²  +  ε ‖c − c₀‖²
    subject to c_j ≥ 0                                 (eq. 18, non-negativity)
               Σ_j g_j^l c_j ≤ 1 − ρ_d,   l < N_l      (eq. 19, energy conservation)

solved as a QP on the J×J normal equations with DAQP (a dual active-set solver, warm-started
from the previous solution's active set). The small proximal term ε (relative to the mean
diagonal) keeps the Hessian positive definite when some basis functions are seen by no pixel and
pulls their coefficients towards c₀ (the current material's, or zero) instead of leaving them
arbitrary. ``constrained=False`` drops both constraint families (the paper allows physically
impossible designs) and solves the regularised normal equations directly.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import daqp
import numpy as np
import scipy.linalg as sla

from .basis import DEFAULT_NL, SRBFBasis


@dataclass
class FitRows:
    """The rows one view contributes.

    T : (3, N, J) float32 transfer (radiance per unit coefficient, channel-major),
    E : (N, 3) diffuse transfer, target : (N, 3) float64 radiance B, weight : (N,) float64 w_i ≥ 0,
    gram : optional (3, J, J) float64 Σ_i T_iᵀT_i over all N rows (weight-independent, cached
    per view, so a fit only adds the rows whose weight differs from the most common one).
    """
    T: np.ndarray
    E: np.ndarray
    target: np.ndarray
    weight: np.ndarray
    gram: np.ndarray | None = None


@dataclass
class SolveResult:
    coefficients: np.ndarray            # (J, 3) float64
    residual_rms: float                 # radiance, over rows with w > 0 and channels, unweighted
    residual_rel: float                 # residual_rms / RMS of the target
    energy_max: float                   # largest Σ_j g_j^l c_j over rows and channels
    energy_bound: np.ndarray            # (3,) 1 − ρ_d
    seconds: float
    iterations: list = field(default_factory=list)
    constrained: bool = True


def gram(T: np.ndarray) -> np.ndarray:
    """(3, J, J) float64 Σ_i T_i T_iᵀ per channel for T (3, N, J)."""
    return np.stack([T[c].T.astype(np.float64) @ T[c].astype(np.float64) for c in range(3)])


def normal_equations(rows: list[FitRows], rho: np.ndarray):
    """H (3, J, J) and f (3, J) of Σ_i w_i (B_i − ρ_d E_i − T_i c)² = cᵀHc − 2fᵀc + const."""
    J = rows[0].T.shape[2]
    H = np.zeros((3, J, J))
    f = np.zeros((3, J))
    for r in rows:
        resid0 = (r.target - rho * r.E) * r.weight[:, None]             # (N, 3)
        if r.gram is not None:
            # the Gram matrix of all rows, scaled by the most common weight, plus the few rows
            # whose weight differs (the painted ones, or the pixels a target image leaves out)
            vals, counts = np.unique(r.weight, return_counts=True)
            gw = vals[np.argmax(counts)]
            dw = r.weight - gw
            sel = np.nonzero(dw != 0)[0]
            for c in range(3):
                Ts = r.T[c, sel].astype(np.float64)
                H[c] += gw * r.gram[c] + (Ts.T * dw[sel]) @ Ts
        else:
            for c in range(3):
                Tc = r.T[c].astype(np.float64)
                H[c] += (Tc.T * r.weight) @ Tc
        for c in range(3):
            f[c] += resid0[:, c] @ r.T[c]
    return H, f


def _qp(H, f, G, bound, warm, tol, seed_rows=None):
    """min ½xᵀHx − fᵀx, x ≥ 0, G x ≤ bound, by constraint generation: solve with the bounds
    and the energy rows believed active (``seed_rows``, and rows the warm start presses
    against), add every row the solution violates or nearly meets, repeat. Each round is an
    exact DAQP solve; it stops when no row is violated, so the result solves the full QP (rows
    left out are inactive at its optimum). Designs rarely press against energy conservation
    along many directions, so most fits take one or two small solves.
    Returns (x (J,), DAQP iterations, rows used (bool (N_l,)))."""
    J = len(f)
    active = np.zeros(len(G), bool) if seed_rows is None else seed_rows.copy()
    if warm is not None:
        active |= G @ warm >= 0.9 * bound        # rows the previous design pressed against
    iters = 0
    for _ in range(len(G) + 1):
        A = G[active]
        lower = np.concatenate([np.zeros(J), np.full(len(A), -np.inf)])
        upper = np.concatenate([np.full(J, np.inf), np.full(len(A), bound)])
        kw = {"primal_start": warm.copy()} if warm is not None else {}
        x, _, flag, info = daqp.solve(H, -f, A, upper, lower, **kw)
        if flag < 1 and kw:
            x, _, flag, info = daqp.solve(H, -f, A, upper, lower)   # warm starts can stall
        if flag < 1:
            raise RuntimeError(f"QP solver failed (DAQP exit flag {flag})")
        iters += int(info.get("iterations", 0))
        x = np.maximum(x, 0.0)               # bounds hold to solver tolerance; clip the −1e-15s
        lhs = G @ x
        viol = ~active & (lhs > bound + tol)
        if not viol.any():
            return x, iters, active
        active |= lhs > 0.95 * bound
        warm = x


def solve(rows: list[FitRows], basis: SRBFBasis, albedo, constrained: bool = True,
          n_l: int = DEFAULT_NL, prior: np.ndarray | None = None, prox: float = 1e-6,
          warm: np.ndarray | None = None, tol: float = 1e-9) -> SolveResult:
    """Coefficients (J, 3) for the stacked rows of one or more views (footnote 1).

    albedo : (3,) ρ_d in [0, 1]. prior : (J, 3) c₀ (default 0). warm : (J, 3) previous solution.
    tol : allowed energy-row violation (albedo units) of the returned coefficients.
    """
    t0 = time.perf_counter()
    rho = np.asarray(albedo, np.float64)
    J = basis.J
    prior = np.zeros((J, 3)) if prior is None else np.asarray(prior, np.float64)
    G = basis.energy_rows(n_l)
    bound = 1.0 - rho
    if constrained and np.any(bound < 0):
        raise ValueError(f"diffuse albedo {rho.tolist()} exceeds 1: no energy-conserving specular part exists")
    H_all, f_all = normal_equations(rows, rho)
    coef = np.zeros((J, 3))
    iters = []
    seed = None
    # channels share work: the three problems differ only by the light's colour, so each
    # channel starts from the previous channel's solution and active energy rows
    for c in range(3):
        H, f = H_all[c], f_all[c]
        scale = max(np.trace(H) / J, 1e-30)                             # condition the QP
        Hs = H / scale + prox * np.eye(J)
        fs = f / scale + prox * prior[:, c]
        if not constrained:
            coef[:, c] = sla.solve(Hs, fs, assume_a="pos")
            continue
        if warm is not None:
            w = np.asarray(warm, np.float64)[:, c].copy()
        else:
            w = None if c == 0 else coef[:, c - 1].copy()
        coef[:, c], it, rows_used = _qp(Hs, fs, G, bound[c], w, tol, seed)
        seed = rows_used
        iters.append(it)
    seconds = time.perf_counter() - t0
    # report on the rows that count (w > 0), unweighted
    sse, n, tss = 0.0, 0, 0.0
    for r in rows:
        k = r.weight > 0
        pred = rho * r.E[k] + np.stack([r.T[c][k] @ coef[:, c] for c in range(3)], axis=1)
        sse += float(((r.target[k] - pred) ** 2).sum())
        tss += float((r.target[k] ** 2).sum())
        n += pred.size
    rms = np.sqrt(sse / max(n, 1))
    emax = float((G @ coef).max())
    return SolveResult(coef, float(rms), float(rms / max(np.sqrt(tss / max(n, 1)), 1e-30)), emax, bound,
                       seconds, iters, constrained)
