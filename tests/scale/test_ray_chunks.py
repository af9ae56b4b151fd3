"""The pieces of the Ray precomputation that need no cluster: guided chunks (decreasing sizes,
contiguous, on batch boundaries, assembling to the bytes of one run), the scene as shipped to
the tasks through the object store, and a task process adopting the coordinator's tree."""
import pickle

import numpy as np

from helpers import scene_file


def _bunny():
    from worker.scene import load_scene

    return load_scene(scene_file("bunny.json"))


def test_guided_chunks_cover_the_part_in_decreasing_contiguous_ranges(shared_assets):
    from worker.jobs.ray_actors import guided
    from worker.renderers import get
    from worker.renderers.cuts.precompute import BATCH

    sc = _bunny()
    _, pre = get("cuts")
    (part,) = pre.parts(sc, {})
    nv = len(sc.mesh.vertices)
    for cpus in (1, 2, 4):
        pieces = pre.chunks(sc, part, {}, 32 * cpus)
        g = guided(pieces, cpus)
        sizes = [b - a for a, b in g]
        assert g[0][0] == 0 and g[-1][1] == nv, g
        assert all(a[1] == b[0] for a, b in zip(g, g[1:])), g
        assert all(a % BATCH == 0 for a, _ in g), g                   # the same batches as one run
        assert all(x >= y for x, y in zip(sizes[:-2], sizes[1:-1])), sizes   # the last may be a remainder
        assert len(g) < len(pieces) and sizes[0] > sizes[-2], (len(pieces), sizes)
    # chunk lists that are not contiguous ranges are left alone
    assert guided([None], 2) == [None]
    assert guided([(0, 16), (32, 48)], 2) == [(0, 16), (32, 48)]


def test_guided_chunks_assemble_to_the_bytes_of_one_run(shared_assets):
    from worker.jobs.ray_actors import guided
    from worker.renderers.cuts.precompute import BATCH, CutPrecomputation

    sc = _bunny()
    pre = CutPrecomputation()
    (part,) = pre.parts(sc, {})
    stop = 20 * BATCH                     # a prefix of the mesh keeps the test short
    pieces = [(s, s + BATCH) for s in range(0, stop, BATCH)]
    g = guided(pieces, 2)
    assert len(g) > 2
    chunked = pre.assemble(sc, part, {}, [pre.compute(sc, part, {}, c, threads=1) for c in g])
    whole = pre.assemble(sc, part, {}, [pre.compute(sc, part, {}, (0, stop), threads=2)])
    assert chunked[0] == whole[0], f"{len(g)} guided chunks: {len(chunked[0])} bytes vs {len(whole[0])}"
    assert chunked[1]["bytes_index_deflated"] == whole[1]["bytes_index_deflated"]


def test_the_shipped_scene_and_tree(shared_assets):
    """What goes into the object store: the loaded scene without its resolver (picklable, arrays
    intact), and a tree a task process adopts as its get_tree()."""
    from worker.core import directions
    from worker.jobs.ray_actors import _portable

    sc = _bunny()
    sc._resolver = lambda ref: ref                    # as DataCache's: a closure, not picklable
    back = pickle.loads(pickle.dumps(_portable(sc), protocol=5))
    assert back._resolver is None and sc._resolver is not None
    for a in ("vertices", "faces", "normals"):
        assert np.array_equal(getattr(back.mesh, a), getattr(sc.mesh, a))
    assert np.array_equal(back.envmap, sc.envmap) and back.spec == sc.spec

    tree = pickle.loads(pickle.dumps(directions.get_tree(), protocol=5))
    assert tree is not directions.get_tree()
    try:
        directions.adopt_tree(tree)
        assert directions.get_tree() is tree
    finally:
        directions._adopted.clear()
    assert directions.get_tree() is not tree
