"""Converting a material to another model while keeping its look: the new model's parameters
are fitted to the old material's BRDF over sampled direction pairs, so switching models in the
studio changes the controls, not the appearance (as the paint renderer converts materials to its
lobes basis, worker/renderers/paint/renderer.py ``as_basis``).

The fit: every model here is linear in its colours (albedo, specular, a curve's values) once
its shape (GGX α, a Phong exponent) is fixed, so for each shape the colours are a bounded
linear least-squares problem per channel (scipy ``lsq_linear``); the shape is searched on a log
grid and refined with a bounded scalar minimisation of the same residual. The residual rows:

* f_new − f_old at cosine-weighted ωi for a set of views ωo (the BRDF as the lighting sees it),
  plus ωi concentrated around each view's mirror direction (where a glossy lobe lives, which
  cosine sampling would miss);
* per view, the mean of f·π over the cosine samples (the directional albedo ρ(ωo), what a
  smooth environment shows: the object's mean colour), weighted ALBEDO_WEIGHT times more, so the
  mean colour is kept even when the new model cannot take the old lobe's shape.

Handwritten because no library fits one analytic BRDF to another; the solvers are SciPy's.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import lsq_linear, minimize_scalar

from .base import BRDFModel, Geometry, model_class

# models the studio can convert to (the creatable analytic ones and the editable curve); srbf
# comes from strokes, lobes from the paint designer
TARGETS = ("lambert", "ggx", "blinn-phong", "ashikhmin-shirley", "curve")
ALBEDO_WEIGHT = 4.0        # a view's directional-albedo row against one sample row (see module doc)
CURVE_BINS = 24            # a converted curve's bins over θh ∈ [0°, 90°] (the curve editor's points)
THETA_O = np.radians(np.linspace(0.0, 80.0, 8))     # the views ωo: θo × φo (φo from the tangent:
PHI_O = np.radians([0.0, 45.0, 90.0])               # anisotropic models differ with it)
N_VIEWS = len(THETA_O) * len(PHI_O)
N_COS = 192                # cosine-weighted ωi per view
N_MIRROR = 96              # ωi near the mirror direction per view
ALBEDO_N = 32              # the albedo rows' cosine-weighted ωi per view: ALBEDO_N² (stratified)


class ConvertError(ValueError):
    """A material cannot be converted to the asked model (message says why)."""


@dataclass
class Conversion:
    """material : the fitted material (target model); error : relative RMS of f over the
    sample rows; albedo_error : the largest relative difference of the views' directional
    albedo ρ(ωo) (per channel), i.e. how far the mean colour under a smooth light moved."""
    material: BRDFModel
    error: float
    albedo_error: float


def _cosine(n: int, rng) -> np.ndarray:
    """n×n stratified cosine-weighted directions (Malley's method), (n², 3)."""
    u = (np.arange(n)[:, None] + rng.random((n, n))) / n
    v = (np.arange(n)[None, :] + rng.random((n, n))) / n
    r, phi = np.sqrt(u.ravel()), 2 * np.pi * v.ravel()
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1 - r * r))], -1)


def _samples(seed: int = 7):
    """Direction pairs, deterministic (same input, same conversion): the fit's (Geometry of S
    pairs: per view N_COS cosine-weighted ωi and N_MIRROR near the mirror direction) and the
    albedo rows' (Geometry of N_VIEWS × ALBEDO_N² cosine-weighted pairs, view-major)."""
    rng = np.random.default_rng(seed)
    wis, wos, awi, awo = [], [], [], []
    for t, p in [(t, p) for t in THETA_O for p in PHI_O]:
        wo = np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])
        wi_c = _cosine(int(np.sqrt(N_COS)), rng)
        # around the mirror direction m: cones of 1° to 40° (t1, t2 ⟂ m; m·z ≥ cos 80°, so m ∦ x + z)
        m = np.array([-wo[0], -wo[1], wo[2]])
        t1 = np.cross(m, [1.0, 0.0, 1.0])
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(m, t1)
        a = np.radians(np.geomspace(1.0, 40.0, N_MIRROR)) * np.sqrt(rng.random(N_MIRROR))
        ph = 2 * np.pi * rng.random(N_MIRROR)
        wi_m = np.cos(a)[:, None] * m + np.sin(a)[:, None] * (np.cos(ph)[:, None] * t1 + np.sin(ph)[:, None] * t2)
        wi = np.concatenate([wi_c, wi_m[wi_m[:, 2] > 0.01]])
        wis.append(wi)
        wos.append(np.broadcast_to(wo, wi.shape))
        wa = _cosine(ALBEDO_N, rng)
        awi.append(wa)
        awo.append(np.broadcast_to(wo, wa.shape))
    unit = lambda w: w / np.linalg.norm(w, axis=1, keepdims=True)  # noqa: E731
    return Geometry.of(unit(np.concatenate(wis)), np.concatenate(wos)), \
        Geometry.of(unit(np.concatenate(awi)), np.concatenate(awo))


_SAMPLES = None


def _geometry():
    global _SAMPLES
    if _SAMPLES is None:
        _SAMPLES = _samples()
    return _SAMPLES


def _albedo(cols: np.ndarray) -> np.ndarray:
    """Per-view directional albedo of per-sample columns of the albedo set: (N_VIEWS, C), the
    mean of π·cols over each view's cosine-weighted samples (a Monte Carlo estimate of ρ(ωo))."""
    return np.pi * cols.reshape(N_VIEWS, -1, cols.shape[-1]).mean(axis=1)


def _design(model: str, shape: float | None, g: Geometry):
    """Per-sample columns of the target model at a shape (S, C) for the colour unknowns (the
    same for each channel), the constant part (S, 3) the colours do not scale, and a function
    (x (C, 3), shape) -> the material. Colour bounds are [0, 1] (energy)."""
    inv_pi = np.full(len(g.ci), 1.0 / np.pi)
    zero = np.zeros((len(g.ci), 3))
    if model == "lambert":
        return inv_pi[:, None], zero, lambda x, s: model_class("lambert")(albedo=tuple(x[0]))
    if model == "ggx":
        unit = model_class("ggx")(alpha=shape, specular=(1.0, 1.0, 1.0)).specular_part(g)[:, 0]
        return np.stack([inv_pi, unit], 1), zero, lambda x, s: model_class("ggx")(
            alpha=s, albedo=tuple(x[0]), specular=tuple(x[1]))
    if model == "blinn-phong":
        unit = model_class("blinn-phong")(exponent=shape, specular=(1.0, 1.0, 1.0)).specular_part(g)[:, 0]
        return np.stack([inv_pi, unit], 1), zero, lambda x, s: model_class("blinn-phong")(
            exponent=s, albedo=tuple(x[0]), specular=tuple(x[1]))
    if model == "ashikhmin-shirley":
        # Schlick's F = F0 (1 − w) + w, w = (1 − ωi·h)^5: linear in F0 with a constant part
        cls = model_class("ashikhmin-shirley")
        full = cls(exponent_u=shape, exponent_v=shape, specular=(1.0, 1.0, 1.0)).specular_part(g)[:, 0]
        w = np.clip(1.0 - g.cd, 0.0, 1.0) ** 5
        return np.stack([inv_pi, full * (1 - w)], 1), np.repeat((full * w)[:, None], 3, 1), \
            lambda x, s: cls(exponent_u=s, exponent_v=s, albedo=tuple(x[0]), specular=tuple(x[1]))
    if model == "curve":
        # box basis over θh: p_k · F(ωi·h)/(cosθi + cosθo − cosθi cosθo), F0 = 1 (the values carry the colour)
        th = np.arccos(np.clip(g.ch, 0.0, 1.0))
        k = np.clip((th * (2.0 * CURVE_BINS / np.pi)).astype(np.int64), 0, CURVE_BINS - 1)
        q = 1.0 / np.maximum(g.ci + g.co - g.ci * g.co, 1e-12)
        box = np.zeros((len(th), CURVE_BINS))
        box[np.arange(len(th)), k] = q
        return np.concatenate([inv_pi[:, None], box], 1), zero, lambda x, s: model_class("curve")(
            albedo=tuple(x[0]), values=[tuple(v) for v in x[1:]], fresnel_f0=1.0)
    raise ConvertError(f"cannot convert to {model!r} (models: {', '.join(TARGETS)})")


# shape parameter of each model: (log-grid lo, hi); None: no shape
_SHAPES = {"lambert": None, "curve": None, "ggx": (0.02, 1.0), "blinn-phong": (1.0, 5000.0),
           "ashikhmin-shirley": (1.0, 5000.0)}


def _solve(model: str, shape, fit, alb, f_old, a_old, weight):
    """(residual² sum, x (C, 3), build) of the bounded colour fit at one shape. fit, alb : the
    sample sets; f_old, a_old : the old material on them; weight : (S,) the fit rows' weights."""
    cols, const, build = _design(model, shape, fit)
    acols, aconst, _ = _design(model, shape, alb)
    w_alb = ALBEDO_WEIGHT / np.sqrt(N_VIEWS)
    A = np.concatenate([cols * weight[:, None], _albedo(acols) * w_alb])
    B = np.concatenate([(f_old - const) * weight[:, None], _albedo(a_old - aconst) * w_alb])
    x = np.zeros((cols.shape[1], 3))
    res = 0.0
    upper = np.full(cols.shape[1], 1.0)
    if model == "curve":
        upper[1:] = np.inf           # a curve's p values are densities, not albedos
    # the thousands of rows reduced to C by a QR factorisation: ‖Ax − b‖² = ‖Rx − Qᵀb‖² + (‖b‖² − ‖Qᵀb‖²)
    Q, R = np.linalg.qr(A)
    QB = Q.T @ B
    for c in range(3):
        r = lsq_linear(R, QB[:, c], bounds=(np.zeros(cols.shape[1]), upper), method="bvls")
        x[:, c] = r.x
        res += float(np.sum((R @ r.x - QB[:, c]) ** 2) + B[:, c] @ B[:, c] - QB[:, c] @ QB[:, c])
    return res, x, build


def _scaled(m: BRDFModel, k: np.ndarray) -> BRDFModel:
    """``m`` with its colour parameters (albedo, specular, a curve's values) times k (3,);
    albedos and specular reflectances stay in [0, 1]."""
    upd = {}
    for name in ("albedo", "specular"):
        if name in type(m).model_fields:
            upd[name] = tuple(float(x) for x in np.clip(np.asarray(getattr(m, name)) * k, 0.0, 1.0))
    if m.model == "curve":
        upd["values"] = [tuple(float(x) for x in np.asarray(v) * k) for v in m.values]
    return m.model_copy(update=upd)


def convert(material: BRDFModel, model: str, measure=None) -> Conversion:
    """``material`` (any model) as a ``model`` material with the same look (module docstring).
    The same model converts to itself unchanged.

    measure : optional material -> (3,) mean linear colour of the object as a renderer draws it
    (the session's view and light), or None when it cannot be seen. The BRDF fit keeps the colour under a smooth light; under a
    real map a sharp lobe and a wide one gather different light (a sunset's sun), so the fitted
    colours are then scaled per channel to give the measured mean colour of the old material
    (radiance is linear in them)."""
    if model not in TARGETS:
        raise ConvertError(f"cannot convert to {model!r} (models: {', '.join(TARGETS)})")
    if material.model == model:
        return Conversion(material, 0.0, 0.0)
    fit, alb = _geometry()
    f_old = material.evaluate(fit.wi, fit.wo)
    a_old = material.evaluate(alb.wi, alb.wo)
    # rows between absolute and relative (1/√f): a sharp lobe's peak (f in the hundreds) must not outweigh the rest of the
    # hemisphere, where a smooth light gathers most of what the eye sees
    rho = float(_albedo(a_old).mean())
    weight = 1.0 / np.sqrt(f_old.mean(axis=1) + max(rho, 1e-3) / np.pi) / np.sqrt(len(f_old))
    solve = lambda s: _solve(model, s, fit, alb, f_old, a_old, weight)  # noqa: E731
    rng = _SHAPES[model]
    if rng is None:
        shape = None
    else:
        lo, hi = np.log(rng[0]), np.log(rng[1])
        grid = np.linspace(lo, hi, 16)
        scores = [solve(float(np.exp(t)))[0] for t in grid]
        i = int(np.argmin(scores))
        a, b = grid[max(0, i - 1)], grid[min(len(grid) - 1, i + 1)]
        opt = minimize_scalar(lambda t: solve(float(np.exp(t)))[0], bounds=(a, b), method="bounded",
                              options={"xatol": 1e-3})
        shape = float(np.exp(opt.x if opt.fun <= scores[i] else grid[i]))
    _, x, build = solve(shape)
    mat = build(x, shape)
    if measure is not None:
        for _ in range(2):           # a second pass where a clip to [0, 1] took some of the scale
            want, got = measure(material), measure(mat)
            if want is None or got is None:           # the object is not in view: the fit alone
                break
            want, got = np.asarray(want, np.float64), np.asarray(got, np.float64)
            k = np.where(got > 1e-9, want / np.maximum(got, 1e-9), 1.0)
            if np.max(np.abs(k - 1.0)) < 1e-3:
                break
            mat = _scaled(mat, k)
    f_new = mat.evaluate(fit.wi, fit.wo)
    err = float(np.sqrt(np.mean(((f_new - f_old) * weight[:, None]) ** 2)) /
                max(np.sqrt(np.mean((f_old * weight[:, None]) ** 2)), 1e-12))
    r_old, r_new = _albedo(a_old).mean(axis=0), _albedo(mat.evaluate(alb.wi, alb.wo)).mean(axis=0)
    return Conversion(mat, err, float(np.max(np.abs(r_new - r_old) / np.maximum(r_old, 1e-3))))
