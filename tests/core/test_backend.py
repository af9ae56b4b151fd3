"""The kernel backend is chosen once and passed down: every family of a backend is that
backend's, renderers and precomputations keep the backend they were built with, and a process
without the C library (GLINT_NO_NATIVE=1) runs everything on the NumPy references."""
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from worker import native
from worker.native.kernels import kernels

ROOT = Path(__file__).resolve().parents[2]
FAMILIES = ("fields", "gi", "paint", "capture", "refine", "fit")
# a tiny GI scene: the NumPy path tracer accumulates a dense tile tensor, exact but slow
GI_SCENE = ("cornell", 8, 8)
GI_OPTIONS = {"spp": 2, "series": [16, 1]}


def backends():
    return ["numpy"] + (["native"] if native.available() else [])


@pytest.mark.parametrize("name", backends())
def test_every_family_belongs_to_its_backend(name):
    k = kernels(name)
    assert k is kernels(name)                              # one object per backend and process
    fams = k.families()
    assert set(fams) == set(FAMILIES)
    assert all(f.name == name for f in fams.values()), {n: f.name for n, f in fams.items()}


def test_default_backend_is_native_when_built():
    assert kernels().name == ("native" if native.available() else "numpy")


def test_precomputations_keep_the_backend_they_were_given():
    from worker.renderers.paint.renderer import PaintPrecomputation
    from worker.renderers import get
    from worker.renderers.cuts.precompute import CutPrecomputation
    from worker.renderers.gi import GIPrecomputation

    for cls in (CutPrecomputation, GIPrecomputation, PaintPrecomputation):
        assert cls(kernels("numpy")).kernels is kernels("numpy")
        assert cls().kernels is kernels()                  # the process's, when none is given
    for kind in ("cuts", "gi", "paint"):
        assert get(kind)[1].kernels is kernels()


def test_combiner_keeps_the_backend_it_was_given():
    """The cut renderer's field stage holds the backend given and builds with it."""
    from worker.core.directions import get_tree
    from worker.renderers.cuts.combine import Combiner
    from worker.renderers.cuts.rotate import LeafMap

    k = kernels("numpy")
    cb = Combiner(kernels=k)
    assert cb.k is k
    q = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])
    lm = cb.leaf_map(q)                                    # nearest leaves by k.fields
    if native.available():
        assert np.array_equal(lm.perm, LeafMap(get_tree(), q, kernels("native")).perm)


_CHILD = textwrap.dedent("""
    import json, sys
    import numpy as np
    from worker import native
    from worker.native.kernels import kernels
    assert native.lib is None, "GLINT_NO_NATIVE=1 must leave the library unloaded"
    k = kernels()
    assert k.name == "numpy" and all(f.name == "numpy" for f in k.families().values())
    try:
        kernels("native")
        raise AssertionError("a native backend without the library")
    except RuntimeError:
        pass

    # core, fields, paint, capture: each family through the default backend
    from worker.core.render import camera_rays, env_lookup
    from worker.core.tonemap import tonemap
    o, d = camera_rays((0, 0, 3), (0, 0, 0), (0, 1, 0), 40.0, 8, 6)
    env = np.random.default_rng(0).random((16, 32, 3)).astype(np.float32)
    tonemap(env_lookup(d, env, 30.0, 1.0))
    from worker.core.directions import get_tree
    from worker.renderers.cuts.rotate import LeafMap
    LeafMap(get_tree(), np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]))
    from worker.renderers.paint.prefilter import prefilter_all
    from worker.renderers.paint.render import background
    maps = prefilter_all(env, [4.0])
    background(np.zeros((4, 2), np.float32), env, 10.0, 1.0)
    from worker.capture.fisheye import Lens
    from worker.capture.stitch import fisheye_map
    fisheye_map(8, 16, Lens(40, 30, "equidistant", 190.0), 20.0)

    # GI: the precomputation traces with the NumPy references, the renderer freezes and draws
    from gi_harness import scene_with
    from worker.artifacts import DirStore
    from worker.renderers import ensure, load
    from worker.renderers.gi import GIPrecomputation, GIRenderer
    name, w, h = json.loads(sys.argv[1])
    opts, store_dir, out = json.loads(sys.argv[2]), sys.argv[3], sys.argv[4]
    sc = scene_with(name, w, h)
    pre = GIPrecomputation(kernels("numpy"))
    store = DirStore(store_dir, "gi")
    ensure(pre, sc, store, opts)
    r = GIRenderer(sc, load(pre, sc, store, opts), kernels=kernels("numpy"))
    assert r.k.name == "numpy" and pre.kernels.name == "numpy"
    np.save(out, r.draw())
""")


def test_numpy_backend_never_needs_the_library(tmp_path):
    """With the library made unavailable, the NumPy backend runs every family, and a GI
    precomputation and renderer built on it work end to end (a C call would fail: there is no
    library). When the library is built here, the image agrees with the C kernels' own."""
    env = {**os.environ, "GLINT_NO_NATIVE": "1",
           "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "tests"), str(ROOT / "tests" / "gi")])}
    out = tmp_path / "numpy.npy"
    r = subprocess.run([sys.executable, "-c", _CHILD, json.dumps(GI_SCENE), json.dumps(GI_OPTIONS),
                        str(tmp_path / "store_numpy"), str(out)],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-4000:]
    img_numpy = np.load(out)
    assert np.isfinite(img_numpy).all() and img_numpy.max() > 0
    if not native.available():
        return
    sys.path.insert(0, str(ROOT / "tests" / "gi"))     # gi_harness, as tests/gi imports it
    from gi_harness import scene_with

    from worker.artifacts import DirStore
    from worker.renderers import ensure, load
    from worker.renderers.gi import GIPrecomputation, GIRenderer

    sc = scene_with(*GI_SCENE)
    pre = GIPrecomputation(kernels("native"))
    store = DirStore(tmp_path / "store_native", "gi")
    ensure(pre, sc, store, GI_OPTIONS)
    img = GIRenderer(sc, load(pre, sc, store, GI_OPTIONS), kernels=kernels("native")).draw()
    # same random numbers: tensors to float rounding, frames to half-float rounding of F
    assert np.abs(img - img_numpy).max() <= 1e-4 * np.abs(img).max()
