"""A real Ray cluster of one-CPU nodes on loopback addresses (127.0.0.2, 127.0.0.3, …), for the
tests and the benchmark: each node is a ``ray start --block`` process of ours, stopped by SIGTERM
(Ray drains and stops what it started); anything of this cluster still running afterwards is
found by its unique temp folder in its command line and killed by pid. Nothing else on the
machine is touched (never ``ray stop``, which stops every Ray on the machine)."""
from __future__ import annotations

import os
import re
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RAY = str(Path(sys.executable).with_name("ray"))


class RayCluster:
    def __init__(self, nodes: int = 2, cpus: int = 1, object_store_mb: int = 150):
        self.tmp = Path(tempfile.mkdtemp(prefix="glr-", dir="/tmp"))     # short: Ray's socket paths
        self.cpus, self.object_store = cpus, object_store_mb * 1024 * 1024
        # token authentication with a token of this cluster's own (Ray 2.60): every node and the
        # driver must present it; a token left in ~/.ray by another Ray is never used
        self.token = secrets.token_hex(32)
        self.env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "OPENBLAS_NUM_THREADS": "1",
                    "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": self.token}
        self.procs: list[subprocess.Popen] = []
        self.address: str | None = None
        self.head_ip = "127.0.0.2"
        try:
            self._start(head=True)
            for _ in range(nodes - 1):
                self.add_node()
        except Exception:
            self.stop()
            raise

    def _start(self, head: bool) -> None:
        ip = f"127.0.0.{2 + len(self.procs)}"
        log = open(self.tmp / f"node-{len(self.procs)}.log", "w")
        args = [RAY, "start", "--block", f"--node-ip-address={ip}", f"--num-cpus={self.cpus}",
                f"--object-store-memory={self.object_store}", "--disable-usage-stats", f"--temp-dir={self.tmp}"]
        args += ["--head", "--port=0", "--include-dashboard=false"] if head else [f"--address={self.address}"]
        p = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT, env=self.env, start_new_session=True)
        self.procs.append(p)
        marker = "Ray runtime started"
        t0 = time.monotonic()
        path = self.tmp / f"node-{len(self.procs) - 1}.log"
        while marker not in path.read_text():
            if p.poll() is not None or time.monotonic() - t0 > 240:
                raise RuntimeError(f"ray start failed:\n{path.read_text()[-3000:]}")
            time.sleep(0.3)
        if head:
            self.address = (self.tmp / "ray_current_cluster").read_text().strip()
            assert self.address.startswith(self.head_ip), self.address

    def add_node(self) -> None:
        n = len(self._alive_nodes()) if self.address else 0
        self._start(head=False)
        self.wait_nodes(n + 1)

    def _alive_nodes(self) -> list:
        out = subprocess.run([sys.executable, "-c", (
            "import ray, json; ray.init(address=%r, _node_ip_address=%r, logging_level='ERROR');"
            "print(json.dumps([n['NodeManagerAddress'] for n in ray.nodes() if n['Alive']]))") % (self.address, self.head_ip)],
            capture_output=True, text=True, env=self.env, timeout=120)
        m = re.findall(r"\[.*\]", out.stdout)
        return eval(m[-1]) if m else []

    def wait_nodes(self, n: int, timeout: float = 120) -> list:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            nodes = self._alive_nodes()
            if len(nodes) >= n:
                return nodes
            time.sleep(1)
        raise TimeoutError(f"{n} Ray nodes did not come up")

    def driver_env(self) -> dict:
        """What a Glint server needs to join this cluster."""
        return {"GLINT_BACKEND": "ray", "GLINT_RAY_ADDRESS": self.address, "GLINT_RAY_NODE_IP": self.head_ip,
                "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": self.token}

    def _leftovers(self) -> list[int]:
        mark = str(self.tmp)
        pids = []
        for d in os.listdir("/proc"):
            if d.isdigit() and int(d) != os.getpid():
                try:
                    if mark in open(f"/proc/{d}/cmdline").read().replace("\0", " "):
                        pids.append(int(d))
                except OSError:
                    pass
        return pids

    def stop(self) -> None:
        for p in reversed(self.procs):        # workers first, then the head
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(timeout=60)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
        time.sleep(1)
        for pid in self._leftovers():
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        shutil.rmtree(self.tmp, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *a):
        self.stop()
