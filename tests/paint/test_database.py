"""The paint database (worker/paint/data/paints.json) and its provenance."""
import numpy as np

from worker.paint.database import Lafortune, build_entry, load_paints, model_of


def test_thirty_paints_spanning_what_designers_use():
    paints = load_paints()
    assert len(paints) == 30
    assert len({p["name"] for p in paints}) == 30
    cats = {p["category"] for p in paints}
    assert cats == {"metallic", "pearl", "solid"}
    for p in paints:
        src = p["source"]
        assert src["model"] == "lafortune" and "MERL" in src["measured"] and "Ngan" in src["fit"]
        assert len(src["rho_d"]) == 3 and len(src["rho_s"]) == 3 and src["n"] > 0
    fl = {p["name"]: p["flop_index"] for p in paints}
    # high-flop silvers and metallics against flop-free solids
    assert fl["silver-metallic-paint"] > 15 and fl["gold-metallic-paint"] > 15
    assert max(fl[n] for n in fl if "phenolic" in n or "acrylic" in n) < 1.0
    gloss = [p["measurements"]["gloss"] for p in paints]
    assert min(gloss) < 1 and max(gloss) > 90          # matte to high gloss


def test_stored_measurements_are_the_model_measured():
    # every stored value is reproduced from the transcribed parameters (spot-check a few entries)
    for p in [load_paints()[i] for i in (0, 5, 15, 26)]:
        again = build_entry({k: v for k, v in p.items() if k not in ("measurements", "flop_index")})
        assert again["measurements"]["gloss"] == p["measurements"]["gloss"]
        for k, v in p["measurements"]["aspecular"].items():
            assert np.allclose(again["measurements"]["aspecular"][k], v, atol=1e-6)


def test_lafortune_normalisation():
    # Cz = −Cxy: exactly the normalised Phong lobe about the mirror direction
    m = Lafortune((0.1, 0.1, 0.1), (0.5, 0.5, 0.5), -0.577, 0.577, 50.0)
    wi = np.array([-np.sin(0.5), 0, np.cos(0.5)])
    wo = np.array([np.sin(0.6), 0, np.cos(0.6)])
    expect = 0.1 / np.pi + 0.5 * 52 / (2 * np.pi) * np.cos(0.1) ** 50
    assert np.allclose(m.evaluate(wi, wo), expect)
    # reciprocity
    assert np.allclose(m.evaluate(wi, wo), m.evaluate(wo, wi))
    # the plug-in conversion of J.-H. Lee reproduces: gold-metallic-paint -> xy0 = −1.00881
    g = [p for p in load_paints() if p["name"] == "gold-metallic-paint"][0]
    lf = model_of(g)
    xy0 = (lf.rho_s[0] * (lf.n + 2) / (2 * np.pi)) ** (1 / lf.n)
    assert abs(xy0 - 1.00881) < 1e-4
