"""The FastAPI application: ``create_app(settings)`` builds it (nothing happens at import).

On start it upgrades the database (migrations), opens the blob store, starts the worker pool
and, with ``demo`` on, makes sure the demo scene exists and is precomputed (progress at
``/v1/status`` for the studio, and in the log). Errors are JSON ``{"detail": …}`` with a 4xx
status for bad input; an unexpected error is a 500 with a short message (the trace goes to the
log, never to the client).

Every request must name this server in ``Host`` (DNS rebinding), and requests that change state
from a browser must come from one of its origins; secrets in URLs never reach the access log.
"""
from __future__ import annotations

import asyncio
import datetime as dt
import logging
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles

from worker.memory import freeze_start_up

from .config import Settings
from .deps import Client, check_host, check_origin
from .logs import RequestContext, redact_text
from .metrics import CONTENT_TYPE, Metrics
from .routes import assets, bundle_files, captures, exports, materials, publications, renders, scenes, sessions
from .state import AppState

log = logging.getLogger("glint")
VERSION = "0.4.0"
SAFE_METHODS = {"GET", "HEAD", "OPTIONS"}


class RedactSecrets(logging.Filter):
    """Log lines never carry a token (``?token=…`` on a stream URL, for old clients, in any
    percent-encoding: server/logs.py redact_text)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.args:
            args = record.args if isinstance(record.args, tuple) else (record.args,)
            if isinstance(record.args, tuple):
                record.args = tuple(redact_text(a) if isinstance(a, str) else a for a in args)
        if isinstance(record.msg, str):
            record.msg = redact_text(record.msg)
        return True


class SecurityHeaders:
    """ASGI middleware: security headers on every HTTP response. ``X-Content-Type-Options:
    nosniff`` and ``Referrer-Policy: no-referrer`` everywhere; a Content-Security-Policy that
    allows the studio what it uses (its own ES modules and stylesheet, frames drawn from blob
    images, its WebSocket to this host) and nothing else: no inline script, no other origin.
    The studio and the API may be framed by themselves only (also X-Frame-Options for old
    browsers); the published viewer by ``embed_origins`` (all by default, it is meant to be
    embedded). The interactive API docs (/docs, /redoc) load their scripts from a CDN."""

    PAGE = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; "
            "font-src 'self'; connect-src 'self'{ws}; object-src 'none'; base-uri 'none'; form-action 'self'; "
            "frame-ancestors {ancestors}")
    API = "default-src 'none'; frame-ancestors 'self'; base-uri 'none'; form-action 'none'"
    DOCS = ("default-src 'self'; script-src 'self' 'unsafe-inline' https://cdn.jsdelivr.net; "
            "style-src 'self' 'unsafe-inline' https://cdn.jsdelivr.net https://fonts.googleapis.com; "
            "font-src 'self' https://fonts.gstatic.com; img-src 'self' data: https://fastapi.tiangolo.com "
            "https://cdn.redoc.ly; worker-src 'self' blob:; connect-src 'self'; object-src 'none'; base-uri 'none'; "
            "frame-ancestors 'self'")

    def __init__(self, app, embed_origins: list[str]):
        self.app = app
        self.embed = " ".join(embed_origins) or "'none'"

    def _policy(self, scope) -> tuple[str, bool]:
        """(CSP, whether X-Frame-Options: SAMEORIGIN applies)."""
        path = scope.get("path", "")
        host = next((v.decode("latin-1") for k, v in scope.get("headers") or () if k == b"host"), "")
        ok_host = host and all(c.isalnum() or c in ".-:[]" for c in host)
        ws = f" ws://{host} wss://{host}" if ok_host else ""
        if path.startswith("/view/"):
            return self.PAGE.format(ws=ws, ancestors=self.embed), False
        if path == "/" or path.startswith("/web/"):
            return self.PAGE.format(ws=ws, ancestors="'self'"), True
        if path in ("/docs", "/redoc", "/docs/oauth2-redirect"):
            return self.DOCS, True
        return self.API, True

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        csp, same_origin = self._policy(scope)

        async def send_with_headers(msg):
            if msg["type"] == "http.response.start":
                extra = [(b"content-security-policy", csp.encode()), (b"x-content-type-options", b"nosniff"),
                         (b"referrer-policy", b"no-referrer")]
                if same_origin:
                    extra.append((b"x-frame-options", b"SAMEORIGIN"))
                names = {k for k, _ in extra}
                msg = {**msg, "headers": [h for h in msg.get("headers") or [] if h[0].lower() not in names] + extra}
            await send(msg)
        await self.app(scope, receive, send_with_headers)


class JsonBodyCap:
    """ASGI middleware: a JSON request body (renders, fits, materials, sessions) is at most
    ``limit`` bytes, refused with 413 naming the limit and the size before it is parsed: FastAPI
    parses and validates such bodies on the event loop, which a large one stalls (every stream
    with it). Scenes read their larger bodies themselves, in a thread (routes/scenes.py); uploads
    are not JSON. A body without Content-Length is read up to the limit first, then passed on."""

    def __init__(self, app, limit: int, exempt: tuple[str, ...] = ("/v1/scenes",)):
        self.app = app
        self.limit = limit
        self.exempt = exempt

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope.get("method") not in ("POST", "PUT", "PATCH") or scope.get("path") in self.exempt:
            return await self.app(scope, receive, send)
        headers = dict(scope.get("headers") or ())
        if b"json" not in headers.get(b"content-type", b"").lower():
            return await self.app(scope, receive, send)
        declared = headers.get(b"content-length", b"")
        if declared.isdigit():
            if int(declared) > self.limit:
                return await self._refuse(send, f"a JSON body of {int(declared)} bytes is over the {self.limit}-byte "
                                                "limit (GLINT_MAX_JSON_BODY_BYTES)")
            return await self.app(scope, receive, send)
        chunks, size = [], 0
        while True:
            msg = await receive()
            if msg["type"] != "http.request":
                return                                        # the client went away
            size += len(msg.get("body", b""))
            if size > self.limit:
                return await self._refuse(send, f"a JSON body of more than {self.limit} bytes is over the "
                                                f"{self.limit}-byte limit (GLINT_MAX_JSON_BODY_BYTES)")
            chunks.append(msg.get("body", b""))
            if not msg.get("more_body"):
                break
        body = [b"".join(chunks)]

        async def replay():
            if body:
                return {"type": "http.request", "body": body.pop(), "more_body": False}
            return await receive()
        await self.app(scope, replay, send)

    @staticmethod
    async def _refuse(send, detail: str) -> None:
        import json as _json

        data = _json.dumps({"detail": detail}).encode()
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(data)).encode())]})
        await send({"type": "http.response.body", "body": data})


def install_log_redaction() -> None:
    for name in ("uvicorn.access", "uvicorn.error", "glint"):
        lg = logging.getLogger(name)
        if not any(isinstance(f, RedactSecrets) for f in lg.filters):
            lg.addFilter(RedactSecrets())


DISK_FULL = ("the server's disk is full ({why}): nothing was stored and earlier data is intact; "
             "free space on the server (its data folder) or ask its operator, then try again")


def disk_full(exc: BaseException) -> str | None:
    """Why, when an exception (or one it was raised from) means the disk or quota is full:
    an OSError ENOSPC/EDQUOT (uploads, blobs), SQLite's SQLITE_FULL ("database or disk is full"),
    PostgreSQL's disk_full (SQLSTATE 53100). None for anything else."""
    import errno

    seen = 0
    while exc is not None and seen < 8:
        seen += 1
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
            return exc.strerror or "no space left on device"
        orig = getattr(exc, "orig", None)            # SQLAlchemy wraps the driver's error
        for e in (exc, orig):
            if e is None:
                continue
            if getattr(e, "sqlite_errorcode", None) == 13 or "database or disk is full" in str(e):
                return "database or disk is full"
            if getattr(e, "sqlstate", None) == "53100" or getattr(e, "pgcode", None) == "53100":
                return "no space left for the database"
        exc = orig if orig is not None and orig is not exc else (exc.__cause__ or exc.__context__)
    return None


def _validation_message(exc: RequestValidationError) -> str:
    parts = []
    for e in exc.errors()[:5]:
        loc = ".".join(str(x) for x in e.get("loc", ()) if x != "body")
        parts.append(f"{loc}: {e.get('msg')}" if loc else str(e.get("msg")))
    return "; ".join(parts)


def create_app(settings: Settings | None = None, pool=None) -> FastAPI:
    settings = settings or Settings.from_env()
    install_log_redaction()
    metrics = Metrics(lambda: getattr(app.state, "glint", None),
                      {"version": VERSION, "backend": settings.backend, "database": settings.db_url.split(":")[0].split("+")[0]})

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        st = AppState(settings, pool)
        app.state.glint = st
        st.metrics = metrics
        st.pool.run_job = metrics.wrap_job(st.pool.run_job)
        st.pool.start()
        who = "anonymous access is allowed from loopback only; other clients need an API token" \
            if settings.allow_anonymous_loopback else "every client needs an API token (glint token create)"
        log.info("Glint %s: data in %s, database %s, %d worker(s); %s", VERSION, settings.data_dir,
                 settings.db_url.split("://")[0], settings.workers, who)
        # what start-up made (modules, routes, models) out of full collections, which stopped
        # the event loop (and every stream) for 50-170 ms at a time under load
        freeze_start_up()
        tasks = [asyncio.create_task(_janitor(st)), asyncio.create_task(sessions.share_loop(st))]
        if settings.demo:
            from .demo import ensure_demo

            tasks.append(asyncio.create_task(ensure_demo(st)))
        try:
            yield
        finally:
            await _shutdown(st, tasks)

    app = FastAPI(title="Glint", version=VERSION, lifespan=lifespan,
                  description="Design materials (BRDFs) under real-world lighting: assets, scenes, "
                              "precomputed visibility cuts, renders, paint-to-BRDF fits, versioned "
                              "materials and interactive sessions streamed over WebSockets.")

    @app.middleware("http")
    async def _guard(request: Request, call_next):
        if not check_host(settings, request.headers):
            return JSONResponse({"detail": "unknown Host: this server answers to "
                                           f"{', '.join(sorted(settings.allowed_hosts))} (GLINT_ALLOWED_HOSTS)"},
                                status_code=421)
        if request.method not in SAFE_METHODS and not check_origin(settings, request.headers):
            return JSONResponse({"detail": "cross-origin request refused (GLINT_ALLOWED_ORIGINS)"}, status_code=403)
        return await call_next(request)

    app.add_middleware(JsonBodyCap, limit=settings.max_json_body_bytes)
    app.add_middleware(SecurityHeaders, embed_origins=settings.embed_origins)
    # published frames already in memory are answered before the layers above (routes/bundle_files.py)
    app.add_middleware(bundle_files.CachedBundleFiles)
    # outermost: a request id for every request and stream, its access line and its metrics
    app.add_middleware(RequestContext, observe=metrics.http)

    @app.exception_handler(RequestValidationError)
    async def _bad_request(request: Request, exc: RequestValidationError):
        return JSONResponse({"detail": _validation_message(exc)}, status_code=422)

    def _server_error(request: Request, exc: Exception) -> JSONResponse:
        why = disk_full(exc)
        if why is not None:
            log.error("disk full on %s %s: %s", request.method, request.url.path, exc)
            return JSONResponse({"detail": DISK_FULL.format(why=why)}, status_code=507)
        log.exception("unhandled error on %s %s", request.method, request.url.path, exc_info=exc)
        return JSONResponse({"detail": f"internal error ({type(exc).__name__}); see the server log"}, status_code=500)

    # OSError and database errors are handled inside the middleware stack (so a 507 carries the
    # security headers and its access line); anything else reaches the outermost handler
    from sqlalchemy.exc import DBAPIError

    for kind in (OSError, DBAPIError):
        app.add_exception_handler(kind, lambda request, exc: _server_error(request, exc))

    def _out_of_range(request: Request, exc: OverflowError) -> JSONResponse:
        # a client's integer beyond 64 bits reaches the database driver only where the schema
        # gives no upper bound (path and query integers have one): the request is wrong, not us
        log.warning("number out of range on %s %s: %s", request.method, request.url.path, exc)
        return JSONResponse({"detail": f"a number in the request is out of range ({exc}); integers are at most "
                                       f"{2**63 - 1}"}, status_code=422)
    app.add_exception_handler(OverflowError, _out_of_range)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception):
        return _server_error(request, exc)

    @app.get("/healthz", tags=["health"])
    async def healthz(request: Request):
        st = request.app.state.glint
        h = st.pool.health()
        ok = h.get("workers_alive", 0) == h.get("workers", 0)
        return {"status": "ok" if ok else "degraded", "version": VERSION, **h, "streams": st.sessions.open_streams()}

    @app.get("/metrics", include_in_schema=False)
    async def prometheus_metrics(_: Client):
        """Prometheus metrics (text exposition format): sessions, frames, latencies, jobs, workers
        (server/metrics.py lists them). Anonymous from loopback, else an API token."""
        return Response(metrics.render(), media_type=CONTENT_TYPE)

    @app.get("/v1/status", tags=["health"])
    async def status(request: Request):
        """What the studio shows before a scene is ready: the demo scene's preparation
        ({"state": "off" | "fetching" | "precomputing" | "ready" | "failed", "scene_id",
        "progress", "message", and "preview": the URL of its first look once drawn)."""
        st = request.app.state.glint
        return {"version": VERSION, "demo": st.demo}

    @app.get("/v1/models", tags=["materials"])
    async def list_models():
        """Every BRDF model the server knows: its controls, defaults and JSON schema."""
        from worker.models import describe

        return describe()

    for r in (assets, scenes, renders, materials, publications, bundle_files, sessions, captures, exports):
        app.include_router(r.router)

    web = Path(settings.web_dir)
    app.mount("/web", StaticFiles(directory=web, check_dir=False), name="web")

    def page(name: str) -> HTMLResponse:
        f = web / name
        if not f.is_file():
            return HTMLResponse("<h1>Glint</h1><p>The web client is missing; the API is at <a href='/docs'>/docs</a>.</p>")
        # plain ES modules, no build step; no-cache so an updated studio is picked up at once
        return HTMLResponse(f.read_text(), headers={"Cache-Control": "no-cache"})

    @app.get("/", include_in_schema=False)
    async def studio():
        return page("index.html")

    @app.get("/view/{pub_id}", include_in_schema=False)
    async def viewer(pub_id: str):
        return page("viewer.html")

    @app.get("/favicon.ico", include_in_schema=False)
    async def favicon():
        # browsers ask for /favicon.ico before (or without) reading the pages' <link rel="icon">:
        # the same SVG, so no page load logs a 404
        f = web / "favicon.svg"
        if not f.is_file():
            return Response(status_code=404)
        return Response(f.read_bytes(), media_type="image/svg+xml", headers={"Cache-Control": "public, max-age=86400"})
    return app


async def _shutdown(st, tasks: list) -> None:
    """Graceful stop (SIGTERM): running precomputations get ``shutdown_grace_seconds`` to finish,
    then are cancelled, and each one's cancellation is awaited so that it is recorded as failed
    with a message before the workers stop (nothing is left "running" in the database)."""
    running = [t for t in st.precompute_tasks.values() if not t.done()]
    grace = st.settings.shutdown_grace_seconds
    if running and grace > 0:
        log.info("stopping: waiting up to %.0f s for %d precomputation(s)", grace, len(running))
        await asyncio.wait(running, timeout=grace)
    pending = [t for t in tasks + list(st.precompute_tasks.values()) if not t.done()]
    for t in pending:
        t.cancel()
    if pending:
        await asyncio.wait(pending, timeout=15)
    n = sum(1 for t in running if t.cancelled() or (t.done() and t.exception() is not None))
    if n:
        log.warning("stopping: %d precomputation(s) failed as cancelled; start them again after the restart", n)
    st.pool.stop()


async def _janitor(st) -> None:
    """Every ``janitor_seconds``: close editing sessions left without a stream for
    ``session_retention_seconds`` (their rows say so; until then a reload, another tab or the
    studio's URL reopens them), delete unused viewer sessions (``sessions.expire_idle``)."""
    from fastapi.concurrency import run_in_threadpool

    while True:
        try:
            n = await run_in_threadpool(sessions.expire_idle, st,
                                        dt.timedelta(seconds=st.settings.session_retention_seconds))
            if n:
                log.info("closed or deleted %d idle session(s)", n)
        except Exception as e:
            log.warning("session janitor: %s", e)
        await asyncio.sleep(st.settings.janitor_seconds)
