"""The industry measurement geometries (worker/paint/geometry.py) against closed forms."""
import json

import numpy as np
import pytest

from worker.errors import GlintError
from worker.paint.geometry import (GLOSS_RECEPTOR_DEG, GLOSS_STANDARD_R, aspecular_directions, export_measurements,
                                   flop_index, fresnel_dielectric, gloss_units, measure, parse_measurements)
from worker.scene import GGX, SRBF, BlinnPhong, Curve, Lambert, Lobes


def test_aspecular_geometry_follows_e2194():
    wi, wo = aspecular_directions([15, 25, 45, 75, 110, -15])
    assert np.allclose(wi, [-np.sqrt(0.5), 0, np.sqrt(0.5)])
    spec = np.array([np.sqrt(0.5), 0, np.sqrt(0.5)])
    # the aspecular angle is the angle between the detector and the specular direction
    ang = np.degrees(np.arccos(np.clip(wo @ spec, -1, 1)))
    assert np.allclose(ang, [15, 25, 45, 75, 110, 15], atol=1e-9)
    # positive angles turn towards the normal (45° is the normal), −15° goes beyond the specular
    assert np.allclose(np.degrees(np.arctan2(wo[:, 0], wo[:, 2])), [30, 20, 0, -30, -65, 60])
    with pytest.raises(GlintError):
        aspecular_directions([140])


def test_white_diffuser_reads_one_everywhere():
    m = measure(Lambert(albedo=(1, 1, 1)))
    for v in m["aspecular"].values():
        assert np.allclose(v, 1.0, atol=1e-12)
    # its gloss: ρ = (1/π)∫_receptor cosθo dω ≈ Ω cos20°/π, relative to the standard
    omega = np.radians(GLOSS_RECEPTOR_DEG[0]) * np.radians(GLOSS_RECEPTOR_DEG[1])
    expect = 100 * omega * np.cos(np.radians(20)) / np.pi / GLOSS_STANDARD_R
    assert abs(m["gloss"] - expect) < 0.01 * expect, (m["gloss"], expect)


def test_gloss_scale_is_the_black_glass_standard():
    assert abs(GLOSS_STANDARD_R - 0.04917) < 2e-4
    # a lobe much narrower than the receptor reflects its directional albedo into it: for a sharp
    # normalised cosine lobe of weight w that is w·cos20° ((E+2)/(2π)∫(r·ωo)^E cosθo dωo → cosθr)
    c20 = np.cos(np.radians(20))
    sharp = Lobes(exponents=[2e5], gloss=[GLOSS_STANDARD_R / c20], directional_diffuse=[(0, 0, 0)], albedo=(0, 0, 0))
    g = gloss_units(sharp)
    assert abs(g - 100.0) < 0.5, g
    # a mirror-smooth clearcoat of index 1.5 reflects R_F(20°) = 0.0401: 82 GU
    cc = Lobes(exponents=[2e5], gloss=[fresnel_dielectric(c20, 1.5) / c20],
               directional_diffuse=[(0, 0, 0)], albedo=(0, 0, 0))
    assert 81.5 < gloss_units(cc) < 82.5, gloss_units(cc)
    # a wide lobe spills most of its light outside the 1.8° × 3.6° receptor
    wide = Lobes(exponents=[100.0], gloss=[GLOSS_STANDARD_R], directional_diffuse=[(0, 0, 0)], albedo=(0, 0, 0))
    assert gloss_units(wide) < 10.0


def test_reflectance_factor_is_pi_times_brdf_for_every_model():
    mats = [Lambert(albedo=(0.2, 0.3, 0.4)), GGX(alpha=0.2, specular=(0.5, 0.5, 0.5), albedo=(0.1, 0.1, 0.1)),
            BlinnPhong(exponent=80), Curve(values=[(1, 1, 1)] * 8, albedo=(0.1, 0.1, 0.1)),
            SRBF(centers=[(0, 0, 1)], bandwidth=50.0, coefficients=[(1, 1, 1)], albedo=(0.1, 0.2, 0.3)),
            Lobes(exponents=[10.0], gloss=[0.1], directional_diffuse=[(0.2, 0.1, 0.0)], albedo=(0.1, 0.1, 0.1))]
    from worker.core.brdf import evaluate
    for m in mats:
        r = measure(m)
        assert set(r["aspecular"]) == {"-15", "15", "25", "45", "75", "110"}
        wi, wo = aspecular_directions([25.0])
        assert np.allclose(r["aspecular"]["25"], np.pi * evaluate(m, wi[None], wo)[0], rtol=1e-9)
        assert r["gloss"] >= 0 and np.isfinite(r["gloss"])
    # lobes: in the plane of incidence r·ωo is the cosine of the aspecular angle
    m = mats[-1]
    r = measure(m)
    c = np.cos(np.radians(25))
    assert np.allclose(r["aspecular"]["25"], np.array([0.1, 0.1, 0.1]) + (0.1 + np.array([0.2, 0.1, 0.0])) * 6 * c ** 10)
    assert np.allclose(r["aspecular"]["110"], [0.1, 0.1, 0.1])   # beyond 90°: diffuse only


def test_flop_index_and_export():
    solid = measure(Lambert(albedo=(0.5, 0.1, 0.1)))
    assert flop_index(solid) == pytest.approx(0.0, abs=1e-9)
    metallic = measure(Lobes(exponents=[12.0], gloss=[0.0], directional_diffuse=[(0.5, 0.5, 0.5)], albedo=(0.05, 0.05, 0.05)))
    assert flop_index(metallic) > 10
    js = json.loads(export_measurements(metallic, "json"))
    g, angles, vals = parse_measurements(js)
    assert g == pytest.approx(metallic["gloss"]) and np.allclose(vals[list(angles).index(15.0)], metallic["aspecular"]["15"])
    csv = export_measurements(metallic, "csv").splitlines()
    assert csv[0] == "geometry,angle_deg,r,g,b,value" and csv[1].startswith("gloss_D523,20,")
    row = [l for l in csv if l.startswith("aspecular_45,110,")][0].split(",")
    assert np.allclose([float(x) for x in row[2:5]], metallic["aspecular"]["110"], rtol=1e-5)
    with pytest.raises(GlintError):
        export_measurements(metallic, "xml")
    with pytest.raises(GlintError):
        parse_measurements({"gloss": 10, "aspecular": {"15": [1, 2]}})
