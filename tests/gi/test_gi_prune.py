"""Re-sparsification of the live rows at freezing (freeze.prune_sparse): exact at the freeze-time
material, and within the bound of the folded entries at any material inside the probe range."""
import numpy as np

from gi_harness import gi_renderer, scene_with
from worker.scene import GGX


def test_prune_exact_at_freeze_material_and_bounded_elsewhere(shared_assets):
    sc = scene_with("cornell", 24, 24)
    r = gi_renderer(sc, {"spp": 16, "series": [64, 1, 1, 1]}, "native")
    before = GGX(alpha=0.3, specular=(0.4, 0.4, 0.4), albedo=(0.5, 0.3, 0.2))
    after = GGX(alpha=0.05, specular=(0.9, 0.6, 0.3), albedo=(0.1, 0.6, 0.2))
    checked = 0
    for u in range(r.U):
        r.prune = 0.0
        r.set_unit_material(u, before); r.freeze(u)
        fz0 = r.frozen
        if fz0.dense is not None or not len(fz0.live):
            continue
        ref_b = r.draw().reshape(-1, 3).astype(np.float64).copy()
        r.set_unit_material(u, after)
        ref_a = r.draw().reshape(-1, 3).astype(np.float64).copy()
        r.prune = 0.02
        r.set_unit_material(u, before); r.freeze(u)
        fz = r.frozen
        assert 0 < r.last_pruned < 0.2 and len(fz.entries) < len(fz0.entries), (r.last_pruned, len(fz.entries))
        got_b = r.draw().reshape(-1, 3).astype(np.float64).copy()
        # the folded entries' contribution moved into V: the same frame at the freeze material
        tol = 1e-5 * np.abs(ref_b).max()
        assert np.abs(got_b - ref_b).max() <= tol, (u, np.abs(got_b - ref_b).max(), tol)
        r.set_unit_material(u, after)
        got_a = r.draw().reshape(-1, 3).astype(np.float64)
        # bound: a folded entry's coefficient moved by at most 2·slot_weight (both materials are
        # inside the probe range, white and d ≤ 1), times h·scale·|F_e|
        kept = {(q, int(k)) for q in range(len(fz.live)) for k in fz.key[fz.offsets[q]:fz.offsets[q + 1]]}
        w = r._slot_weight(u)
        bound = np.zeros((len(fz0.live), 3))
        val = np.abs(fz0.val.astype(np.float64))
        for q in range(len(fz0.live)):
            for e in range(fz0.offsets[q], fz0.offsets[q + 1]):
                k = int(fz0.key[e])
                if (q, k) not in kept:
                    bound[q] += 2 * w[k // (fz0.K2 * fz0.NP)] * val[e]
        bound *= (fz0.h * fz0.scale)[:, None]
        pix = r.prim.pixel[fz0.live]
        err = np.abs(got_a[pix] - ref_a[pix])
        assert (err <= bound * 1.001 + 1e-4 * np.abs(ref_a).max()).all(), (u, (err - bound).max())
        assert np.abs(got_a - ref_a).max() > 0        # the edit does see the pruning
        checked += 1
    assert checked, "no unit froze to the sparse layout"
