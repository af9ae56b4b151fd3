"""Recovery benchmark: fit ``srbf`` to an independent render of a known GGX material, re-render
with Glint, and measure how close it comes.

For each case (scene, environment map, GGX α, specular, diffuse albedo):

1. Mitsuba 3 renders the scene with the GGX material (``mitsuba_ref.render_mitsuba``, two seeds;
   their mean is the target, their difference estimates its noise). Renders are cached under a
   content key of everything they depend on (``mitsuba_target``).
2. A ``Fitter`` fits the srbf material to the target (constrained: c ≥ 0 and the energy rows),
   with the diffuse albedo given, as a designer would give it.
3. Glint re-renders the fitted material, in ``pixel`` mode (what the model can do), the default
   ``refined`` mode (per pixel where vertex shading is wrong) with one sample per pixel (the
   frames of a moving camera, ``glint render``'s default) and as the studio's settled frame
   (``STILL_SAMPLES`` at ``STILL_ANTIALIAS``: samples at silhouettes, occlusions and creases),
   and ``vertex`` mode, and the GGX material itself (the renderer's own floor) in each.

A Mitsuba pixel is the mean radiance over the pixel's area (box filter); a one-sample frame is
the radiance at its centre. Where the object has detail a few pixels wide (a sofa's piping)
that difference dominates: the sofa2 under sunset, GGX α 0.1, per pixel: 17.1% at one sample,
5.2% at 16 (512-spp references). The settled frame's figure is the one that compares shading.

Figures are relative RMSE over the object's pixels away from its silhouette (the object mask
eroded by one pixel: a pixel straddling the silhouette mixes object and background differently
in the two renderers), ``residual_rel`` of the solve (at the fit pixels), the largest specular
directional albedo by an independent quadrature (``basis.energy_maximum``), and times.
"""
from __future__ import annotations

import copy
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_write
from ..errors import GlintError
from ..keys import content_key
from ..scene import GGX, Lambert, LoadedScene
from .basis import SRBFBasis, default_basis, energy_maximum

ALPHAS = (0.05, 0.1, 0.15, 0.25, 0.4)
# (specular, diffuse albedo) pairs: a bright conductor-like coat without diffuse, and a coloured
# diffuse base under a dimmer coat (max specular + max albedo ≤ 1 for Mitsuba's blend)
FINISHES = ((0.95, (0.0, 0.0, 0.0)), (0.5, (0.45, 0.3, 0.2)))


class RecoveryError(GlintError):
    """A recovery case that cannot run (unknown object, no Mitsuba)."""


@dataclass(frozen=True)
class Case:
    scene: str                      # label of the scene (mesh and camera)
    env: str                        # label of the environment map
    alpha: float
    specular: float
    albedo: tuple[float, float, float]

    @property
    def material(self) -> GGX:
        return GGX(alpha=self.alpha, specular=(self.specular,) * 3, albedo=self.albedo)


def rel_rmse(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """RMS of a − b over mask pixels, relative to the RMS of b there."""
    d = (a[mask] - b[mask]).astype(np.float64)
    return float(np.sqrt((d ** 2).mean()) / max(np.sqrt((b[mask].astype(np.float64) ** 2).mean()), 1e-30))


def interior_mask(renderer, object_index: int = 0) -> np.ndarray:
    """(H, W) bool: the object's pixels (in the scene camera's view) whose 4-neighbours are the
    object's too."""
    from scipy.ndimage import binary_erosion

    return binary_erosion(renderer.object_mask(renderer.scene.spec.camera) == object_index, iterations=1)


def _render(renderer, materials, shading: str, samples: int = 1, antialias: str = "full") -> np.ndarray:
    """(H, W, 3) float32 radiance of the scene camera's view under the scene's lighting."""
    from ..renderers.base import FrameRequest, Lighting

    spec = renderer.scene.spec
    env = spec.environment
    req = FrameRequest(camera=spec.camera, lighting=Lighting(env.rotation_deg, env.intensity),
                       materials=list(materials), shading=shading, samples=samples, antialias=antialias)
    return renderer.render(req).radiance


def _render_still(renderer, materials) -> np.ndarray:
    """The studio's settled frame of the scene camera's view: refined, anti-aliased as a session's
    still (jobs/lod.py)."""
    from ..jobs.lod import STILL_ANTIALIAS, STILL_SAMPLES

    return _render(renderer, materials, "refined", STILL_SAMPLES, STILL_ANTIALIAS)


TARGET_VERSION = 2      # of the cached targets' key (worker/keys.py)


def _target_key(scene: LoadedScene, spp: int, seeds, mitsuba_version: str, **options) -> str:
    """Content key of a Mitsuba target: geometry, normals, objects, map, camera, lighting,
    materials, samples, seeds, Mitsuba's version and the render options set (render_mitsuba's
    ``two_sided``, ``face_normals``; left out when unset, so older targets keep their keys)."""
    m = scene.mesh
    extra = {k: bool(v) for k, v in options.items() if v}
    return content_key("mitsuba-target", TARGET_VERSION, vertices=m.vertices, faces=m.faces, normals=m.normals,
                       object_of_face=scene.object_of_face, envmap=scene.envmap,
                       camera=scene.spec.camera.model_dump(mode="json"),
                       environment=scene.spec.environment.model_copy(update={"map": ""}).model_dump(mode="json"),
                       materials=[o.material.model_dump(mode="json") for o in scene.spec.objects],
                       spp=int(spp), seeds=[int(s) for s in seeds], mitsuba=mitsuba_version, **extra)


def mitsuba_target(scene: LoadedScene, spp: int, seeds=(1, 2), cache_dir: Path | None = None,
                   two_sided: bool = False, face_normals: bool = False):
    """Mitsuba's render of the scene: (mean (H, W, 3) float32 of the seeds' renders, their stack
    (S, H, W, 3)). Cached as .npy under a content key of the geometry, normals, map, camera,
    lighting, materials, spp, seeds, Mitsuba's version and the options (render_mitsuba's)."""
    try:
        import mitsuba
    except ImportError as e:
        raise RecoveryError("the recovery benchmark needs Mitsuba 3 (pip install mitsuba)") from e
    from ..mitsuba_ref import render_mitsuba

    key = _target_key(scene, spp, seeds, mitsuba.__version__, two_sided=two_sided, face_normals=face_normals)
    path = Path(cache_dir) / f"{key}.npy" if cache_dir else None
    if path is not None and path.is_file():
        try:
            imgs = np.load(path, allow_pickle=False)
            return imgs.mean(0), imgs
        except (OSError, ValueError):
            path.unlink(missing_ok=True)       # a damaged cache entry is rebuilt, not trusted
    imgs = np.stack([render_mitsuba(scene, spp=spp, seed=s, two_sided=two_sided, face_normals=face_normals)
                     for s in seeds]).astype(np.float32)
    if path is not None:
        import io

        buf = io.BytesIO()
        np.save(buf, imgs)
        atomic_write(path, buf.getvalue())
    return imgs.mean(0), imgs


def noise_of_mean(imgs: np.ndarray, mask: np.ndarray) -> float:
    """Relative RMS noise of the mean of S independent renders (S, H, W, 3), over mask: the
    seeds' spread estimates one render's variance, divided by S for the mean."""
    s = len(imgs)
    if s < 2:
        return float("nan")
    m = imgs.mean(0)
    var = ((imgs - m) ** 2).sum(0)[mask] / (s - 1)
    return float(np.sqrt(var.mean() / s) / max(np.sqrt((m[mask].astype(np.float64) ** 2).mean()), 1e-30))


def recover(renderer, case: Case, *, basis: SRBFBasis | None = None, fit_scale: float = 1.0,
            spp: int = 128, seeds=(1, 2), cache_dir: Path | None = None, object_index: int = 0,
            renders: bool = True, auto_static: bool = True) -> dict:
    """Run one case; returns its figures (see the module doc). ``renderer`` is the cut renderer
    of the scene loaded with the case's environment map; its object ``object_index`` gets the
    case's material."""
    from .fitter import Fitter

    scene = renderer.scene
    spec = scene.spec.model_copy(deep=True)
    spec.objects[object_index].material = case.material
    target_scene = copy.copy(scene)
    target_scene.spec = spec
    t0 = time.perf_counter()
    target, imgs = mitsuba_target(target_scene, spp, seeds, cache_dir)
    t_target = time.perf_counter() - t0
    mats = list(scene.materials)
    mask = interior_mask(renderer, object_index)
    fx = Fitter(renderer, spec.objects[object_index].name, base_material=Lambert(albedo=case.albedo),
                basis=basis or default_basis(), fit_scale=fit_scale, albedo=case.albedo)
    fx.add_view()
    out = fx.fit_targets([target], auto_static=auto_static)
    s = out.solve
    emax = energy_maximum(fx.basis, s.coefficients)
    res = {**asdict(case), "pixels": out.pixels, "basis": fx.basis.J, "static": fx.basis.static,
           "static_alpha": fx.basis.static_alpha,
           "residual_rel": s.residual_rel, "energy_max_rows": s.energy_max,
           # per channel: the largest specular albedo by independent quadrature, and 1 − ρ_d
           "energy": emax.tolist(), "energy_bound": (1.0 - np.asarray(case.albedo)).tolist(),
           "energy_fraction": float((emax / (1.0 - np.asarray(case.albedo))).max()),
           "energy_ok": bool(np.all(emax <= 1.0 - np.asarray(case.albedo) + 1e-9)),
           "ms_solve": s.seconds * 1e3, "ms_transfer": out.seconds_transfer * 1e3,
           "noise": noise_of_mean(imgs, mask), "seconds_target": t_target, "mask_pixels": int(mask.sum())}
    if renders:
        mats[object_index] = out.material
        fit_px = _render(renderer, mats, "pixel")
        fit_rf = _render(renderer, mats, "refined")
        fit_vx = _render(renderer, mats, "vertex")
        fit_st = _render_still(renderer, mats)
        mats[object_index] = case.material
        ggx_px = _render(renderer, mats, "pixel")
        ggx_rf = _render(renderer, mats, "refined")
        ggx_vx = _render(renderer, mats, "vertex")
        ggx_st = _render_still(renderer, mats)
        res.update({"rel_rmse": rel_rmse(fit_px, target, mask), "rel_rmse_vertex": rel_rmse(fit_vx, target, mask),
                    "rel_rmse_refined": rel_rmse(fit_rf, target, mask), "rel_rmse_still": rel_rmse(fit_st, target, mask),
                    "ggx_floor": rel_rmse(ggx_px, target, mask), "ggx_floor_vertex": rel_rmse(ggx_vx, target, mask),
                    "ggx_floor_refined": rel_rmse(ggx_rf, target, mask), "ggx_floor_still": rel_rmse(ggx_st, target, mask),
                    "fit_vs_glint_ggx": rel_rmse(fit_px, ggx_px, mask)})
        res["_images"] = {"target": target, "fit": fit_px, "ggx": ggx_px, "fit_still": fit_st}
    res["_material"] = out.material          # the fitted design (public() leaves it out)
    return res


def matrix(alphas=ALPHAS, finishes=FINISHES):
    """The (α, specular, albedo) combinations of the benchmark, in order."""
    return [(a, s, tuple(alb)) for a in alphas for s, alb in finishes]


def summary_row(r: dict) -> str:
    """One markdown table row of a result."""
    alb = "none" if max(r["albedo"]) == 0 else "(" + ", ".join(f"{x:g}" for x in r["albedo"]) + ")"
    return (f"| {r['scene']} | {r['env']} | {r['alpha']:g} | {r['specular']:g} | {alb} | {r['pixels']} | "
            f"{100 * r['rel_rmse']:.1f}% | {100 * r['rel_rmse_vertex']:.1f}% | {100 * r['ggx_floor']:.1f}% | "
            f"{100 * r['noise']:.1f}% | {100 * r['residual_rel']:.1f}% | {r['energy_fraction']:.3f} | "
            f"{r['ms_solve']:.1f} |")


def public(r: dict) -> dict:
    """A result without its images (JSON-serialisable)."""
    return json.loads(json.dumps({k: v for k, v in r.items() if not k.startswith("_")}))
