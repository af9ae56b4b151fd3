"""A GI session, worker side (worker/jobs/runtime.py on the GI renderer, no server): every
editable object can be picked, is frozen when picked (not on its first edit), and can be painted
with strokes that fit its BRDF through the multibounce tensors; an object marked
``"editable": false`` keeps its BRDF (its material and strokes are refused with the reason)."""
import numpy as np
import pytest

from gi_harness import gi_renderer, scene_with
from gi_harness import session_frame as _frame
from gi_harness import session_runtime as _runtime
from worker.protocol import StateError, new_state


@pytest.fixture(scope="module")
def sofa(shared_assets):
    return gi_renderer(scene_with("sofa", 48, 36), {"spp": 64, "series": [64, 1, 1, 1]})


def test_pick_freeze_and_paint_the_floor_under_gi(sofa):
    rt = _runtime(sofa)
    floor_unit = sofa.layout.index("floor")
    assert sofa.frozen is not None and sofa.frozen.unit == sofa.layout.index("sofa")    # frozen at open
    before, ids = _frame(rt)
    rt.frame(-1)
    H, W = ids.shape
    ys, xs = np.nonzero(ids == 1)
    y = int(np.median(ys))
    row = xs[ys == y]
    ev = rt.handle({"seq": 1, "type": "pick", "u": (row[len(row) // 2] + 0.5) / W, "v": (y + 0.5) / H})
    assert ev[0]["object"] == "floor", ev
    ev = rt.handle({"seq": 2, "type": "object", "object": "floor", "strokes": []})
    assert ev[-1]["object"] == "floor"
    assert sofa.frozen.unit == floor_unit             # frozen when picked
    x0, x1 = float(np.quantile(row, 0.3)) + 0.5, float(np.quantile(row, 0.7)) + 0.5
    stroke = {"points": [[x0, y + 0.5], [x1, y + 0.5]], "mode": "scale", "scale": 1.3, "diameter": 4, "kappa": 0.05}
    assert rt.handle({"seq": 3, "type": "stroke", "stroke": stroke})[0]["rejected"] is False
    fit = rt.fit_if_needed()
    assert fit[0]["object"] == "floor" and fit[0]["material"]["model"] == "srbf", fit
    stats = fit[0]["stats"]
    assert stats["achieved"] >= 0.3 and stats["spill"] <= 0.3 and stats["steps"] >= 1, stats
    after, _ = _frame(rt)
    painted = np.zeros((H, W), bool)
    painted[y - 1:y + 2, int(x0):int(x1)] = True
    painted &= ids == 1
    assert after[painted].mean() > 1.05 * before[painted].mean()
    # the sofa's material is as it was; its pixels still change a little (light off the floor)
    assert rt.state.material_of("sofa") == new_state(sofa.scene.spec).materials[0]
    assert np.abs(after[ids == 0] - before[ids == 0]).max() > 1e-5


def test_a_fixed_object_keeps_its_brdf(sofa):
    rt = _runtime(sofa)
    with pytest.raises(StateError, match="fixed"):
        rt.handle({"seq": 1, "type": "object", "object": "side_wall", "strokes": []})
    assert rt.state.object == "sofa"
    with pytest.raises(StateError, match="fixed"):
        rt.handle({"seq": 2, "type": "material", "object": "side_wall",
                   "material": {"model": "lambert", "albedo": [0.1, 0.1, 0.1]}})
    # the direct-light renderer has no precomputation to bake it into: there it is editable
    st = new_state({**sofa.scene.spec.model_dump(mode="json"), "renderer": "cuts"})
    assert not st.fixed("side_wall") and st.baked == ["side_wall"]
