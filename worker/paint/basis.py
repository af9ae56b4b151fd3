"""The fit's basis: exponents chosen on generated paints, reported on held-out ones.

What the basis must do: a designer's readings that some non-negative lobes material can produce
(exponents anywhere in [1, 10⁴], generated.py) should come back from measure → fit → measure
within TOLERANCE (fit.TOLERANCE, 3%) in every reading, the error of a reading r being
|fit − r| / (|r| + floor) with the fit's floors (0.01 in reflectance factor, 1 GU in gloss).

The cacad §3.2 search (exponents.py) chooses exponents for the 30 paints of the database; its
optimum ([1, 22, 1216, 1517, 3039, 3970, 5439, 9580]) puts six of eight lobes where the
database's one-lobe fits are and none between 22 and 1216, so a directional diffuse spread
over 15-75° has no lobe to land on (−74% at 45° for the issue's [3, 12, 45, 180, 900] paint).
Here the exponents are chosen on a tuning set of generated paints and reported on a held-out set
from another seed (generated.TUNING_SEED / HELD_OUT_SEED):

* lobes paints (generated.random_lobes_paint): their readings, exactly (measurement_matrix is
  the measurement of a lobes material, tests/paint);
* clearcoated GGX / Ashikhmin-Shirley paints (generated.random_microfacet_paint): not every
  reading of a microfacet paint is reachable by any lobes material — cosine lobes about the
  mirror direction read the same at −15° and 15°, which a microfacet lobe (its 1/cosθo) does
  not — so they enter as their *reachable part*: the readings of their fit on DENSE, 64
  exponents log-spaced over [1, 10⁴] ("some lobes material"). What is not reachable there is
  reported separately (``inherent``): no basis can meet it, and the fit names it (``unmet``).

Objective (cacad eq. 4 in form): max + mean over the cases of the case's largest relative
reading error. Search: coordinate descent in log E from each of ``starts`` (E = 1 stays,
exponents.FIXED: its map is the diffuse map), each exponent moved by the factors STEPS in turn,
kept if the objective drops, the step shrunk when no move helps; the best end point is kept.
SIZE = 24 (the lobes model allows MAX_LOBES = 32, models/lobes.py, the packed kernel layout):
the smallest of 16, 24, 32 log-spaced lobes over [1, 10⁴] whose round trip stays within
TOLERANCE on every tuning paint (16: worst 9.7%, 24: 2.6%, 32: 1.6%). The frame cost does not
grow with it (the shading kernel skips a material's zero-weight lobes); prefiltering does, one
map per exponent (and vector maps for E ≤ VECTOR_MAX_E).
The weight of the max-residual term (fit.MAX_WEIGHT) is chosen on the tuning set the same way
(``choose_max_weight``).

``glint paint basis [--json]`` prints the stored choice (data/basis.json) with its tuning and
held-out figures, the old basis's on the same held-out set, and the inherent misses;
``--recompute`` reruns the choice (minutes).
"""
from __future__ import annotations

import json
import sys
import time
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import GlintError
from ..models import Lobes
from .exponents import FIXED
from .fit import TOLERANCE, fit_weights, measurement_matrix
from .generated import HELD_OUT_SEED, TUNING_SEED, paint_set
from .geometry import ASPECULAR_DEG, angle_key, measure

BASIS_PATH = Path(__file__).parent / "data" / "basis.json"
SIZE = 24
E_BOUNDS = (1.0, 2e4)
DENSE = tuple(float(e) for e in np.geomspace(1.0, 1e4, 64))
TUNING = {"lobes": 160, "microfacet": 40}
HELD_OUT = {"lobes": 160, "microfacet": 40}
STEPS = (1.6, 1.25, 1.1)
OLD_BASIS = (1.0, 22.0011, 1215.94, 1516.64, 3039.3, 3969.74, 5438.87, 9580.34)
ISSUE_PAINT = Lobes(exponents=[3, 12, 45, 180, 900], gloss=[0.0, 0.0, 0.0, 0.02, 0.04],
                    directional_diffuse=[(0.08, 0.05, 0.2), (0.06, 0.04, 0.15), (0.04, 0.03, 0.1),
                                         (0.02, 0.02, 0.05), (0.0, 0.0, 0.0)], albedo=(0.02, 0.02, 0.06))


def readings(paint, angles=ASPECULAR_DEG) -> dict:
    """The industry readings ``{"gloss", "aspecular"}`` of a paint: for a lobes material from
    its measurement matrix (exact), for any other BRDF by geometry.measure."""
    if isinstance(paint, Lobes):
        ex = tuple(float(e) for e in paint.exponents)
        a = measurement_matrix(ex, tuple(float(v) for v in angles))
        x = np.concatenate([paint.albedo, np.asarray(paint.directional_diffuse, np.float64).reshape(-1), paint.gloss])
        b = a @ x
        return {"gloss": float(b[0]), "aspecular": {angle_key(an): [float(v) for v in b[1 + 3 * i: 4 + 3 * i]]
                                                    for i, an in enumerate(angles)}}
    m = measure(paint, angles)
    m["gloss"] = float(m["gloss"])
    return m


def reading_errors(meas: dict, exponents, max_weight: float | None = None) -> np.ndarray:
    """(1 + 3K,) signed relative errors of measure(fit(meas)) against meas: the fitted weights'
    readings A x against b, which are the fitted material's measurements (A is exact)."""
    x, a, b, scale, _, _ = fit_weights(meas, exponents, max_weight=max_weight)
    return (a @ x - b) * scale


def reachable(meas: dict, max_weight: float | None = None) -> dict:
    """The readings of the fit of ``meas`` on DENSE: what some lobes material reads nearest to
    ``meas`` (identical to ``meas`` when a lobes material can produce it)."""
    x, a, _, _, angles, _ = fit_weights(meas, DENSE, max_weight=max_weight)
    p = a @ x
    return {"gloss": float(p[0]), "aspecular": {angle_key(an): [float(v) for v in p[1 + 3 * i: 4 + 3 * i]]
                                                for i, an in enumerate(angles)}}


@lru_cache(maxsize=4)
def cases(seed: int, lobes: int, microfacet: int) -> tuple[tuple[dict, ...], tuple[dict, ...]]:
    """(lobes readings, microfacet readings) of a generated set: the raw readings of every paint
    (the microfacet ones' reachable part is taken by ``case_readings``)."""
    lp, mp = paint_set(seed, lobes, microfacet)
    return tuple(readings(p) for p in lp), tuple(readings(p) for p in mp)


@lru_cache(maxsize=4)
def case_readings(seed: int, lobes: int, microfacet: int) -> tuple[dict, ...]:
    """The readings a basis is judged on: the lobes paints' readings, then the microfacet
    paints' reachable parts."""
    lr, mr = cases(seed, lobes, microfacet)
    return lr + tuple(reachable(m) for m in mr)


def tuning_cases() -> tuple[dict, ...]:
    return case_readings(TUNING_SEED, TUNING["lobes"], TUNING["microfacet"])


def held_out_cases() -> tuple[dict, ...]:
    return case_readings(HELD_OUT_SEED, HELD_OUT["lobes"], HELD_OUT["microfacet"])


def case_errors(exponents, meas, max_weight: float | None = None) -> np.ndarray:
    """(n,) each case's largest relative reading error after the round trip."""
    return np.array([np.abs(reading_errors(m, exponents, max_weight)).max() for m in meas])


def objective(exponents, meas, max_weight: float | None = None) -> float:
    e = case_errors(exponents, meas, max_weight)
    return float(e.max() + e.mean())


def summary(errors: np.ndarray) -> dict:
    """Figures of (n,) per-case errors: worst, percentiles, share within TOLERANCE."""
    e = np.asarray(errors, np.float64)
    return {"cases": int(len(e)), "max": float(e.max()), "p50": float(np.median(e)), "p90": float(np.percentile(e, 90)),
            "p99": float(np.percentile(e, 99)), "within": float((e <= TOLERANCE).mean())}


def _sorted(searched) -> tuple[float, ...]:
    return tuple(sorted(FIXED + tuple(float(x) for x in searched)))


def starts(size: int = SIZE) -> list[list[float]]:
    """The searched exponents' starting points: log-spaced over [2, 10⁴]; and most of them
    log-spaced over [2, 300] with four over [10³, 10⁴] (above E ≈ 300 a lobe adds nothing but
    gloss at the E2194 angles, so sharp lobes only need to span the gloss response)."""
    n = size - len(FIXED)
    return [list(np.geomspace(2.0, 1e4, n)), list(np.geomspace(2.0, 300.0, n - 4)) + list(np.geomspace(1e3, 1e4, 4))]


def search_all(meas, size: int = SIZE, max_weight: float | None = None, log=None) -> dict:
    """``search`` from every start; the best on ``meas`` (the tuning cases)."""
    found = [search(meas, size, max_weight, start=s, log=log) for s in starts(size)]
    best = min(found, key=lambda r: r["objective"])
    best["start_objectives"] = [r["objective"] for r in found]
    best["evaluations"] = sum(r["evaluations"] for r in found)
    return best


def search(meas, size: int = SIZE, max_weight: float | None = None, rounds: int = 6, start=None, log=None) -> dict:
    """Coordinate descent in log E (module docstring) from ``start`` (size − 1 exponents; default
    the first of ``starts``). Returns {"basis", "objective", "evaluations"}."""
    cur = list(start if start is not None else starts(size)[0])
    best = objective(_sorted(cur), meas, max_weight)
    n_eval = 1
    for step in STEPS:
        for _ in range(rounds):
            improved = False
            for i in range(len(cur)):
                for f in (step, 1.0 / step):
                    trial = list(cur)
                    trial[i] = float(np.clip(cur[i] * f, *E_BOUNDS))
                    if any(abs(np.log(trial[i] / e)) < 1e-3 for e in FIXED + tuple(trial[:i] + trial[i + 1:])):
                        continue                       # two lobes on one exponent: no new direction
                    v = objective(_sorted(trial), meas, max_weight)
                    n_eval += 1
                    if v < best - 1e-6:
                        best, cur, improved = v, trial, True
                        break
            if log:
                log(f"step ×{step}: objective {best:.4f} basis {[round(e, 1) for e in _sorted(cur)]}")
            if not improved:
                break
    return {"basis": [float(f"{e:.6g}") for e in _sorted(cur)], "objective": best, "evaluations": n_eval}


def choose_max_weight(meas, candidates=(0.0, 1.0, 5.0, 20.0, 100.0, 1000.0)) -> tuple[float, dict]:
    """The max-residual weight of the fit with the lowest objective on the tuning cases, on the
    log-spaced start of ``search``; returns (weight, {weight: objective})."""
    start = _sorted(np.geomspace(2.0, 1e4, SIZE - len(FIXED)))
    scores = {float(w): objective(start, meas, w) for w in candidates}
    return min(scores, key=scores.get), scores


def inherent(max_weight: float | None = None) -> dict:
    """What no basis meets on the held-out microfacet paints: the round trip of their raw readings
    on DENSE, its per-reading misses counted by reading name."""
    _, mr = cases(HELD_OUT_SEED, HELD_OUT["lobes"], HELD_OUT["microfacet"])
    worst, counts = [], {}
    for m in mr:
        rel = reading_errors(m, DENSE, max_weight)
        worst.append(np.abs(rel).max())
        names = ["gloss"] + [f"{k}" for k in m["aspecular"] for _ in range(3)]
        for r, nm in zip(rel, names):
            if abs(r) > TOLERANCE:
                counts[nm] = counts.get(nm, 0) + 1
    return {"paints": len(mr), "raw_round_trip": summary(np.array(worst)), "misses_by_reading": counts}


def main_recompute(out: Path | None = None, log=None) -> dict:
    """Choose the max-residual weight and the basis on the tuning cases, report on the held-out
    ones (and the old basis there); write data/basis.json when ``out`` is given."""
    log = log or (lambda s: print(s, file=sys.stderr, flush=True))
    t0 = time.perf_counter()
    tune = tuning_cases()
    mw, scores = choose_max_weight(tune)
    log(f"max-residual weight {mw} (tuning objectives {scores})")
    found = search_all(tune, max_weight=mw, log=log)
    held = held_out_cases()
    doc = {"about": "worker.paint.basis: exponents chosen on generated tuning paints, figures on held-out ones "
                    "(round trip measure -> fit -> measure, per-case largest relative reading error)",
           "basis": found["basis"], "max_weight": mw, "max_weight_objectives": scores,
           "tuning": {"seed": TUNING_SEED, **TUNING, **summary(case_errors(found["basis"], tune, mw))},
           "held_out": {"seed": HELD_OUT_SEED, **HELD_OUT, **summary(case_errors(found["basis"], held, mw))},
           "held_out_old_basis": {"basis": list(OLD_BASIS), **summary(case_errors(OLD_BASIS, held, 0.0))},
           "issue_paint": {"new": float(case_errors(found["basis"], [readings(ISSUE_PAINT)], mw)[0]),
                           "old": float(case_errors(OLD_BASIS, [readings(ISSUE_PAINT)], 0.0)[0])},
           "inherent_microfacet": inherent(mw), "evaluations": found["evaluations"],
           "start_objectives": found["start_objectives"],
           "seconds": time.perf_counter() - t0}
    if out is not None:
        from ..atomic import atomic_write
        atomic_write(Path(out), (json.dumps(doc, indent=1) + "\n").encode())
    return doc


def stored(path: Path | None = None) -> dict:
    p = Path(path or BASIS_PATH)
    if not p.is_file():
        raise GlintError(f"{p}: no stored basis (run `glint paint basis --recompute --out {p}`)")
    return json.loads(p.read_text())


@lru_cache(maxsize=1)
def default_exponents() -> tuple[float, ...]:
    """The basis the fit and the paint renderer use (data/basis.json)."""
    return tuple(float(e) for e in stored()["basis"])
