"""GI test fixtures. Tensors are cached content-addressed in tests/.cache/gi (their key covers
geometry, camera, lighting, fixed materials and settings), Mitsuba references in
tests/.cache/gi-mitsuba, so only the first run pays for path tracing."""
import numpy as np
import pytest

from gi_harness import CACHE, gi_renderer, scene_with
from helpers import cache_lock


@pytest.fixture(scope="session")
def sofa_small(shared_assets):
    """GIRenderer of tests/scenes/gi/sofa.json at 48×36, (64,1,1,1), 64 spp."""
    return gi_renderer(scene_with("sofa", 48, 36), {"spp": 64, "series": [64, 1, 1, 1]})


@pytest.fixture(scope="session")
def sofa_all_editable(shared_assets):
    """As sofa_small with the side wall editable too (every surface's albedo is a variable)."""
    from worker.scene import LoadedScene
    sc = scene_with("sofa", 48, 36)
    spec = sc.spec.model_copy(deep=True)
    for o in spec.objects:
        o.editable = True
    return gi_renderer(LoadedScene(spec, sc.root, envmap=sc.envmap), {"spp": 32, "series": [64, 1, 1, 1]})


@pytest.fixture(scope="session")
def sphere_scene(tmp_path_factory):
    """A unit icosphere seen from the front under a constant white environment (L = 1): a convex
    object, so its radiance is the directional albedo ∫f cos dωi at every pixel (closed form)."""
    import trimesh

    from worker.scene import LoadedScene, parse_scene

    d = CACHE / "gi-sphere"
    d.mkdir(parents=True, exist_ok=True)
    obj = d / "sphere.obj"
    with cache_lock(str(obj)):
        if not obj.is_file():
            sph = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
            tmp = obj.with_suffix(".tmp")
            tmp.write_text(trimesh.exchange.obj.export_obj(sph, include_normals=True))
            tmp.replace(obj)

    def make(material: dict, gi: dict, size: int = 40):
        spec = {"version": 1, "renderer": "gi", "environment": {"map": "constant"},
                "camera": {"eye": [0, 0.5, 3.5], "target": [0, 0, 0], "fov_y_deg": 40, "width": size, "height": size},
                "objects": [{"name": "ball", "mesh": "sphere.obj", "material": material}], "gi": gi}
        return LoadedScene(parse_scene(spec), d, envmap=np.ones((32, 64, 3), np.float32))
    return make
