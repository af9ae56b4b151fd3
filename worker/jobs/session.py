"""Compatibility: a session's runtime is worker/jobs/runtime.py (SessionRuntime, message
dispatch), with its parts in fit_driver.py (fit orchestration), lod.py (level of detail),
compose.py (frame composition, encoding), curves.py (brdf_curve) and reporting.py
(error_event). The names other modules imported from here still are."""
from .compose import BIG_FRAME_PIXELS  # noqa: F401
from .curves import CURVE_SAMPLES, brdf_curve  # noqa: F401
from .fit_driver import QUICK_ROWS_MIN  # noqa: F401
from .lod import FRAME_BUDGET_MS, STILL_SAMPLES, busy_sessions  # noqa: F401
from .reporting import error_event  # noqa: F401
from .runtime import EFFECTS, SessionRuntime  # noqa: F401
