"""``glint bench stream`` and ``glint bench load``: the service measured over real WebSockets, as
a client sees it.

Both start ``glint serve`` on a free loopback port (default data directory, so the demo scene's
precomputation is made once) or use the server on ``--port``, and open sessions on the demo
scene (the oak chair, 640×480).

``bench stream`` (one session):
* ``stroke_p50_ms`` / ``stroke_p95_ms``: a stroke in an unchanged view until the first frame
  whose ``ack`` covers it, one at a time;
* ``orbit_fps_drag``: frames received per second while ``view`` messages with ``drag: true``
  arrive at 60 Hz. The session draws each at full quality when recent full frames fit its frame
  budget and at the drag level of detail (``width_drag`` × ``height_drag``, coarsened cuts)
  otherwise: ``orbit_share_full_drag`` is the share of full-quality frames, with
  their render times ``orbit_frame_render_ms_p50_drag_full`` and ``…_drag_lod``;
* ``orbit_fps_full``: the same with ``drag: false``, where every frame is a still frame (full
  quality, 640×480, anti-aliased with ``orbit_samples_full`` samples per pixel);
* ``first_stroke_ms``: a stroke 0.3 s after an orbit ends (a designer moving the camera, then
  painting), until its frame; ``first_stroke_ms_immediate``: the stroke sent right after the
  last orbit message (the worst case, no time to prepare the view).

``bench load`` (N sessions at once): each orbits at 30 Hz (drag) and strokes every 3 s; per
session fps, view and stroke latencies and errors, totals, and the peak resident memory of the
server and its workers, twice in a row (memory must stay flat).
"""
from __future__ import annotations

import asyncio
import json
import math
import os
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stroke_fields(i: int, W: int, H: int) -> dict:
    """The benchmark's i-th stroke message fields on a W × H frame: a short white stroke (2× the
    display white) across the middle of the demo chair, moved a little each time."""
    y = H * (0.45 + 0.1 * ((i * 0.37) % 1.0))
    x0 = W * (0.40 + 0.1 * ((i * 0.61) % 1.0))
    return {"stroke": {"points": [[x0, y], [x0 + W * 0.08, y + 3]], "color": [2.0, 2.0, 2.0], "diameter": 16,
                       "kappa": 0.05}}


def pct(v, q):
    v = sorted(v)
    return v[min(len(v) - 1, int(round(q / 100 * (len(v) - 1))))] if v else None


class Server:
    """``glint serve`` started for the benchmark (or one already running on ``port``)."""

    def __init__(self, port: int | None, data_dir: str | None, quiet: bool, workers: int | None = None,
                 demo: bool = True):
        import httpx

        self.proc = None
        if port is None:
            port = _free_port()
            cmd = [sys.executable, "-m", "glint", "serve", "--port", str(port)]
            if data_dir:
                cmd += ["--data-dir", data_dir]
            if workers:
                cmd += ["--workers", str(workers)]
            if not demo:
                cmd += ["--no-demo"]
            log = open(os.devnull, "w") if quiet else sys.stderr
            self.proc = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=log)
        self.port = port
        self.base = f"http://127.0.0.1:{port}"
        for _ in range(600):
            try:
                if httpx.get(self.base + "/healthz", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                time.sleep(0.2)
            if self.proc is not None and self.proc.poll() is not None:
                raise RuntimeError("the server exited during start-up")

    def demo(self, quiet: bool, timeout: float = 1800.0) -> str:
        """The demo scene's id, once precomputed (progress on stderr)."""
        import httpx

        t0, last = time.monotonic(), None
        while time.monotonic() - t0 < timeout:
            st = httpx.get(self.base + "/v1/status", timeout=5).json()["demo"]
            if st["state"] == "ready":
                return st["scene_id"]
            if st["state"] in ("failed", "off"):
                raise RuntimeError(f"the demo scene is not available: {st.get('message')}")
            if not quiet and st.get("progress") != last:
                last = st.get("progress")
                print(f"waiting for the demo scene: {st.get('message')} {100 * (last or 0):.0f}%", file=sys.stderr)
            time.sleep(1.0)
        raise TimeoutError("the demo scene was not ready in time")

    def session(self, scene: str) -> dict:
        import httpx

        r = httpx.post(self.base + "/v1/sessions", json={"scene_id": scene}, timeout=60)
        r.raise_for_status()
        return r.json()

    def pids(self) -> list[int]:
        """The server and its worker processes."""
        if self.proc is None:
            return []
        out = [self.proc.pid]
        for d in Path("/proc").iterdir():
            if d.name.isdigit():
                try:
                    stat = (d / "stat").read_text()
                    if int(stat.rsplit(")", 1)[1].split()[1]) == self.proc.pid:
                        out.append(int(d.name))
                except (OSError, ValueError, IndexError):
                    pass
        return out

    def cpu_seconds(self) -> dict:
        """CPU seconds (user + system) used so far: {"server": s, "workers": s} (the machine's
        other load does not count, so runs on a busy machine can be compared by it)."""
        tick = os.sysconf("SC_CLK_TCK")
        out = {"server": 0.0, "workers": 0.0}
        for pid in self.pids():
            try:
                f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
                out["server" if pid == self.proc.pid else "workers"] += (int(f[11]) + int(f[12])) / tick
            except (OSError, ValueError, IndexError):
                pass
        return out

    def memory(self) -> dict:
        """Resident memory now and at peak (VmRSS, VmHWM), MiB, summed over server and workers,
        and now per process (``rss_mib_server``, ``rss_mib_workers``: one figure per worker)."""
        rss = hwm = 0
        server, workers = 0.0, []
        for pid in self.pids():
            try:
                for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                    if line.startswith("VmRSS:"):
                        kib = int(line.split()[1])
                        rss += kib
                        if pid == self.proc.pid:
                            server = kib / 1024
                        else:
                            workers.append(kib / 1024)
                    elif line.startswith("VmHWM:"):
                        hwm += int(line.split()[1])
            except OSError:
                pass
        return {"rss_mib": rss / 1024, "peak_rss_mib": hwm / 1024, "rss_mib_server": server,
                "rss_mib_workers": sorted(workers)}

    def close(self) -> None:
        if self.proc is not None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()


class Stream:
    """One session's stream: authenticates with its first message, records every frame."""

    def __init__(self, ws, ses: dict):
        self.ws = ws
        self.ses = ses
        self.seq = 0
        self.frames: list[tuple[float, dict]] = []       # (time received, header)
        self.errors: list[dict] = []
        self.sent: dict[int, float] = {}
        self._waiters: list = []
        cam = ses["state"]["camera"]
        self.cam = cam
        self.W, self.H = cam["width"], cam["height"]

    @classmethod
    async def open(cls, port: int, ses: dict):
        import websockets

        ws = await websockets.connect(f"ws://127.0.0.1:{port}{ses['stream']}", max_size=None)
        await ws.send(json.dumps({"type": "auth", "token": ses["token"]}))
        s = cls(ws, ses)
        s.task = asyncio.create_task(s._recv())
        await s.wait_ack(-1)
        return s

    async def _recv(self):
        from worker.protocol.wire import decode_frame

        try:
            async for x in self.ws:
                now = time.perf_counter()
                if isinstance(x, bytes):
                    hdr, _ = decode_frame(x)
                    self.frames.append((now, hdr))
                    for fut, seq in list(self._waiters):
                        if hdr["ack"] >= seq and not fut.done():
                            fut.set_result((now, hdr))
                else:
                    ev = json.loads(x)
                    if ev.get("type") == "error":
                        self.errors.append(ev)
        except Exception:
            pass

    async def send(self, type_: str, **fields) -> int:
        self.seq += 1
        self.sent[self.seq] = time.perf_counter()
        await self.ws.send(json.dumps({"seq": self.seq, "type": type_, **fields}))
        return self.seq

    async def wait_ack(self, seq: int, timeout: float = 300.0):
        for t, hdr in self.frames:
            if hdr["ack"] >= seq:
                return t, hdr
        fut = asyncio.get_running_loop().create_future()
        self._waiters.append((fut, seq))
        try:
            return await asyncio.wait_for(fut, timeout)
        finally:
            self._waiters = [w for w in self._waiters if w[0] is not fut]

    def stroke_fields(self, i: int) -> dict:
        return stroke_fields(i, self.W, self.H)

    def orbit_eye(self, phase: float) -> list[float]:
        eye, tgt = self.cam["eye"], self.cam["target"]
        r = math.hypot(eye[0] - tgt[0], eye[2] - tgt[2])
        a = math.atan2(eye[0] - tgt[0], eye[2] - tgt[2]) + 0.5 * math.sin(phase)
        return [tgt[0] + r * math.sin(a), eye[1], tgt[2] + r * math.cos(a)]

    async def stroke_latency(self, i: int) -> tuple[float, dict]:
        seq = await self.send("stroke", **self.stroke_fields(i))
        t, hdr = await self.wait_ack(seq)
        return (t - self.sent[seq]) * 1e3, hdr

    async def orbit(self, seconds: float, hz: float, drag: bool, phase0: float = 0.0) -> dict:
        """View messages at ``hz`` for ``seconds``; frames received per second and view latency."""
        n0 = len(self.frames)
        t_start = time.perf_counter()
        k = 0
        seqs = []
        while time.perf_counter() < t_start + seconds:
            seqs.append(await self.send("view", eye=self.orbit_eye(phase0 + 2 * math.pi * 0.25 * k / hz), drag=drag))
            k += 1
            await asyncio.sleep(max(0.0, t_start + k / hz - time.perf_counter()))
        dur = time.perf_counter() - t_start
        got = self.frames[n0:]
        return {"fps": len(got) / dur, "views": k, "frames": got, "seconds": dur}

    def view_latencies(self, frames) -> list[float]:
        """Per frame: time since the newest view message its ack covers was sent (ms)."""
        return [(t - self.sent[h["ack"]]) * 1e3 for t, h in frames if h["ack"] in self.sent]

    async def close(self):
        self.task.cancel()
        await self.ws.close()


async def _stream(port: int, ses: dict, strokes: int, orbit_seconds: float, repeats: int = 5) -> dict:
    s = await Stream.open(port, ses)
    try:
        lat, render_ms = [], []
        for i in range(strokes + 1):
            dt, hdr = await s.stroke_latency(i)
            if i:                                  # the first one builds the view's fit rows
                lat.append(dt)
                render_ms.append(hdr["ms_render"])
        drag = await s.orbit(orbit_seconds, 60.0, True)
        await s.wait_ack(s.seq)
        full = await s.orbit(orbit_seconds, 60.0, False, phase0=1.0)
        await s.wait_ack(s.seq)
        first, immediate = [], []
        for r in range(repeats):
            for pause, out in ((0.3, first), (0.0, immediate)):
                await s.orbit(0.5, 30.0, True, phase0=2.0 + r + pause)
                await s.send("view", eye=s.orbit_eye(2.3 + r + pause), drag=False)   # the user lets go
                await asyncio.sleep(pause)
                dt, _ = await s.stroke_latency(100 + r)
                out.append(dt)
        dh = [h for _, h in drag["frames"] if h.get("lod")]
        fh = [h for _, h in drag["frames"] if not h.get("lod")]
        res = {"stroke_p50_ms": pct(lat, 50), "stroke_p95_ms": pct(lat, 95), "strokes": len(lat),
               "stroke_frame_render_ms_p50": pct(render_ms, 50),
               "orbit_fps_drag": drag["fps"], "width_drag": dh[0]["width"] if dh else None,
               "height_drag": dh[0]["height"] if dh else None,
               "orbit_share_full_drag": len(fh) / max(1, len(dh) + len(fh)),
               "orbit_frame_render_ms_p50_drag_full": pct([h["ms_render"] for h in fh], 50),
               "orbit_frame_render_ms_p50_drag_lod": pct([h["ms_render"] for h in dh], 50),
               "orbit_fps_full": full["fps"], "width": s.W, "height": s.H,
               "orbit_samples_full": pct([h.get("samples", 1) for _, h in full["frames"]], 50),
               "orbit_view_p50_ms_drag": pct(s.view_latencies(drag["frames"]), 50),
               "orbit_view_p50_ms_full": pct(s.view_latencies(full["frames"]), 50),
               "orbit_frame_render_ms_p50_drag": pct([h["ms_render"] for _, h in drag["frames"]], 50),
               "orbit_frame_render_ms_p50_full": pct([h["ms_render"] for _, h in full["frames"]], 50),
               "first_stroke_ms": statistics.median(first), "first_stroke_ms_max": max(first),
               "first_stroke_ms_immediate": statistics.median(immediate), "orbit_seconds": orbit_seconds,
               "errors": len(s.errors)}
        return res
    finally:
        await s.close()


def bench_stream(port: int | None = None, data_dir: str | None = None, strokes: int = 20,
                 orbit_seconds: float = 5.0, quiet: bool = False) -> dict:
    _freeze_client()
    srv = Server(port, data_dir, quiet)
    try:
        scene = srv.demo(quiet)
        res = asyncio.run(_stream(srv.port, srv.session(scene), strokes, orbit_seconds))
        res["scene"] = scene
        return res
    finally:
        srv.close()


async def _load_session(port: int, ses: dict, seconds: float, index: int) -> dict:
    """One designer: orbit at 30 Hz (drag), a stroke every 3 s (while still orbiting)."""
    s = await Stream.open(port, ses)
    try:
        n0 = len(s.frames)
        t_start = time.perf_counter()
        strokes, views = [], []
        pending: list = []
        k = 0
        next_stroke = t_start + 1.0 + 0.37 * index     # staggered
        while time.perf_counter() < t_start + seconds:
            now = time.perf_counter()
            if now >= next_stroke:
                seq = await s.send("stroke", **s.stroke_fields(k))
                pending.append(seq)
                next_stroke += 3.0
            else:
                views.append(await s.send("view", eye=s.orbit_eye(index + 2 * math.pi * 0.1 * k / 30), drag=True))
            k += 1
            await asyncio.sleep(max(0.0, t_start + k / 30.0 - time.perf_counter()))
        dur = time.perf_counter() - t_start
        if pending:
            try:
                await s.wait_ack(pending[-1], timeout=120)
            except asyncio.TimeoutError:
                pass
        parts = {k: [] for k in ("wait", "apply", "fit", "render", "encode", "other")}
        for seq in pending:
            hit = [(t, h) for t, h in s.frames if h["ack"] >= seq]
            if hit:
                t, h = hit[0]
                strokes.append((t - s.sent[seq]) * 1e3)
                inside = 0.0
                for k in ("wait", "apply", "fit", "render", "encode"):
                    parts[k].append(h.get("ms_" + k, 0.0))
                    inside += parts[k][-1]
                parts["other"].append(strokes[-1] - inside)     # the server, pipes, the client
        got = [f for f in s.frames[n0:] if f[0] <= t_start + dur]
        vl = [v for v in s.view_latencies(got) if v is not None]
        return {"fps": len(got) / dur, "frames": len(got), "view_p50_ms": pct(vl, 50), "view_p95_ms": pct(vl, 95),
                "stroke_p50_ms": pct(strokes, 50), "stroke_p95_ms": pct(strokes, 95), "strokes": len(pending),
                "stroke_ms": [round(x, 1) for x in strokes],
                "strokes_framed": len(strokes), "errors": len(s.errors),
                # where a stroke's time goes, from its frame's header: waiting in the worker,
                # applying (the fit view), the fit, rendering, encoding, and the rest (server, pipes)
                "stroke_parts_p50_ms": {k: pct(v, 50) for k, v in parts.items()},
                "stroke_parts_p95_ms": {k: pct(v, 95) for k, v in parts.items()},
                "error_messages": [e.get("message") for e in s.errors][:3]}
    finally:
        await s.close()


def _freeze_client() -> None:
    """The benchmark's own full garbage collections (its imports' objects) must not show as the
    service's latency: they are frozen out of them (as the server and workers do theirs)."""
    import httpx  # noqa: F401
    import websockets  # noqa: F401

    from worker.memory import freeze_start_up

    freeze_start_up()


def bench_load(sessions: int = 8, seconds: float = 20.0, runs: int = 2, port: int | None = None,
               data_dir: str | None = None, quiet: bool = False, workers: int | None = None) -> dict:
    _freeze_client()
    srv = Server(port, data_dir, quiet, workers)
    try:
        scene = srv.demo(quiet)
        out = {"sessions_per_run": sessions, "seconds": seconds, "runs": [],
               "rss_mib_start": srv.memory()["rss_mib"]}     # before any session
        for run in range(runs):
            ses = [srv.session(scene) for _ in range(sessions)]

            async def all_sessions():
                return await asyncio.gather(*[_load_session(srv.port, s, seconds, i) for i, s in enumerate(ses)])

            cpu0 = srv.cpu_seconds()
            per = asyncio.run(all_sessions())
            cpu1 = srv.cpu_seconds()
            time.sleep(2.0)                      # the streams have closed: what stays resident
            mem = srv.memory()
            frames = sum(x["frames"] for x in per)
            strokes_sent = sum(x["strokes"] for x in per)
            mem.update({"cpu_s_server": cpu1["server"] - cpu0["server"], "cpu_s_workers": cpu1["workers"] - cpu0["workers"],
                        "frames": frames, "strokes_sent": strokes_sent,
                        "load_avg_1min": os.getloadavg()[0]})
            worst = [x["stroke_p95_ms"] for x in per if x["stroke_p95_ms"] is not None]
            pooled = [t for x in per for t in x["stroke_ms"]]
            out["runs"].append({"sessions": per, "min_fps": min(x["fps"] for x in per),
                                "mean_fps": statistics.mean(x["fps"] for x in per),
                                "view_p95_ms": max((x["view_p95_ms"] or 0) for x in per),
                                # every stroke of the run, and the worst session's own p95 (a
                                # session's ~10 strokes in 30 s make its p95 nearly its maximum)
                                "stroke_p50_ms": pct(pooled, 50), "stroke_p95_ms": pct(pooled, 95),
                                "stroke_max_ms": max(pooled) if pooled else None,
                                "stroke_p95_ms_worst_session": max(worst) if worst else None,
                                "errors": sum(x["errors"] for x in per),
                                "stroke_parts_p50_ms": {k: statistics.median(v) for k in per[0]["stroke_parts_p50_ms"]
                                                        if (v := [x["stroke_parts_p50_ms"][k] for x in per
                                                                  if x["stroke_parts_p50_ms"][k] is not None])},
                                **mem})
            if not quiet:
                r = out["runs"][-1]
                print(f"run {run + 1}: min fps {r['min_fps']:.1f}, stroke p95 {r['stroke_p95_ms']} ms "
                      f"(worst session {r['stroke_p95_ms_worst_session']} ms), "
                      f"errors {r['errors']}, rss {r['rss_mib']:.0f} MiB (server {r['rss_mib_server']:.0f}, "
                      f"workers {', '.join(f'{w:.0f}' for w in r['rss_mib_workers'])})", file=sys.stderr)
        last = out["runs"][-1]
        out.update({k: last[k] for k in ("min_fps", "mean_fps", "view_p95_ms", "stroke_p50_ms", "stroke_p95_ms",
                                         "stroke_max_ms", "stroke_p95_ms_worst_session", "errors",
                                         "rss_mib", "peak_rss_mib", "cpu_s_server", "cpu_s_workers", "frames",
                                         "strokes_sent", "load_avg_1min")})
        out["sessions"] = last["sessions"]
        if runs > 1:
            out["rss_growth_mib"] = out["runs"][-1]["rss_mib"] - out["runs"][0]["rss_mib"]
        return out
    finally:
        srv.close()
