"""The FastAPI application: ``create_app(settings)`` builds it (nothing happens at import).

On start it opens the database and blob store, starts the worker pool and, with ``demo`` on,
makes sure the demo scene exists and is precomputed (progress in the log). Errors are JSON
``{"detail": …}`` with a 4xx status for bad input; an unexpected error is a 500 with a short
message (the trace goes to the log, never to the client).
"""
from __future__ import annotations

import asyncio
import logging
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse
from fastapi.staticfiles import StaticFiles

from .config import Settings
from .routes import assets, materials, publications, renders, scenes, sessions
from .state import AppState

log = logging.getLogger("glint")
VERSION = "0.3.0"


def _validation_message(exc: RequestValidationError) -> str:
    parts = []
    for e in exc.errors()[:5]:
        loc = ".".join(str(x) for x in e.get("loc", ()) if x != "body")
        parts.append(f"{loc}: {e.get('msg')}" if loc else str(e.get("msg")))
    return "; ".join(parts)


def create_app(settings: Settings | None = None, pool=None) -> FastAPI:
    settings = settings or Settings.from_env()

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        st = AppState(settings, pool)
        app.state.glint = st
        st.pool.start()
        who = "anonymous access is allowed from loopback only; other clients need an API token" \
            if settings.allow_anonymous_loopback else "every client needs an API token (glint token create)"
        log.info("Glint %s: data in %s, database %s, %d worker(s); %s", VERSION, settings.data_dir,
                 settings.db_url.split("://")[0], settings.workers, who)
        demo_task = None
        if settings.demo:
            from .demo import ensure_demo

            demo_task = asyncio.create_task(ensure_demo(st))
        try:
            yield
        finally:
            if demo_task is not None:
                demo_task.cancel()
            for t in list(st.precompute_tasks.values()):
                t.cancel()
            st.pool.stop()

    app = FastAPI(title="Glint", version=VERSION, lifespan=lifespan,
                  description="Design materials (BRDFs) under real-world lighting: assets, scenes, "
                              "precomputed visibility cuts, renders, paint-to-BRDF fits, versioned "
                              "materials and interactive sessions streamed over WebSockets.")

    @app.exception_handler(RequestValidationError)
    async def _bad_request(request: Request, exc: RequestValidationError):
        return JSONResponse({"detail": _validation_message(exc)}, status_code=422)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception):
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return JSONResponse({"detail": f"internal error ({type(exc).__name__}); see the server log"}, status_code=500)

    @app.get("/healthz", tags=["health"])
    async def healthz(request: Request):
        st = request.app.state.glint
        alive = [w.proc.is_alive() for w in getattr(st.pool, "workers", [])]
        return {"status": "ok" if all(alive) else "degraded", "version": VERSION, "workers": len(alive),
                "workers_alive": sum(alive), "worker_restarts": getattr(st.pool, "restarts", 0)}

    for r in (assets, scenes, renders, materials, publications, sessions):
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
    return app
