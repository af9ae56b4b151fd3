import copy

import numpy as np
import pytest

from worker.engine import Engine
from worker.scene import Lambert

DULL = Lambert(albedo=(0.4, 0.4, 0.4))


@pytest.fixture(scope="module")
def bunny_view(bunny):
    """(Engine, FitView): the bunny's view at 160×120 fit pixels (the issue's default fit size),
    transfer built once per module."""
    from worker.fit.fitter import Fitter

    scene, cuts = bunny
    eng = Engine(scene, cuts)
    eng.set_materials([DULL])
    fx = Fitter(eng, "bunny", fit_scale=1.0)
    fx.add_view()
    return eng, fx.views[0]


@pytest.fixture
def fitter(bunny_view):
    """A fresh Fitter on the dull (Lambert 0.4) bunny, sharing the module's transfer matrix."""
    from worker.fit.fitter import Fitter

    eng, view = bunny_view
    eng.set_materials([DULL])
    fx = Fitter(eng, "bunny", fit_scale=1.0)
    v = copy.copy(view)
    v.base = view.base.copy()
    fx.views.append(v)
    return fx


def stroke_across(fx, frac=(0.3, 0.5), dy=-6.0, view=0):
    """Two points across the object's middle row, in view pixels."""
    v = fx.views[view]
    ys = v.xy[:, 1]
    y0 = float(np.median(ys)) + dy
    row = v.xy[np.abs(ys - y0) < 1.0, 0]
    x0, x1 = row.min(), row.max()
    return [(float(x0 + frac[0] * (x1 - x0)), y0), (float(x0 + frac[1] * (x1 - x0)), y0 + 4.0)]


@pytest.fixture
def across():
    """stroke_across as a fixture (test modules are not a package)."""
    return stroke_across
