"""Brush strokes (inverse-brdf-modeling eq. 23) and the stroke history."""
import numpy as np
import pytest
from pydantic import ValidationError

from worker.fit.brush import Stroke, StrokeHistory, apply_stroke, polyline_distance, stroke_weights


def test_polyline_distance():
    xy = np.array([[0.0, 1.0], [5.0, -2.0], [12.0, 0.0], [-3.0, -4.0]])
    d = polyline_distance(xy, [(0, 0), (10, 0)])
    np.testing.assert_allclose(d, [1.0, 2.0, 2.0, 5.0])
    np.testing.assert_allclose(polyline_distance(xy[:1], [(0, 0)]), [1.0])


def test_weights_follow_eq_23():
    s = Stroke(points=[(0, 0), (10, 0)], diameter=6, kappa=0.5)
    xy = np.array([[5.0, 0.0], [5.0, 2.0], [5.0, 3.0], [5.0, 3.5]])
    w = stroke_weights(s, xy)
    np.testing.assert_allclose(w, [1.0, np.exp(-1.0), np.exp(-1.5), 0.0])
    # a fit pixel's footprint counts: 0.5 px more reach
    assert stroke_weights(s, xy, footprint=0.5)[3] == pytest.approx(np.exp(-1.5))


def test_colour_and_scale_modes():
    base = np.array([[0.2, 0.4, 0.6], [0.2, 0.4, 0.6]])
    w = np.array([1.0, 0.25])
    t = apply_stroke(base.copy(), Stroke(points=[(0, 0)], color=(2.0, -1.0, 0.0)), w)
    np.testing.assert_allclose(t[0], [2.0, -1.0, 0.0])
    np.testing.assert_allclose(t[1], 0.25 * np.array([2.0, -1.0, 0.0]) + 0.75 * base[1])
    t = apply_stroke(base.copy(), Stroke(points=[(0, 0)], mode="scale", scale=3.0), w)
    np.testing.assert_allclose(t[0], 3.0 * base[0])
    np.testing.assert_allclose(t[1], (0.25 * 3.0 + 0.75) * base[1])


def test_history_undo_redo():
    h = StrokeHistory()
    a, b, c = (Stroke(points=[(i, i)]) for i in range(3))
    h.push(a); h.push(b)
    assert h.undo() is b and h.strokes == [a] and h.can_redo
    assert h.redo() is b and h.strokes == [a, b]
    h.undo(); h.push(c)
    assert h.strokes == [a, c] and not h.can_redo      # a new stroke clears the redo stack
    h.undo(); h.undo()
    assert h.undo() is None and h.strokes == []


@pytest.mark.parametrize("bad", [{"points": []}, {"points": [[0, float("nan")]]}, {"points": [[0, 0]], "diameter": -1},
                                 {"points": [[0, 0]], "mode": "smudge"}, {"points": [[0, 0]], "colour": [1, 1, 1]}])
def test_bad_strokes_are_refused(bad):
    with pytest.raises(ValidationError):
        Stroke.model_validate(bad)
