"""The session side of the paint designer: a ``paint`` stream message becomes a lobes material.

Client message (web/js/paint.js, on every slider change):
    {"type": "paint", "seq": n, "object": "car", "gloss": G, "aspecular": {"15": [r, g, b], …}}
The session calls ``apply_paint(fields)``, sets the returned material on the object, renders the
next frame (the paint renderer), and sends the returned event to the client.
"""
from __future__ import annotations

from typing import Any, Mapping

from ..scene import Lobes
from .fit import fit_measurements
from .geometry import MeasurementError, flop_index, measure
from .swatch import swatch_png


def apply_paint(msg_fields: Mapping[str, Any], exponents=None) -> tuple[Lobes, dict]:
    """Fit a ``paint`` message's measurements.

    Returns (material, event) where event is
    ``{"type": "paint", "seq", "object", "material", "measured": {gloss, aspecular} of the fitted
    material (what the render shows), "requested": the message's values, "error_l1",
    "error_max", "residuals": signed relative residual of every reading (same form as the
    readings), "unmet": the readings off by more than fit.TOLERANCE ("gloss", "45:r", …),
    "warning": a sentence naming them or None, "flop_index", "ms_fit", "swatch": the fitted paint
    on a sphere (swatch.py), a PNG data URL}``.
    Raises MeasurementError (a GlintError) on bad fields."""
    if "aspecular" not in msg_fields:
        raise MeasurementError("paint message needs aspecular readings")
    requested = {"gloss": msg_fields.get("gloss", 0.0), "aspecular": msg_fields["aspecular"]}
    r = fit_measurements(requested, exponents)
    angles = [float(k) for k in requested["aspecular"]]
    measured = measure(r.material, angles)
    measured["gloss"] = float(measured["gloss"])
    event = {"type": "paint", "seq": msg_fields.get("seq"), "object": msg_fields.get("object"),
             "material": r.material.model_dump(), "measured": measured, "requested": requested,
             "error_l1": r.error_l1, "error_max": r.error_max, "residuals": r.residuals,
             "unmet": r.unmet, "warning": r.warning, "flop_index": flop_index(measured),
             "ms_fit": 1e3 * r.seconds, "swatch": swatch_png(r.material)}
    return r.material, event
