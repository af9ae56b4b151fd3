"""Real-time fit (worker/paint/fit.py): round trip, solver agreement, the session and CLI."""
import json

import numpy as np
import pytest

from worker.errors import GlintError
from worker.paint.basis import default_exponents
from worker.paint.fit import fit_measurements, fit_samples, measurement_matrix, sample_reflectance
from worker.paint.geometry import ASPECULAR_DEG, angle_key, measure
from worker.paint.session import apply_paint
from worker.scene import Lobes


def _random_lobes(rng, exps, sparsity=0.5):
    """A random paint on the basis: clearcoat-like gloss weights, flake-like dd weights that
    shrink with the exponent (sharp coloured lobes are rare in paints, but allowed)."""
    m = len(exps)
    g = rng.uniform(0, 0.03, m) * (rng.random(m) < sparsity)
    dd = rng.uniform(0, 0.3, (m, 3)) * (rng.random((m, 1)) < sparsity) / np.sqrt(np.asarray(exps))[:, None]
    return Lobes(exponents=list(exps), gloss=list(g), directional_diffuse=[tuple(r) for r in dd],
                 albedo=tuple(rng.uniform(0.01, 0.5, 3)))


def test_round_trip_measure_fit_measure_within_one_percent():
    exps = default_exponents()
    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(12):
        mat = _random_lobes(rng, exps)
        m = measure(mat)
        r = fit_measurements(m, exps)
        back = measure(r.material)
        assert r.material.model_dump()["model"] == "lobes"
        assert min(r.material.gloss) >= 0 and np.min(r.material.directional_diffuse) >= 0 and min(r.material.albedo) >= 0
        rel = [abs(back["gloss"] - m["gloss"]) / max(m["gloss"], 1.0)]
        for k in m["aspecular"]:
            a, b = np.asarray(back["aspecular"][k]), np.asarray(m["aspecular"][k])
            rel.append(np.max(np.abs(a - b) / np.maximum(b, 1e-3)))
        worst = max(worst, max(rel))
    assert worst < 0.01, f"round trip: worst relative measurement error {worst:.2e} (threshold 1%)"


def test_warm_solver_equals_linprog_reference():
    exps = default_exponents()
    from worker.paint.database import load_paints
    for p in load_paints():
        a = fit_measurements(p["measurements"], exps, solver="warm")
        b = fit_measurements(p["measurements"], exps, solver="linprog")
        # the same LP optimum (the weights may differ on a degenerate face; the error may not,
        # beyond HiGHS's feasibility tolerance 1e-7 on rows scaled by up to 1/floor = 100)
        assert abs(a.error_l1 - b.error_l1) < 1e-5, (p["name"], a.error_l1, b.error_l1)
        assert abs(a.error_max - b.error_max) < 1e-5, (p["name"], a.error_max, b.error_max)


def test_gloss_sets_sharpness_not_brightness():
    # the clearcoat prior: lowering the gloss reading spreads the clearcoat, it does not dim it
    exps = default_exponents()
    base = {"15": [0.5, 0.1, 0.1], "45": [0.2, 0.03, 0.03], "110": [0.15, 0.02, 0.02]}
    hi = fit_measurements({"gloss": 75, "aspecular": base}, exps).material
    lo = fit_measurements({"gloss": 20, "aspecular": base}, exps).material
    mean_e = lambda m: np.dot(m.gloss, np.log(m.exponents)) / max(sum(m.gloss), 1e-12)
    assert sum(hi.gloss) > 0.02 and sum(lo.gloss) > 0.02
    assert mean_e(lo) < mean_e(hi)


def test_measurement_matrix_matches_measure():
    exps = default_exponents()
    a = measurement_matrix(tuple(exps), tuple(ASPECULAR_DEG))
    rng = np.random.default_rng(3)
    mat = _random_lobes(rng, exps, sparsity=1.0)
    x = np.concatenate([mat.albedo, np.asarray(mat.directional_diffuse).reshape(-1), mat.gloss])
    pred = a @ x
    ref = measure(mat)
    # (measure goes through the kernel's float32 parameters)
    assert pred[0] == pytest.approx(ref["gloss"], rel=1e-6)
    for i, ang in enumerate(ASPECULAR_DEG):
        assert np.allclose(pred[1 + 3 * i: 4 + 3 * i], ref["aspecular"][angle_key(ang)], rtol=1e-6)


def test_sample_fit_reproduces_a_lobes_brdf():
    exps = default_exponents()
    mat = _random_lobes(np.random.default_rng(11), exps)
    w, err = fit_samples(exps, sample_reflectance(mat))
    assert err < 1e-6


def test_apply_paint_event_and_errors():
    msg = {"type": "paint", "seq": 4, "object": "car", "gloss": 80,
           "aspecular": {"-15": [1.2, 1.1, 1.0], "15": [0.9, 0.85, 0.8], "25": [0.5, 0.5, 0.48],
                         "45": [0.15, 0.15, 0.15], "75": [0.06, 0.06, 0.06], "110": [0.04, 0.04, 0.045]}}
    mat, ev = apply_paint(msg)
    assert ev["seq"] == 4 and ev["object"] == "car" and ev["type"] == "paint"
    assert set(ev["measured"]["aspecular"]) == set(msg["aspecular"])
    assert ev["material"] == mat.model_dump()
    assert ev["error_l1"] >= 0 and ev["ms_fit"] > 0 and ev["flop_index"] > 5
    # every reading's residual comes back, and the unmet ones are those beyond the tolerance
    assert set(ev["residuals"]["aspecular"]) == set(msg["aspecular"])
    from worker.paint.fit import TOLERANCE
    worst = max([abs(ev["residuals"]["gloss"])] + [abs(r) for v in ev["residuals"]["aspecular"].values() for r in v])
    assert worst == pytest.approx(ev["error_max"])
    assert (ev["warning"] is None) == (ev["unmet"] == []) == (worst <= TOLERANCE)
    # what the event reports as measured is what the fitted material measures
    assert ev["measured"]["gloss"] == pytest.approx(measure(mat)["gloss"])
    with pytest.raises(GlintError):
        apply_paint({"gloss": 10, "aspecular": {"200": [0.1, 0.1, 0.1]}})
    with pytest.raises(GlintError):
        apply_paint({"gloss": -5, "aspecular": {"15": [0.1, 0.1, 0.1]}})


def test_cli_measure_fit_round_trip(tmp_path, capsys):
    from worker.cli import main
    exps = default_exponents()
    mat = _random_lobes(np.random.default_rng(5), exps)
    mp = tmp_path / "m.json"
    mp.write_text(json.dumps(mat.model_dump()))
    assert main(["paint", "measure", str(mp), "--json"]) == 0
    m = json.loads(capsys.readouterr().out)
    asp = ":".join(f"{k}={','.join(repr(x) for x in v)}" for k, v in m["aspecular"].items())
    out = tmp_path / "fit.json"
    assert main(["paint", "fit", "--gloss", repr(m["gloss"]), f"--aspecular={asp}", "--out", str(out), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert {"seconds", "error_l1", "gloss_weights", "directional_diffuse", "albedo", "exponents"} <= set(res)
    assert res["error_l1"] < 1e-3
    assert main(["paint", "measure", str(out), "--json"]) == 0
    back = json.loads(capsys.readouterr().out)
    for k in m["aspecular"]:
        assert np.allclose(back["aspecular"][k], m["aspecular"][k], rtol=0.01, atol=1e-4)
    assert main(["paint", "export", str(out), "--format", "csv"]) == 0
    assert capsys.readouterr().out.startswith("geometry,angle_deg")
    assert main(["paint", "fit", "--gloss", "10", "--aspecular", "15=1,2"]) == 2
