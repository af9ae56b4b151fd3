"""The BRDF curve a session's studio plots for a material (curve and fit events)."""
from __future__ import annotations

import json

import numpy as np

from ..models import SRBF

CURVE_SAMPLES = 91
LOBE_INCIDENT_DEG = tuple(range(0, 90, 5))     # the lobe plot's incident angles (its slider snaps to them)
LOBE_SAMPLES = 91                              # θo from −90° to 90°


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
        q = "f(ωi, ωo = n), θh = θi / 2"
    vals = np.asarray(vals, np.float64)
    diffuse = np.asarray(material.albedo, np.float64) / np.pi
    spec = vals if isinstance(material, SRBF) else np.maximum(vals - np.where(th[:, None] < 45.0, diffuse, 0.0), 0.0)
    return {"theta_deg": th.round(3).tolist(), "values": vals.round(6).tolist(), "quantity": q,
            "diffuse": diffuse.round(6).tolist(), "specular": spec.round(6).tolist(), "lobe": brdf_lobe(material)}


def brdf_lobe(material) -> dict:
    """The BRDF in the plane of incidence for the lobe plot: luminance of f(ωi, ωo)·cosθo with
    ωi at each of LOBE_INCIDENT_DEG on the −x side and ωo from −90° to 90° in the x-z plane.
    Returns {"theta_i_deg": [...], "theta_o_deg": [...], "values": [[...], ...] (per θi)}."""
    from ..core.brdf import evaluate

    ti = np.radians(np.asarray(LOBE_INCIDENT_DEG, np.float64))
    to = np.radians(np.linspace(-90.0, 90.0, LOBE_SAMPLES))
    T, O = np.meshgrid(ti, to, indexing="ij")
    wi = np.stack([-np.sin(T), np.zeros_like(T), np.cos(T)], -1)
    wo = np.stack([np.sin(O), np.zeros_like(O), np.cos(O)], -1)
    f = evaluate(material, wi.reshape(-1, 3), wo.reshape(-1, 3)).reshape(*T.shape, 3)
    lum = f @ np.array([0.2126, 0.7152, 0.0722]) * np.maximum(np.cos(O), 0.0)
    return {"theta_i_deg": list(LOBE_INCIDENT_DEG), "theta_o_deg": np.degrees(to).round(3).tolist(),
            "values": lum.round(6).tolist()}


def _dump(m) -> dict:
    return json.loads(m.model_dump_json())
