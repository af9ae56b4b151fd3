"""Request dependencies: the shared state, a database session, client authentication (a bearer
API token, or anonymous access from loopback when the settings allow it), and the checks that
keep other web pages from driving the API (Host and Origin)."""
from __future__ import annotations

from typing import Annotated
from urllib.parse import urlsplit

from fastapi import Depends, HTTPException, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy import select

from .db import ApiToken, token_hash
from .state import AppState

LOOPBACK = {"127.0.0.1", "::1", "localhost"}


def get_state(request: Request) -> AppState:
    return request.app.state.glint


State = Annotated[AppState, Depends(get_state)]


def get_db(st: State):
    with st.db() as s:
        yield s


DB = Annotated[object, Depends(get_db)]

bearer = HTTPBearer(auto_error=False, scheme_name="apiToken",
                    description="an API token from `glint token create`; anonymous clients on loopback "
                                "need none (when the server allows it)")


def check_client(st: AppState, host: str | None, creds: HTTPAuthorizationCredentials | None) -> str:
    """'token:<id>' for a valid API token, 'anonymous' for loopback when the settings allow it."""
    if creds is not None:
        if creds.scheme.lower() != "bearer" or not creds.credentials:
            raise HTTPException(401, "Authorization must be 'Bearer <token>'")
        with st.db() as s:
            row = s.scalars(select(ApiToken).where(ApiToken.token_sha256 == token_hash(creds.credentials.strip()))).first()
        if row is None or row.revoked:
            raise HTTPException(401, "unknown or revoked API token")
        return f"token:{row.id}"
    if st.settings.allow_anonymous_loopback and host in LOOPBACK:
        return "anonymous"
    raise HTTPException(401, "an API token is required: send 'Authorization: Bearer <token>' "
                             "(create one with `glint token create`)")


def require_client(request: Request, st: State,
                   creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)] = None) -> str:
    if creds is None and request.headers.get("authorization"):
        raise HTTPException(401, "Authorization must be 'Bearer <token>'")
    return check_client(st, request.client.host if request.client else None, creds)


Client = Annotated[str, Depends(require_client)]


def client_key(client: str, request: Request | None) -> str:
    """Who a session counts against for limits: the API token, else the client address."""
    if client.startswith("token:"):
        return client
    host = request.client.host if request is not None and request.client else "?"
    return f"addr:{host}"


# -- DNS rebinding and cross-site requests ---------------------------------------------------------
def _hostname(host_header: str) -> str:
    h = host_header.strip().lower()
    if h.startswith("["):                      # [::1]:8000
        return h[1:h.index("]")] if "]" in h else h
    return h.rsplit(":", 1)[0] if h.count(":") == 1 else h


def allowed_hosts(settings) -> set[str]:
    hosts = {h.lower() for h in settings.allowed_hosts}
    if settings.host not in ("0.0.0.0", "::"):
        hosts.add(settings.host.lower())
    return hosts


def check_host(settings, headers) -> bool:
    """The Host header names this server (an allow-listed name, any port): a page on another
    site that rebinds its DNS name to 127.0.0.1 still sends its own name and is refused."""
    host = headers.get("host")
    if host is None:
        return True                            # HTTP/1.0 clients on loopback send none
    allowed = allowed_hosts(settings)
    return "*" in allowed or _hostname(host) in allowed


def check_origin(settings, headers) -> bool:
    """Browsers send Origin on cross-site requests and WebSocket upgrades: it must be one of ours
    (an allowed host on any port, or an allowed origin). Clients that send no Origin (scripts,
    generated API clients) are not browsers and pass."""
    origin = headers.get("origin")
    if origin is None:
        return True
    if origin in settings.allowed_origins:
        return True
    try:
        parts = urlsplit(origin)
    except ValueError:
        return False
    return parts.scheme in ("http", "https") and (parts.hostname or "").lower() in allowed_hosts(settings)
