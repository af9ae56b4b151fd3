"""The ``paint`` renderer behind the seam (worker/renderers): precomputed parts, frames on real
meshes, self-shadowing from the cut renderer's visibility, environment switching, the CLI."""
import json

import numpy as np
import pytest

from worker.artifacts import DirStore
from worker.renderers import FrameRequest, Lighting, ensure, get, load
from worker.scene import load_scene

def _scene(tmp_path, assets, mesh, env="sunset.exr", material=None, camera=None, name="obj"):
    spec = {"version": 1,
            "environment": {"map": str(assets / "env" / env), "rotation_deg": 0.0, "intensity": 1.0},
            "camera": camera or {"eye": [0, 0.1, 2.6], "target": [0, 0.05, 0], "fov_y_deg": 35, "width": 96, "height": 72},
            "objects": [{"name": name, "mesh": str(mesh),
                         "material": material or {"model": "ggx", "alpha": 0.1, "specular": [0.04] * 3,
                                                  "albedo": [0.3, 0.05, 0.05]}}]}
    p = tmp_path / "scene.json"
    p.write_text(json.dumps(spec))
    return load_scene(p)


@pytest.fixture(scope="module")
def sphere_mesh(tmp_path_factory):
    import trimesh
    p = tmp_path_factory.mktemp("mesh") / "sphere.ply"
    m = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    m.export(p)
    return p


def _renderer(scene, tmp_path, cache, **opts):
    cls, pre = get("paint")
    store = DirStore(tmp_path / "parts", "paint")
    opts = {"cuts_dir": str(cache / "cuts"), **opts}
    st = ensure(pre, scene, store, opts)
    return cls(scene, load(pre, scene, store, opts)), st, pre, store, opts


@pytest.fixture(scope="session")
def cache():
    from pathlib import Path
    c = Path(__file__).resolve().parents[1] / ".cache"
    c.mkdir(parents=True, exist_ok=True)
    return c


def test_registered_and_parts_are_content_keyed(tmp_path, assets, sphere_mesh, cache):
    scene = _scene(tmp_path, assets, sphere_mesh)
    r, st, pre, store, opts = _renderer(scene, tmp_path, cache)
    assert r.kind == "paint" and st["computed"] == 1
    assert ensure(pre, scene, store, opts)["computed"] == 0          # cached by content key
    other = _scene(tmp_path, assets, sphere_mesh, env="city.exr")
    assert pre.parts(other, opts)[0].key != pre.parts(scene, opts)[0].key
    out = r.render(FrameRequest(scene.spec.camera, Lighting(), scene.materials))
    assert out.radiance.shape == (72, 96, 3) and np.isfinite(out.radiance).all() and out.radiance.min() >= 0
    assert (out.object_id == 0).sum() > 500 and (out.object_id == -1).sum() > 500
    # a GGX material is converted the designer's way (measured and fitted onto the basis)
    assert out.info["exponents"] == list(r.exponents)


def test_convex_object_is_unshadowed_and_bunny_is_self_shadowed(tmp_path, assets, sphere_mesh, cache):
    scene = _scene(tmp_path, assets, sphere_mesh)
    r, *_ = _renderer(scene, tmp_path, cache, visibility=True)
    req = FrameRequest(scene.spec.camera, Lighting(), scene.materials)
    r.visibility = True
    a = r.render(req).radiance
    r.visibility = False
    b = r.render(req).radiance
    m = scene.spec.camera
    obj = r.object_mask(m) >= 0
    rel = np.sqrt(np.mean((a[obj] - b[obj]) ** 2)) / np.sqrt(np.mean(b[obj] ** 2))
    assert rel < 0.03, f"an unoccluded convex object must not shadow itself: {rel:.4f}"
    (tmp_path / "b").mkdir(exist_ok=True)
    bunny = _scene(tmp_path / "b", assets, assets / "meshes" / "bunny.ply",
                   camera={"eye": [0, 0.2, 2.2], "target": [0, 0, 0], "fov_y_deg": 35, "width": 96, "height": 72})
    rb, *_ = _renderer(bunny, tmp_path / "b", cache, visibility=True)
    req = FrameRequest(bunny.spec.camera, Lighting(), bunny.materials)
    a = rb.render(req).radiance
    rb.visibility = False
    b = rb.render(req).radiance
    obj = rb.object_mask(bunny.spec.camera) >= 0
    ratio = a[obj].sum(1) / np.maximum(b[obj].sum(1), 1e-9)
    assert ratio.max() <= 1.0 + 1e-5
    assert np.mean(ratio < 0.8) > 0.03, "the bunny's concave parts must darken"


def test_environment_switch_and_materials(tmp_path, assets, sphere_mesh, cache):
    scene = _scene(tmp_path, assets, sphere_mesh)
    r, *_ = _renderer(scene, tmp_path, cache)
    from worker.envmap import load_envmap
    req = FrameRequest(scene.spec.camera, Lighting(rotation_deg=30.0, intensity=0.5), scene.materials)
    a = r.render(req).radiance
    secs = r.set_environment(load_envmap(assets / "env" / "forest.exr"))
    b = r.render(req).radiance
    assert secs > 0 and not np.allclose(a, b)
    # intensity is linear
    req2 = FrameRequest(scene.spec.camera, Lighting(rotation_deg=30.0, intensity=1.0), scene.materials)
    assert np.allclose(r.render(req2).radiance, 2 * b, rtol=1e-4, atol=1e-6)


def test_cli_render_and_bench(tmp_path, assets, sphere_mesh, capsys):
    from worker.cli import main
    _scene(tmp_path, assets, sphere_mesh)
    sp = tmp_path / "scene.json"
    mat = tmp_path / "m.json"
    mat.write_text(json.dumps({"model": "lambert", "albedo": [0.8, 0.8, 0.8]}))
    png, raw = tmp_path / "o.png", tmp_path / "o.npy"
    assert main(["paint", "render", str(sp), "--out", str(png), "--raw", str(raw), "--material", f"obj={mat}",
                 "--store", str(tmp_path / "st"), "--fresnel"]) == 0
    img = np.load(raw)
    assert png.is_file() and img.shape == (72, 96, 3)
    capsys.readouterr()
    # the benchmark is the benchmark package's (bench/paint.py), in the composed glint command
    from glint.cli import main as glint_main
    assert glint_main(["paint", "bench", str(sp), "--frames", "3", "--json", "--store", str(tmp_path / "st")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert {"ms_prefilter", "ms_per_frame", "fps", "ms_fit", "ms_shade"} <= set(res)
    assert main(["paint", "exponents", "--lobes", "3", "--json"]) == 0
    ex = json.loads(capsys.readouterr().out)
    assert ex["selected"]["lobes"] == 3 and len(ex["selected"]["exponents"]) == 3
    assert [r["lobes"] for r in ex["table"]] == [1, 2, 3]
    assert main(["paint", "render", str(sp), "--out", str(png), "--material", "nope=x.json",
                 "--store", str(tmp_path / "st")]) == 2


def test_painted_regions_are_drawn(tmp_path, assets, sphere_mesh, cache):
    """A regions material on the sphere (a second paint over its upper half): pixels whose face
    lies wholly in the region are the frame of the region's paint alone, pixels wholly outside
    are the base's, and the soft band between blends the two (a renderer drawing the base alone
    fails the first)."""
    from worker.models import Lobes, Region, Regions

    scene = _scene(tmp_path, assets, sphere_mesh)
    r, *_ = _renderer(scene, tmp_path, cache)
    ex = list(r.exponents)
    base = Lobes(exponents=ex, albedo=(0.3, 0.05, 0.05), gloss=[0.0] * (len(ex) - 1) + [0.04],
                 directional_diffuse=[(0.0, 0.0, 0.0)] * len(ex))
    top = Lobes(exponents=ex, albedo=(0.05, 0.1, 0.4), gloss=[0.0] * (len(ex) - 1) + [0.04],
                directional_diffuse=[(0.0, 0.0, 0.0)] * (len(ex) - 2) + [(0.2, 0.3, 0.5), (0.0, 0.0, 0.0)])
    y = scene.mesh.vertices[:, 1]
    up = np.nonzero(y > 0.05)[0]
    regions = Regions(base=base, vertex_count=len(y), regions=[Region(name="top", material=top,
                                                                        vertices=up.tolist(), weights=[1.0] * len(up))])
    cam, light = scene.spec.camera, Lighting(rotation_deg=20.0, intensity=1.0)
    got = r.render(FrameRequest(cam, light, [regions])).radiance.reshape(-1, 3)
    a = r.render(FrameRequest(cam, light, [base])).radiance.reshape(-1, 3)
    b = r.render(FrameRequest(cam, light, [top])).radiance.reshape(-1, 3)
    v = r.view(cam)
    inside = (y[v.corners] > 0.05).all(1)
    outside = (y[v.corners] <= 0.05).all(1)
    px_in, px_out = v.hit[inside], v.hit[outside]
    assert len(px_in) > 500 and len(px_out) > 500, (len(px_in), len(px_out))
    assert np.allclose(got[px_in], b[px_in], rtol=1e-5, atol=1e-7)
    assert np.allclose(got[px_out], a[px_out], rtol=1e-5, atol=1e-7)
    assert np.abs(a[px_in] - b[px_in]).mean() > 0.2 * np.abs(b[px_in]).mean()       # the two paints differ
    band = v.hit[~inside & ~outside]
    lo, hi = np.minimum(a[band], b[band]), np.maximum(a[band], b[band])
    assert ((got[band] >= lo - 1e-6) & (got[band] <= hi + 1e-6)).all()
