"""Schema migrations (Alembic, server/migrations). ``upgrade`` runs at every start (and as
``glint db upgrade``): a new database is created by the migrations, a database made by release
0.3 (tables from ``create_all``, no version table) is stamped at its revision first, then both
are brought to head. Migrations are the only way the schema changes."""
from __future__ import annotations

from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import inspect

HERE = Path(__file__).resolve().parent
RELEASE_0_3 = "0001"       # the schema release 0.3 created without Alembic


def config(connection=None) -> Config:
    cfg = Config()
    cfg.set_main_option("script_location", str(HERE / "migrations"))
    cfg.attributes["connection"] = connection
    return cfg


def head() -> str:
    return ScriptDirectory.from_config(config()).get_current_head()


def current(engine) -> str | None:
    with engine.connect() as conn:
        return MigrationContext.configure(conn).get_current_revision()


def upgrade(engine, revision: str = "head") -> str | None:
    """Bring the database to ``revision``; returns the revision it was at before."""
    with engine.begin() as conn:
        tables = set(inspect(conn).get_table_names())
        cfg = config(conn)
        before = MigrationContext.configure(conn).get_current_revision()
        if before is None and "assets" in tables:
            command.stamp(cfg, RELEASE_0_3)
            before = RELEASE_0_3
        command.upgrade(cfg, revision)
    return before
