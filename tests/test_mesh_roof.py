"""The fordFocus's roof against Mitsuba, and in the car-paint renderer: what the repair of
winding, orientation and thin surfaces on load (worker.mesh_repair) is for.

The car as downloaded (no normals in the file) has pieces wound inward, pieces whose winding
flips from face to face, and roof parts modelled as flattened shells (two layers on the same
positions, some sharing vertices): the cut renderer shaded its roof with black triangles and
speckles (59% relative error against the reference before the repair).

Scene: the repaired car cut above y = 20 cm (the greenhouse: nothing below it rises above the
roof's horizon, so the roof's light is the whole car's), a grey Lambert under sunset, 320×240,
vertex mode. Reference: Mitsuba 3 ``direct`` on the same triangles with ``twosided`` BSDFs and
the faces' own normals, so it does not depend on winding or normals at all (2 × 128 spp, cached
in tests/.cache/mitsuba by content). Measured: relative RMSE of 2×2 pixel blocks over the roof
panel (faces above y = 57 cm facing up, 2 px from its borders).
"""
from pathlib import Path

import numpy as np
import pytest
from helpers import open_renderer
from scipy.ndimage import binary_erosion

mi = pytest.importorskip("mitsuba")

Y_CUT = 20.0     # cm: the greenhouse
ROOF_Y = 57.0    # cm: the roof panel, above the windows' top edge


def _blocks(x: np.ndarray, b: int = 2) -> np.ndarray:
    h, w = x.shape[0] // b * b, x.shape[1] // b * b
    return x[:h, :w].reshape(h // b, b, w // b, b, -1).mean((1, 3))


@pytest.fixture(scope="module")
def car(shared_assets):
    from worker.scene import load_mesh

    return load_mesh(shared_assets / "meshes" / "fordFocus" / "fordFocus.obj")


def _greenhouse(car, shared_assets, folder, renderer: str, material: str):
    """A LoadedScene of the repaired car's greenhouse (its mesh set to the cut of load_mesh's
    output, so the repair under test is the whole car's), the camera above the roof."""
    from worker.scene import Mesh, load_scene

    v, f, n = car.vertices, car.faces, car.normals
    keep = (v[f][:, :, 1] > Y_CUT).all(1)
    used = np.unique(f[keep])
    remap = np.full(len(v), -1, np.int64)
    remap[used] = np.arange(len(used))
    (folder / "scene.json").write_text(
        '{"version": 1, "renderer": "%s", "environment": {"map": "%s", "rotation_deg": 0.0, "intensity": 1.0},'
        ' "camera": {"eye": [230, 280, 60], "target": [0, 50, -70], "up": [0, 1, 0], "fov_y_deg": 40,'
        ' "width": 320, "height": 240},'
        ' "objects": [{"name": "car", "mesh": "%s", "material": %s}]}'
        % (renderer, shared_assets / "env" / "sunset.exr", shared_assets / "meshes" / "bunny.ply", material))
    sc = load_scene(folder / "scene.json")
    sc.mesh = Mesh(v[used], remap[f[keep]], n[used])
    sc.object_of_vertex = np.zeros(len(used), np.int32)
    sc.object_of_face = np.zeros(int(keep.sum()), np.int32)
    return sc


def _first_faces(sc) -> np.ndarray:
    """(H·W,) int: the face each pixel centre sees first (−1: none)."""
    from worker.core.render import camera_rays
    from worker.trace.embree import Tracer

    cam = sc.spec.camera
    o, d = camera_rays(cam.eye, cam.target, cam.up, cam.fov_y_deg, cam.width, cam.height)
    prim, _, _ = Tracer(sc.mesh.vertices, sc.mesh.faces).first_hit(o, d)
    return prim


def _roof_mask(sc) -> np.ndarray:
    """(H, W) bool: pixels whose first hit is an upward face of the roof panel (above ROOF_Y),
    2 px from its border."""
    cam = sc.spec.camera
    v, f = sc.mesh.vertices.astype(np.float64), sc.mesh.faces
    prim = _first_faces(sc)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    up = fn[:, 1] / np.linalg.norm(fn, axis=1)
    roof = (v[f][:, :, 1].mean(1) > ROOF_Y) & (np.abs(up) > 0.7)
    mask = np.zeros(len(prim), bool)
    mask[prim >= 0] = roof[prim[prim >= 0]]
    return binary_erosion(mask.reshape(cam.height, cam.width), iterations=2)


@pytest.fixture(scope="module")
def roof_scene(car, shared_assets, tmp_path_factory):
    return _greenhouse(car, shared_assets, tmp_path_factory.mktemp("roof"), "cuts",
                       '{"model": "lambert", "albedo": [0.6, 0.6, 0.6]}'), car.repair


@pytest.mark.slow
def test_the_ford_focus_roof_matches_mitsuba_without_speckles(roof_scene, cache_dir, artifacts):
    from PIL import Image

    from worker.core.tonemap import tonemap
    from worker.fit.recovery import mitsuba_target
    from worker.renderers import FrameRequest

    sc, rep = roof_scene
    # the repair did its work on this car (else the comparison below measures nothing new)
    assert rep["outward_flipped_faces"] > 0 and rep["winding_flipped_faces"] > 0, rep
    cam = sc.spec.camera
    ours = open_renderer(sc).render(FrameRequest(camera=cam, materials=[sc.spec.objects[0].material],
                                                 shading="vertex")).radiance
    ref, imgs = mitsuba_target(sc, 128, (1, 2), cache_dir / "mitsuba", two_sided=True, face_normals=True)
    mask = _roof_mask(sc)
    inside = _blocks(mask[..., None].astype(float))[..., 0] == 1
    a, b = _blocks(ours)[inside], _blocks(ref)[inside]
    norm = np.sqrt((b ** 2).mean())
    rel = float(np.sqrt(((a - b) ** 2).mean()) / norm)
    noise = float(0.5 * np.sqrt(((_blocks(imgs[0])[inside] - _blocks(imgs[1])[inside]) ** 2).mean()) / norm)
    luma = np.array([0.2126, 0.7152, 0.0722])
    dark = int(((a @ luma) < 0.5 * (b @ luma)).sum())
    Image.fromarray(np.concatenate([tonemap(ours), tonemap(ref)], axis=1)).save(artifacts / "mitsuba-ford-roof.png")
    # the whole greenhouse (every block all of whose pixels see the car): windows in their frames,
    # pillars, the roof's gutters, all layered shells
    seen = _blocks((_first_faces(sc) >= 0).reshape(cam.height, cam.width, 1).astype(float))[..., 0] == 1
    ga, gb = _blocks(ours)[seen], _blocks(ref)[seen]
    whole = float(np.sqrt(((ga - gb) ** 2).mean()) / np.sqrt((gb ** 2).mean()))
    print(f"roof: {inside.sum()} blocks, relative RMSE {rel:.4f} (reference noise {noise:.4f}), {dark} at half; "
          f"greenhouse {seen.sum()} blocks, {whole:.4f}")
    assert inside.sum() > 2000, inside.sum()
    # measured 2026-12-07: roof 2.4% (reference noise 0.7%), 0 blocks below half the reference's
    # luminance; the greenhouse 4.3%. With rays from the vertices themselves (an offset of 1e-4 of
    # the scene's diagonal) it was 5.5% and 18.3%: a vertex under the next shell of the mesh (the
    # gutter over the roof panel's edge, glass in its frame) darkened its faces; without the
    # mesh repair, 59% and about 1,350 blocks at half. The roof's target is 5%.
    assert rel <= 0.05, f"roof relative RMSE {rel:.4f} against Mitsuba (2x2 blocks)"
    assert dark <= 12, f"{dark} of {inside.sum()} roof blocks below half of Mitsuba's luminance"
    assert whole <= 0.08, f"greenhouse relative RMSE {whole:.4f} against Mitsuba (2x2 blocks)"


def test_the_car_paint_renderer_draws_the_roof_without_speckles(car, shared_assets, tmp_path, artifacts):
    """The car-paint renderer (per-pixel normals, one Embree hit per pixel, no visibility) on the
    same roof with the benchmark's paint: a speckle is a roof pixel below half the median of its
    9×9 neighbourhood (a layer facing away from the camera winning the depth test, or a normal
    summed from opposite faces). Measured 2026-12-06: 0 of ~10,860 roof pixels, 2026-12-07: 4
    (with the cuts of either ray offset: dots on the thin gutter strips); without the repair
    2,220."""
    import json

    from PIL import Image
    from scipy.ndimage import median_filter

    from worker.core.tonemap import tonemap
    from worker.renderers import FrameRequest

    root = Path(__file__).resolve().parents[1]
    paint = json.loads((root / "bench" / "paint_ford.json").read_text())["objects"][0]["material"]
    sc = _greenhouse(car, shared_assets, tmp_path, "paint", json.dumps(paint))
    img = open_renderer(sc).render(FrameRequest(camera=sc.spec.camera, materials=[sc.spec.objects[0].material])).radiance
    mask = _roof_mask(sc)
    lum = img @ np.array([0.2126, 0.7152, 0.0722])
    speckles = int((mask & (lum < 0.5 * median_filter(lum, size=9))).sum())
    Image.fromarray(tonemap(img)).save(artifacts / "paint-ford-roof.png")
    print(f"paint renderer roof: {speckles} speckle pixels of {mask.sum()}")
    assert mask.sum() > 8000, mask.sum()
    assert speckles <= 20, f"{speckles} of {mask.sum()} roof pixels below half their 9x9 median"
