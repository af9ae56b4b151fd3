"""Basis exponents by Levenberg-Marquardt over the paint database (cacad-cosine-lobes §3.2).

f(E) = max_i Error(E, B_i) + (1/n) Σ_i Error(E, B_i)            (eq. 4)

Error(E, B_i) is the RMS relative error of the §4 fit (non-negative least absolute error, here
``fit.fit_samples``) of the lobes with exponents E to paint B_i sampled in the plane of
incidence (``fit.sample_geometry``: incidence 10°, 45°, 70°, aspecular −30…110° with dense
samples within 8° of the mirror direction). Levenberg-Marquardt (MINPACK through SciPy) minimises
a sum of squares, so the residuals are r_i = sqrt(Error_i / n) and r_0 = sqrt(max_i Error_i):
Σ r² is exactly f(E). Exponents are searched as log E. Lobes are added one at a time; each
search starts from the previous optimum plus one new exponent. The objective is multimodal
(each sharp paint pulls an exponent towards its own), so, as the paper warns ("much supervision
is required"), the new exponent is tried at every candidate position — the points at 1/3 and
2/3 of every gap in log E, and a quarter/four times the extremes — LM runs from the STARTS
best of them, and the best optimum is kept.

One lobe is fixed and not searched: E = 1 (FIXED). The renderer prefilters the E = 1 map anyway
(the diffuse map of eq. 9), so as a directional-diffuse lobe it costs one more lookup and no
prefiltering, and it gives the designer's wide-angle readings (45°, 75°) a lobe to move: the
database's flake lobes are all narrower (n ≥ 10), so the search alone never places one there.
The searched exponents are added to it; M counts the searched lobes.

The result for M = 1 … 11 is stored in ``data/exponents.json`` (``glint paint exponents``). The
fit and the renderer no longer use it: chosen on the database alone, the optimum clusters where
the database's one-lobe fits are and misses paints unlike them; basis.py chooses the basis on
generated paints and reports it on held-out ones (the old M = 7 row is its baseline).
"""
from __future__ import annotations

import json
import sys
import time
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from ..errors import GlintError
from .database import load_paints, models
from .fit import fit_samples, sample_reflectance

EXPONENTS_PATH = Path(__file__).parent / "data" / "exponents.json"
DEFAULT_LOBES = 7           # cacad Fig. 4 fits seven basis lobes (the table's reference row)
MAX_LOBES = 11
E_MIN, E_MAX = 0.5, 1e6
FIXED = (1.0,)
STARTS = 2


@lru_cache(maxsize=1)
def database_samples() -> tuple[np.ndarray, ...]:
    """(S, 3) sampled reflectance factors of every database paint."""
    return tuple(sample_reflectance(m) for m in models())


def errors(exponents, samples=None) -> np.ndarray:
    """(n,) Error(E, B_i): RMS relative error of the fit of each database paint."""
    samples = samples if samples is not None else database_samples()
    return np.array([fit_samples(exponents, s)[1] for s in samples])


def objective(exponents, samples=None) -> float:
    """cacad eq. 4: max + mean of the database's fit errors."""
    e = errors(exponents, samples)
    return float(e.max() + e.mean())


def _to_e(u: np.ndarray) -> np.ndarray:
    return np.sort(np.clip(np.exp(u), E_MIN, E_MAX))


def optimise(m: int, start: list[float] | None = None, samples=None, max_nfev: int = 60,
             log=None) -> dict:
    """LM search for m exponents from ``start`` (m values). Returns a table row."""
    samples = samples if samples is not None else database_samples()
    n = len(samples)

    def resid(u):
        e = errors(_basis(_to_e(u)), samples)
        return np.concatenate([[np.sqrt(e.max())], np.sqrt(e / n)])

    u0 = np.log(np.asarray(start, np.float64))
    t0 = time.perf_counter()
    res = least_squares(resid, u0, method="lm", diff_step=2e-3, max_nfev=max_nfev * (m + 1))
    ex = _to_e(res.x)
    e = errors(_basis(ex), samples)
    row = {"lobes": m, "fixed": list(FIXED), "exponents": [float(f"{x:.6g}") for x in ex],
           "basis": [float(f"{x:.6g}") for x in _basis(ex)], "error_mean": float(e.mean()),
           "error_max": float(e.max()), "objective": float(e.max() + e.mean()),
           "worst_paint": load_paints()[int(np.argmax(e))]["name"], "evaluations": int(res.nfev),
           "seconds": time.perf_counter() - t0}
    if log:
        log(f"M={m}: f={row['objective']:.4f} (mean {row['error_mean']:.4f}, max {row['error_max']:.4f}) "
            f"E={row['exponents']}")
    return row


def _basis(searched) -> tuple[float, ...]:
    return tuple(sorted(FIXED + tuple(float(x) for x in searched)))


def _candidates(prev: list[float]) -> list[list[float]]:
    if not prev:
        return [[x] for x in (4.0, 30.0, 300.0, 3000.0)]
    lg = np.log(prev)
    new = [np.exp(a + f * (b - a)) for a, b in zip(lg[:-1], lg[1:]) for f in (1 / 3, 2 / 3)]
    new += [prev[0] / 4.0, prev[-1] * 4.0]
    return [sorted(prev + [float(np.clip(x, E_MIN, E_MAX))]) for x in new]


def search(max_lobes: int = MAX_LOBES, log=None) -> list[dict]:
    """Lobes added one at a time (§3.2); returns the table rows for M = 1 … max_lobes."""
    samples = database_samples()
    rows, prev = [], []
    for m in range(1, max_lobes + 1):
        cands = sorted(_candidates(prev), key=lambda c: objective(_basis(c), samples))[:STARTS]
        tried = [optimise(m, c, samples, max_nfev=20) for c in cands]
        row = min(tried, key=lambda r: r["objective"])
        row["candidates"] = len(tried)
        if log:
            log(f"M={m}: f={row['objective']:.4f} (mean {row['error_mean']:.4f}, max {row['error_max']:.4f}) "
                f"E={row['exponents']} from {len(tried)} starts")
        rows.append(row)
        prev = list(row["exponents"])
    return rows


def stored_table(path: Path | None = None) -> dict:
    p = Path(path or EXPONENTS_PATH)
    if not p.is_file():
        raise GlintError(f"{p}: no stored exponent table (run `glint paint exponents --recompute`)")
    return json.loads(p.read_text())


def exponents_for(m: int, path: Path | None = None) -> dict:
    """The stored table row for m lobes."""
    for row in stored_table(path)["table"]:
        if row["lobes"] == m:
            return row
    raise GlintError(f"--lobes must be within 1…{MAX_LOBES}, got {m}")


def main_recompute(out: Path | None = None, max_lobes: int = MAX_LOBES) -> dict:
    rows = search(max_lobes, log=lambda s: print(s, file=sys.stderr, flush=True))
    doc = {"about": "cacad §3.2 basis exponents by Levenberg-Marquardt over worker/paint/data/paints.json "
                    "(worker.paint.exponents.search); 'exponents' are the searched lobes, 'basis' adds the "
                    "fixed E = 1 lobe", "default_lobes": DEFAULT_LOBES, "table": rows}
    if out is not None:
        from ..atomic import atomic_write
        atomic_write(Path(out), (json.dumps(doc, indent=1) + "\n").encode())
    return doc
