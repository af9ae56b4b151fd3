"""Anti-aliasing of still frames: S samples per pixel for primary visibility, each
pixel the mean of its samples' interpolated vertex radiance or background. Edges approach a
supersampled reference; interiors do not change."""
import numpy as np
import pytest

from worker.core.render import sample_offsets
from worker.renderers import FrameRequest


def _render(r, cam, samples, mode="vertex"):
    return r.render(FrameRequest(camera=cam, materials=r.scene.materials, samples=samples, shading=mode))


@pytest.mark.parametrize("s", [1, 2, 4, 9, 16])
def test_sample_patterns_are_symmetric_about_the_centre(s):
    off = sample_offsets(s)
    assert off.shape == (s, 2) and np.all(np.abs(off) < 0.5)
    np.testing.assert_allclose(off.mean(0), 0.0, atol=1e-12)
    # point-symmetric: the pattern negated is the pattern
    a = np.round(off, 9)[np.lexsort(np.round(off, 9).T)]
    b = np.round(-off, 9)[np.lexsort(np.round(-off, 9).T)]
    np.testing.assert_allclose(a, b, atol=1e-9)


def test_unsupported_sample_counts_are_refused(bunny_renderer):
    with pytest.raises(ValueError, match="samples"):
        _render(bunny_renderer, bunny_renderer.scene.spec.camera, 3)


def test_edges_approach_a_supersampled_reference_and_interiors_stay(bunny_renderer):
    """The bunny at 160×120 against the box-filtered mean of an 8× (1280×960) one-sample render:
    over edge pixels (mixed coverage in the reference), 4 samples cut the RMSE well below one
    sample, and 16 samples further; 16 samples (a 4×4 grid) are exactly the mean of a 4× render.
    Pixels whose samples all hit the centre's triangle are unchanged up to the second-order
    perspective term (the pattern is symmetric, the interpolation nearly affine in the image),
    and background pixels away from edges change by the map's curvature only."""
    r = bunny_renderer
    cam = r.scene.spec.camera

    def boxed(k):
        big = cam.model_copy(update={"width": cam.width * k, "height": cam.height * k})
        hi = _render(r, big, 1)
        cover = (hi.object_id >= 0).reshape(cam.height, k, cam.width, k).mean((1, 3))
        return hi.radiance.reshape(cam.height, k, cam.width, k, 3).mean((1, 3)), cover

    ref, cover = boxed(8)
    edge = (cover > 0) & (cover < 1)
    assert edge.sum() > 200
    img = {s: _render(r, cam, s).radiance for s in (1, 4, 16)}
    np.testing.assert_allclose(img[16], boxed(4)[0], rtol=1e-5, atol=1e-6)
    norm = np.sqrt((ref[edge] ** 2).mean())
    err = {s: np.sqrt(((img[s][edge] - ref[edge]) ** 2).mean()) / norm for s in img}
    print("edge RMSE against the 8×8-supersampled reference: " + ", ".join(f"S={s}: {e:.4f}" for s, e in err.items()))
    # measured on this scene: S=1 0.285, S=4 0.101, S=16 0.033
    assert err[4] < 0.6 * err[1], err
    assert err[16] < err[4], err

    centre = r.view(cam, 1).tri.reshape(-1)
    v4 = r.view(cam, 4)
    same = (v4.tri.reshape(-1, 4) == centre[:, None]).all(1) & (centre >= 0)
    assert same.sum() > 0.2 * (centre >= 0).sum()
    a, b = img[4].reshape(-1, 3)[same], img[1].reshape(-1, 3)[same]
    d = np.abs(a - b) / np.maximum(b, 1e-6 * b.max())
    print(f"interior: max relative change {d.max():.2e}, median {np.median(d):.2e}")
    # measured: median 5e-6, max 4.7e-4 (Embree's barycentrics are perspective-correct, not
    # affine in the image, so the mean over a symmetric pattern differs from the centre at second
    # order: most on triangles seen edge-on)
    assert np.median(d) < 2e-5 and d.max() < 1e-3
    sky = (v4.tri.reshape(-1, 4) < 0).all(1) & ~edge.reshape(-1)
    rel = np.abs(img[4].reshape(-1, 3)[sky] - img[1].reshape(-1, 3)[sky]) / np.maximum(img[1].reshape(-1, 3)[sky], 1e-3)
    print(f"background away from edges: median relative change {np.median(rel):.2e}, p99 {np.percentile(rel, 99):.2e}")
    assert np.median(rel) < 1e-3


def test_pixel_mode_anti_aliases_too(bunny_renderer):
    """Per-pixel shading with samples shades every sample; interiors again match one sample
    where all samples share the centre's triangle (within the per-sample normal's change)."""
    r = bunny_renderer
    cam = r.scene.spec.camera.model_copy(update={"width": 80, "height": 60})
    one, four = _render(r, cam, 1, "pixel"), _render(r, cam, 4, "pixel")
    assert four.info["samples"] == 4
    inner = (one.object_id >= 0)
    rel = np.abs(four.radiance[inner] - one.radiance[inner]).mean() / one.radiance[inner].mean()
    assert rel < 0.05, rel


def test_edge_sampling_is_full_sampling_where_it_matters_and_one_sample_elsewhere(bunny_renderer):
    """``antialias="edges"`` takes the S samples only at pixels next to a discontinuity of the
    surface seen and where a refined highlight is steep (renderers/cuts/edges.py): against an
    8×-supersampled refined reference, over the pixels that see the bunny, it is nearly as
    close as S samples everywhere; every other pixel is the one-sample frame's bit for bit, and
    the pixels whose samples see more than one surface are (nearly) all among the edge pixels."""
    from worker.models import GGX
    from worker.renderers.cuts.edges import edge_pixels, edge_pixels_reference

    r = bunny_renderer
    cam = r.scene.spec.camera
    mats = [GGX(alpha=0.15, specular=[0.4, 0.4, 0.4], albedo=[0.3, 0.2, 0.1])]

    def render(c, s, aa="full"):
        return r.render(FrameRequest(camera=c, materials=mats, samples=s, antialias=aa, shading="refined"))

    k = 8
    big = cam.model_copy(update={"width": cam.width * k, "height": cam.height * k})
    ref = render(big, 1).radiance.reshape(cam.height, k, cam.width, k, 3).mean((1, 3)).reshape(-1, 3)
    one, full, edges = render(cam, 1), render(cam, 4), render(cam, 4, "edges")
    # the pixels some sample of which sees the bunny (the sky's own 1-vs-4-sample difference is
    # the bilinear map's curvature, no edge)
    seen = ~(r.view(cam, 4).tri.reshape(-1, 4) < 0).all(1)
    err = {n: float(np.sqrt(((x.radiance.reshape(-1, 3)[seen] - ref[seen]) ** 2).mean() / (ref[seen] ** 2).mean()))
           for n, x in (("one", one), ("full", full), ("edges", edges))}
    n_edge, n_steep = edges.info["edge_pixels"], edges.info["steep_pixels"]
    print(f"relative RMSE against 8x8 supersampled: {err}; edge pixels {n_edge}, steep {n_steep} "
          f"of {cam.width * cam.height}")
    # measured: one 0.0478, full 0.0175, edges 0.0189; 1,798 edge and 653 steep pixels of 19,200
    assert edges.info["antialias"] == "edges" and edges.info["samples"] == 4
    assert 0 < n_edge < 0.25 * cam.width * cam.height and n_steep < 0.1 * cam.width * cam.height, (n_edge, n_steep)
    assert err["edges"] < 0.5 * err["one"], err
    assert err["edges"] < 1.15 * err["full"], err

    v1 = r.view(cam, 1)
    pix = edge_pixels(v1.tri, r.scene.mesh.faces, r.scene.object_of_face, cam.height, cam.width)
    assert len(pix) == n_edge
    changed = np.abs(edges.radiance - one.radiance).reshape(-1, 3).max(1) > 0
    rest = np.ones(cam.width * cam.height, bool)
    rest[pix] = False
    assert changed[rest].sum() <= n_steep, (changed[rest].sum(), n_steep)

    # pixels whose four samples do not all see the centre's surface (object or background)
    cls = lambda t: np.where(t >= 0, r.scene.object_of_face[np.maximum(t, 0)], -1)   # noqa: E731
    mixed = (cls(r.view(cam, 4).tri).reshape(-1, 4) != cls(v1.tri)[:, None]).any(1)
    caught = (~rest)[mixed].mean()
    print(f"pixels with mixed coverage: {mixed.sum()}, {caught:.3f} of them edge pixels")
    assert mixed.sum() > 50 and caught > 0.97, caught

    small = cam.model_copy(update={"width": 48, "height": 36})
    t = r.view(small, 1).tri
    np.testing.assert_array_equal(edge_pixels(t, r.scene.mesh.faces, r.scene.object_of_face, 36, 48),
                                  edge_pixels_reference(t, r.scene.mesh.faces, r.scene.object_of_face, 36, 48))


def test_edge_sampling_finds_occlusions_and_object_boundaries():
    """The edge test on a hand-made hit buffer: faces that share a vertex are one surface;
    faces that share none (an occlusion), faces of two objects and the background are not."""
    from worker.renderers.cuts.edges import edge_pixels, edge_pixels_reference

    faces = np.array([[0, 1, 2], [1, 2, 3], [4, 5, 6], [7, 8, 9]], np.int32)
    obj = np.array([0, 0, 0, 1], np.int32)
    tri = np.array([[0, 0, 1, 1, 2, 2],
                    [0, 0, 1, 1, 2, 2],
                    [-1, -1, 3, 3, 3, 3]], np.int32).reshape(-1)
    got = edge_pixels(tri, faces, obj, 3, 6)
    np.testing.assert_array_equal(got, edge_pixels_reference(tri, faces, obj, 3, 6))
    mark = np.zeros(18, bool)
    mark[got] = True
    mark = mark.reshape(3, 6)
    # faces 0 and 1 share vertices 1, 2: no edge between them; 1 | 2 share none: an edge
    assert not mark[0, 0] and not mark[0, 1] and not mark[0, 2]
    assert mark[0, 3] and mark[0, 4]
    assert mark[2].all() and mark[1].all()      # next to the background and to object 1


def test_edge_kernels_agree_on_a_real_view(bunny_renderer):
    """The C edge kernel (refine.c glk_edge_pixels) and its NumPy reference pick the same pixels."""
    from worker.native.kernels import kernels
    from worker.native.refine import edge_pixels_numpy

    r = bunny_renderer
    cam = r.scene.spec.camera.model_copy(update={"width": 320, "height": 240})
    t = r.view(cam, 1).tri
    a = kernels("native").refine.edge_pixels(t, r.scene.mesh.faces, r.scene.object_of_face, 240, 320)
    b = edge_pixels_numpy(t, r.scene.mesh.faces, r.scene.object_of_face, 240, 320)
    assert len(a) > 500
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(kernels("numpy").refine.edge_pixels(t, r.scene.mesh.faces, r.scene.object_of_face,
                                                                     240, 320), b)
