"""Helpers the test modules share (a module, not conftest: conftest names are ambiguous across
folders)."""
import asyncio
import atexit
import io
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import websockets
from PIL import Image

from worker.protocol import decode_frame, server_event

ROOT = Path(__file__).resolve().parent.parent
CACHE = ROOT / "tests" / ".cache"


def cache_lock(*key):
    """An inter-process lock for computing one cached fixture (``key``: any JSON-able parts, e.g. a
    scene spec and a renderer kind). The suite runs in several pytest-xdist processes: without it two
    of them would both pay for the same cold precomputation (or race on its temporary files). Hold
    it around "look in the cache, else compute and store"."""
    import hashlib

    import filelock

    name = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()[:24]
    (CACHE / "locks").mkdir(parents=True, exist_ok=True)
    return filelock.FileLock(CACHE / "locks" / f"{name}.lock")


def open_renderer(scene, kernels=None, kind=None):
    """A renderer for a loaded scene, its precomputation cached in tests/.cache (by content key)."""
    from worker.artifacts import DirStore
    from worker.native.kernels import kernels as get_kernels
    from worker.renderers import prepare

    CACHE.mkdir(parents=True, exist_ok=True)
    kind = kind or scene.spec.renderer
    with cache_lock("prepare", kind, scene.spec.model_dump(mode="json"), str(getattr(scene, "root", ""))):
        r, _ = prepare(scene, DirStore(CACHE, kind), kind, kernels=get_kernels(kernels))
    return r


def render(r, material, shading="pixel", camera=None):
    """(radiance (H, W, 3), object index (H, W)) of a one-object scene with a material."""
    from worker.renderers import FrameRequest

    out = r.render(FrameRequest(camera=camera or r.scene.spec.camera, materials=[material], shading=shading))
    return out.radiance, out.object_id


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


_started: list[subprocess.Popen] = []


@atexit.register
def _stop_leftovers() -> None:
    """No server outlives the test run, even one a failing test or fixture never stopped."""
    for p in _started:
        if p.poll() is None:
            p.terminate()
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()


def proc_cpu_s(pids) -> float:
    """CPU seconds (user + system) the processes (ids) have used, from /proc; gone ones count 0."""
    total = 0
    for pid in pids:
        try:
            f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            total += int(f[11]) + int(f[12])
        except (OSError, ValueError, IndexError):
            pass
    return total / os.sysconf("SC_CLK_TCK")


class GlintServer:
    """A real ``glint serve`` in a subprocess on a free loopback port (stop() or use as a context)."""

    def __init__(self, data: Path, workers: int = 2, demo: bool = False, env: dict | None = None, port: int | None = None,
                 log_path: Path | None = None, shared_parts: bool = False):
        """shared_parts : the server copies precomputed parts from tests/.cache/server-parts (and
        writes its own there) instead of computing again what another test server computed, for
        tests that need a scene ready, not its precomputation (Settings.shared_parts)."""
        self.data = Path(data)
        self.data.mkdir(parents=True, exist_ok=True)
        self.port = port or free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        full = {**os.environ, "GLINT_MAX_MESH_BYTES": str(8 * 1024 * 1024), "PYTHONUNBUFFERED": "1"}
        full.pop("GLINT_SHARED_PARTS", None)
        if shared_parts:
            full["GLINT_SHARED_PARTS"] = str(CACHE / "server-parts")
        full.update(env or {})
        self.log_path = Path(log_path) if log_path else self.data / "server.log"
        self._log = open(self.log_path, "a")
        args = [sys.executable, "-m", "glint", "serve", "--port", str(self.port), "--data-dir", str(self.data),
                "--workers", str(workers)] + ([] if demo else ["--no-demo"])
        self.proc = subprocess.Popen(args, cwd=ROOT, env=full, stdout=self._log, stderr=subprocess.STDOUT)
        _started.append(self.proc)
        for _ in range(600):
            try:
                if httpx.get(self.base + "/healthz", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if self.proc.poll() is not None:
                raise RuntimeError("server exited: " + self.log()[-3000:])
            time.sleep(0.2)
        else:
            self.proc.kill()
            raise RuntimeError("server did not start: " + self.log()[-3000:])

    def log(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()

    def stop(self, sig=None) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig) if sig else self.proc.terminate()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()
        return self.proc.returncode

    def as_dict(self) -> dict:
        return {"base": self.base, "port": self.port, "data": self.data, "proc": self.proc, "server": self}


# -- session streams ----------------------------------------------------------------------------
class connect:
    """A session stream that authenticates with its first message (the token never appears in a
    URL, so never in a log)."""

    def __init__(self, server, path, token, **kw):
        self.cm = websockets.connect(f"ws://127.0.0.1:{server['port']}{path}", max_size=None, **kw)
        self.token = token

    async def __aenter__(self):
        ws = await self.cm.__aenter__()
        await ws.send(json.dumps({"type": "auth", "token": self.token}))
        return ws

    async def __aexit__(self, *a):
        return await self.cm.__aexit__(*a)


async def next_frame(ws, min_ack=-1, events=None, timeout=60):
    """Receive until a binary frame whose ack ≥ min_ack; JSON events are collected."""
    deadline = time.monotonic() + timeout
    while True:
        x = await asyncio.wait_for(ws.recv(), timeout=max(0.1, deadline - time.monotonic()))
        if isinstance(x, bytes):
            hdr, img = decode_frame(x)
            if hdr["ack"] >= min_ack:
                return hdr, np.asarray(Image.open(io.BytesIO(img)).convert("RGB"), np.float64)
        else:
            ev = json.loads(x)
            server_event.validate_python(ev)          # every event matches the published schema
            if events is not None:
                events.append(ev)


async def next_event(ws, timeout=30):
    """Receive until a JSON event and return it; binary frames meanwhile are skipped (a session
    sends its settled still some time after a first frame, before or after an answer)."""
    deadline = time.monotonic() + timeout
    while True:
        x = await asyncio.wait_for(ws.recv(), timeout=max(0.1, deadline - time.monotonic()))
        if not isinstance(x, bytes):
            ev = json.loads(x)
            server_event.validate_python(ev)
            return ev


# -- the studio in a browser (Playwright pages) -------------------------------------------------
def frame_no(page) -> int:
    """The number of the last frame the studio's canvas drew."""
    return int(page.evaluate("() => +(document.getElementById('view').dataset.frame || 0)"))


def open_scene(page, scene, timeout=60_000):
    """Open ``scene`` from the studio's Scene panel and wait for its new session's first frame
    (the URL names the new session, and the canvas's frame numbers start again from 1 then:
    a frame number read before the click can be the last session's)."""
    old = page.evaluate("() => new URLSearchParams(location.search).get('session')")
    page.select_option("#scene-select", scene)
    page.click("#open-scene")
    page.wait_for_function("(old) => new URLSearchParams(location.search).get('session') !== old"
                           " && +(document.getElementById('view').dataset.frame || 0) > 0", arg=old, timeout=timeout)
    page.wait_for_timeout(150)


def wait_new_frame(page, after, timeout=60_000):
    page.wait_for_function(f"() => +(document.getElementById('view').dataset.frame || 0) > {after}", timeout=timeout)
    page.wait_for_timeout(150)


def settle(page, quiet_ms=600, timeout=60_000):
    """Wait until the canvas shows a settled frame (FrameHeader.settled: the session draws no
    still after it, so nothing more comes until a message changes its state) and no other
    frame has arrived for quiet_ms (the frame answering the test's last action, had it not been
    drawn yet, would come within that on this machine; a quick or drag frame is never settled)."""
    waited, quiet, first = 0, 0, frame_no(page)
    last = first
    while waited < timeout:
        page.wait_for_timeout(150)
        waited += 150
        now = frame_no(page)
        quiet = quiet + 150 if now == last else 0
        last = now
        if quiet >= quiet_ms and page.evaluate("() => document.getElementById('view').dataset.settled") == "true":
            return
    # which way it failed: frames still coming, or the last one not settled and nothing after it
    # (a still that failed to render, a refit that never finished); the page says what it shows
    seen = page.evaluate("""() => { const d = document.getElementById('view').dataset;
        return {frame: d.frame, ack: d.ack, samples: d.samples, quick: d.quick, settled: d.settled,
                status: (document.getElementById('status') || {}).textContent}; }""")
    raise TimeoutError(f"no settled frame within {timeout} ms: {last - first} frames arrived meanwhile, the last "
                       f"{quiet} ms before the end; the canvas shows {seen}")


def drag(page, x, y, dx, dy, steps=8, step_ms=30):
    """Press at (x, y) and move by (dx, dy) in steps, as a hand would."""
    page.mouse.move(x, y)
    page.mouse.down()
    for k in range(1, steps + 1):
        page.mouse.move(x + dx * k / steps, y + dy * k / steps)
        page.wait_for_timeout(step_ms)
    page.mouse.up()


class AssetDir(os.PathLike):
    """The real test assets, tests/.cache/assets (worker/assets.py lists them), each file fetched
    on first use: ``assets / "env" / "sunset.exr"`` makes sure that file is there (SHA-256
    checked; from ../shared/assets when it has it, else from its registry) and returns its Path,
    so that a test that needs the bunny does not download the furniture."""

    def __init__(self, rel: str = ""):
        self.rel = rel

    def __truediv__(self, name) -> "AssetDir | Path":
        rel = f"{self.rel}/{name}" if self.rel else str(name)
        from worker.assets import BY_PATH
        return asset_file(rel) if rel in BY_PATH else AssetDir(rel)

    def __fspath__(self) -> str:
        return str(_asset_root() / self.rel)

    def __str__(self) -> str:
        return self.__fspath__()


def _asset_root() -> Path:
    from worker.assets import repo_asset_dir
    return repo_asset_dir()


def asset_file(rel: str) -> Path:
    """tests/.cache/assets/<rel> (e.g. "env/sunset.exr"), fetched if missing; a failed fetch
    fails the test with the message naming the asset and its registry."""
    import pytest

    from worker.assets import AssetError, default_mirror, ensure
    try:
        ensure([rel], _asset_root(), default_mirror())
    except AssetError as e:
        pytest.fail(str(e), pytrace=False)
    return _asset_root() / rel


def scene_file(rel: str) -> Path:
    """tests/scenes/<rel> (e.g. "bunny.json") with the assets it refers to fetched if missing."""
    import pytest

    from worker.assets import AssetError, default_mirror, ensure_scene
    try:
        return ensure_scene(ROOT / "tests" / "scenes" / rel, _asset_root(), default_mirror())
    except AssetError as e:
        pytest.fail(str(e), pytrace=False)


def validate_gltf(path) -> dict:
    """The Khronos glTF-Validator's report (JSON) on a .glb: ``node tools/validate-gltf.js``, with
    tools/node_modules installed from tools/package-lock.json as `make tools` does when missing."""
    import shutil

    node = shutil.which("node")
    assert node, "node is missing: the glTF-Validator runs on Node.js (apt-get install nodejs)"
    tools = ROOT / "tools"
    if not (tools / "node_modules" / "gltf-validator").is_dir():
        subprocess.run(["npm", "ci", "--prefix", str(tools), "--no-audit", "--no-fund"], check=True, timeout=600)
    r = subprocess.run([node, str(tools / "validate-gltf.js"), str(path)], capture_output=True, text=True, timeout=300)
    assert r.returncode in (0, 1), r.stderr          # 1: the report has errors (the caller asserts on them)
    return json.loads(r.stdout)


# the studio canvas's luminance (Rec. 709 weights of the drawn sRGB values) on a 64 × 48 grid of
# pixel centres, whatever the canvas's size
CANVAS_GRID_JS = """() => {
  const c = document.getElementById('view'), g = c.getContext('2d');
  const d = g.getImageData(0, 0, c.width, c.height).data, W = 64, H = 48, out = [];
  for (let j = 0; j < H; j++) for (let i = 0; i < W; i++) {
    const x = Math.floor((i + 0.5) * c.width / W), y = Math.floor((j + 0.5) * c.height / H), k = 4 * (y * c.width + x);
    out.push(0.2126 * d[k] + 0.7152 * d[k + 1] + 0.0722 * d[k + 2]);
  }
  return out;
}"""


def canvas_grid(page):
    """(48, 64) float64 luminance of the studio canvas (``#view``) sampled on a regular grid."""
    import numpy as np

    return np.asarray(page.evaluate(CANVAS_GRID_JS), np.float64).reshape(48, 64)
