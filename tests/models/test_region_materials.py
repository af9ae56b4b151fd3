"""The ``regions`` material (worker/models/regions.py): validation at the edge and the layer
weights every renderer and fitter blend with."""
import numpy as np
import pytest

from worker.models import GGX, Lambert, Region, Regions, layer_weights, parse_material
from worker.models.regions import RegionsError


def _regions(n=6, **kw):
    return Regions(base=Lambert(albedo=(0.4, 0.3, 0.2)), vertex_count=n, regions=[
        Region(name="a", material=GGX(alpha=0.2), vertices=[0, 1, 2, 3], weights=[1.0, 0.5, 0.25, 0.0]),
        Region(name="b", material=Lambert(albedo=(0.9, 0.1, 0.1)), vertices=[2, 3, 4], weights=[0.5, 1.0, 0.2])], **kw)


def test_layers_composite_in_order_and_sum_to_one():
    m = _regions()
    mats, a = m.layers()
    assert [x.model for x in mats] == ["lambert", "ggx", "lambert"]
    assert a.shape == (3, 6) and a.dtype == np.float32
    wa = np.array([1.0, 0.5, 0.25, 0.0, 0.0, 0.0])
    wb = np.array([0.0, 0.0, 0.5, 1.0, 0.2, 0.0])
    # b is painted over a, which is painted over the base
    np.testing.assert_allclose(a[2], wb, atol=1e-7)
    np.testing.assert_allclose(a[1], wa * (1 - wb), atol=1e-7)
    np.testing.assert_allclose(a[0], (1 - wa) * (1 - wb), atol=1e-7)
    np.testing.assert_allclose(a.sum(0), 1.0, atol=1e-6)
    # a plain material is one layer of weight 1
    mats, a = layer_weights(GGX(), 5)
    assert len(mats) == 1 and np.all(a == 1)


def test_json_round_trip_and_albedo_is_the_base():
    m = _regions()
    d = m.model_dump(mode="json")
    assert d["albedo"] == [0.4, 0.3, 0.2]
    again = parse_material(d)
    assert again == m
    again.layers()                      # the cache never makes equal materials unequal
    assert again == m
    del d["albedo"]
    assert parse_material(d) == m
    # as one BRDF (what renderers without regions draw) it is the base
    wi = np.array([[0.1, 0.2, 0.97]])
    np.testing.assert_allclose(m.evaluate(wi, wi), m.base.evaluate(wi, wi))


@pytest.mark.parametrize("change,message", [
    (lambda d: d["regions"][0].update(weights=[1.0]), "1 weights for 4 vertices"),
    (lambda d: d["regions"][0].update(vertices=[0, 2, 1, 3]), "sorted and unique"),
    (lambda d: d["regions"][0].update(weights=[1.0, 0.5, 1.5, 0.0]), "less than or equal to 1"),
    (lambda d: d["regions"][0].update(weights=[1.0, float("nan"), 0.5, 0.0]), "finite"),
    (lambda d: d.update(vertex_count=4), "beyond vertex_count 4"),
    (lambda d: d.update(albedo=[1, 1, 1]), "albedo is its base's"),
    (lambda d: d["regions"][1].update(name="a"), "unique"),
    (lambda d: d.update(regions=[]), "at least 1"),
    (lambda d: d.update(base=_regions().model_dump(mode="json")), "cannot itself have regions"),
    (lambda d: d["regions"][0].update(material=_regions().model_dump(mode="json")), "cannot itself have regions"),
])
def test_bad_regions_are_refused(change, message):
    d = _regions().model_dump(mode="json")
    change(d)
    with pytest.raises(ValueError, match=message):
        parse_material(d)


def test_weights_painted_on_another_mesh_are_refused():
    with pytest.raises(RegionsError, match="mesh of 6 vertices, but the object has 7"):
        layer_weights(_regions(), 7)
