"""How a session reports an exception while handling a message: an error event."""
from __future__ import annotations

from ..errors import GlintError
from ..protocol import ErrorEvent, StateError


def _msg(e: Exception) -> str:
    from pydantic import ValidationError

    if isinstance(e, ValidationError):
        err = e.errors()[0]
        return f"{'.'.join(str(x) for x in err['loc'])}: {err['msg']}"
    return str(e)


def error_event(e: Exception, seq=None) -> dict:
    """An error event for an exception while handling a message: user errors say what was
    wrong; anything else is a bug, reported as such without a trace."""
    if isinstance(e, (GlintError, StateError, ValueError)):
        from ..renderers.base import NotPrecomputed

        # a status the server acts on travels with it: 409, the scene lacks precomputed parts (it
        # precomputes the scene again)
        return ErrorEvent(seq=seq, message=_msg(e), code=409 if isinstance(e, NotPrecomputed) else None).model_dump()
    return ErrorEvent(seq=seq, message=f"internal error ({type(e).__name__}): {e}").model_dump()
