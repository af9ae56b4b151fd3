"""Structured logs with request ids.

Every HTTP request and every stream gets a request id: the client's ``X-Request-ID`` when it is a
short token of safe characters (a proxy's id is kept, so one id follows a request through the
proxy and the server), else a new one. It is sent back in the response's ``X-Request-ID`` header
and stamped on every log line written while the request is handled (a context variable, so it
follows the request into ``await``\\ s and thread-pool calls).

``configure_logging(format)``: ``text`` lines (``… [rid] message``) or ``json``, one object per
line (time, level, logger, message, request_id, and the exception when there is one) for a log
collector. One access line per request (method, path, status, milliseconds) comes from
``RequestContext``; uvicorn's own access log is switched off.
"""
from __future__ import annotations

import contextvars
import datetime as dt
import json
import logging
import re
import secrets
import time

request_id: contextvars.ContextVar[str] = contextvars.ContextVar("glint_request_id", default="-")
_SAFE_ID = re.compile(r"^[A-Za-z0-9._:-]{1,64}$")
_TOKEN = re.compile(r"(token=)[^&\s\"']+", re.I)          # secrets in URLs never reach the log
_QUERY_IN_TEXT = re.compile(r"\?([^\s\"']+)")


def _decoded(text: str) -> str:
    """Percent-decoded until it no longer changes (at most 3 rounds: %2574 is %74 is t)."""
    from urllib.parse import unquote_plus

    for _ in range(3):
        d = unquote_plus(text)
        if d == text:
            break
        text = d
    return text


def redact_query(qs: str) -> str:
    """A query string with every secret replaced by ``[redacted]``: the value of any parameter
    whose name decodes to ``token`` (any case: the server decodes names, so ``?%74oken=`` is
    ``?token=``), and any parameter whose decoded text holds ``token=`` (``?token%3D…``)."""
    out = []
    for part in re.split(r"([&;])", qs):
        if part in ("&", ";") or not part:
            out.append(part)
            continue
        key, eq, _ = part.partition("=")
        if _decoded(key).strip().lower() == "token":
            out.append(f"{key}=[redacted]")
        elif "token=" in _decoded(part).lower() or "token" in _decoded(key).lower():
            out.append("[redacted]")
        else:
            out.append(part)
    return "".join(out)


def redact_text(text: str) -> str:
    """Free text (a log message) with the secrets of any URL query in it redacted."""
    text = _QUERY_IN_TEXT.sub(lambda m: "?" + redact_query(m.group(1)), text)
    return _TOKEN.sub(r"\1[redacted]", text)
access = logging.getLogger("glint.access")
# routes that clients poll for progress (studio, scripts): successful answers are DEBUG lines
POLLED_ROUTES = frozenset({"/v1/status", "/v1/scenes/{scene_id}", "/v1/precomputations/{pre_id}", "/v1/captures/{cid}"})


class RequestIdFilter(logging.Filter):
    """Puts the current request id on every record (``-`` outside a request)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if not hasattr(record, "request_id"):
            record.request_id = request_id.get()
        return True


class JsonFormatter(logging.Formatter):
    """One JSON object per line; extra fields given with ``extra={"fields": {...}}`` are merged."""

    def format(self, record: logging.LogRecord) -> str:
        out = {"time": dt.datetime.fromtimestamp(record.created, dt.timezone.utc).isoformat(timespec="milliseconds"),
               "level": record.levelname, "logger": record.name, "message": record.getMessage(),
               "request_id": getattr(record, "request_id", "-")}
        out.update(getattr(record, "fields", None) or {})
        if record.exc_info:
            out["exception"] = self.formatException(record.exc_info)
        return json.dumps(out, default=str)


TEXT_FORMAT = "%(asctime)s %(name)s %(levelname)s [%(request_id)s] %(message)s"


def configure_logging(fmt: str = "text", level: int = logging.INFO) -> None:
    """The root logger's one handler on stderr, in ``fmt`` ("text" or "json"), with request ids."""
    handler = logging.StreamHandler()
    handler.addFilter(RequestIdFilter())
    handler.setFormatter(JsonFormatter() if fmt == "json" else logging.Formatter(TEXT_FORMAT))
    root = logging.getLogger()
    for h in list(root.handlers):
        root.removeHandler(h)
    root.addHandler(handler)
    root.setLevel(level)
    # uvicorn's loggers propagate to the root handler (one format for all lines)
    for name in ("uvicorn", "uvicorn.error"):
        lg = logging.getLogger(name)
        lg.handlers.clear()
        lg.propagate = True
    logging.getLogger("uvicorn.access").disabled = True      # RequestContext logs each request


class RequestContext:
    """ASGI middleware: a request id per HTTP request and stream, an access log line, and the
    request's outcome for the metrics (``observe(method, route, status, seconds)``)."""

    def __init__(self, app, observe=None):
        self.app = app
        self.observe = observe

    @staticmethod
    def _incoming(scope) -> str | None:
        for k, v in scope.get("headers") or ():
            if k == b"x-request-id":
                s = v.decode("latin-1")
                return s if _SAFE_ID.match(s) else None
        return None

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        rid = self._incoming(scope) or secrets.token_hex(8)
        token = request_id.set(rid)
        t0 = time.perf_counter()
        status = [0]

        qs = scope.get("query_string") or b""
        target = scope.get("path", "") + ("?" + redact_query(qs.decode("latin-1")) if qs else "")

        async def send_with_id(msg):
            if msg["type"] == "http.response.start":
                status[0] = msg["status"]
                msg = {**msg, "headers": list(msg.get("headers") or []) + [(b"x-request-id", rid.encode())]}
            elif msg["type"] == "websocket.accept":
                status[0] = 101
                msg = {**msg, "headers": list(msg.get("headers") or []) + [(b"x-request-id", rid.encode())]}
                access.info("WS %s accepted", target, extra={"fields": {"method": "WS", "path": target, "status": 101}})
            elif msg["type"] == "websocket.close" and not status[0]:
                status[0] = 403
            await send(msg)

        try:
            await self.app(scope, receive, send_with_id)
        except Exception:
            status[0] = status[0] or 500
            raise
        finally:
            secs = time.perf_counter() - t0
            route = scope.get("route")
            tmpl = getattr(route, "path", None) or "(unmatched)"
            method = scope.get("method", "WS")
            if self.observe is not None:
                self.observe(method, tmpl, status[0], secs)
            # the studio polls progress every 0.7 s while a scene precomputes or a capture is
            # processed: those answers are logged at DEBUG, so the log shows what happened rather
            # than a line a second; their failures, and every other request, at INFO
            quiet = method in ("GET", "HEAD") and 200 <= status[0] < 400 and tmpl in POLLED_ROUTES
            access.log(logging.DEBUG if quiet else logging.INFO, "%s %s %s %.1f ms", method, target, status[0],
                       1000 * secs, extra={"fields": {"method": method, "path": target, "route": tmpl,
                                                      "status": status[0], "ms": round(1000 * secs, 2)}})
            request_id.reset(token)
