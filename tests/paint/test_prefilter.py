"""Prefiltered lobe maps (worker/renderers/paint/prefilter.py, C glp_prefilter): closed forms, C against the
NumPy reference, and a brute-force convolution of a real HDRI for the sharp lobes."""
import numpy as np
import pytest

from worker import native
from worker.native.kernels import kernels
from worker.core.lighting import pixel_directions
from worker.envmap import load_envmap
from worker.renderers.paint.prefilter import (LobeMaps, level_for, prefilter, prefilter_all, prefilter_numpy, pyramid,
                                    support_cos)
from worker.renderers.paint.render import _lookup


def test_constant_map_is_unchanged():
    c = np.full((32, 64, 3), 0.7, np.float32)
    for e in (1.0, 7.0, 300.0):
        assert np.abs(prefilter_numpy(c, e) - 0.7).max() < 1e-5
        assert np.abs(prefilter(c, e) - 0.7).max() < 1e-5


@pytest.mark.skipif(not native.available(), reason="C kernels not built")
def test_c_kernel_matches_numpy_reference(assets):
    env = load_envmap(assets / "env" / "sunset.exr")
    lv = pyramid(env)
    for e in (1.0, 25.0, 900.0, 6000.0):
        img = lv[max(level_for(e, lv), 2)]            # small levels keep the reference quick
        a, b = prefilter(img, e, kernels("native")), prefilter(img, e, kernels("numpy"))
        err = np.abs(a - b).max() / np.abs(b).max()
        assert err < 1e-4, (e, err)


def test_rotation_commutes_with_prefiltering(assets):
    env = load_envmap(assets / "env" / "city.exr")
    img = pyramid(env)[3]                              # 32 × 64
    shift = 16                                         # a quarter turn
    a = prefilter(np.roll(img, -shift, axis=1), 5.0)
    b = np.roll(prefilter(img, 5.0), -shift, axis=1)
    assert np.abs(a - b).max() < 1e-5 * np.abs(b).max()


def _brute(env, dirs, e, s=4):
    """(K, 3) normalised cosine-lobe convolution at directions (K, 3) of the piecewise-constant map,
    each pixel split into s×s sub-pixels with their exact solid angles (only pixels near R)."""
    h, w, _ = env.shape
    d1, sa1 = pixel_directions(h, w, 1)
    ds, sas = pixel_directions(h, w, s)
    pix = d1.reshape(-1, 3)
    cmin = np.cos(np.arccos(support_cos(e)) + 2 * np.pi / h)
    out = np.zeros((len(dirs), 3))
    for k, r in enumerate(dirs):
        near = np.nonzero(pix @ r > cmin)[0]
        rows, cols = near // w, near % w
        sub_r = rows[:, None] * s + np.arange(s)[None, :]
        sub_c = cols[:, None] * s + np.arange(s)[None, :]
        sd = ds[sub_r[:, :, None], sub_c[:, None, :]]                       # (n, s, s, 3)
        om = np.broadcast_to(sas[sub_r][:, :, None], sd.shape[:3])
        kern = np.maximum(sd @ r, 0.0) ** e * om * (e + 1) / (2 * np.pi)
        out[k] = (kern[..., None] * env[rows, cols][:, None, None, :]).sum((0, 1, 2))
    return out


def test_sharp_lobes_against_brute_force_convolution(assets, cached):
    """The sharp lobes (computed at the 1K map's own resolution) against a 4×4-supersampled direct
    convolution at 300 directions: relative RMSE per lobe."""
    env = load_envmap(assets / "env" / "interior-1k.exr")
    rng = np.random.default_rng(1)
    dirs = rng.normal(size=(300, 3)); dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    exps = [300.0, 3000.0, 9000.0]
    maps = prefilter_all(env, exps)
    for i, e in enumerate(exps):
        ref = cached("brute-lobe", [env, dirs, e, "v1"], lambda: _brute(env, dirs, e))
        got = _lookup(maps.maps[i + 1], dirs, 0.0)
        rel = np.sqrt(np.mean((got - ref) ** 2)) / np.sqrt(np.mean(ref ** 2))
        assert rel < 0.02, f"E={e}: relative RMSE {rel:.4f} against brute force (threshold 2%)"


def test_maps_round_trip_bytes(assets):
    env = load_envmap(assets / "env" / "forest.exr")
    m = prefilter_all(env, [4.0, 40.0])
    m2 = LobeMaps.from_bytes(m.to_bytes())
    assert m2.exponents == m.exponents and all(np.array_equal(a, b) for a, b in zip(m.maps, m2.maps))
