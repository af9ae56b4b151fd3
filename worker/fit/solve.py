"""Linearly constrained least squares for the SRBF coefficients (inverse-brdf-modeling eq. 17-19).

Per RGB channel c:

    minimise   Σ_i w_i (B_i − ρ_d E(x_i) − Σ_j c_j T_j(x_i))²  +  ε ‖c − c₀‖²
    subject to c_j ≥ 0                                 (eq. 18, non-negativity)
               Σ_j g_j^l c_j ≤ 1 − ρ_d,   l < N_l      (eq. 19, energy conservation)

solved as a QP on the J×J normal equations with DAQP (a dual active-set solver) over working
sets of variables and energy rows grown until the full problem's KKT conditions hold (``_qp``).
The proximal term ε (DEFAULT_PROX, relative to the mean diagonal) keeps the Hessian positive
definite when some basis functions are seen by no pixel, pulls their coefficients towards c₀
(the current material's, or zero) instead of leaving them arbitrary, and damps fine-level lobes
that only the sparse fit pixels support. The energy rows hold 1 − ρ_d less the rows' quadrature
margin (``SRBFBasis.row_margin``). ``constrained=False`` drops both constraint families (the paper allows physically
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
    energy: np.ndarray | None = None    # (3,) largest Σ_j g_j^l c_j per channel (against energy_bound)
    albedo: np.ndarray | None = None    # (3,) ρ_d of the solution (fitted when fit_albedo)

    @property
    def at_bound(self) -> np.ndarray:
        """(3,) bool: channels whose specular albedo reached its bound (within the margin)."""
        e = self.energy if self.energy is not None else np.full(3, self.energy_max)
        return e >= self.energy_bound * (1.0 - 0.02) - 1e-12


_POOL = None


def gram(T: np.ndarray) -> np.ndarray:
    """(3, J, J) float64 Σ_i T_i T_iᵀ per channel for T (3, N, J) float32.

    Single-precision products (T is float32 already; sums of N ≤ 10⁴ terms keep ~1e-6 relative
    accuracy, below the solver's 1e-4 proximal term), one channel per thread: BLAS releases the
    GIL and worker processes pin it to one thread each (docs/design/conventions.md, measured facts)."""
    global _POOL
    if _POOL is None:
        from concurrent.futures import ThreadPoolExecutor
        _POOL = ThreadPoolExecutor(max_workers=2, thread_name_prefix="gram")
    Tf = np.ascontiguousarray(T, np.float32)
    out = list(_POOL.map(lambda c: Tf[c].T @ Tf[c], range(3)))
    g = np.stack(out).astype(np.float64)
    return 0.5 * (g + g.transpose(0, 2, 1))


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


ROWS_PER_ROUND = 8
# the proximal (ridge) weight, relative to the mean diagonal of the normal equations. 1e-4, not
# the 1e-6 that only keeps H definite: the fine levels near the normal can otherwise fit a sun's
# reflection at the sparse fit pixels and miss it between them (sofa under stinson-beach, α = 0.1:
# 46% against Mitsuba at 1e-6, 27% at 1e-4; cases without a sun move by ≤ 0.3%)
DEFAULT_PROX = 1e-4


def _qp(H, f, G, bound, warm, tol, seed_rows=None, seed_vars=None, grow: int = 24, ub=None, always=None):
    """min ½xᵀHx − fᵀx, 0 ≤ x ≤ ub (default ∞), G x ≤ bound, by generating both variables and rows.
    ``always`` (bool (J,)) marks variables kept in the working set from the start.

    Most coefficients are zero at the optimum (a design lights few half-vector directions) and
    few energy rows are active, so DAQP solves the QP restricted to a working set of variables
    S and rows R (its cost grows with every bound it has to activate, ~J of them on the full
    problem), and the KKT conditions of the full problem decide what to add: a variable j ∉ S
    enters when its reduced gradient (Hx − f + G_Rᵀλ_R)_j is negative (raising it would lower
    the objective; the ``grow`` most negative enter), a row enters when x violates it. When
    neither happens, x with multipliers λ_R (0 elsewhere) satisfies the full problem's KKT
    conditions: it is the exact optimum (convex QP), not an approximation.
    Returns (x (J,), DAQP iterations, rows used (bool (N_l,)), variables used (bool (J,)))."""
    J = len(f)
    rows = np.zeros(len(G), bool) if seed_rows is None else seed_rows.copy()
    S = np.zeros(J, bool) if seed_vars is None else seed_vars.copy()
    ub = np.full(J, np.inf) if ub is None else np.asarray(ub, np.float64)
    if always is not None:
        S |= always
    if warm is not None:
        rows |= G @ warm >= 0.9 * bound        # rows the previous design pressed against
        S |= warm > 0
    g0 = -f                                      # gradient at x = 0
    S[np.argsort(g0)[:grow]] = True
    x = np.zeros(J)
    iters = 0
    for _ in range(4 * J + len(G) + 2):
        idx = np.nonzero(S)[0]
        A = G[np.ix_(rows, idx)]
        n = len(idx)
        lower = np.concatenate([np.zeros(n), np.full(len(A), -np.inf)])
        upper = np.concatenate([ub[idx], np.full(len(A), bound)])
        Hs, As = np.ascontiguousarray(H[np.ix_(idx, idx)]), np.ascontiguousarray(A)
        xs, _, flag, info = daqp.solve(Hs, -f[idx], As, upper, lower, primal_start=np.ascontiguousarray(x[idx]))
        if flag < 1:                             # warm starts can stall
            xs, _, flag, info = daqp.solve(Hs, -f[idx], As, upper, lower)
        if flag < 1:
            raise RuntimeError(f"QP solver failed (DAQP exit flag {flag})")
        iters += int(info.get("iterations", 0))
        x = np.zeros(J)
        x[idx] = np.clip(xs, 0.0, ub[idx])       # bounds hold to solver tolerance; clip the −1e-15s
        lam = np.asarray(info["lam"])[n:]        # row multipliers (≥ 0 at their upper bound)
        lhs = G @ x
        viol = ~rows & (lhs > bound + tol)
        r = H @ x - f + G[rows].T @ lam
        scale = max(np.abs(f).max(), 1e-300)
        enter = ~S & (r < -1e-9 * scale)
        if not viol.any() and not enter.any():
            return x, iters, rows, S
        if viol.any():
            # the most violated rows only: neighbouring rows are nearly parallel (the albedo is
            # smooth in ωo), so one active row usually stands for a whole region
            cand = np.nonzero(viol)[0]
            rows[cand[np.argsort(-lhs[cand])[:ROWS_PER_ROUND]]] = True
        if enter.any():
            cand = np.nonzero(enter)[0]
            S[cand[np.argsort(r[cand])[:grow]]] = True
    raise RuntimeError("QP working sets did not converge")


def solve(rows: list[FitRows], basis: SRBFBasis, albedo, constrained: bool = True,
          n_l: int = DEFAULT_NL, prior: np.ndarray | None = None, prox: float = DEFAULT_PROX,
          warm: np.ndarray | None = None, tol: float = 1e-9, fit_albedo: bool = False,
          neutral: bool = False) -> SolveResult:
    """Coefficients (J, 3) for the stacked rows of one or more views (footnote 1).

    albedo : (3,) ρ_d in [0, 1]. prior : (J, 3) c₀ (default 0). warm : (J, 3) previous solution.
    tol : allowed energy-row violation (albedo units) of the returned coefficients.
    fit_albedo : also solve for ρ_d per channel (the paper has the designer give it, §3.1): E is
        one more column of the transfer matrix, 0 ≤ ρ_d ≤ 1, the energy rows become
        Σ_j g_j^l c_j + ρ_d ≤ 1 (eq. 14 itself), and the proximal term keeps ρ_d near ``albedo``
        where the strokes do not decide it. This is what makes a darkening or a colour change of a
        matte object possible: the specular part can only add light.
    neutral : one set of coefficients for the three channels (a white specular part, as a
        dielectric's; ``_solve_neutral``): the squared errors of all channels summed, the diffuse
        albedo still per channel. For strokes that ask for no colour (white or grey paint,
        scaling): fitted per channel, a white highlight under a coloured sky took lobes of
        different shapes per channel and tinted the rest of the object (pink and cyan bands).
    """
    if neutral:
        return _solve_neutral(rows, basis, albedo, constrained, n_l, prior, prox, warm, tol, fit_albedo)
    t0 = time.perf_counter()
    rho, J, prior, G, keep = _problem(basis, albedo, prior, n_l, constrained)
    if fit_albedo:
        H_all, f_all = _augmented_normal_equations(rows)
        G = np.concatenate([G, np.full((len(G), 1), 1.0)], axis=1)     # Σ g c + ρ_d ≤ 1
        prior = np.concatenate([prior, rho[None, :]], axis=0)
        n_var, ub = J + 1, np.concatenate([np.full(J, np.inf), [1.0]])
        always = np.zeros(J + 1, bool)
        always[J] = True
    else:
        H_all, f_all = normal_equations(rows, rho)
        n_var, ub, always = J, None, None
    coef = np.zeros((n_var, 3))
    iters = []
    seed, seed_vars = None, None
    # channels share work: the three problems differ only by the light's colour, so each
    # channel starts from the previous channel's solution, variables and active energy rows
    for c in range(3):
        H, f = H_all[c], f_all[c]
        scale = max(np.trace(H) / n_var, 1e-30)                         # condition the QP
        Hs = H / scale + prox * np.eye(n_var)
        fs = f / scale + prox * prior[:, c]
        if not constrained:
            coef[:, c] = sla.solve(Hs, fs, assume_a="pos")
            continue
        w = None
        if warm is not None and np.shape(warm)[0] == n_var:
            w = np.asarray(warm, np.float64)[:, c].copy()
        elif c > 0:
            w = coef[:, c - 1].copy()
        bound = keep if fit_albedo else (1.0 - rho[c]) * keep
        coef[:, c], it, seed, seed_vars = _qp(Hs, fs, G, bound, w, tol, seed, seed_vars, ub=ub, always=always)
        iters.append(it)
    if fit_albedo:
        rho = np.clip(coef[J], 0.0, 1.0)
        coef, G = coef[:J], G[:, :J]
    return _solve_result(rows, coef, rho, G, time.perf_counter() - t0, iters, constrained)


def _problem(basis, albedo, prior, n_l: int, constrained: bool):
    """What both solves start from: (ρ (3,), J, prior (J, 3), energy rows G (R, J), keep: the
    share of each energy bound the rows may use)."""
    rho = np.asarray(albedo, np.float64)
    J = basis.J
    prior = np.zeros((J, 3)) if prior is None else np.asarray(prior, np.float64)
    if constrained and np.any(rho > 1):
        raise ValueError(f"diffuse albedo {rho.tolist()} exceeds 1: no energy-conserving specular part exists")
    # the rows are a quadrature: a margin for its error keeps the albedo within its bound by an
    # independent quadrature too (basis.SRBFBasis.row_margin)
    return rho, J, prior, basis.energy_rows(n_l), 1.0 - basis.row_margin


def _solve_result(rows: list[FitRows], coef: np.ndarray, rho: np.ndarray, G: np.ndarray, seconds: float, iters,
                  constrained: bool) -> SolveResult:
    """SolveResult of coefficients coef (J, 3) and albedo rho (3,): the residual reported on the
    rows that count (w > 0), unweighted, and the energy rows G (R, J) at the solution."""
    sse, n, tss = 0.0, 0, 0.0
    for r in rows:
        k = r.weight > 0
        pred = rho * r.E[k] + np.stack([r.T[c][k] @ coef[:, c] for c in range(3)], axis=1)
        sse += float(((r.target[k] - pred) ** 2).sum())
        tss += float((r.target[k] ** 2).sum())
        n += pred.size
    rms = np.sqrt(sse / max(n, 1))
    energy = (G @ coef).max(axis=0)
    return SolveResult(coef, float(rms), float(rms / max(np.sqrt(tss / max(n, 1)), 1e-30)), float(energy.max()),
                       1.0 - rho, seconds, iters, constrained, energy, rho)


def _solve_neutral(rows, basis, albedo, constrained, n_l, prior, prox, warm, tol, fit_albedo) -> SolveResult:
    """``solve`` with one coefficient vector c (J,) for the three channels: minimise
    Σ_ch Σ_i w_i (B_i,ch − ρ_ch E_i,ch − T_i,ch c)² (+ ε‖c − c₀‖², c₀ the prior's channel mean)
    subject to c ≥ 0 and Σ_j g_j^l c_j ≤ 1 − ρ_ch for every channel (eq. 18-19); with
    fit_albedo the unknowns are [c, ρ_R, ρ_G, ρ_B] and the rows Σ_j g_j^l c_j + ρ_ch ≤ 1."""
    t0 = time.perf_counter()
    rho, J, prior, G, keep = _problem(basis, albedo, prior, n_l, constrained)
    if fit_albedo:
        Ha, fa = _augmented_normal_equations(rows)
        n_var = J + 3
        H, f = np.zeros((n_var, n_var)), np.zeros(n_var)
        for c in range(3):
            H[:J, :J] += Ha[c, :J, :J]
            H[:J, J + c] = H[J + c, :J] = Ha[c, :J, J]
            H[J + c, J + c] = Ha[c, J, J]
            f[:J] += fa[c, :J]
            f[J + c] = fa[c, J]
        Gx = np.zeros((3 * len(G), n_var))
        for c in range(3):
            Gx[c * len(G):(c + 1) * len(G), :J] = G
            Gx[c * len(G):(c + 1) * len(G), J + c] = 1.0
        bound = keep
        pri = np.concatenate([prior.mean(axis=1), rho])
        ub = np.concatenate([np.full(J, np.inf), np.ones(3)])
        always = np.zeros(n_var, bool)
        always[J:] = True
    else:
        Hc, fc = normal_equations(rows, rho)
        H, f, n_var, Gx = Hc.sum(axis=0), fc.sum(axis=0), J, G
        bound = (1.0 - float(rho.max())) * keep            # the tightest channel's bound
        pri, ub, always = prior.mean(axis=1), None, None
    scale = max(np.trace(H) / n_var, 1e-30)
    Hs = H / scale + prox * np.eye(n_var)
    fs = f / scale + prox * pri
    iters = []
    if not constrained:
        x = sla.solve(Hs, fs, assume_a="pos")
    else:
        w = None
        if warm is not None and np.shape(warm)[0] == J:
            w = np.asarray(warm, np.float64).mean(axis=1)
            w = np.concatenate([w, rho]) if fit_albedo else w
        x, it, _, _ = _qp(Hs, fs, Gx, bound, w, tol, ub=ub, always=always)
        iters.append(it)
    if fit_albedo:
        rho = np.clip(x[J:], 0.0, 1.0)
    coef = np.repeat(x[:J, None], 3, axis=1)
    return _solve_result(rows, coef, rho, G, time.perf_counter() - t0, iters, constrained)


def _augmented_normal_equations(rows: list[FitRows]):
    """H (3, J+1, J+1), f (3, J+1) of Σ_i w_i (B_i − [T_i, E_i]·[c; ρ_d])²: E is the last column."""
    J = rows[0].T.shape[2]
    H0, f0 = normal_equations(rows, np.zeros(3))
    H = np.zeros((3, J + 1, J + 1))
    f = np.zeros((3, J + 1))
    H[:, :J, :J], f[:, :J] = H0, f0
    for r in rows:
        for c in range(3):
            e = r.E[:, c].astype(np.float64) * r.weight
            H[c, :J, J] += e @ r.T[c]
            H[c, J, J] += e @ r.E[:, c]
            f[c, J] += e @ r.target[:, c]
    H[:, J, :J] = H[:, :J, J]
    return H, f


@dataclass
class BlockSolveResult:
    """A stacked fit of several materials (``solve_blocks``): coefficients (k, J, 3), albedo
    (k, 3) ρ_d, energy (k, 3) each block's largest specular albedo per channel, against
    energy_bound (k, 3) = 1 − ρ_d."""
    coefficients: np.ndarray
    albedo: np.ndarray
    energy: np.ndarray
    energy_bound: np.ndarray
    seconds: float
    constrained: bool = True
    iterations: list = field(default_factory=list)
    residual_rms: float = 0.0           # radiance, over rows with w > 0 and channels, unweighted
    residual_rel: float = 0.0           # residual_rms / RMS of the target

    @property
    def energy_max(self) -> float:
        return float(self.energy.max())

    @property
    def at_bound(self) -> np.ndarray:
        """(3,) bool: channels whose specular albedo reached its bound in any block."""
        return np.any(self.energy + self.albedo >= (1.0 - 0.02) - 1e-12, axis=0)


def solve_blocks(A: np.ndarray, target: np.ndarray, weight: np.ndarray, basis: SRBFBasis, blocks: int,
                 albedo_prior: np.ndarray, constrained: bool = True, n_l: int = DEFAULT_NL,
                 prox: float = DEFAULT_PROX, tol: float = 1e-9) -> BlockSolveResult:
    """Several materials' SRBF coefficients and diffuse albedos in one least squares: the
    unknowns of ``blocks`` materials stacked (each J coefficients then ρ_d), the rows
    A (3, N, blocks·(J+1)) float32 holding each material's transfer rows times its weight at the
    pixel (inverse-brdf-modeling eq. 21 with the weights of painted regions), target (N, 3),
    weight (N,). Constraints per block as ``solve`` with ``fit_albedo``: c ≥ 0, 0 ≤ ρ_d ≤ 1 and
    Σ_j g_j^l c_j + ρ_d ≤ 1 (eq. 14, 18-19): the energy rows are block diagonal. The proximal
    term pulls unseen coefficients to 0 and ρ_d to albedo_prior (blocks, 3)."""
    t0 = time.perf_counter()
    J = basis.J
    nb = J + 1
    n = blocks * nb
    if A.shape[2] != n:
        raise ValueError(f"rows have {A.shape[2]} columns for {blocks} blocks of {nb}")
    G1 = np.concatenate([basis.energy_rows(n_l), np.ones((len(basis.energy_rows(n_l)), 1))], axis=1)
    G = sla.block_diag(*([G1] * blocks))
    keep = 1.0 - basis.row_margin
    prior = np.zeros((n, 3))
    prior[J::nb] = np.asarray(albedo_prior, np.float64)
    ub = np.tile(np.concatenate([np.full(J, np.inf), [1.0]]), blocks)
    always = np.zeros(n, bool)
    always[J::nb] = True
    x = np.zeros((n, 3))
    iters = []
    seed = seed_vars = None
    w = np.asarray(weight, np.float64)
    for c in range(3):
        Ac = A[c].astype(np.float64)
        H = (Ac.T * w) @ Ac
        f = (Ac.T * w) @ np.asarray(target[:, c], np.float64)
        scale = max(np.trace(H) / n, 1e-30)
        Hs = H / scale + prox * np.eye(n)
        fs = f / scale + prox * prior[:, c]
        if not constrained:
            x[:, c] = sla.solve(Hs, fs, assume_a="pos")
            continue
        warm = x[:, c - 1].copy() if c > 0 else None
        x[:, c], it, seed, seed_vars = _qp(Hs, fs, G, keep, warm, tol, seed, seed_vars, ub=ub, always=always)
        iters.append(it)
    xb = x.reshape(blocks, nb, 3)
    coef, rho = xb[:, :J], np.clip(xb[:, J], 0.0, 1.0)
    Gs = basis.energy_rows(n_l)
    energy = np.stack([(Gs @ coef[b]).max(axis=0) for b in range(blocks)])
    xs = np.concatenate([coef, rho[:, None]], axis=1).reshape(n, 3)
    k = w > 0
    pred = np.stack([A[c][k].astype(np.float64) @ xs[:, c] for c in range(3)], 1)
    t = np.asarray(target, np.float64)[k]
    rms = float(np.sqrt(((t - pred) ** 2).mean())) if k.any() else 0.0
    rel = rms / max(float(np.sqrt((t ** 2).mean())) if k.any() else 0.0, 1e-30)
    return BlockSolveResult(coef, rho, energy, 1.0 - rho, time.perf_counter() - t0, constrained, iters, rms, rel)
