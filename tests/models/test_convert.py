"""Converting a material to another model keeps its look (worker/models/convert.py): the mean
colour of the object stays within a few percent (directional albedo, and measured in rendered
frames), the lobe's width is fitted, and the conversion of a model to itself is the identity."""
import numpy as np
import pytest

from worker.models import SRBF, parse_material
from worker.models.convert import TARGETS, ConvertError, convert
from worker.renderers import FrameRequest

SOURCES = {
    "grey plastic": {"model": "ggx", "alpha": 0.3, "specular": [0.04] * 3, "albedo": [0.5, 0.5, 0.5]},
    "leather brown": {"model": "ggx", "alpha": 0.45, "specular": [0.05] * 3, "albedo": [0.35, 0.16, 0.07]},
    "glossy red": {"model": "blinn-phong", "exponent": 200, "specular": [0.3] * 3, "albedo": [0.5, 0.05, 0.05]},
    "brushed metal": {"model": "ashikhmin-shirley", "exponent_u": 100, "exponent_v": 400,
                      "specular": [0.5, 0.4, 0.3], "albedo": [0.2, 0.2, 0.2]},
}
ALBEDO_TOL = 0.03            # the fit alone: relative change of the mean directional albedo, per channel
FRAME_TOL = 0.06             # the fit alone, in a frame under the sunset map: a diffuse-dominated material
MEASURED_TOL = 0.01          # measured in the session's view: that view's mean colour


def _mean_colour(r, material, camera=None):
    # the test's measure, interpolated: a conversion keeps the colour of whatever measure it is
    # given (the session's is its refined frame at 200 px), and refined frames of every
    # model pair cost this test 35-50 s
    out = r.render(FrameRequest(camera=camera or r.scene.spec.camera, materials=[material], samples=1,
                                shading="vertex"))
    return out.radiance[out.object_id == 0].mean(axis=0).astype(np.float64)


def _pairs(sources):
    for name in sources:
        old = parse_material(SOURCES[name]) if name in SOURCES else SRBF.examples()[0]
        for model in TARGETS:
            if model != old.model:
                yield name, old, model


def test_the_fit_keeps_the_directional_albedo():
    """Under a smooth light the mean colour is the directional albedo: every conversion keeps it."""
    for name, old, model in _pairs([*SOURCES, "srbf"]):
        c = convert(old, model)
        assert c.material.model == model
        assert c.albedo_error < ALBEDO_TOL, (name, model, c.albedo_error, c.material.model_dump())


def test_the_fit_keeps_a_diffuse_materials_colour_in_a_frame(bunny_renderer):
    """Measured in a rendered frame (the bunny under the sunset map): the mean object colour of
    a plastic and a leather after any conversion, without a measured correction."""
    for name, old, model in _pairs(["grey plastic", "leather brown"]):
        ref = _mean_colour(bunny_renderer, old)
        got = _mean_colour(bunny_renderer, convert(old, model).material)
        rel = np.abs(got - ref) / ref
        assert rel.max() < FRAME_TOL, (name, model, rel.round(4).tolist())


def test_a_measured_conversion_keeps_the_views_mean_colour(bunny_renderer):
    """With the renderer's measure (what the session does: its view and light), the mean colour
    in that view is kept for every material, however different its lobe; in another view a
    diffuse-dominated one stays close too (held out: the correction did not see it)."""
    from worker.scene import Camera

    r = bunny_renderer
    other = Camera.model_validate({**r.scene.spec.camera.model_dump(), "eye": [2.4, 1.2, 2.0]})
    for name, old, model in _pairs([*SOURCES, "srbf"]):
        c = convert(old, model, measure=lambda m: _mean_colour(r, m))
        ref, got = _mean_colour(r, old), _mean_colour(r, c.material)
        assert (np.abs(got - ref) / ref).max() < MEASURED_TOL, (name, model, got, ref)
        if name in ("grey plastic", "leather brown"):
            ref, got = _mean_colour(r, old, other), _mean_colour(r, c.material, other)
            assert (np.abs(got - ref) / ref).max() < FRAME_TOL, (name, model, got, ref)


def test_conversion_fits_the_lobe_not_only_the_colour():
    """A glossy plastic converted to Blinn-Phong keeps a lobe of about its width: a sharp GGX
    gives a high exponent, a rough one a low exponent (the shape is fitted, not defaulted)."""
    sharp = convert(parse_material({"model": "ggx", "alpha": 0.1, "specular": [0.5] * 3, "albedo": [0.2] * 3}),
                    "blinn-phong").material
    rough = convert(parse_material({"model": "ggx", "alpha": 0.5, "specular": [0.5] * 3, "albedo": [0.2] * 3}),
                    "blinn-phong").material
    assert sharp.exponent > 2 * rough.exponent, (sharp.exponent, rough.exponent)
    assert max(sharp.specular) > 0.1, sharp


def test_a_fitted_srbf_converts_and_the_same_model_is_the_identity():
    ex = SRBF.examples()[0]
    c = convert(ex, "ggx")
    assert c.material.model == "ggx" and c.albedo_error < ALBEDO_TOL, c
    m = parse_material(SOURCES["grey plastic"])
    assert convert(m, "ggx").material is m
    with pytest.raises(ConvertError):
        convert(m, "srbf")
