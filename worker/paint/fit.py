"""Real-time fit of cosine-lobe weights to paint measurements (cacad-cosine-lobes §4).

The BRDF is Glint's ``lobes`` model (scene.Lobes, cacad eq. 1-3 in reciprocal form):
    f = albedo/π + Σ_i (g_i + dd_i) (E_i+2)/(2π) max(0, r·ωo)^E_i
with fixed exponents E_i, achromatic gloss weights g_i and RGB directional-diffuse weights dd_i.
Every measurement of ``geometry`` is linear in the weights, so a measurement set is A x ≈ b with
x = [albedo (3), dd (M×3, lobe-major), g (M)] ≥ 0 (eq. 5-6). As the paper prescribes, the fit
minimises the absolute error by linear programming (negative weights are not allowed, and
least squares followed by clamping accumulates error):

    min Σ_r s_r |A_r x − b_r| + λ·e·x    subject to x ≥ 0

solved as an LP in equality form (A x − u + v = b, u, v ≥ 0) with HiGHS's dual simplex. The
rows are relative: s_r = 1/(|b_r| + floor). Two light priors make an under-determined fit
(a handful of readings, 4M + 3 weights) pick what a paint designer means:
  * the clearcoat's reflectance: Σ g_i ≥ CLEARCOAT_ALBEDO (a dielectric of index 1.5 reflects
    4% at normal incidence), a one-sided row weighted PRIOR_WEIGHT ≪ 1, so a low gloss reading
    spreads the clearcoat (less of it falls in the 1.8° receptor) rather than dimming it, and a
    high one is met by the achromatic gloss lobes, not by a sharp coloured lobe;
  * the least lobe energy, λ = ENERGY_WEIGHT per unit of luminance albedo, which among exact fits
    takes for each reading the lobe that explains it with the least energy. A gloss weight costs
    a little less than its luminance on the sharp lobes (E ≥ SHARP_E, the clearcoat's) and a
    little more on the wide ones, so the gloss reading is met by the achromatic clearcoat and
    not by a sharp lobe of the cheapest colour, while grey flake readings stay in the
    directional diffuse.
Both are far lighter than a measurement row, so readings that a lobes material can produce are
reproduced exactly (the round trip of tests/paint).

A fixed basis cannot reproduce every lobes material exactly: the readings of one cosine lobe,
E ↦ ((E+2)/2·cos^E a_k)_k, form a Chebyshev system in E, so every lobe is an extreme ray of the
cone of lobes and lies outside the cone of any finite set of other exponents. The pure L1 fit
then puts the whole shortfall on one reading (the LP's optimum is a vertex: 18% on one reading
for a lone E = 63 lobe on a 16-lobe basis). The objective therefore also charges the largest
relative residual, MAX_WEIGHT·max_r s_r|A_r x − b_r| (one more LP variable t with s_r u_r ≤ t and
s_r v_r ≤ t), which spreads an unavoidable shortfall over the readings that can absorb it. The
weight is chosen on the generated tuning paints (basis.py). The per-reading relative residuals
are returned with the fit, and readings off by more than TOLERANCE are named (``unmet``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.optimize import linprog

from ..scene import Lobes
from .geometry import (LUMA, MeasurementError, angle_key, aspecular_directions, gloss_units,
                       parse_measurements)

CLEARCOAT_ALBEDO = 0.04
PRIOR_WEIGHT = 0.05
ENERGY_WEIGHT = 1e-3
SHARP_E = 500.0               # lobes narrower than ~2.5°: the clearcoat's
GLOSS_DISCOUNT = (0.97, 1.1)  # gloss weight cost / its luminance, on sharp and on wide lobes
ASPECULAR_FLOOR = 0.01        # reflectance-factor floor of the relative rows (a black paint's 110°)
GLOSS_FLOOR = 1.0             # GU
ITERATION_LIMIT = 5000        # warm solves take tens of iterations; beyond this, solve afresh
MAX_WEIGHT = 1000.0           # weight of the largest relative residual: chosen in basis.py on the tuning paints
                              # (the objective kept falling up to this, the largest weight tried)
TOLERANCE = 0.03              # a reading off by more than this (relative) is reported as unmet


def lobe_response(exponents, cos_angle) -> np.ndarray:
    """Reflectance factor π·(E+2)/(2π)·max(0, c)^E of unit-weight lobes: (…, M) for cosines (…)."""
    e = np.asarray(exponents, np.float64)
    c = np.maximum(np.asarray(cos_angle, np.float64), 0.0)[..., None]
    return 0.5 * (e + 2.0) * c ** e


@lru_cache(maxsize=256)
def _unit_gloss(exponent: float | None) -> float:
    """D523 gloss (GU) of a unit-weight lobe (or of albedo 1 when exponent is None)."""
    if exponent is None:
        return gloss_units(Lobes(exponents=[1.0], gloss=[0.0], directional_diffuse=[(0, 0, 0)], albedo=(1, 1, 1)))
    return gloss_units(Lobes(exponents=[exponent], gloss=[1.0], directional_diffuse=[(0, 0, 0)], albedo=(0, 0, 0)))


@lru_cache(maxsize=64)
def measurement_matrix(exponents: tuple[float, ...], angles: tuple[float, ...]) -> np.ndarray:
    """(1 + 3K, 3 + 4M) matrix of the measurements' response to each weight.

    Row 0 is the gloss (GU), rows 1 + 3k + c the reflectance factor of channel c at aspecular
    angle k. Columns: albedo (3), dd (lobe-major, 3 per lobe), gloss weights (M)."""
    m, k = len(exponents), len(angles)
    a = np.zeros((1 + 3 * k, 3 + 4 * m))
    # in the plane of incidence, r·ωo = cos(aspecular angle): the cosine lobes are exact there
    resp = lobe_response(exponents, np.cos(np.radians(angles)))            # (K, M)
    g_alb = _unit_gloss(None)
    g_lobe = np.array([_unit_gloss(float(e)) for e in exponents])
    for c in range(3):
        a[0, c] = g_alb * LUMA[c]
        a[0, 3 + c: 3 + 3 * m: 3] = g_lobe * LUMA[c]
        rows = 1 + 3 * np.arange(k) + c
        a[rows, c] = 1.0
        a[rows[:, None], 3 + 3 * np.arange(m)[None, :] + c] = resp
        a[rows, 3 + 3 * m:] = resp
    a[0, 3 + 3 * m:] = g_lobe
    return a


def solve_l1(a: np.ndarray, b: np.ndarray, scale: np.ndarray, cost: np.ndarray | None = None,
             time_limit: float | None = None, scale_under: np.ndarray | None = None,
             cap: np.ndarray | None = None, max_weight: float = 0.0) -> np.ndarray:
    """min Σ_r (scale_r·max(0, A_r x − b_r) + scale_under_r·max(0, b_r − A_r x)) + cost·x
    + max_weight·max_r cap_r·|A_r x − b_r| over x ≥ 0 (scale_under defaults to scale: the
    weighted absolute error; cap, default scale, is 0 on rows left out of the max), by HiGHS
    (dual simplex) through scipy.optimize.linprog. Returns x (n,)."""
    m, n = a.shape
    su = scale if scale_under is None else scale_under
    c = np.concatenate([np.zeros(n) if cost is None else cost, scale, su])
    a_eq = np.hstack([a, -np.eye(m), np.eye(m)])
    a_ub = b_ub = None
    if max_weight > 0:
        cap = scale if cap is None else cap
        rows = np.nonzero(cap > 0)[0]
        k = len(rows)
        a_ub = np.zeros((2 * k, n + 2 * m + 1))
        a_ub[np.arange(k), n + rows] = cap[rows]              # cap_r u_r ≤ t
        a_ub[k + np.arange(k), n + m + rows] = cap[rows]      # cap_r v_r ≤ t
        a_ub[:, -1] = -1.0
        b_ub = np.zeros(2 * k)
        c = np.concatenate([c, [max_weight]])
        a_eq = np.hstack([a_eq, np.zeros((m, 1))])
    opts = {"presolve": False}
    if time_limit is not None:
        opts["time_limit"] = time_limit
    res = linprog(c, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=b, bounds=(0, None), method="highs-ds", options=opts)
    if res.x is None:
        raise MeasurementError(f"the lobe fit failed: {res.message}")
    return np.maximum(res.x[:n], 0.0)


def solve_l1_core(a: np.ndarray, b: np.ndarray, scale: np.ndarray, cost: np.ndarray | None = None) -> np.ndarray:
    """The LP of ``solve_l1`` handed straight to SciPy's bundled HiGHS core: the same solver
    without linprog's per-call validation (which costs more than these tiny solves). Used by
    the exponent search, which runs thousands of fits."""
    x = WarmL1(a, np.zeros(a.shape[1]) if cost is None else cost).solve(b, scale)
    return x if x is not None else solve_l1(a, b, scale, cost)


class WarmL1:
    """The same LP as ``solve_l1`` for a fixed matrix A, kept in one HiGHS instance (SciPy's
    bundled highspy core) so that a new fit only changes the right-hand side, the row costs and
    the max-residual coefficients, and re-solves from the previous optimal basis (dual simplex,
    warm). ``linprog`` rebuilds and re-validates the model on every call, which costs more than
    the solve itself (BENCHMARKS). ``cap_rows`` (k,) are the rows in the max term (none when
    max_weight is 0)."""

    def __init__(self, a: np.ndarray, cost: np.ndarray, cap_rows=(), max_weight: float = 0.0):
        from scipy.optimize._highspy import _core
        m, n = a.shape
        self.m, self.n = m, n
        self.cap_rows = np.asarray(cap_rows if max_weight > 0 else (), np.int64)
        k = len(self.cap_rows)
        h = _core._Highs()
        h.setOptionValue("output_flag", False)
        h.setOptionValue("presolve", "off")
        h.setOptionValue("solver", "simplex")
        h.setOptionValue("simplex_iteration_limit", ITERATION_LIMIT)
        ncol = n + 2 * m + (1 if k else 0)
        full = np.zeros((m + 2 * k, ncol))
        full[:m, :n + 2 * m] = np.hstack([a, -np.eye(m), np.eye(m)])
        if k:                                   # cap_r u_r − t ≤ 0, cap_r v_r − t ≤ 0 (cap set per fit)
            full[m + np.arange(k), n + self.cap_rows] = 1.0
            full[m + k + np.arange(k), n + m + self.cap_rows] = 1.0
            full[m:, -1] = -1.0
        lp = _core.HighsLp()
        lp.num_col_, lp.num_row_ = ncol, m + 2 * k
        lp.col_cost_ = np.concatenate([cost, np.ones(2 * m), [max_weight] if k else []])
        lp.col_lower_ = np.zeros(ncol)
        lp.col_upper_ = np.full(ncol, np.inf)
        lp.row_lower_ = np.concatenate([np.zeros(m), np.full(2 * k, -np.inf)])
        lp.row_upper_ = np.zeros(m + 2 * k)
        col = np.nonzero(full.T)            # column-wise sparse storage
        mat = _core.HighsSparseMatrix()
        mat.num_col_, mat.num_row_ = ncol, m + 2 * k
        mat.start_ = np.concatenate([[0], np.cumsum(np.count_nonzero(full, axis=0))]).astype(np.int32)
        mat.index_ = col[1].astype(np.int32)
        mat.value_ = full.T[col]
        lp.a_matrix_ = mat
        h.passModel(lp)
        self.h = h
        self.idx = np.arange(n, n + 2 * m, dtype=np.int32)
        self.lock = __import__("threading").Lock()

    def solve(self, b: np.ndarray, scale: np.ndarray, scale_under: np.ndarray | None = None,
              cap: np.ndarray | None = None) -> np.ndarray | None:
        """x (n,), or None when the solve did not reach the optimum (the caller falls back).
        cap (m,): the max-residual coefficients (default scale); only ``cap_rows`` are used.

        The guard against a slow solve is an iteration limit, not HiGHS's time_limit: that clock
        accumulates over the runs of one instance, so a kept instance would soon stop at once."""
        cap = scale if cap is None else cap
        with self.lock:
            h = self.h
            h.changeColsCost(2 * self.m, self.idx,
                             np.concatenate([scale, scale if scale_under is None else scale_under]))
            for r in range(self.m):
                h.changeRowBounds(r, float(b[r]), float(b[r]))
            k = len(self.cap_rows)
            for j, r in enumerate(self.cap_rows):
                h.changeCoeff(self.m + j, self.n + int(r), float(cap[r]))
                h.changeCoeff(self.m + k + j, self.n + self.m + int(r), float(cap[r]))
            h.run()
            ok = h.modelStatusToString(h.getModelStatus()) == "Optimal"
            x = np.asarray(h.getSolution().col_value[: self.n])
        if not ok or not np.isfinite(x).all():
            return None
        return np.maximum(x, 0.0)


@lru_cache(maxsize=32)
def _warm(exponents: tuple[float, ...], angles: tuple[float, ...], max_weight: float) -> WarmL1:
    m = len(exponents)
    a = measurement_matrix(exponents, angles)
    prior = np.zeros(a.shape[1]); prior[3 + 3 * m:] = 1.0
    return WarmL1(np.vstack([a, prior]), _energy_cost(exponents), np.arange(a.shape[0]), max_weight)


def _energy_cost(exponents) -> np.ndarray:
    """Per-variable cost: albedo and dd by their luminance (3·Y weights, so a grey unit on all
    three channels costs 3), gloss weights 3·GLOSS_DISCOUNT (sharp, wide lobes)."""
    m = len(exponents)
    lum = 3.0 * LUMA
    gloss = [3.0 * (GLOSS_DISCOUNT[0] if e >= SHARP_E else GLOSS_DISCOUNT[1]) for e in exponents]
    cost = np.concatenate([lum, np.tile(lum, m), gloss])
    return ENERGY_WEIGHT * cost


@dataclass
class FitResult:
    material: Lobes
    seconds: float
    error_l1: float            # mean relative absolute error of the measurements (dimensionless)
    error_max: float           # largest relative error of one reading
    predicted: dict            # the fitted material's measurements, same form as the input
    residuals: dict            # signed relative residuals (fit − reading)/(|reading| + floor), same form
    unmet: list                # the readings off by more than TOLERANCE: "gloss", "45:r", …

    @property
    def warning(self) -> str | None:
        """A sentence naming the readings the fit cannot meet, or None."""
        if not self.unmet:
            return None
        return (f"{len(self.unmet)} reading(s) cannot be met within {100 * TOLERANCE:g}% by a lobes material on "
                f"this basis: {', '.join(self.unmet)} (largest {100 * self.error_max:.0f}%)")

    def to_json(self) -> dict:
        m = self.material
        return {"seconds": self.seconds, "error_l1": self.error_l1, "error_max": self.error_max,
                "exponents": list(m.exponents), "gloss_weights": list(m.gloss),
                "directional_diffuse": [list(d) for d in m.directional_diffuse], "albedo": list(m.albedo),
                "predicted": self.predicted, "residuals": self.residuals, "unmet": self.unmet,
                "warning": self.warning, "material": m.model_dump()}


def _unmet(rel: np.ndarray, angles) -> list[str]:
    """Names of the readings whose relative residual exceeds TOLERANCE (rel: gloss, then K×RGB)."""
    out = ["gloss"] if abs(rel[0]) > TOLERANCE else []
    for i, an in enumerate(angles):
        for c, ch in enumerate("rgb"):
            if abs(rel[1 + 3 * i + c]) > TOLERANCE:
                out.append(f"{angle_key(an)}:{ch}")
    return out


def fit_weights(measurements: dict, exponents, time_limit: float | None = 0.05, solver: str = "warm",
                max_weight: float | None = None):
    """The LP of ``fit_measurements`` on any number of exponents (no Lobes material is built, so
    the basis may exceed the model's MAX_LOBES: the dense reference basis of basis.py).
    Returns (x (3 + 4M,) weights, A (1 + 3K, 3 + 4M), b (1 + 3K,) readings, scale (1 + 3K,),
    angles (K,), seconds)."""
    mw = float(MAX_WEIGHT if max_weight is None else max_weight)
    exps = tuple(float(e) for e in exponents)
    g, angles, vals = parse_measurements(measurements)
    t0 = time.perf_counter()
    a = measurement_matrix(exps, tuple(float(x) for x in angles))
    m = len(exps)
    b = np.concatenate([[g], vals.reshape(-1)])
    scale = 1.0 / (np.abs(b) + np.concatenate([[GLOSS_FLOOR], np.full(len(b) - 1, ASPECULAR_FLOOR)]))
    # prior row: Σ g_i ≥ clearcoat albedo
    prior = np.zeros(a.shape[1]); prior[3 + 3 * m:] = 1.0
    a_all = np.vstack([a, prior])
    b_all = np.concatenate([b, [CLEARCOAT_ALBEDO]])
    s_all = np.concatenate([scale, [PRIOR_WEIGHT / CLEARCOAT_ALBEDO]])
    cap = np.concatenate([scale, [0.0]])       # the prior is no reading: not in the max term
    cost = _energy_cost(exps)
    s_over = s_all.copy()
    s_over[-1] = 0.0                           # the clearcoat prior is one-sided: more is free
    if solver == "warm":
        x = _warm(exps, tuple(float(v) for v in angles), mw).solve(b_all, s_over, s_all, cap)
        if x is None:                          # not optimal within the iteration limit: solve afresh
            x = solve_l1(a_all, b_all, s_over, cost, time_limit, s_all, cap, mw)
    elif solver == "linprog":
        x = solve_l1(a_all, b_all, s_over, cost, time_limit, s_all, cap, mw)
    else:
        raise ValueError(f"unknown solver {solver!r}")
    return x, a, b, scale, angles, time.perf_counter() - t0


def fit_measurements(measurements: dict, exponents=None, time_limit: float | None = 0.05,
                     solver: str = "warm", max_weight: float | None = None) -> FitResult:
    """Lobe weights from ``{"gloss": G, "aspecular": {"15": [r, g, b], …}}`` (any aspecular set).

    exponents : the basis (default: the stored choice, ``basis.default_exponents()``).
    time_limit : seconds granted to a fresh linprog solve (the paper's guard against a slow
        solve); the warm solver is guarded by an iteration limit and falls back to linprog.
    solver : "warm" (a kept HiGHS instance re-solved from its last basis, WarmL1) or "linprog"
        (scipy.optimize.linprog with HiGHS, the reference: same LP, built anew each call).
    max_weight : weight of the largest relative residual in the objective (default MAX_WEIGHT;
        0 is the pure L1 fit of cacad §4)."""
    if exponents is None:
        from .basis import default_exponents
        exponents = default_exponents()
    exps = tuple(float(e) for e in exponents)
    m = len(exps)
    x, a, b, scale, angles, seconds = fit_weights(measurements, exps, time_limit, solver, max_weight)
    pred = a @ x
    rel = (pred - b) * scale
    mat = Lobes(exponents=list(exps), gloss=[float(v) for v in x[3 + 3 * m:]],
                directional_diffuse=[tuple(float(v) for v in x[3 + 3 * i: 6 + 3 * i]) for i in range(m)],
                albedo=tuple(float(v) for v in x[:3]))
    predicted = {"gloss": float(pred[0]),
                 "aspecular": {angle_key(an): [float(v) for v in pred[1 + 3 * i: 4 + 3 * i]]
                               for i, an in enumerate(angles)}}
    residuals = {"gloss": float(rel[0]),
                 "aspecular": {angle_key(an): [float(v) for v in rel[1 + 3 * i: 4 + 3 * i]]
                               for i, an in enumerate(angles)}}
    return FitResult(mat, seconds, float(np.abs(rel).mean()), float(np.abs(rel).max()), predicted, residuals,
                     _unmet(rel, angles))


# --- fits to sampled BRDFs (the database, for the exponent search of §3.2) ---------------------

SAMPLE_INCIDENCE_DEG = (10.0, 45.0, 70.0)     # cacad Fig. 4 lights its slices from 10°, 40°, 70°
SAMPLE_ASPECULAR_DEG = (-30.0, -15.0, -8.0, -4.0, -2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0, 4.0, 8.0,
                        15.0, 25.0, 35.0, 45.0, 60.0, 75.0, 90.0, 110.0)
SAMPLE_FLOOR = 0.02


@lru_cache(maxsize=1)
def sample_geometry():
    """(wi (S, 3), wo (S, 3), cos(r·wo) (S,)) of the in-plane samples used to compare BRDFs:
    each incidence of SAMPLE_INCIDENCE_DEG with the aspecular angles whose view is above 85°."""
    wis, wos, cs = [], [], []
    for ti in SAMPLE_INCIDENCE_DEG:
        a = np.array([x for x in SAMPLE_ASPECULAR_DEG if abs(ti - x) < 85.0])
        wi, wo = aspecular_directions(a, ti)
        wis.append(np.broadcast_to(wi, wo.shape)); wos.append(wo); cs.append(np.cos(np.radians(a)))
    return np.concatenate(wis), np.concatenate(wos), np.concatenate(cs)


def sample_reflectance(brdf) -> np.ndarray:
    """(S, 3) reflectance factors π f of a BRDF (Glint material or object with ``evaluate``)."""
    from .geometry import _eval
    wi, wo, _ = sample_geometry()
    return np.pi * _eval(brdf, wi, wo)


def fit_samples(exponents, target: np.ndarray) -> tuple[np.ndarray, float]:
    """Fit albedo + per-channel lobe weights to sampled reflectance factors target (S, 3) by the
    same relative L1 LP, channel by channel (achromatic gloss adds nothing a per-channel lobe
    weight cannot represent). Returns (weights (3, 1 + M): albedo then lobes, RMS relative error)."""
    _, _, c = sample_geometry()
    basis = np.hstack([np.ones((len(c), 1)), lobe_response(exponents, c)])      # (S, 1 + M)
    w = np.zeros((3, basis.shape[1]))
    err = []
    for ch in range(3):
        b = target[:, ch]
        s = 1.0 / (np.abs(b) + SAMPLE_FLOOR)
        w[ch] = solve_l1_core(basis, b, s)
        err.append((basis @ w[ch] - b) * s)
    return w, float(np.sqrt(np.mean(np.square(err))))
