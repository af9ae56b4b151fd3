"""The service layer's errors, independent of HTTP (server/routes/errors.py maps them to status
codes). NotFound and Conflict are AppState's own (server/state.py), which the scene payloads
raise, so a route needs one mapping for both."""
from __future__ import annotations

from ..state import Conflict, NotFound

__all__ = ["Conflict", "Invalid", "NotFound"]


class Invalid(ValueError):
    """A request that cannot be done as asked, explained. ``status`` says which kind, as an
    HTTP-like code, like worker's GlintError: 422 by default, 413 for too large, 415 for a type
    that is not accepted."""

    def __init__(self, message: str, status: int = 422):
        super().__init__(message)
        self.status = status
