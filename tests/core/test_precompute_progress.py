"""A precomputation's progress never reaches 100% before its last part is assembled and stored
(renderers/base.py ensure): the couch's cut assembly (encoding, deflate) took 13 s after its
tracing reported the whole of its work, and the studio showed 100% all that time."""
from worker.renderers import ensure, get
from worker.renderers.base import ASSEMBLE_SHARE


class _Store(dict):
    """An in-memory ArtifactStore that records how much progress was reported at each put."""

    def __init__(self, done):
        super().__init__()
        self.done, self.at_put = done, []

    def get(self, key):
        return super().get(key)

    def put(self, key, data):
        self.at_put.append(self.done[0])
        self[key] = data


def test_progress_keeps_a_share_for_assembling_and_storing(bunny):
    scene, _ = bunny
    _, pre = get("paint")                 # lobe maps: a real precomputation of a second or two
    total = sum(p.work for p in pre.parts(scene, {}))
    done, stages = [0.0], []
    store = _Store(done)
    ensure(pre, scene, store, {}, lambda k: done.__setitem__(0, done[0] + k), stage=stages.append)
    assert store.at_put, "nothing was stored"
    # when the last part is being stored, the bar is still short of the end by its share
    assert store.at_put[-1] <= (1 - ASSEMBLE_SHARE) * total + 1e-9, (store.at_put, total)
    assert abs(done[0] - total) < 1e-6, (done[0], total)          # and it ends at 100%
    assert any(s.startswith("assembling and storing") for s in stages), stages
    # a second run finds every part stored: the whole work at once, nothing computed
    done[0] = 0.0
    st = ensure(pre, scene, store, {}, lambda k: done.__setitem__(0, done[0] + k))
    assert st["computed"] == 0 and abs(done[0] - total) < 1e-6
