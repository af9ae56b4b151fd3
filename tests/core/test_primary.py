"""Primary hits by face projection (core.primary, src/primary.c) against the NumPy reference
and against Embree's traced rays on real meshes.

Tolerances: Embree intersects in single precision, the projection in double, so a sample that
lies on a shared edge or on a silhouette within rounding may see the neighbouring face (or a
miss) in one of them: at most 0.1% of the samples may differ in face (measured: none on these
80×60 frames, 3e-6 of the oak chair's 640×480 samples), and where both see the same face the
barycentrics agree to 1e-2 (measured ≤ 4.3e-4 here, 5e-3 on the oak chair at 640×480:
Embree's float32 rounding on long faces).
"""
from __future__ import annotations

import numpy as np
import pytest

from helpers import scene_file


@pytest.fixture(scope="module")
def meshes(shared_assets):
    from worker.scene import load_scene

    return {n: load_scene(scene_file(n)) for n in ("bunny.json", "sofa2.json")}


def cameras(scene):
    """The scene's camera at 80×60, one from three times as far, and one from inside the
    mesh's bounding box (faces behind the eye: the projection clips them)."""
    cam = scene.spec.camera.model_copy(update={"width": 80, "height": 60})
    v = np.asarray(scene.mesh.vertices, np.float64)
    centre = (v.min(0) + v.max(0)) / 2
    far = cam.model_copy(update={"eye": tuple(centre + 3.0 * (np.asarray(cam.eye) - centre))})
    inside = cam.model_copy(update={"eye": tuple(centre), "target": tuple(centre + [0, 0, 1.0])})
    return {"scene": cam, "far": far, "inside": inside}


def _hits(scene, cam, samples, k):
    from worker.core.primary import primary_hits
    from worker.core.render import camera_dirs

    d = camera_dirs(cam.eye, cam.target, cam.up, cam.fov_y_deg, cam.width, cam.height, samples)
    return d, primary_hits(scene.mesh.vertices, scene.mesh.faces, cam, samples, d, k)


@pytest.mark.parametrize("name", ["bunny.json", "sofa2.json"])
def test_native_primary_hits_agree_with_the_numpy_reference(meshes, name):
    from worker.native.kernels import kernels

    scene = meshes[name]
    for cname, cam in cameras(scene).items():
        for samples in (1, 4):
            _, (tn, uvn, t_n) = _hits(scene, cam, samples, kernels("native"))
            _, (tr, uvr, t_r) = _hits(scene, cam, samples, kernels("numpy"))
            assert (tn >= 0).any(), f"{name} {cname}: no sample sees the mesh"
            same = tn == tr
            # the kernel keeps the first face found at an equal distance, the reference the lower index
            tie = ~same & (tn >= 0) & (tr >= 0) & np.isclose(t_n, t_r, rtol=1e-6)
            assert (same | tie).all(), f"{name} {cname} S={samples}: {(~(same | tie)).sum()} samples differ"
            hit = same & (tn >= 0)
            assert np.abs(uvn[hit] - uvr[hit]).max() < 1e-5
            assert np.allclose(t_n[hit], t_r[hit], rtol=1e-6)


@pytest.mark.parametrize("name", ["bunny.json", "sofa2.json"])
def test_projected_primary_hits_agree_with_embree(meshes, name):
    from worker.native.kernels import kernels
    from worker.trace.embree import Tracer

    scene = meshes[name]
    tracer = Tracer(scene.mesh.vertices, scene.mesh.faces)
    for cname, cam in cameras(scene).items():
        for samples in (1, 4):
            d, (tri, uv, t) = _hits(scene, cam, samples, kernels("native"))
            te, uve, tfe = tracer.first_hit(np.broadcast_to(np.asarray(cam.eye, np.float32), d.shape).copy(), d)
            differ = float((tri != te).mean())
            assert differ <= 1e-3, f"{name} {cname} S={samples}: {differ:.2e} of the samples see another face"
            assert (te >= 0).sum() > 50, f"{name} {cname}: the camera sees too little of the mesh"
            both = (tri == te) & (te >= 0)
            du = float(np.abs(uv[both] - uve[both]).max())
            assert du < 1e-2, f"{name} {cname} S={samples}: barycentrics differ by {du:.2e}"
            assert np.allclose(t[both], tfe[both], rtol=1e-3), f"{name} {cname}: distances differ"


def test_renderer_views_by_projection_equal_traced_views(bunny_renderer):
    """The cut renderer's default view (projection) and its traced view see the same faces,
    visible vertices and background within the tolerance above."""
    from worker.renderers.cuts import CutRenderer

    r0 = bunny_renderer
    cam = r0.scene.spec.camera.model_copy(update={"width": 96, "height": 72})
    views = {}
    for how in ("project", "embree"):
        r = CutRenderer(r0.scene, r0.data)
        r.primary = how
        views[how] = r.view(cam, 4)
    p, e = views["project"], views["embree"]
    assert p.traced == 0 and e.traced > 0
    assert float((p.tri != e.tri).mean()) <= 1e-3
    assert len(np.setxor1d(p.visible, e.visible)) <= 0.01 * len(e.visible)
    assert abs(len(p.bg) - len(e.bg)) <= 1e-3 * len(p.tri)


@pytest.mark.parametrize("backend", ["native", "numpy"])
def test_hits_drawn_over_earlier_hits_are_the_whole_meshs(meshes, backend):
    """``into``: the sofa's second half of faces drawn over the hits of its first half (face
    numbers offset by fbase) gives the hits of the whole mesh (a moved object drawn over the
    static scene's kept hits), with the earlier hits kept where they are nearer."""
    from worker.core.primary import primary_hits
    from worker.core.render import camera_dirs
    from worker.native.kernels import kernels

    scene = meshes["sofa2.json"]
    V, Fc = scene.mesh.vertices, scene.mesh.faces
    k = len(Fc) // 2
    for cname, cam in cameras(scene).items():
        d = camera_dirs(cam.eye, cam.target, cam.up, cam.fov_y_deg, cam.width, cam.height, 1)
        whole = primary_hits(V, Fc, cam, 1, d, kernels(backend))
        first = tuple(np.ascontiguousarray(a) for a in primary_hits(V, Fc[:k], cam, 1, d, kernels(backend)))
        n_first = int((first[0] >= 0).sum())
        got = primary_hits(V, Fc[k:], cam, 1, d, kernels(backend), into=(*first, k))
        assert got[0] is first[0]
        same = got[0] == whole[0]
        tie = ~same & np.isclose(got[2], whole[2], rtol=1e-6)
        assert (same | tie).all(), f"{cname}: {(~(same | tie)).sum()} samples differ"
        assert ((got[0] >= k).sum() > 0) and ((got[0] < k) & (got[0] >= 0)).sum() > 0 and n_first > 0
        hit = same & (whole[0] >= 0)
        assert np.abs(got[1][hit] - whole[1][hit]).max() < 1e-6
