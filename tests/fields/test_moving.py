"""The cut renderer with movable objects (moving.py): what it precomputes, that moving needs
nothing new, and that its frames after a move agree with a static precomputation of the moved
scene as well as unmoved frames do; the drag level of detail; errors.

References: ``reference_frame`` renders a configuration with the unchanged static path
(CutRenderer over cuts traced through the whole scene as it stands), for the vertices the
camera sees; the object mask comes from tracing the placed meshes directly."""
import json

import numpy as np
import pytest
from fields_kit import reference_cuts
from helpers import CACHE, open_renderer

from worker.core.cuts import CutSet
from worker.core.directions import get_tree
from worker.core.render import camera_rays
from worker.renderers import FrameRequest, Lighting, Unsupported
from worker.renderers.cuts import CutData, CutRenderer
from worker.renderers.cuts.fields import MoveError
from worker.renderers.cuts.moving import SNAP_DEG
from worker.scene import LoadedScene, Transform
from worker.trace.embree import Tracer


def placed(scene, name, transform) -> LoadedScene:
    """The scene with one object at another transform (its meshes loaded there)."""
    spec = scene.spec.model_copy(deep=True)
    spec.objects[[o.name for o in spec.objects].index(name)].transform = transform
    return LoadedScene(spec, scene.root, envmap=scene.envmap)


def hits(scene, camera):
    o, d = camera_rays(camera.eye, camera.target, camera.up, camera.fov_y_deg, camera.width, camera.height)
    tri, uv, _ = Tracer(scene.mesh.vertices, scene.mesh.faces).first_hit(o, d)
    return tri, uv


def reference_frame(scene, camera, lighting, materials=None):
    """(radiance (H, W, 3), object ids (H, W)) of the static cut renderer over cuts traced
    through the whole scene for the vertices the camera sees (others get an empty cut), with
    the scene's materials or ``materials``."""
    tri, _ = hits(scene, camera)
    vis = np.unique(scene.mesh.faces[tri[tri >= 0]])
    cs = reference_cuts(scene.mesh, vis)
    H = get_tree().height
    V = len(scene.mesh.vertices)
    sizes = np.ones(V, np.int64)
    sizes[vis] = cs.sizes()
    off = np.zeros(V + 1, np.int64)
    np.cumsum(sizes, out=off[1:])
    h = np.full(off[-1], H, np.uint8)
    q = np.zeros(off[-1], np.uint8)
    for k, v in enumerate(vis):
        a, b = cs.offsets[k], cs.offsets[k + 1]
        h[off[v]:off[v + 1]] = cs.heights[a:b]
        q[off[v]:off[v + 1]] = cs.quant[a:b]
    r = CutRenderer(scene, CutData(CutSet(off, h, q, H)))
    out = r.render(FrameRequest(camera=camera, lighting=lighting, materials=materials or scene.materials))
    return out.radiance, out.object_id


def rel_rmse(a, b, mask=None):
    d = (a - b).mean(-1) if mask is None else (a - b).mean(-1)[mask]
    ref = b.mean(-1) if mask is None else b.mean(-1)[mask]
    return float(np.sqrt((d ** 2).mean()) / ref.mean())


@pytest.fixture(scope="module")
def room_scene(room):
    return room.load()


@pytest.fixture(scope="module")
def room_renderer(room_scene):
    return open_renderer(room_scene)


MOVED = {"rotate_deg": (0, -70, 0), "translate": (-60.0, None, 75.0)}


def moved_transform(scene, name="bunny"):
    t = scene.spec.objects[[o.name for o in scene.spec.objects].index(name)].transform
    return Transform(scale=t.scale, rotate_deg=MOVED["rotate_deg"],
                     translate=(MOVED["translate"][0], t.translate[1], MOVED["translate"][2]))


# --- precomputation ------------------------------------------------------------------------------

def test_parts_are_keyed_by_geometry_that_never_moves(crate):
    from worker.renderers import get
    from worker.renderers.cuts.precompute import geometry_key

    _, pre = get("cuts")
    scene = crate.load()
    parts = pre.parts(scene, {"tau": 1.0})
    kinds = sorted((p.meta["kind"], p.meta.get("object")) for p in parts)
    assert kinds == [("field", 0), ("field", 1), ("self_cuts", 1), ("static_cuts", None)]
    moved = crate.load("moved", lambda s: s["objects"][1].update(transform={"rotate_deg": [0, 33, 0],
                                                                             "translate": [45, 15, -20]}))
    assert [p.key for p in pre.parts(moved, {"tau": 1.0})] == [p.key for p in parts]
    # the static cuts are those of a scene of the static objects alone (same key, same bytes)
    alone = crate.load("floor-alone", lambda s: s.update(objects=s["objects"][:1]))
    (whole,) = pre.parts(alone, {"tau": 1.0})
    assert whole.key == next(p.key for p in parts if p.meta["kind"] == "static_cuts")
    m = alone.mesh
    assert whole.key == geometry_key(m.vertices, m.faces, m.normals, 1.0, get_tree().height)
    # the scene file's field grid is part of the fields' keys; another grid, other fields
    finer = crate.load("finer", lambda s: s["cuts"]["field_grid"].update(shells=5))
    assert {p.key for p in pre.parts(finer, {"tau": 1.0}) if p.meta["kind"] == "field"}.isdisjoint(
        {p.key for p in parts if p.meta["kind"] == "field"})


def test_glint_render_of_an_edited_scene_precomputes_nothing(crate, tmp_path, capsys):
    from worker import cli

    first = crate.write("crate")
    assert cli.main(["precompute", str(first), "--out", str(CACHE), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {p["kind"] for p in out["parts"]} == {"static_cuts", "self_cuts", "field"}
    edited = crate.write("crate-edited", lambda s: s["objects"][1].update(
        transform={"rotate_deg": [0, 40, 0], "translate": [30, 15, 25]}))
    assert cli.main(["render", str(edited), "--cuts", str(CACHE), "--out", str(tmp_path / "m.png"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["precomputed_parts"] == 0 and all(p["cached"] for p in out["parts"]), out
    assert (tmp_path / "m.png").is_file()


def test_scenes_without_movable_objects_are_unchanged(crate):
    from worker.renderers import get
    from worker.renderers.cuts.precompute import geometry_key

    _, pre = get("cuts")
    scene = crate.load("fixed", lambda s: s["objects"][1].update(movable=False))
    (part,) = pre.parts(scene, {"tau": 1.0})
    m = scene.mesh
    assert part.label == "visibility cuts" and part.key == geometry_key(m.vertices, m.faces, m.normals, 1.0, 15)
    r = open_renderer(scene)
    assert r.data.moving is None
    cam = scene.spec.camera
    same = {"box": scene.spec.objects[1].transform}
    a = r.render(FrameRequest(camera=cam, materials=scene.materials, transforms=same)).radiance
    b = r.render(FrameRequest(camera=cam, materials=scene.materials)).radiance
    assert np.array_equal(a, b)
    with pytest.raises(Unsupported, match="no movable objects"):
        r.render(FrameRequest(camera=cam, materials=scene.materials,
                              transforms={"box": Transform(translate=(0, 15, 30))}))


# --- frames ---------------------------------------------------------------------------------------

def test_moved_objects_are_drawn_where_they_stand(room_scene, room_renderer):
    """The object mask of frames with the bunny moved and turned equals tracing the placed meshes."""
    cam = room_scene.spec.camera
    for tr in (room_scene.spec.objects[2].transform, moved_transform(room_scene),
               Transform(scale=40.0, rotate_deg=(0, 200, 0), translate=(60.0, 80.0, -30.0))):   # lifted too
        out = room_renderer.render(FrameRequest(camera=cam, materials=room_scene.materials, transforms={"bunny": tr}))
        sc = placed(room_scene, "bunny", tr)
        tri, _ = hits(sc, cam)
        ref = np.where(tri >= 0, sc.object_of_face[np.maximum(tri, 0)], -1).reshape(cam.height, cam.width)
        agree = (out.object_id == ref).mean()
        assert agree > 0.998, (tr, agree)
        assert (ref == 2).sum() > 200


def test_frames_after_a_move_agree_with_precomputing_the_moved_scene(room_scene, room_renderer):
    """Relative RMSE over the image against the static renderer of the configuration (cuts
    traced through the whole scene), unmoved and moved: the move costs little accuracy."""
    cam = room_scene.spec.camera
    light = Lighting(room_scene.spec.environment.rotation_deg, 1.0)
    errs = {}
    for name, tr in (("unmoved", room_scene.spec.objects[2].transform), ("moved", moved_transform(room_scene))):
        out = room_renderer.render(FrameRequest(camera=cam, lighting=light, materials=room_scene.materials,
                                                transforms={"bunny": tr}))
        ref, ids = reference_frame(placed(room_scene, "bunny", tr), cam, light)
        obj = ids >= 0
        errs[name] = (rel_rmse(out.radiance, ref, obj), rel_rmse(out.radiance, ref, ids == 2),
                      out.info["moving"]["affected_static"])
    msg = {k: f"objects {v[0]:.4f}, bunny {v[1]:.4f}, affected static vertices {v[2]}" for k, v in errs.items()}
    print(msg)
    # the tests' coarse fields (8 × 8²): measured 0.037 / 0.046 (unmoved), 0.036 / 0.013 (moved)
    assert errs["unmoved"][0] < 0.08 and errs["moved"][0] < 0.08, msg
    assert errs["moved"][0] < 1.3 * errs["unmoved"][0] + 0.005, msg
    assert errs["moved"][1] < 0.08, msg


def _half_region(scene, index: int, axis: int, albedo):
    """A regions material on object ``index``: its own material, and a Lambert of ``albedo``
    over the vertices beyond the object's median along ``axis`` (weight 1)."""
    from worker.models import Lambert, Region, Regions

    ids = np.nonzero(scene.object_of_vertex == index)[0]
    y = scene.mesh.vertices[ids, axis]
    up = np.nonzero(y > np.median(y))[0]
    return Regions(base=scene.materials[index], vertex_count=len(ids),
                   regions=[Region(name="top", material=Lambert(albedo=albedo), vertices=up.tolist(),
                                   weights=[1.0] * len(up))])


def test_painted_regions_are_drawn_on_moved_and_static_objects(room_scene, room_renderer):
    """A region painted on the movable bunny and one on the static floor: the moved frame draws
    both as the static renderer draws them over the configuration precomputed, and differs from
    the frame of the base materials (a renderer drawing the bases alone fails both)."""
    cam = room_scene.spec.camera
    light = Lighting(room_scene.spec.environment.rotation_deg, 1.0)
    tr = moved_transform(room_scene)
    mats = list(room_scene.materials)
    mats[0] = _half_region(room_scene, 0, 0, (0.1, 0.2, 0.9))       # the floor's right half
    mats[2] = _half_region(room_scene, 2, 1, (0.9, 0.15, 0.1))       # the bunny's top
    out = room_renderer.render(FrameRequest(camera=cam, lighting=light, materials=mats, transforms={"bunny": tr}))
    base = room_renderer.render(FrameRequest(camera=cam, lighting=light, materials=room_scene.materials,
                                             transforms={"bunny": tr}))
    ref, ids = reference_frame(placed(room_scene, "bunny", tr), cam, light, mats)
    err = rel_rmse(out.radiance, ref, ids >= 0)
    err_bunny = rel_rmse(out.radiance, ref, ids == 2)
    changed = {o: rel_rmse(out.radiance, base.radiance, ids == o) for o in (0, 2)}
    print(f"regions: against the reference {err:.4f} (bunny {err_bunny:.4f}); changed from the bases {changed}")
    # measured: 0.046 / 0.013 over the objects / the bunny (0.036 / 0.013 without regions); the
    # regions change the floor by 0.17 (half of it, blue) and the bunny by 0.48 (its top, red)
    assert err < 0.08 and err_bunny < 0.08, (err, err_bunny)
    assert changed[0] > 0.08 and changed[2] > 0.3, changed


def test_drag_level_of_detail(room_scene, room_renderer):
    """Half resolution, coarse cuts, h_min 5, the yaw snapped for the fields: close to the full
    frame, and a turn within one snap step re-uses every rotated sample."""
    cam = room_scene.spec.camera.model_copy(update={"width": 320, "height": 240})   # drag halves from 320 up
    t0 = moved_transform(room_scene)
    req = {"camera": cam, "materials": room_scene.materials}
    full = room_renderer.render(FrameRequest(**req, transforms={"bunny": t0})).radiance
    drag = room_renderer.render(FrameRequest(**req, lod="drag", transforms={"bunny": t0}))
    assert drag.radiance.shape == (cam.height // 2, cam.width // 2, 3) and drag.info["hmin"] == 5
    small = full.reshape(cam.height // 2, 2, cam.width // 2, 2, 3).mean((1, 3))
    e = rel_rmse(drag.radiance, small)
    assert e < 0.12, e                                          # measured 0.05 (edges: half resolution)
    yaw = t0.rotate_deg[1]
    step = SNAP_DEG * np.round(yaw / SNAP_DEG)                  # the yaw the fields use while dragging
    for y in (step - 0.3 * SNAP_DEG, step + 0.3 * SNAP_DEG):
        t = Transform(scale=t0.scale, rotate_deg=(0, y, 0), translate=t0.translate)
        out = room_renderer.render(FrameRequest(**req, lod="drag", transforms={"bunny": t}))
    # only vertices newly in view need samples (measured 2 against 600 for the first drag frame)
    first = drag.info["moving"]["samples_rotated"]
    assert first > 100 and out.info["moving"]["samples_rotated"] < 0.05 * first, (first, out.info["moving"])


def test_the_static_receivers_thread_draws_what_the_frames_own_thread_draws(room_scene, room_renderer):
    """At full quality the static receivers are combined and shaded on a second thread beside
    the moved object's vertices: the frame is bit for bit the one computed on the frame's own
    thread, frame after frame (each part keeps its own rotated samples and cells), and the
    second thread did the work."""
    import threading
    from concurrent.futures import Future

    mf = room_renderer._moving
    cam = room_scene.spec.camera.model_copy(update={"width": 160, "height": 120})
    t0 = moved_transform(room_scene)
    path = [Transform(scale=t0.scale, rotate_deg=t0.rotate_deg, translate=(t0.translate[0] + 3.0 * k,
                                                                           t0.translate[1], t0.translate[2]))
            for k in range(3)]
    req = {"camera": cam, "materials": room_scene.materials}
    threads = set()
    real = mf._static_thread

    class Recording:
        def submit(self, fn):
            def run():
                threads.add(threading.current_thread().name)
                return fn()
            return real().submit(run)

    class Inline:
        def submit(self, fn):
            f = Future()
            f.set_result(fn())
            return f

    frames = {}
    try:
        for name, ex in (("thread", Recording()), ("inline", Inline())):
            mf._static_thread = lambda ex=ex: ex
            frames[name] = [room_renderer.render(FrameRequest(**req, transforms={"bunny": t})) for t in path]
    finally:
        del mf._static_thread
    assert threads == {n for n in threads if n.startswith("glint-moving-static")} and threads
    for a, b in zip(frames["thread"], frames["inline"]):
        assert a.info["moving"]["affected_static"] > 0
        np.testing.assert_array_equal(a.radiance, b.radiance)


def test_moving_what_cannot_move_is_an_error(crate):
    scene = crate.load()
    r = open_renderer(scene)
    cam, mats = scene.spec.camera, scene.materials
    with pytest.raises(MoveError, match="not movable: floor"):
        r.render(FrameRequest(camera=cam, materials=mats, transforms={"floor": Transform(translate=(0, 1, 0))}))
    with pytest.raises(MoveError, match="no object 'chair'"):
        r.render(FrameRequest(camera=cam, materials=mats, transforms={"chair": Transform()}))
    with pytest.raises(MoveError, match="non-uniform scale"):
        r.render(FrameRequest(camera=cam, materials=mats, transforms={"box": Transform(scale=(1, 2, 1))}))
    with pytest.raises(Unsupported, match="per vertex"):
        r.render(FrameRequest(camera=cam, materials=mats, shading="pixel"))
    # the floor at its own place is fine
    r.render(FrameRequest(camera=cam, materials=mats, transforms={"floor": scene.spec.objects[0].transform}))


def test_the_fitters_questions_are_answered_where_objects_stand(room_scene, room_renderer):
    """After a frame with the bunny moved and turned, the paint-to-BRDF fitter's questions (vertex
    and surface samples, shading, SRBF transfer rows) describe the bunny where it now stands:
    positions, shading against cuts traced there, and transfer rows that predict the shading."""
    from worker.core.render import MaterialTable, shade_points
    from worker.fit.basis import default_basis
    from worker.models import parse_material

    r, cam = room_renderer, room_scene.spec.camera
    light = Lighting(room_scene.spec.environment.rotation_deg, 1.0)
    t = moved_transform(room_scene)
    r.render(FrameRequest(camera=cam, lighting=light, materials=room_scene.materials, transforms={"bunny": t}))
    sc = placed(room_scene, "bunny", t)
    smp = r.vertex_samples(cam, 2)
    assert len(smp) > 300
    np.testing.assert_allclose(smp.positions, sc.mesh.vertices[smp.pix], atol=1e-2)
    np.testing.assert_allclose(smp.normals, sc.mesh.normals[smp.pix], atol=1e-3)
    mask = r.object_mask(cam)
    tri, _ = hits(sc, cam)
    assert ((mask == 2) == (sc.object_of_face[np.maximum(tri, 0)] == 2).reshape(mask.shape) & (tri >= 0).reshape(mask.shape)).mean() > 0.998
    ggx = room_scene.materials[2]
    got = r.shade_samples(smp, ggx, 2, light)
    from worker.core.lighting import node_lighting

    world = node_lighting(*r.lighting.leaf_radiance(light.rotation_deg, 1.0), r.tree)
    ref = shade_points(smp.normals, smp.wo, np.arange(len(smp), dtype=np.int32), np.zeros(len(smp), np.int32),
                       reference_cuts(sc.mesh, smp.pix), *world, r.tree, MaterialTable([ggx.pack()]))
    err = np.abs(got.mean(1) - ref.mean(1)) / ref.mean()
    assert err.mean() < 0.03, err.mean()                        # measured 0.011 (the tests' 8 × 8² fields)
    # transfer rows predict the shading of an srbf material: ρ_d E + T c
    basis = default_basis()
    rng = np.random.default_rng(0)
    c = rng.uniform(0, 0.2, (basis.J, 3))
    srbf = parse_material(basis.to_material(c, [0.2, 0.2, 0.2]))
    T, E = r.transfer(smp, basis, light)
    pred = 0.2 * E + np.stack([T[k] @ c[:, k] for k in range(3)], axis=1)
    shade = r.shade_samples(smp, srbf, 2, light)
    rel = np.abs(pred - shade).mean() / shade.mean()
    assert rel < 0.02, rel
    surf = r.surface_samples(cam, 2)
    assert len(surf) > 0.9 * (mask == 2).sum()
