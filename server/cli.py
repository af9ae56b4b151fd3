"""The server's commands of the ``glint`` command line: serve, token create, openapi, nginx-conf, db upgrade.

They live here rather than in worker/cli.py because they start or describe the service, and
worker never imports server. glint/cli.py composes them with worker's commands and the
benchmarks into one ``glint`` parser. Everything is imported inside the commands, so building
the parser (``glint --help``) loads neither FastAPI nor the database driver.
"""
from __future__ import annotations

import sys
from pathlib import Path


def cmd_serve(a) -> int:
    import logging
    import signal

    import uvicorn

    from worker.memory import cap_malloc_arenas

    from .config import Settings
    from .logs import configure_logging
    from .main import create_app

    settings = Settings.from_env(host=a.host, port=a.port, data_dir=a.data_dir, workers=a.workers,
                                 demo=False if a.no_demo else None, backend=a.backend, ray_address=a.ray_address)
    configure_logging(settings.log_format, logging.INFO)
    if settings.host not in ("127.0.0.1", "localhost", "::1") and settings.allow_anonymous_loopback:
        print("glint: listening beyond loopback; remote clients need an API token (glint token create)", file=sys.stderr)
    # SIGTERM is a clean stop (uvicorn drains, the lifespan fails running jobs with a message);
    # uvicorn re-raises the signal once it has shut down, which must end the process with 0
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    cap_malloc_arenas()         # the threadpool's freed memory in a few arenas (trimmed as streams end)
    # proxy headers (X-Forwarded-For) are believed only from proxies named in GLINT_TRUSTED_PROXIES.
    # No per-message deflate on the WebSockets: the frames are JPEG (incompressible) and the
    # messages a few hundred bytes, so zlib only cost both ends CPU (about 100 frames/s)
    uvicorn.run(create_app(settings), host=settings.host, port=settings.port, log_level="info",
                ws_max_size=4 * 1024 * 1024, ws_per_message_deflate=False, proxy_headers=bool(settings.trusted_proxies),
                forwarded_allow_ips=",".join(settings.trusted_proxies) or None, log_config=None,
                server_header=False)       # no "server: uvicorn": the software is nobody's business
    return 0


def cmd_db_upgrade(a) -> int:
    from .config import Settings
    from .db import make_engine
    from .migrate import head, upgrade

    settings = Settings.from_env(data_dir=a.data_dir, database_url=a.database_url)
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    before = upgrade(make_engine(settings.db_url))
    print(f"database {settings.db_url.split('://')[0]}: {before or 'empty'} -> {head()}")
    return 0


def cmd_token_create(a) -> int:
    from .config import Settings
    from .db import create_api_token, make_sessionmaker

    settings = Settings.from_env(data_dir=a.data_dir)
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    token = create_api_token(make_sessionmaker(settings.db_url), a.name)
    print(token)
    print(f"glint: API token {a.name!r} created; send it as 'Authorization: Bearer <token>'. It is shown only once.",
          file=sys.stderr)
    return 0


def openapi_yaml() -> str:
    """The API description as YAML, as openapi.yaml holds it (a test keeps the two equal)."""
    import yaml

    from .config import Settings
    from .main import create_app

    return yaml.safe_dump(create_app(Settings(demo=False)).openapi(), sort_keys=False, allow_unicode=True, width=100)


def cmd_openapi(a) -> int:
    from worker.cli import write_text_or_print

    return write_text_or_print(openapi_yaml(), a.out)


def cmd_nginx_conf(a) -> int:
    """The nginx configuration of a static front (server/static_site.py) for a data folder."""
    from worker.cli import write_text_or_print

    from .static_site import NginxSite, nginx_conf

    d = NginxSite()
    site = NginxSite(published=str(Path(a.data_dir) / "blobs" / "published") if a.data_dir else d.published,
                     web=a.web_dir or d.web, upstream=a.upstream or d.upstream, listen=a.listen or d.listen,
                     listen_h2=a.listen_h2, workers=a.nginx_workers or d.workers, run_dir=a.run_dir,
                     access_log=a.access_log or d.access_log, user=a.user)
    return write_text_or_print(nginx_conf(site), a.out)


def add_commands(sub) -> None:
    """The server's commands into the subparsers ``sub`` of a ``glint`` parser."""
    sv = sub.add_parser("serve", help="run the service (FastAPI + worker processes)")
    sv.add_argument("--host", default=None, help="default 127.0.0.1"); sv.add_argument("--port", type=int, default=None, help="default 8000")
    sv.add_argument("--data-dir", default=None, help="database, blobs and assets (default $GLINT_DATA_DIR or ~/.cache/glint)")
    sv.add_argument("--workers", type=int, default=None, help="worker processes (default: cores)")
    sv.add_argument("--no-demo", action="store_true", help="do not prepare the demo scene")
    sv.add_argument("--backend", choices=["local", "ray"], default=None,
                    help="workers: local processes (default) or a Ray cluster ($GLINT_BACKEND)")
    sv.add_argument("--ray-address", default=None,
                    help="with --backend ray: the cluster's GCS address host:port (default: start a local Ray)")
    sv.set_defaults(fn=cmd_serve)

    tk = sub.add_parser("token", help="API tokens"); tsub = tk.add_subparsers(dest="what", required=True)
    tc = tsub.add_parser("create", help="create an API token (printed once)")
    tc.add_argument("--name", default="automation"); tc.add_argument("--data-dir", default=None)
    tc.set_defaults(fn=cmd_token_create)

    oa = sub.add_parser("openapi", help="print (or write) the API description as YAML")
    oa.add_argument("--out"); oa.set_defaults(fn=cmd_openapi)

    ng = sub.add_parser("nginx-conf", help="print (or write) an nginx configuration that serves published bundles "
                                           "and the web client from disk in front of the service")
    ng.add_argument("--data-dir", help="the service's data folder (default /data, as in docker/compose.yaml)")
    ng.add_argument("--web-dir", help="the web client's folder (default /srv/glint/web)")
    ng.add_argument("--upstream", help="the service's host:port (default glint:8000)")
    ng.add_argument("--listen", help="port or host:port for HTTP/1.1 (default 8080)")
    ng.add_argument("--listen-h2", help="port or host:port for HTTP/2 over cleartext (default: none)")
    ng.add_argument("--nginx-workers", help="worker processes (default auto: one per core)")
    ng.add_argument("--run-dir", help="folder for nginx's pid and temporary files (default: nginx's own)")
    ng.add_argument("--access-log", help="access log path (default off)")
    ng.add_argument("--user", help="the workers' user (default: nginx's own)")
    ng.add_argument("--out"); ng.set_defaults(fn=cmd_nginx_conf)

    dbp = sub.add_parser("db", help="the service database"); dsub = dbp.add_subparsers(dest="what", required=True)
    du = dsub.add_parser("upgrade", help="apply schema migrations (also done at every start)")
    du.add_argument("--data-dir", default=None); du.add_argument("--database-url", default=None)
    du.set_defaults(fn=cmd_db_upgrade)
