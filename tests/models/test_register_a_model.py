"""A BRDF model registered from this file, without editing the package: it validates
in scene files and stream messages, is listed for the studio, and renders through the NumPy
reference (it has no C kernel branch), beside a model that has one."""
from typing import ClassVar, Literal

import numpy as np
import pytest
from pydantic import Field

from worker.models import BRDFModel, Color, Geometry, models, register, unregister
from worker.renderers import FrameRequest


class IsotropicWard(BRDFModel):
    """albedo/π + specular·exp(−tan²θh/α²)/(4πα² √(cosθi cosθo)) (Ward 1992, isotropic)."""
    label: ClassVar[str] = "Ward (test)"
    controls: ClassVar[tuple] = ({"name": "alpha", "kind": "range", "min": 0.05, "max": 0.5, "step": 0.01},)
    model: Literal["ward-test"] = "ward-test"
    alpha: float = Field(0.2, gt=0.0)
    specular: Color = (0.3, 0.3, 0.3)
    albedo: Color = (0.4, 0.4, 0.4)

    def specular_part(self, g: Geometry) -> np.ndarray:
        ch2 = np.clip(g.ch, 1e-6, 1.0) ** 2
        tan2 = (1 - ch2) / ch2
        s = np.exp(-tan2 / self.alpha ** 2) / (4 * np.pi * self.alpha ** 2 * np.sqrt(np.maximum(g.ci * g.co, 1e-12)))
        return s[..., None] * np.asarray(self.specular)

    def lobe_width(self) -> float:
        return 4 * self.alpha


@pytest.fixture
def ward():
    register(IsotropicWard)
    yield IsotropicWard
    unregister("ward-test")


def test_a_model_registered_from_a_test_renders(ward, bunny_renderer):
    from worker.protocol import client_msg
    from worker.models import describe
    from worker.scene import parse_scene

    spec = bunny_renderer.scene.spec.model_dump(mode="json")
    spec["objects"][0]["material"] = {"model": "ward-test", "alpha": 0.15, "specular": [0.5, 0.4, 0.3]}
    parsed = parse_scene(spec)                                   # scene files know it
    m = parsed.objects[0].material
    assert isinstance(m, IsotropicWard) and m.alpha == 0.15
    assert client_msg.validate_python({"seq": 1, "type": "material", "material": m.model_dump()}).material == m
    assert any(d["model"] == "ward-test" and d["kernel"] is None for d in describe())   # the studio lists it
    assert "ward-test" in models()
    r = bunny_renderer
    out = r.render(FrameRequest(camera=r.scene.spec.camera, materials=[m]))       # native backend: NumPy for it
    from helpers import open_renderer
    ref = open_renderer(r.scene, "numpy").render(FrameRequest(camera=r.scene.spec.camera, materials=[m]))
    obj = out.object_id >= 0
    assert out.radiance[obj].mean() > 0.01
    np.testing.assert_allclose(out.radiance, ref.radiance, rtol=1e-4, atol=1e-5)
    # it has a highlight: brighter than its own diffuse part somewhere
    lam = r.render(FrameRequest(camera=r.scene.spec.camera,
                                materials=[m.model_copy(update={"specular": (0.0, 0.0, 0.0)})]))
    assert (out.radiance[obj] - lam.radiance[obj]).max() > 0.05
