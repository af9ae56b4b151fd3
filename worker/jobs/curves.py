"""The BRDF curve a session's studio plots for a material (curve and fit events)."""
from __future__ import annotations

import json

import numpy as np

from ..models import SRBF

CURVE_SAMPLES = 91


def brdf_curve(material, n: int = CURVE_SAMPLES) -> dict:
    """The 1D half-angle distribution to plot: p(θh) averaged over φh for srbf, the curve's
    values for curve, and f(θh) in the plane of incidence at normal viewing otherwise.
    Returns {"theta_deg": [...], "values": [[r, g, b], ...], "quantity": str}."""
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
    return {"theta_deg": th.round(3).tolist(), "values": np.asarray(vals, np.float64).round(6).tolist(), "quantity": q}


def _dump(m) -> dict:
    return json.loads(m.model_dump_json())
