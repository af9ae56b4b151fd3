"""The fit's basis (worker/paint/basis.py) on generated paints it was not chosen on, and the fit's
report of readings it cannot meet."""
import numpy as np
import pytest

from worker.models.lobes import MAX_LOBES
from worker.paint import basis as B
from worker.paint import fit as F
from worker.paint.generated import (HELD_OUT_SEED, TUNING_SEED, ClearcoatPaint, paint_set, random_lobes_paint,
                                    random_microfacet_paint)
from worker.paint.geometry import aspecular_directions

# a prefix of the held-out set basis.json reports on (the two families come from separate
# streams, so these are its first paints): small enough for the suite, never seen by the choice
N_LOBES, N_MICROFACET = 40, 8
# what the held-out set gives the stored basis (data/basis.json: 0.6% worst), with the margin of
# a 48-case sample; and the target itself: every held-out paint within TOLERANCE in every reading
WORST_BOUND = B.stored()["held_out"]["max"] * 1.05 + 1e-3
WITHIN_BOUND = 1.0


@pytest.fixture(scope="module")
def held_out():
    return B.case_readings(HELD_OUT_SEED, N_LOBES, N_MICROFACET) + (B.readings(B.ISSUE_PAINT),)


def _check(exponents, cases, max_weight=None):
    e = B.case_errors(exponents, cases, max_weight)
    within = float((e <= F.TOLERANCE).mean())
    msg = (f"round trip on {len(e)} held-out paints: worst {100 * e.max():.1f}% (bound {100 * WORST_BOUND:.1f}%), "
           f"{100 * within:.0f}% of paints within {100 * F.TOLERANCE:g}% in every reading (bound "
           f"{100 * WITHIN_BOUND:.0f}%), issue paint {100 * e[-1]:.1f}%")
    return e.max() <= WORST_BOUND and within >= WITHIN_BOUND and e[-1] <= F.TOLERANCE, msg


def test_held_out_round_trip(held_out):
    ok, msg = _check(B.default_exponents(), held_out)
    print(msg)
    assert ok, msg


def test_the_old_basis_fails_the_same_held_out_check(held_out):
    # the database-chosen basis of cacad §3.2 and its pure L1 fit: the check above must reject it
    ok, msg = _check(B.OLD_BASIS, held_out, max_weight=0.0)
    print(msg)
    assert not ok, msg


def test_stored_choice_is_what_the_fit_uses():
    doc = B.stored()
    assert doc["max_weight"] == F.MAX_WEIGHT
    ex = B.default_exponents()
    assert 1.0 in ex and len(ex) <= MAX_LOBES and list(ex) == sorted(ex)
    assert all(B.E_BOUNDS[0] <= e <= B.E_BOUNDS[1] for e in ex)
    assert doc["tuning"]["seed"] == TUNING_SEED != doc["held_out"]["seed"] == HELD_OUT_SEED
    # the tuning and held-out paints are different draws
    t, _ = paint_set(TUNING_SEED, 5, 0)
    h, _ = paint_set(HELD_OUT_SEED, 5, 0)
    assert not set(e for p in t for e in p.exponents) & set(e for p in h for e in p.exponents)


def test_generated_paints_conserve_energy():
    rng = np.random.default_rng(3)
    for _ in range(20):
        p = random_lobes_paint(rng)
        assert (np.asarray(p.albedo) + sum(p.gloss) + np.sum(p.directional_diffuse, axis=0)).max() <= 1.0 + 1e-9
        assert 1.0 <= min(p.exponents) and max(p.exponents) <= 1e4
    # microfacet paints: directional albedo ≤ 1 at 0°, 45° and 70° incidence (midpoint quadrature
    # over the hemisphere, fine enough near the clearcoat's mirror peak)
    th = (np.arange(400) + 0.5) / 400 * (np.pi / 2)
    ph = (np.arange(240) + 0.5) / 240 * (2 * np.pi)
    T, P = np.meshgrid(th, ph, indexing="ij")
    wo = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    dw = (np.sin(T) * (np.pi / 2 / 400) * (2 * np.pi / 240)).reshape(-1)
    for _ in range(4):
        p = random_microfacet_paint(rng)
        assert isinstance(p, ClearcoatPaint) and 0.05 <= getattr(p.base, "alpha", 0.05) <= 0.6
        for ti in (0.0, 45.0, 70.0):
            wi = np.array([-np.sin(np.radians(ti)), 0.0, np.cos(np.radians(ti))])
            f = p.evaluate(np.broadcast_to(wi, wo.shape), wo)
            alb = (f * (wo[:, 2] * dw)[:, None]).sum(0)
            assert alb.max() <= 1.0, (p, ti, alb)


def test_fit_names_the_readings_it_cannot_meet():
    # cosine lobes about the mirror direction read the same at −15° and 15°; a microfacet paint
    # does not (its 1/cosθo), so no lobes material meets both and the fit must say so
    p = random_microfacet_paint(np.random.default_rng(5))
    m = B.readings(p)
    asym = np.max(np.abs(np.asarray(m["aspecular"]["-15"]) / np.asarray(m["aspecular"]["15"]) - 1))
    assert asym > 0.1
    r = F.fit_measurements(m)
    assert any(u.split(":")[0] in ("-15", "15") for u in r.unmet), r.unmet
    assert r.warning and any(s in r.warning for s in ("-15:", " 15:")), r.warning
    for name in r.unmet:
        ang, _, ch = name.partition(":")
        res = r.residuals["gloss"] if name == "gloss" else r.residuals["aspecular"][ang]["rgb".index(ch)]
        assert abs(res) > F.TOLERANCE
    # its reachable part (the readings of some lobes material) is met: no warning
    ok = F.fit_measurements(B.reachable(m))
    assert ok.unmet == [] and ok.warning is None, ok.unmet
    # and the direction pair of the −15° reading is the mirror image of the 15° one about r
    wi, wo = aspecular_directions([-15.0, 15.0])
    r_dir = np.array([-wi[0], -wi[1], wi[2]])
    assert np.allclose(wo @ r_dir, np.cos(np.radians(15.0)))


def test_max_term_spreads_what_one_basis_lobe_cannot_hold():
    # one lobe between basis exponents: the pure L1 optimum is a vertex with the whole shortfall
    # on one reading; the max term lowers the worst reading
    ex = B.default_exponents()
    mid = float(np.sqrt(ex[5] * ex[6]))
    from worker.scene import Lobes
    p = Lobes(exponents=[mid], gloss=[0.0], directional_diffuse=[(0.6, 0.6, 0.6)], albedo=(0.01, 0.01, 0.01))
    m = B.readings(p)
    l1 = np.abs(B.reading_errors(m, ex, 0.0)).max()
    mm = np.abs(B.reading_errors(m, ex)).max()
    assert mm < l1, (mid, l1, mm)


def test_warm_solver_with_max_term_equals_linprog():
    ex = B.default_exponents()
    for m in B.case_readings(HELD_OUT_SEED, 6, 2):
        a = F.fit_measurements(m, ex, solver="warm")
        b = F.fit_measurements(m, ex, solver="linprog")
        assert abs(a.error_max - b.error_max) < 1e-5 and abs(a.error_l1 - b.error_l1) < 1e-5
