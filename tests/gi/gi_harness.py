"""Comparison of the GI renderer with Mitsuba 3 ``path`` (max_depth = bounces + 1), with the
noise of both sides subtracted (shared by tests/gi and the BENCHMARKS numbers).

Both sides are the mean of two independent renders (our precomputation with seeds 0 and 1,
Mitsuba with seeds 1 and 2); half the RMS difference of a pair estimates the noise left in its
mean. The error is the relative RMSE over object pixels whose 3×3 neighbourhood is one object
(silhouettes differ: Mitsuba box-filters the pixel, we trace its centre), reported raw and with
both noises subtracted in quadrature. Mitsuba renders and our tensors are cached in tests/.cache.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
from scipy.ndimage import minimum_filter, maximum_filter
from helpers import cache_lock

ROOT = Path(__file__).resolve().parents[2]
CACHE = ROOT / "tests" / ".cache"
SCENES = ROOT / "tests" / "scenes" / "gi"


def scene_with(name: str, width: int, height: int, materials: dict | None = None):
    """A test scene at a resolution, with some objects' materials replaced."""
    from worker.scene import load_scene, LoadedScene
    from helpers import scene_file
    sc = load_scene(scene_file(f"gi/{name}.json"))
    spec = sc.spec.model_copy(deep=True)
    spec.camera.width, spec.camera.height = width, height
    for o in spec.objects:
        if materials and o.name in materials:
            o.material = materials[o.name]
    return LoadedScene(spec, sc.root, envmap=sc.envmap)


def gi_renderer(scene, options: dict, backend: str | None = None, precompute: str | None = None):
    """A GIRenderer on the kernel backend ``backend`` (None: the process's) over tensors from the
    shared cache, traced (when missing) by the backend ``precompute`` (None: the process's; the
    NumPy trace is exact but slow, so the test scenes precompute with the default)."""
    from worker.artifacts import DirStore
    from worker.native.kernels import kernels
    from worker.renderers import ensure, load
    from worker.renderers.gi import GIPrecomputation, GIRenderer
    pre = GIPrecomputation(kernels(precompute))
    store = DirStore(CACHE, "gi")
    with cache_lock("gi", scene.spec.model_dump(mode="json"), options, str(getattr(scene, "root", ""))):
        ensure(pre, scene, store, options)
    return GIRenderer(scene, load(pre, scene, store, options), kernels=kernels(backend))


def mitsuba(scene, spp: int, seed: int, max_depth: int) -> np.ndarray:
    from worker.mitsuba_ref import render_mitsuba
    h = hashlib.sha256(json.dumps([scene.spec.model_dump(mode="json"), spp, seed, max_depth, "path2s"]).encode())
    h.update(np.ascontiguousarray(scene.envmap).tobytes())
    path = CACHE / "gi-mitsuba" / f"{h.hexdigest()[:32]}.npy"
    with cache_lock(str(path)):
        if path.is_file():
            return np.load(path)
        img = render_mitsuba(scene, spp=spp, seed=seed, integrator="path", max_depth=max_depth, two_sided=True)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npy")
        np.save(tmp, img)
        tmp.replace(path)
        return img


def inner_mask(renderer) -> np.ndarray:
    """Object pixels whose 3×3 neighbourhood is one object and one smooth surface (shading
    normals within ~25°): silhouettes and creases are box-filtered by Mitsuba, not by us."""
    oid = renderer.prim.object_id
    H, W = oid.shape
    n = np.zeros((H * W, 3)); n[renderer.prim.pixel] = renderer.prim.ns
    n = n.reshape(H, W, 3)
    m = (oid >= 0) & (minimum_filter(oid, 3, mode="nearest") == maximum_filter(oid, 3, mode="nearest"))
    pad = np.pad(n, ((1, 1), (1, 1), (0, 0)), mode="edge")
    for dy in range(3):
        for dx in range(3):
            m &= (pad[dy:dy + H, dx:dx + W] * n).sum(-1) > 0.9
    return m


def compare(ours: tuple, ref: tuple, mask: np.ndarray) -> dict:
    """ours, ref: pairs of independent images (H, W, 3). Relative RMSE of the means over mask,
    raw and noise-corrected, and each side's noise (relative)."""
    a = 0.5 * (ours[0] + ours[1]); b = 0.5 * (ref[0] + ref[1])
    norm = np.sqrt((b[mask] ** 2).mean())
    err2 = ((a[mask] - b[mask]) ** 2).mean()
    n_o = 0.25 * ((ours[0][mask] - ours[1][mask]) ** 2).mean()
    n_r = 0.25 * ((ref[0][mask] - ref[1][mask]) ** 2).mean()
    return {"rel_rmse": float(np.sqrt(err2) / norm), "rel_rmse_corrected": float(np.sqrt(max(err2 - n_o - n_r, 0.0)) / norm),
            "noise_ours": float(np.sqrt(n_o) / norm), "noise_ref": float(np.sqrt(n_r) / norm),
            "mean_ratio": float(a[mask].mean() / b[mask].mean()), "pixels": int(mask.sum())}


def session_runtime(r, state=None):
    """A worker session (jobs/runtime.py, no server) on GI renderer r, from a new state of its
    scene or ``state`` (a SessionState)."""
    from worker.jobs.runtime import SessionRuntime
    from worker.protocol import new_state
    st = state if state is not None else new_state(r.scene.spec)
    return SessionRuntime(r.scene, r, {"state": st.model_dump(mode="json"), "strokes": []})


def session_frame(rt):
    """(radiance (H, W, 3) float64, object ids (H, W)) of the session's current state."""
    from worker.renderers import FrameRequest, Lighting
    st = rt.state
    out = rt.renderer.render(FrameRequest(camera=st.camera, lighting=Lighting(st.rotation_deg, st.intensity),
                                          materials=st.materials))
    return out.radiance.astype(np.float64).copy(), out.object_id


def middle_row(ids, obj: int, lo: float = 0.3, hi: float = 0.7):
    """(y, x0, x1): the object's median image row and the x pixel centres at the lo and hi
    quantiles of its pixels on that row (a stroke across the object's middle)."""
    ys, xs = np.nonzero(ids == obj)
    y = int(np.median(ys))
    row = xs[ys == y]
    return y, float(np.quantile(row, lo)) + 0.5, float(np.quantile(row, hi)) + 0.5
