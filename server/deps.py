"""Request dependencies: the shared state, a database session, and client authentication."""
from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Header, HTTPException, Request
from sqlalchemy import select

from .db import ApiToken, token_hash
from .state import AppState

LOOPBACK = {"127.0.0.1", "::1", "localhost", "testclient"}


def get_state(request: Request) -> AppState:
    return request.app.state.glint


State = Annotated[AppState, Depends(get_state)]


def get_db(st: State):
    with st.db() as s:
        yield s


DB = Annotated[object, Depends(get_db)]


def check_client(st: AppState, host: str | None, authorization: str | None) -> str:
    """'token:<id>' for a valid API token, 'anonymous' for loopback when the settings allow it."""
    if authorization:
        scheme, _, tok = authorization.partition(" ")
        if scheme.lower() != "bearer" or not tok:
            raise HTTPException(401, "Authorization must be 'Bearer <token>'")
        with st.db() as s:
            row = s.scalars(select(ApiToken).where(ApiToken.token_sha256 == token_hash(tok.strip()))).first()
        if row is None or row.revoked:
            raise HTTPException(401, "unknown or revoked API token")
        return f"token:{row.id}"
    if st.settings.allow_anonymous_loopback and host in LOOPBACK:
        return "anonymous"
    raise HTTPException(401, "an API token is required: send 'Authorization: Bearer <token>' "
                             "(create one with `glint token create`)")


def require_client(request: Request, st: State, authorization: Annotated[str | None, Header()] = None) -> str:
    return check_client(st, request.client.host if request.client else None, authorization)


Client = Annotated[str, Depends(require_client)]
