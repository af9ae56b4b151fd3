"""The one base class of errors in what a user brought (files, parameters, requests).

Every capability raises a subclass with a message that names the bad field or file; the CLI
prints it and exits 2, the service answers 4xx with it, a session sends it as an ``error``
event. Anything else that escapes is a bug and is reported as such.
"""
from __future__ import annotations


class GlintError(ValueError):
    """Bad input, explained. ``status`` is the HTTP-like status the service answers with."""

    status = 422

    def __init__(self, message: str, status: int | None = None):
        super().__init__(message)
        if status is not None:
            self.status = status
