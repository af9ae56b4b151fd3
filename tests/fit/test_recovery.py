"""Recovery of glossy GGX materials rendered by Mitsuba 3: the hardest cases of the
benchmark matrix (BENCHMARKS.md "Paint to BRDF: recovery") at test size.

The bunny at 160×120, fitted at full resolution, against the mean of two 256-spp Mitsuba
renders (cached in tests/.cache/mitsuba by content). ``rel_rmse`` is the srbf fit re-rendered in
pixel mode, ``ggx_floor`` Glint's own render of the GGX material: the renderer's error, which no
fit can remove (a sun's sharp reflections on a coarse mesh).

Time (2 cores, loaded machine): 10-15 s per case with the targets cached (two transfers at 6,370
fit pixels for the fitted roughness, the independent energy check ~5-10 s, four renders); the
first run adds ~5 s per target for the two Mitsuba renders. The paper's-model test runs two
cases (13-24 s)."""

import pytest

from worker.fit.basis import paper_basis
from worker.fit.recovery import Case, recover

pytest.importorskip("mitsuba")

SPP = 256


@pytest.fixture(scope="module")
def bunny_env(shared_assets, cache_dir):
    """The cut renderer of the test bunny under an environment map, by name (cuts cached)."""
    from helpers import open_renderer, scene_file

    from worker.envmap import load_envmap
    from worker.scene import LoadedScene, load_scene

    out = {}

    def get(env):
        if env not in out:
            sc = load_scene(scene_file("bunny.json"))
            spec = sc.spec.model_copy(deep=True)
            spec.environment.map = str(shared_assets / "env" / env)
            out[env] = open_renderer(LoadedScene(spec, sc.root, envmap=load_envmap(shared_assets / "env" / env)))
        return out[env]
    return get


def _run(bunny_env, cache_dir, env, alpha, specular, albedo, **kw):
    r = recover(bunny_env(env), Case("bunny", env, alpha, specular, albedo), fit_scale=1.0, spp=SPP,
                cache_dir=cache_dir / "mitsuba", **kw)
    print(f"{env} α={alpha} s={specular} ρd={albedo}: fit {r['rel_rmse']:.4f} (vertex {r['rel_rmse_vertex']:.4f}, "
          f"settled {r['rel_rmse_still']:.4f}), Glint's GGX {r['ggx_floor']:.4f} (settled {r['ggx_floor_still']:.4f}), "
          f"noise {r['noise']:.4f}, residual {r['residual_rel']:.4f}, "
          f"energy {r['energy_fraction']:.4f} of its bound, static α {r['static_alpha']:.3f}")
    return r


@pytest.mark.slow
def test_sharp_gloss_under_a_sun(bunny_env, cache_dir):
    """α = 0.1 under a real sun (stinson-beach): the worst α ≥ 0.1 case of the matrix. Glint's
    own GGX render is 24% off here with one sample per pixel, most of it the sun's reflections on
    2.8K vertices aliasing at 160×120 against Mitsuba's pixel means: the settled frame (16 samples
    at edges and curved highlights) is 4.6% off (6.8% at 4 samples, which the bounds below
    refuse). The fit, its rows at edges and glints the mean over their pixels, is as close in the
    settled frame (10.1% with centre rows everywhere); its one-sample frame is as far off as the
    GGX's. Energy conservation holds by an independent quadrature."""
    r = _run(bunny_env, cache_dir, "stinson-beach.hdr", 0.1, 0.95, (0.0, 0.0, 0.0))
    assert r["energy_ok"], r["energy"]
    assert r["rel_rmse"] < r["ggx_floor"] + 0.015, (r["rel_rmse"], r["ggx_floor"])   # measured 0.224 vs 0.244
    assert r["ggx_floor_still"] < 0.055, (r["ggx_floor_still"], r["ggx_floor"])   # 0.046 vs 0.244 (4 samples: 0.068)
    assert r["rel_rmse_still"] < 0.055, r["rel_rmse_still"]                      # measured 0.043 (4 samples: 0.060)
    assert 0.07 < r["static_alpha"] < 0.15            # the fitted shadowing roughness finds α


@pytest.mark.slow
def test_coated_sharp_gloss_under_a_sky(bunny_env, cache_dir):
    """α = 0.1 specular 0.5 over a coloured diffuse base, sunset sky: within the 8% the recovery benchmark targets."""
    r = _run(bunny_env, cache_dir, "sunset.exr", 0.1, 0.5, (0.45, 0.3, 0.2))
    assert r["energy_ok"], r["energy"]
    assert r["rel_rmse"] < 0.08                        # measured 0.046 (Mitsuba noise 0.036)


@pytest.mark.slow
def test_the_papers_model_is_what_fails(bunny_env, cache_dir):
    """The same bare α = 0.15 target through inverse-brdf-modeling's basis and static function,
    against the default model: the default is within 1.5% of Glint's GGX floor, the paper's is not."""
    new = _run(bunny_env, cache_dir, "sunset.exr", 0.15, 0.95, (0.0, 0.0, 0.0), renders=True)
    old = _run(bunny_env, cache_dir, "sunset.exr", 0.15, 0.95, (0.0, 0.0, 0.0), basis=paper_basis(),
               auto_static=False)
    assert new["rel_rmse"] < new["ggx_floor"] + 0.015  # measured 0.044 vs 0.049
    assert old["rel_rmse"] > new["rel_rmse"] + 0.02    # measured 0.093
    assert new["energy_ok"] and old["energy_ok"]
