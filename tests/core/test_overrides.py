"""worker/overrides.py: the one place objects' materials are replaced by name."""
from types import SimpleNamespace

import pytest

from worker.models import parse_material
from worker.overrides import InvalidMaterial, UnknownObject, apply_material_overrides

GREY = {"model": "lambert", "albedo": [0.5, 0.5, 0.5]}
GGX = {"model": "ggx", "alpha": 0.2, "specular": [0.9, 0.8, 0.6], "albedo": [0.1, 0.1, 0.1]}


def _scene():
    objs = [SimpleNamespace(name="chair"), SimpleNamespace(name="floor")]
    return SimpleNamespace(spec=SimpleNamespace(objects=objs), materials=[parse_material(GREY)] * 2)


def test_overrides_replace_by_name_in_order():
    sc = _scene()
    mats = apply_material_overrides(sc, [("floor", GGX), ("floor", lambda: {**GGX, "alpha": 0.4})])
    assert mats[0] == sc.materials[0] and mats[1].model == "ggx" and mats[1].alpha == 0.4
    assert sc.materials[1].model == "lambert"          # the scene's own list is left alone
    again = apply_material_overrides(sc, [("chair", mats[1])], mats)   # a parsed model, on top of others
    assert again[0] is mats[1] and again[1] is mats[1]


def test_a_bad_name_is_named_before_its_material_is_read():
    def never():
        raise AssertionError("read")

    with pytest.raises(UnknownObject) as e:
        apply_material_overrides(_scene(), [("sofa", never)])
    assert e.value.object == "sofa" and "objects: chair, floor" in str(e.value)
    with pytest.raises(InvalidMaterial) as e:
        apply_material_overrides(_scene(), [("chair", {"model": "ggx", "alpha": "rough"})])
    assert e.value.object == "chair" and e.value.reason
