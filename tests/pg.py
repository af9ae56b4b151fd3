"""A real PostgreSQL server for the tests: Debian's ``postgresql`` binaries (installed by
``scripts/ensure-postgresql``, which ``make test`` runs), a cluster initialised in a temporary
folder, listening on a free loopback port, trust authentication, fsync off (a test cluster: its
durability is not under test). PostgreSQL refuses to run as root, so under root the cluster
belongs to the ``postgres`` system user the Debian package creates; the test process talks to it
over TCP only."""
from __future__ import annotations

import glob
import itertools
import os
import pwd
import shutil
import subprocess
import tempfile
from pathlib import Path

from helpers import free_port


def bindir() -> Path:
    """The newest installed server's bin folder (Debian: /usr/lib/postgresql/<major>/bin)."""
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"), key=lambda p: int(p.split("/")[-3]))
    if found:
        return Path(found[-1]).parent
    w = shutil.which("initdb")
    if w:
        return Path(w).parent
    raise RuntimeError("PostgreSQL is not installed: run scripts/ensure-postgresql (make test does)")


class PostgresServer:
    def __init__(self):
        self.bin = bindir()
        self.root = Path(tempfile.mkdtemp(prefix="glint-pg-"))
        self.data = self.root / "data"
        self.port = free_port()
        self._ids = itertools.count()
        self.user = None
        if os.geteuid() == 0:
            try:
                self.user = pwd.getpwnam("postgres")
            except KeyError:
                raise RuntimeError("running as root and there is no 'postgres' user to run PostgreSQL as "
                                   "(Debian's postgresql package creates it)") from None
            os.chown(self.root, self.user.pw_uid, self.user.pw_gid)
        self._run(["initdb", "-D", str(self.data), "-U", "postgres", "-A", "trust", "-E", "UTF8",
                   "--locale=C", "--no-sync"])
        opts = f"-F -p {self.port} -k {self.root} -c listen_addresses=127.0.0.1 -c max_connections=200"
        self._run(["pg_ctl", "-D", str(self.data), "-l", str(self.root / "server.log"), "-o", opts, "-w", "-t", "120",
                   "start"])

    def _run(self, args: list[str]) -> None:
        kw = {}
        if self.user is not None:
            kw = {"user": self.user.pw_uid, "group": self.user.pw_gid, "extra_groups": []}
        r = subprocess.run([str(self.bin / args[0])] + args[1:], capture_output=True, text=True, cwd=self.root,
                           timeout=300, **kw)
        if r.returncode != 0:
            raise RuntimeError(f"{args[0]} failed ({r.returncode}): {r.stdout[-2000:]}{r.stderr[-2000:]}")

    def dsn(self, dbname: str = "postgres") -> str:
        return f"host=127.0.0.1 port={self.port} user=postgres dbname={dbname}"

    def new_database(self, prefix: str = "glint") -> str:
        """A new empty database; returns its SQLAlchemy URL (psycopg 3)."""
        import psycopg

        name = f"{prefix}_{next(self._ids)}"
        with psycopg.connect(self.dsn(), autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')
        return f"postgresql+psycopg://postgres@127.0.0.1:{self.port}/{name}"

    def stop(self) -> None:
        if self.data.exists():
            try:
                self._run(["pg_ctl", "-D", str(self.data), "-m", "fast", "-w", "stop"])
            except RuntimeError:
                pass
        shutil.rmtree(self.root, ignore_errors=True)
