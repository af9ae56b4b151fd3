"""The frame kernels agree with their NumPy references: light tables
(glk_light_tables), the shading kernel's vector and scalar paths (glk_shade_points), the
background (glk_background) and the resolve (glk_resolve)."""
import numpy as np
import pytest

from worker import native
from worker.core.directions import get_tree
from worker.core.lighting import LeafLighting, light_tables
from worker.core.render import (
    MaterialTable,
    background,
    env_coords,
    env_lookup,
    resolve,
    shade_points_numpy,
)
from worker.models import models
from worker.native.kernels import kernels

pytestmark = pytest.mark.skipif(not native.available(), reason="C kernels not built")


@pytest.mark.parametrize("rot,inten", [(0.0, 1.0), (90.0, 2.0), (33.3, 0.7), (-200.5, 1.0)])
def test_light_tables_agree(shared_assets, rot, inten):
    """One C pass over the rotated map gives the reference's per-node tables (fractional and
    whole-column rotations, negative angles)."""
    from worker.envmap import load_envmap

    tree = get_tree()
    L = LeafLighting(load_envmap(shared_assets / "env" / "studio.exr"), tree)
    a = light_tables(L, rot, inten, tree, kernels("native"))
    b = light_tables(L, rot, inten, tree, kernels("numpy"))
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-6 * np.abs(y).max())


def _cases():
    out = []
    for name, cls in models().items():
        for i, m in enumerate(cls.examples()):
            out.append(pytest.param(m, id=f"{name}-{i}"))
    return out


def _bunny_points(bunny, count, seed, eyes):
    """count random bunny vertices, each seen from one of eyes (cycled), lit by the bunny's map
    turned 47°: (tree, kernels, (node_l, node_w, node8), vertex ids, normals, unit ωo)."""
    scene, _ = bunny
    tree = get_tree()
    k = kernels("native")
    lights = light_tables(LeafLighting(scene.envmap, tree), 47.0, 1.0, tree, k)
    vi = np.random.default_rng(seed).choice(len(scene.mesh.vertices), count, replace=False).astype(np.int32)
    eye = np.asarray(eyes, np.float32)
    wo = eye[np.arange(len(vi)) % len(eye)] - scene.mesh.vertices[vi]
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    return tree, k, lights, vi, scene.mesh.normals[vi], wo


@pytest.mark.parametrize("m", _cases())
def test_vector_and_scalar_shading_agree_with_the_reference(bunny, m):
    """Every model example, on 400 bunny vertices seen from several sides (so clusters are
    refined near the mirror direction and straddle the horizon): the AVX2 path (when the CPU
    has it) and the forced scalar path both match the NumPy reference."""
    cuts = bunny[1]
    tree, k, (nl, nw, n8), vi, n, wo = _bunny_points(
        bunny, 400, 3, [[0.3, 0.8, 3.0], [-3.0, 0.2, 0.5], [0.5, 3.0, -1.0], [2.0, -1.0, 2.0]])
    mats = MaterialTable([m.pack()])
    mat_of = np.zeros(len(vi), np.int32)
    ref = shade_points_numpy(n, wo, vi, mat_of, cuts, nl, nw, tree, mats)
    assert ref.max() > 0
    best = k.simd(-1)
    try:
        for mode in sorted({0, best}):
            assert k.simd(mode) == mode
            got = k.shade_points(n, wo, vi, mat_of, cuts, nl, nw, tree, mats, node8=n8)
            np.testing.assert_allclose(got, ref, rtol=2e-4, atol=1e-6 * ref.max(), err_msg=f"simd={mode}")
    finally:
        k.simd(1)


def test_the_ancestor_test_changes_no_cluster_list(bunny):
    """The shading walk skips the cone tests of entries under tree nodes whose every descendant
    is too far from the mirror direction to be split (shade.c ancestors_reaching): a sharp
    multi-scale srbf (extent ~0.2 rad) shades bit for bit as with every ancestor reaching, and
    each ancestor's bound covers its descendants' cones."""
    from worker.models import SRBF
    from worker.native import kernels as K

    cuts = bunny[1]
    tree, k, (nl, nw, n8), vi, n, wo = _bunny_points(bunny, 600, 5, [[0.3, 0.8, 3.0]])
    m = SRBF(centers=[(0.0, 0.0, 1.0), (0.05, 0.0, 0.99875), (0.0, 0.3, 0.9539)], bandwidths=[5000.0, 1300.0, 80.0],
             bandwidth=80.0, coefficients=[(3.0, 3.0, 3.0), (1.0, 0.8, 0.6), (0.05, 0.05, 0.05)], albedo=(0.2, 0.2, 0.2))
    mats = MaterialTable([m.pack()])
    assert mats.extent[0] < 0.5
    mat_of = np.zeros(len(vi), np.int32)
    got = k.shade_points(n, wo, vi, mat_of, cuts, nl, nw, tree, mats, node8=n8)
    anc, level = K._ancestor_bounds(tree)
    saved = K._ANC[id(tree)]
    try:       # every ancestor reaching: the walk tests every entry as before
        K._ANC[id(tree)] = (tree, np.tile(np.float32([-1.0, 0.0, np.pi]), (len(anc), 1)), level)
        every = k.shade_points(n, wo, vi, mat_of, cuts, nl, nw, tree, mats, node8=n8)
    finally:
        K._ANC[id(tree)] = saved
    assert got.max() > 0
    np.testing.assert_array_equal(got, every)
    ref = shade_points_numpy(n, wo, vi, mat_of, cuts, nl, nw, tree, mats)
    np.testing.assert_allclose(got, ref, rtol=2e-4, atol=1e-6 * ref.max())
    # the bounds, by brute force over each ancestor's descendants at every level
    lev = tree.level_offset
    d = tree.node_dir / np.linalg.norm(tree.node_dir, axis=1, keepdims=True)
    for a in range(0, len(anc), 5):
        for h in range(level + 1):
            ids = lev[h] + np.arange(a << (level - h), (a + 1) << (level - h))
            ang = np.arccos(np.clip(d[ids] @ d[lev[level] + a], -1, 1)) + tree.node_radius[ids]
            assert ang.max() <= anc[a, 2] + 1e-5, (a, h, ang.max(), anc[a, 2])


def test_background_and_resolve_agree(bunny_renderer):
    """The background from per-view map coordinates equals a direct lookup (and its reference),
    with and without a ground-shadow grid; the map coordinates of the background rows, read in
    place from all the view's rays, are those of the rows copied out (C and NumPy); the resolve
    of S samples equals the reference's mean."""
    r = bunny_renderer
    cam = r.scene.spec.camera
    env = r.lighting.map
    for s in (1, 4):
        v = r.view(cam, s)
        bgdirs = v.dirs[v.bg]
        uv0 = env_coords(bgdirs)
        for k in ("native", "numpy"):
            np.testing.assert_array_equal(env_coords(v.dirs, kernels(k), rows=v.bg), env_coords(bgdirs, kernels(k)))
        np.testing.assert_array_equal(v.uv0, uv0)
        outs = []
        rng = np.random.default_rng(s)
        grid = (rng.random((16, 16, 3)) * 0.8 + 0.2).astype(np.float32)
        shadow = (grid, (-2.0, -2.5, 0.3, -0.6))
        for sh in (None, shadow):
            a = np.zeros((len(v.tri), 3), np.float32)
            b = np.zeros((len(v.tri), 3), np.float32)
            background(v.bg, v.dirs, uv0, env, 123.4, 0.8, a, sh, cam.eye, kernels("native"))
            background(v.bg, v.dirs, uv0, env, 123.4, 0.8, b, sh, cam.eye, kernels("numpy"))
            np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
            outs.append(a)
        direct = env_lookup(bgdirs, env, 123.4, 0.8, kernels=kernels("numpy"))
        np.testing.assert_allclose(outs[0][v.bg], direct, rtol=1e-4, atol=1e-5)
        assert (outs[1][v.bg] < outs[0][v.bg] - 1e-6).any()          # the grid darkens some samples
        vert = np.random.default_rng(0).random((len(r.scene.mesh.vertices), 3)).astype(np.float32)
        p = cam.width * cam.height
        ra = resolve(v.tri, v.uv, r.scene.mesh.faces, vert, outs[1], s, np.empty((p, 3), np.float32), kernels("native"))
        rb = resolve(v.tri, v.uv, r.scene.mesh.faces, vert, outs[1], s, np.empty((p, 3), np.float32), kernels("numpy"))
        np.testing.assert_allclose(ra, rb, rtol=1e-5, atol=1e-6)


def test_camera_rays_and_map_coordinates_agree(bunny_renderer):
    """The rotation of cached camera-frame rays and their map coordinates (per view)."""
    from worker.core.render import _camera_space_dirs

    cam = bunny_renderer.scene.spec.camera
    src = _camera_space_dirs(cam.fov_y_deg, cam.width, cam.height, 4)
    q, _ = np.linalg.qr(np.random.default_rng(5).normal(size=(3, 3)))
    basis = q.astype(np.float32)
    a = kernels("native").rotate_dirs(src, basis)
    b = kernels("numpy").rotate_dirs(src, basis)
    np.testing.assert_allclose(a, b, atol=2e-7)
    u = np.random.default_rng(6).normal(size=(20000, 3))
    d = (u / np.linalg.norm(u, axis=1, keepdims=True)).astype(np.float32)
    d[:4] = [[0, 1, 0], [0, -1, 0], [0, 0, -1], [-1e-8, 0, 1]]          # poles and the seam
    cb = kernels("numpy").env_coords(d)
    simd = kernels("native").env_simd
    best = simd(-1)
    try:
        for path in sorted({0, best}):          # the baseline build and the vector one the CPU has
            assert simd(path) == path
            ca = kernels("native").env_coords(d)
            du = np.abs(ca[:, 0] - cb[:, 0])
            du = np.minimum(du, 1 - du)                                  # u wraps at the seam
            dv = np.abs(ca[:, 1] - cb[:, 1]).max()
            assert du.max() < 1e-6 and dv < 1e-6, f"path {path}: u off by {du.max():.2e}, v by {dv:.2e}"
            assert (ca[:, 0] >= 0).all() and (ca[:, 0] < 1).all()
    finally:
        simd(1)


def test_intensity_change_scales_the_light_tables(bunny_renderer):
    """A change of intensity alone scales the cached tables instead of rebuilding them: the
    same as rebuilding, to float rounding."""
    from worker.renderers import Lighting
    from worker.renderers.cuts import CutRenderer

    r = CutRenderer(bunny_renderer.scene, bunny_renderer.data)
    r.light(Lighting(20.0, 1.0))
    nl, nw = r.light(Lighting(20.0, 2.5))
    n8 = r._node8
    ref = light_tables(r.lighting, 20.0, 2.5, r.tree, kernels("numpy"))
    np.testing.assert_allclose(nl, ref[0], rtol=1e-5, atol=1e-6 * ref[0].max())
    np.testing.assert_allclose(nw, ref[1], atol=1e-6)
    np.testing.assert_allclose(n8, ref[2], rtol=1e-5, atol=1e-6 * ref[0].max())


def test_a_white_srbf_reads_one_table_for_three_channels(bunny):
    """An srbf whose channels' coefficients are equal (the fit of a white stroke) is packed with
    its texel quads and shaded from them once for all three channels (shade.c sum_table): the
    radiance is bit for bit that of the three-channel lookup, and the reference's; a tinted one
    keeps the three-channel path."""
    from worker.core.render import TABLE_NEUTRAL
    from worker.models import SRBF

    cuts = bunny[1]
    tree, k, (nl, nw, n8), vi, n, wo = _bunny_points(
        bunny, 500, 11, [[0.3, 0.8, 3.0], [-3.0, 0.2, 0.5], [0.5, 3.0, -1.0]])
    centers = [(0.0, 0.0, 1.0), (0.05, 0.0, 0.99875), (0.0, 0.3, 0.9539), (0.6, 0.0, 0.8)]
    white = SRBF(centers=centers, bandwidths=[5000.0, 1300.0, 80.0, 20.0], bandwidth=80.0,
                 coefficients=[(3.0, 3.0, 3.0), (1.0, 1.0, 1.0), (0.05, 0.05, 0.05), (0.2, 0.2, 0.2)],
                 albedo=(0.5, 0.3, 0.2), static="smith", static_alpha=0.2)
    tinted = white.model_copy(update={"coefficients": [(3.0, 2.0, 1.0), (1.0, 1.0, 1.0), (0.05, 0.05, 0.05),
                                                       (0.2, 0.2, 0.2)]})
    mats = MaterialTable([white.pack(), tinted.pack()])
    assert mats.params[0, TABLE_NEUTRAL] == 1.0 and mats.params[1, TABLE_NEUTRAL] == 0.0
    n_tab = white.pack().table.size
    assert len(mats.tables) == 2 * n_tab + n_tab // 3 * 4          # the white one's quads after its table
    mat_of = np.zeros(len(vi), np.int32)
    got = k.shade_points(n, wo, vi, mat_of, cuts, nl, nw, tree, mats, node8=n8)
    assert got.max() > 0
    three = MaterialTable([white.pack()])
    three.params[0, TABLE_NEUTRAL] = 0.0                             # the same table, read per channel
    np.testing.assert_array_equal(got, k.shade_points(n, wo, vi, mat_of, cuts, nl, nw, tree, three, node8=n8))
    ref = shade_points_numpy(n, wo, vi, mat_of, cuts, nl, nw, tree, mats)
    np.testing.assert_allclose(got, ref, rtol=2e-4, atol=1e-6 * ref.max())
