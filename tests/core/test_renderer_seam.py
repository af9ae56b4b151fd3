"""The renderer seam (worker/renderers): each renderer package declares its kind and controls
once (read without importing the renderer), its class declares its optional capabilities
(checked against the methods it has), and a renderer added as one package plus one line in
RENDERER_PACKAGES is drawn by the registry and accepted by the session protocol."""
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from worker import renderers
from worker.renderers import CAPABILITIES, Renderer, implemented_capabilities
from worker.renderers.declaration import RendererDeclaration

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("kind", ["cuts", "gi", "paint"])
def test_a_renderer_declares_exactly_the_capabilities_it_has(kind):
    cls, pre = renderers.get(kind)
    assert cls.capabilities == implemented_capabilities(cls), (
        f"{kind}: declared {sorted(cls.capabilities)}, implemented {sorted(implemented_capabilities(cls))}")
    for c in CAPABILITIES:
        assert cls.can(c) == (c in cls.capabilities)


def test_which_renderer_has_which_capability():
    # what the session runtime and the fitter did with hasattr before: only the cut renderer
    # places movable objects, builds a drag level and caches views; it and the GI renderer
    # answer the fitter, the GI one with an expansion (its image is polynomial in the BRDF),
    # and the GI one freezes the other objects when one is picked
    assert renderers.get("cuts")[0].capabilities == set(CAPABILITIES) - {"polynomial_transfer", "live_object"}
    assert renderers.get("gi")[0].capabilities == {"stroke_fit", "polynomial_transfer", "live_object"}
    assert not renderers.get("paint")[0].capabilities


def test_a_capability_declared_without_its_methods_is_refused():
    with pytest.raises(TypeError, match="place needs place"):
        class NoPlace(Renderer):
            kind = "x"
            capabilities = frozenset({"place"})

            def render(self, req):
                raise NotImplementedError

    with pytest.raises(TypeError, match="stroke_fit needs .*shade_samples"):
        class HalfFit(Renderer):
            kind = "x"
            capabilities = frozenset({"stroke_fit"})

            def render(self, req):
                raise NotImplementedError

            def surface_samples(self, camera, object_index, pixels=None):
                raise NotImplementedError

            def transfer(self, samples, basis, lighting, coarse=False):
                raise NotImplementedError

    with pytest.raises(TypeError, match="unknown capabilities"):
        class Typo(Renderer):
            kind = "x"
            capabilities = frozenset({"plcae"})

            def render(self, req):
                raise NotImplementedError

    with pytest.raises(KeyError, match="unknown renderer capability"):
        renderers.get("cuts")[0].can("plcae")


@pytest.mark.parametrize("kind", ["cuts", "gi", "paint"])
def test_class_kind_and_controls_are_the_declarations(kind):
    decl = renderers.declarations()[kind]
    cls, pre = renderers.get(kind)
    assert (cls.kind, pre.kind, cls.controls) == (decl.kind, decl.kind, decl.controls)
    assert renderers.controls(kind) == decl.controls


def test_reading_the_declarations_imports_no_renderer():
    """The API process checks messages against the controls without the renderers' numerical
    imports (ray tracer, C kernels, solvers)."""
    code = ("import sys; from worker.renderers import controls, kinds; "
            "print(sorted(controls('cuts')), kinds()); "
            "print([m for m in sys.modules if m.startswith(('worker.renderers.cuts.', 'worker.renderers.gi.', "
            "'worker.renderers.paint.', 'worker.native.kernels', 'worker.trace', 'embreex', 'scipy'))])")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert lines[0] == "['camera', 'environment', 'ground', 'light', 'materials', 'move', 'strokes'] ['cuts', 'gi', 'paint']"
    assert lines[1] == "[]", f"imported by reading declarations: {lines[1]}"


def test_a_declaration_with_unknown_controls_is_refused():
    with pytest.raises(ValueError, match="unknown controls"):
        RendererDeclaration(kind="x", controls=frozenset({"camera", "zoom"}), renderer="a:B", precomputation="a:C")


# a renderer written as a package, the way a new one is added (a real one: shaded normals of
# Embree first hits, from a precomputed, content-keyed part of per-vertex normals)
TINY_INIT = '''
"""Test renderer: absolute shading normals."""
from worker.renderers.declaration import RendererDeclaration

DECLARATION = RendererDeclaration(kind="normals", controls=frozenset({"camera", "light"}),
                                  renderer="glint_test_normals.renderer:NormalsRenderer",
                                  precomputation="glint_test_normals.renderer:NormalsPrecomputation",
                                  settings="glint_test_normals.settings:NormalsSettings")
'''
TINY_SETTINGS = '''
from pydantic import BaseModel, ConfigDict, Field


class NormalsSettings(BaseModel):
    """The scene file's "normals" object: a gain on the drawn normals."""
    model_config = ConfigDict(extra="forbid")
    gain: float = Field(1.0, gt=0.0, le=1.0)
'''
TINY_RENDERER = '''
import hashlib

import numpy as np

from worker.core.render import camera_rays
from worker.renderers.base import Part, Precomputation, Rendered, Renderer
from worker.trace.embree import Tracer

from . import DECLARATION


class NormalsPrecomputation(Precomputation):
    kind = DECLARATION.kind

    def parts(self, scene, options):
        n = np.ascontiguousarray(scene.mesh.normals, np.float32)
        return [Part(hashlib.sha256(n.tobytes()).hexdigest()[:32], "vertex normals", meta={"n": len(n)})]

    def compute(self, scene, part, options, chunk=None, progress=None, threads=2):
        return np.ascontiguousarray(scene.mesh.normals, np.float32).tobytes()

    def load(self, scene, blobs, options):
        return np.frombuffer(next(iter(blobs.values())), np.float32).reshape(-1, 3)


class NormalsRenderer(Renderer):
    kind = DECLARATION.kind
    controls = DECLARATION.controls

    def render(self, req):
        c = req.camera
        o, d = camera_rays(c.eye, c.target, c.up, c.fov_y_deg, c.width, c.height)
        m = self.scene.mesh
        tri, uv, _ = Tracer(m.vertices, m.faces).first_hit(o, d)
        hit = tri >= 0
        f = m.faces[tri[hit]]
        u, v = uv[hit, 0:1], uv[hit, 1:2]
        n = (1 - u - v) * self.data[f[:, 0]] + u * self.data[f[:, 1]] + v * self.data[f[:, 2]]
        img = np.zeros((len(tri), 3), np.float32)
        settings = self.scene.spec.normals
        img[hit] = np.abs(n) * (settings.gain if settings is not None else 1.0)
        oid = np.where(hit, self.scene.object_of_face[np.maximum(tri, 0)], -1).astype(np.int32)
        return Rendered(img.reshape(c.height, c.width, 3), oid.reshape(c.height, c.width))
'''


@pytest.fixture
def normals_renderer(tmp_path, monkeypatch):
    pkg = tmp_path / "glint_test_normals"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(textwrap.dedent(TINY_INIT))
    (pkg / "renderer.py").write_text(textwrap.dedent(TINY_RENDERER))
    (pkg / "settings.py").write_text(textwrap.dedent(TINY_SETTINGS))
    monkeypatch.syspath_prepend(str(tmp_path))
    # the one registration line
    monkeypatch.setattr(renderers, "RENDERER_PACKAGES", renderers.RENDERER_PACKAGES + ["glint_test_normals"])
    yield "normals"
    for m in [m for m in sys.modules if m.startswith("glint_test_normals")]:
        del sys.modules[m]
    renderers._registry.pop("normals", None)


def _spec(kind: str) -> dict:
    spec = json.loads((ROOT / "tests" / "scenes" / "bunny.json").read_text())
    spec["environment"]["map"] = str((ROOT / "tests" / "scenes" / spec["environment"]["map"]).resolve())
    spec["objects"][0]["mesh"] = str((ROOT / "tests" / "scenes" / spec["objects"][0]["mesh"]).resolve())
    spec["renderer"] = kind
    return spec


def test_a_new_renderer_is_one_package_and_one_line(normals_renderer, tmp_path):
    from server.routes.sessions import _controls
    from worker.artifacts import DirStore
    from worker.protocol import StateError, apply, client_msg, new_state
    from worker.renderers import FrameRequest
    from worker.scene import load_scene

    kind = normals_renderer
    assert kind in renderers.kinds() and renderers.controls(kind) == {"camera", "light"}
    # the server's hello and the protocol's checks use the declared controls
    assert _controls(kind, readonly=False) == {"camera", "light"}
    st = new_state(_spec(kind))
    st, _ = apply(st, client_msg.validate_python({"seq": 1, "type": "view", "eye": [0.0, 0.8, 3.0]}))
    st, _ = apply(st, client_msg.validate_python({"seq": 2, "type": "light", "rotation_deg": 30.0}))
    assert tuple(st.camera.eye) == (0.0, 0.8, 3.0) and st.rotation_deg == 30.0
    with pytest.raises(StateError, match="the normals renderer's lighting is fixed"):
        apply(st, client_msg.validate_python({"seq": 3, "type": "environment", "index": 0}))

    # the registry builds it from the declaration, and it draws a real scene
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(_spec(kind)))
    scene = load_scene(path)
    r, stats = renderers.prepare(scene, DirStore(tmp_path / "parts", kind))
    assert type(r).__name__ == "NormalsRenderer" and stats["computed"] == 1
    out = r.render(FrameRequest(scene.spec.camera))
    hit = out.object_id >= 0
    assert 0.05 < hit.mean() < 0.9, hit.mean()
    # interpolated unit vertex normals: at most 1 long, about 1 away from sharp creases
    n = np.linalg.norm(out.radiance[hit], axis=-1)
    assert n.max() <= 1.0 + 1e-4 and np.median(n) > 0.95 and not out.radiance[~hit].any(), (n.max(), np.median(n))

    # its scene-file settings are registered with it: validated with the scene file under its
    # kind, and read by the renderer
    path.write_text(json.dumps({**_spec(kind), "normals": {"gain": 0.5}}))
    scene = load_scene(path)
    r, _ = renderers.prepare(scene, DirStore(tmp_path / "parts", kind))
    n = np.linalg.norm(r.render(FrameRequest(scene.spec.camera)).radiance[hit], axis=-1)
    assert 0.47 < np.median(n) and n.max() <= 0.5 + 1e-4, (np.median(n), n.max())
    from worker.scene import SceneError, parse_scene
    with pytest.raises(SceneError, match="normals.gian"):
        parse_scene({**_spec(kind), "normals": {"gian": 0.5}})


def test_an_unregistered_renderer_is_refused():
    from worker.scene import SceneFile

    assert renderers.controls("normals") == frozenset()
    with pytest.raises(ValueError, match="unknown renderer 'normals'"):
        SceneFile.model_validate(_spec("normals"))
    # nor are the settings of a renderer that is not registered
    with pytest.raises(ValueError, match="normals"):
        SceneFile.model_validate({**_spec("cuts"), "normals": {"gain": 0.5}})


def test_the_built_in_scene_model_stays_the_module_s(normals_renderer, monkeypatch):
    """A scene model built for another list of renderers does not replace the built-in one:
    worker processes and Ray pickle scene files by the module's name ``SceneFile``."""
    import pickle

    from worker.scene import SceneFile, parse_scene, scene_model

    assert "normals" in scene_model().model_fields and scene_model() is not SceneFile
    monkeypatch.undo()                           # the one registration line taken back
    assert scene_model() is SceneFile
    spec = parse_scene(_spec("cuts"))
    assert pickle.loads(pickle.dumps(spec)) == spec
