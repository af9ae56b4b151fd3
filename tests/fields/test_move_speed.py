"""What the moving-frame speed-ups keep: the light tables of a turned frame built by the kernel
backend agree with frame_lighting; a Combiner builds one LeafMap per rotation for all fields; the
kernel's pass over wholly blocked stretches gives the cut the split gave."""
import numpy as np
import pytest
from test_combine import receivers, rot_y, similarity, vertex_cuts

from worker.core.lighting import LeafLighting, pack_nodes
from worker.envmap import load_envmap
from worker.native import available as native_built
from worker.native.kernels import kernels
from worker.renderers.cuts.combine import (
    Combiner,
    RotatedSamples,
    combine_numpy,
    lookup,
)
from worker.renderers.cuts.fields import frame_light_tables, frame_lighting
from worker.renderers.cuts.rotate import LeafMap

native = pytest.mark.skipif(not native_built(), reason="C kernels not built")


@pytest.mark.parametrize("backend", ["native", "numpy"])
@pytest.mark.parametrize("q", [rot_y(-90.0), rot_y(33.0), rot_y(20.0) @ np.array([[1, 0, 0], [0, 0.8, -0.6], [0, 0.6, 0.8]])])
def test_frame_light_tables_agree_with_frame_lighting(shared_assets, tree, backend, q):
    if backend == "native" and not native_built():
        pytest.skip("C kernels not built")
    env = LeafLighting(load_envmap(shared_assets / "env" / "sunset.exr"), tree)
    nl, nw = frame_lighting(env, q, 140.0, 1.3)
    tl, tw, t8 = frame_light_tables(env, q, 140.0, 1.3, kernels(backend))
    rel = np.abs(tl - nl).max() / np.abs(nl).max()
    assert rel < 1e-5, f"node radiance differs by {rel:.2e} of its maximum"
    assert np.abs(tw - nw).max() < 1e-4, np.abs(tw - nw).max()
    np.testing.assert_array_equal(t8, pack_nodes(tl, tw))


def test_one_leaf_map_per_rotation(bunny_case, table_case, tree):
    cb = Combiner()
    q = rot_y(25.0)
    a, b = cb.pool(bunny_case.field, q), cb.pool(table_case.field, q)
    assert a is not b and a.lmap is b.lmap
    assert cb.pool(bunny_case.field, rot_y(26.0)).lmap is not a.lmap


@native
def test_blocked_stretches_pass_whole(bunny_case, tree):
    """Receivers close to the bunny, facing it: stretches where its field blocks every corner
    (F = 0) are passed whole by glf_combine; the result is the NumPy reference's, node by node."""
    x, nrm = receivers(bunny_case, 80, scale=0.7, seed=5)
    nrm = bunny_case.center - x
    nrm = (nrm / np.linalg.norm(nrm, axis=1, keepdims=True)).astype(np.float32)
    base = vertex_cuts(tree, nrm, seed=5)
    m = similarity(rot_y(15), (0.05, 0.0, -0.02))
    c, w, _ = lookup(bunny_case.field, np.linalg.inv(m), x, nrm)
    a = RotatedSamples(bunny_case.field, LeafMap(tree, m[:3, :3]), 3, kernels("native"))
    b = RotatedSamples(bunny_case.field, a.lmap, 3, kernels("numpy"))
    a.ensure_cells(c); b.ensure_cells(c)
    blocked = sum(int((a.cells.v[a.cells.off[s]:a.cells.off[s] + a.cells.cnt[s]] == 0).all(1).sum())
                  for s in a.cells.slot[np.unique(c[c >= 0])])
    assert blocked > 100, f"only {blocked} wholly blocked stretches"
    ids = np.arange(len(x), dtype=np.int32)
    got = kernels("native").fields.combine(base, ids, c[:, None], w[:, None], [a])
    ref = combine_numpy(base, ids, c[:, None], w[:, None], [b])
    assert np.array_equal(got.offsets, ref.offsets) and np.array_equal(got.heights, ref.heights)
    assert np.abs(got.quant.astype(int) - ref.quant.astype(int)).max() <= 1
