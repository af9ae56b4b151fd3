"""The BRDF curve a session's studio plots for a material (curve and fit events)."""
from __future__ import annotations

import json

import numpy as np

from ..models import SRBF

CURVE_SAMPLES = 91
LOBE_INCIDENT_DEG = tuple(range(0, 90, 5))     # the lobe plot's incident angles (its slider snaps to them)
LOBE_SAMPLES = 91                              # θo from −90° to 90°
# the incident angles of the lobe's RGB (the paint designer's plot; its 45° is the measurement
# geometry's illumination): a few, so a curve event is ~36 KB rather than ~75 KB
LOBE_RGB_INCIDENT_DEG = (15, 30, 45, 60, 75)


def brdf_curve(material, n: int = CURVE_SAMPLES) -> dict:
    """The 1D half-angle distribution to plot: p(θh) averaged over φh for srbf, the curve's
    values for curve, and f(θh) in the plane of incidence at normal viewing otherwise.
    Returns {"theta_deg": [...], "values": [[r, g, b], ...], "quantity": str, "diffuse": [r, g, b]
    (albedo/π, included in values for the non-srbf models), "specular": [[r, g, b], ...] (values
    less the diffuse part: what the curve editor's points move), "lobe": ``brdf_lobe``}."""
    from ..core.brdf import evaluate, srbf_material_p

    th = np.linspace(0.0, 90.0, n)
    t = np.radians(th)
    if isinstance(material, SRBF):
        ph = np.linspace(0, 2 * np.pi, 48, endpoint=False)
        T, P = np.meshgrid(t, ph, indexing="ij")
        h = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
        vals = srbf_material_p(material, h).mean(axis=1)       # every centre with its own λ
        q = "p(θh), mean over φh"
    else:
        # ωo = normal, ωi at 2θh in the x-z plane, so θh is the half angle
        wo = np.broadcast_to([0.0, 0.0, 1.0], (n, 3))
        wi = np.stack([np.sin(2 * t), np.zeros(n), np.cos(2 * t)], -1)
        vals = evaluate(material, wi, wo)       # zero past θh = 45°, where ωi is below the horizon
        # and zero at θh = 45° itself: ωi on the horizon (cos θi ~ 1e-17), where f's
        # 1/(4 cos θi cos θo) made GGX's sample 10⁴, a spike that dwarfed the plot although the
        # light arriving there (f·cos θi) is nothing
        vals = np.where((th < 45.0)[:, None], vals, 0.0)
        q = "f(ωi, ωo = n), θh = θi / 2"
    vals = np.asarray(vals, np.float64)
    diffuse = np.asarray(material.albedo, np.float64) / np.pi
    spec = vals if isinstance(material, SRBF) else np.maximum(vals - np.where(th[:, None] < 45.0, diffuse, 0.0), 0.0)
    return {"theta_deg": th.round(3).tolist(), "values": vals.round(6).tolist(), "quantity": q,
            "diffuse": diffuse.round(6).tolist(), "specular": spec.round(6).tolist(), "lobe": brdf_lobe(material)}


def brdf_lobe(material) -> dict:
    """The BRDF in the plane of incidence for the lobe plots: f(ωi, ωo)·cosθo with ωi at each of
    LOBE_INCIDENT_DEG on the −x side and ωo from −90° to 90° in the x-z plane.
    Returns {"theta_i_deg": [...], "theta_o_deg": [...], "values": [[...], ...] (luminance, per
    θi), "rgb_theta_i_deg": LOBE_RGB_INCIDENT_DEG, "rgb": [[[r, g, b], ...], ...] (per one of
    those θi and θo, rounded to 3 significant digits four decades below each θi's peak: the
    paint designer's log-radius plot, where colour travel across angles shows)}."""
    from ..core.brdf import evaluate

    ti = np.radians(np.asarray(LOBE_INCIDENT_DEG, np.float64))
    to = np.radians(np.linspace(-90.0, 90.0, LOBE_SAMPLES))
    T, O = np.meshgrid(ti, to, indexing="ij")
    wi = np.stack([-np.sin(T), np.zeros_like(T), np.cos(T)], -1)
    wo = np.stack([np.sin(O), np.zeros_like(O), np.cos(O)], -1)
    f = evaluate(material, wi.reshape(-1, 3), wo.reshape(-1, 3)).reshape(*T.shape, 3)
    fc = f * np.maximum(np.cos(O), 0.0)[..., None]
    lum = fc @ np.array([0.2126, 0.7152, 0.0722])
    rgb = fc[[LOBE_INCIDENT_DEG.index(t) for t in LOBE_RGB_INCIDENT_DEG]]
    return {"theta_i_deg": list(LOBE_INCIDENT_DEG), "theta_o_deg": np.degrees(to).round(3).tolist(),
            "values": lum.round(6).tolist(), "rgb_theta_i_deg": list(LOBE_RGB_INCIDENT_DEG),
            "rgb": _rounded(rgb).tolist()}


def _rounded(a: np.ndarray, decades: int = 4, digits: int = 3) -> np.ndarray:
    """``a`` (n_i, n_o, 3) rounded, per incident angle, to the decimals that keep ``digits``
    significant digits ``decades`` below that angle's peak: a log plot of four decades needs
    relative precision there, which one fixed number of decimals loses for a dark material, and
    which every value's own significant digits would cost a Python loop to print."""
    peak = np.maximum(a.max(axis=(1, 2)), 1e-30)
    dec = np.clip(np.ceil(-np.log10(peak)) + decades + digits - 1, 0, 15).astype(int)
    out = np.empty_like(a)
    for i, d in enumerate(dec):
        out[i] = np.round(a[i], int(d))
    return out


def _dump(m) -> dict:
    return json.loads(m.model_dump_json())
