"""Where a vertex's visibility rays start (renderers/cuts/precompute.py ``ray_offsets``)."""
import numpy as np

from worker.core.directions import get_tree
from worker.renderers.cuts.precompute import (OFFSET_EDGE, OFFSET_MAX, ray_epsilon, ray_offsets,
                                               vertex_visibility)
from worker.trace.embree import Tracer


def _plate_under_strip(gap: float):
    """A 1 × 1 plate of two triangles at y = 0 (normal +y), and a 0.2-wide strip over its edge
    x = 1 at height ``gap`` (two triangles, both sides opaque): the gutter over a roof panel's
    edge. Returns (vertices (8, 3) float32, faces (4, 3) int32, normals (8, 3) float32)."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1],
                  [0.9, gap, -0.5], [1.1, gap, -0.5], [1.1, gap, 1.5], [0.9, gap, 1.5]], np.float32)
    f = np.array([[0, 2, 1], [0, 3, 2], [4, 6, 5], [4, 7, 6]], np.int32)
    n = np.tile(np.array([0, 1, 0], np.float32), (8, 1))
    return v, f, n


def test_offsets_follow_the_edges_within_their_bounds():
    v, f, _ = _plate_under_strip(0.02)
    off = ray_offsets(v, f)
    base = ray_epsilon(v)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    # plate corner 0: in both plate faces, its edges (each counted per face) 1, √2 and √2, 1
    e0 = (2.0 + 2.0 * np.sqrt(2.0)) / 4.0
    assert abs(off[0] - np.clip(OFFSET_EDGE * e0, base, OFFSET_MAX * diag)) < 1e-6
    assert (off >= base - 1e-9).all() and (off <= OFFSET_MAX * diag + 1e-6).all()
    # sample points without faces (the ground's grid) keep the scene's epsilon
    assert np.allclose(ray_offsets(v, None), base)
    # one huge face among small ones is capped at OFFSET_MAX of the diagonal
    big = np.concatenate([v, np.array([[-50, -1, -50], [50, -1, -50], [0, -1, 50]], np.float32)])
    fb = np.concatenate([f, np.array([[8, 10, 9]], np.int32)])
    ob = ray_offsets(big, fb)
    dg = float(np.linalg.norm(big.max(0) - big.min(0)))
    assert abs(ob[8] - OFFSET_MAX * dg) < 1e-3 * dg


def test_a_shell_a_fraction_of_an_edge_above_a_vertex_does_not_darken_it():
    """The plate's corner under the strip (a gap of 1% of its edges) sees the sky from the offset
    origin; from the scene's epsilon it is half dark. Far from the strip nothing changes."""
    v, f, n = _plate_under_strip(0.01)
    tree = get_tree()
    tracer = Tracer(v, f)
    pts = np.array([1, 0], np.int64)            # under the strip; the far corner
    near, _ = vertex_visibility(tracer, tree, v[pts], n[pts], ray_epsilon(v))
    lifted, _ = vertex_visibility(tracer, tree, v[pts], n[pts], ray_offsets(v, f)[pts])
    # cosine-weighted visibility over the hemisphere, relative to the open sky's
    sky = np.maximum(tree.leaves @ np.array([0, 1, 0], np.float32), 0).sum()
    old, new = near.sum(1) / sky, lifted.sum(1) / sky
    assert old[0] < 0.6, f"from the vertex itself: {old[0]:.3f} of the sky"
    assert new[0] > 0.9, f"from the offset origin: {new[0]:.3f} of the sky"
    assert abs(old[1] - new[1]) < 0.02 and new[1] > 0.9, (old[1], new[1])
