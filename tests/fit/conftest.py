import copy

import numpy as np
import pytest

from worker.scene import Lambert

DULL = Lambert(albedo=(0.4, 0.4, 0.4))


@pytest.fixture(scope="module")
def bunny_view(bunny_renderer):
    """(renderer, FitView): the bunny's view at 160×120 fit pixels (the default fit size),
    transfer built once per module."""
    from worker.fit.fitter import Fitter

    fx = Fitter(bunny_renderer, "bunny", base_material=DULL, fit_scale=1.0)
    fx.add_view()
    return bunny_renderer, fx.views[0]


@pytest.fixture
def fitter(bunny_view):
    """A fresh Fitter on the dull (Lambert 0.4) bunny, sharing the module's transfer matrix."""
    from worker.fit.fitter import Fitter

    r, view = bunny_view
    fx = Fitter(r, "bunny", base_material=DULL, fit_scale=1.0)
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
