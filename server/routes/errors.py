"""The routes' one translation of the service layer's errors (server/services/errors.py) into
HTTP answers: NotFound 404, Conflict 409, Invalid its status (422, 413, 415)."""
from __future__ import annotations

from contextlib import contextmanager

from fastapi import HTTPException

from ..services.errors import Conflict, Invalid, NotFound


@contextmanager
def http_errors():
    try:
        yield
    except NotFound as e:
        raise HTTPException(404, str(e)) from None
    except Conflict as e:
        raise HTTPException(409, str(e)) from None
    except Invalid as e:
        raise HTTPException(e.status, str(e)) from None
