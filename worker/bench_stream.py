"""``glint bench stream``: stroke-to-frame latency and orbit frame rate over a real WebSocket.

Starts ``glint serve`` on a free loopback port (default data directory, so the demo scene's
precomputation is reused once made) or uses the server on ``--port``; opens a session on the demo
scene; then
* strokes: sends a stroke and waits for the first frame whose ``ack`` covers it, one at a time
  (the first stroke in a view also builds the transfer matrix: reported apart);
* orbit: sends ``view`` messages at 60 Hz for a few seconds while frames stream back, and counts
  the frames received per second.
"""
from __future__ import annotations

import asyncio
import json
import math
import os
import socket
import subprocess
import sys
import time
from pathlib import Path


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_demo(base: str, quiet: bool, timeout: float = 1800.0) -> str:
    import httpx

    t0 = time.monotonic()
    last = None
    while time.monotonic() - t0 < timeout:
        try:
            scenes = httpx.get(base + "/v1/scenes", timeout=5).json()
        except Exception:
            time.sleep(0.5)
            continue
        demo = [s for s in scenes if s["name"] == "demo"]
        if demo and demo[0]["precomputation"]:
            p = demo[0]["precomputation"]
            if p["status"] == "done":
                return demo[0]["id"]
            if p["status"] == "failed":
                raise RuntimeError(f"demo precomputation failed: {p['message']}")
            if not quiet and p["progress"] != last:
                last = p["progress"]
                print(f"waiting for the demo precomputation: {100 * last:.0f}%", file=sys.stderr)
        time.sleep(1.0)
    raise TimeoutError("the demo scene was not ready in time")


async def _run(base_ws: str, ses: dict, strokes: int, orbit_seconds: float) -> dict:
    import websockets

    from .jobs.session import decode_frame

    async with websockets.connect(f"{base_ws}{ses['stream']}?token={ses['token']}", max_size=None) as ws:
        cam = ses["state"]["camera"]
        W, H = cam["width"], cam["height"]

        async def frame_with_ack(seq):
            while True:
                x = await asyncio.wait_for(ws.recv(), 120)
                if isinstance(x, bytes):
                    hdr, _ = decode_frame(x)
                    if hdr["ack"] >= seq:
                        return hdr

        await frame_with_ack(-1)
        seq = 0
        lat, render_ms = [], []
        first = None
        for i in range(strokes + 1):
            seq += 1
            y = H * (0.45 + 0.1 * ((i * 0.37) % 1.0))
            x0 = W * (0.40 + 0.1 * ((i * 0.61) % 1.0))
            st = {"points": [[x0, y], [x0 + W * 0.08, y + 3]], "color": [2.0, 2.0, 2.0], "diameter": 16, "kappa": 0.05}
            t0 = time.perf_counter()
            await ws.send(json.dumps({"seq": seq, "type": "stroke", "stroke": st}))
            hdr = await frame_with_ack(seq)
            dt = (time.perf_counter() - t0) * 1e3
            if i == 0:
                first = dt
            else:
                lat.append(dt)
                render_ms.append(hdr["ms_render"])
        # orbit: views at 60 Hz, frames counted as they arrive
        eye, tgt = cam["eye"], cam["target"]
        r = math.hypot(eye[0] - tgt[0], eye[2] - tgt[2])
        a0 = math.atan2(eye[0] - tgt[0], eye[2] - tgt[2])
        frames = 0
        orbit_render = []
        stop = time.perf_counter() + orbit_seconds

        async def receiver():
            nonlocal frames
            while True:
                x = await ws.recv()
                if isinstance(x, bytes):
                    hdr, _ = decode_frame(x)
                    frames += 1
                    orbit_render.append(hdr["ms_render"])

        rx = asyncio.create_task(receiver())
        t_start = time.perf_counter()
        k = 0
        while time.perf_counter() < stop:
            seq += 1
            a = a0 + 0.5 * math.sin(k / 60.0 * 2 * math.pi * 0.25)
            e = [tgt[0] + r * math.sin(a), eye[1], tgt[2] + r * math.cos(a)]
            await ws.send(json.dumps({"seq": seq, "type": "view", "eye": e, "drag": True}))
            k += 1
            await asyncio.sleep(max(0.0, t_start + k / 60.0 - time.perf_counter()))
        dur = time.perf_counter() - t_start
        rx.cancel()

    def pct(v, q):
        v = sorted(v)
        return v[min(len(v) - 1, int(round(q / 100 * (len(v) - 1))))] if v else None

    return {"p50_ms": pct(lat, 50), "p95_ms": pct(lat, 95), "orbit_fps": frames / dur, "first_stroke_ms": first,
            "strokes": len(lat), "views_sent": k, "orbit_seconds": dur, "width": W, "height": H,
            "stroke_frame_render_ms_p50": pct(render_ms, 50), "orbit_frame_render_ms_p50": pct(orbit_render, 50)}


def bench_stream(port: int | None = None, data_dir: str | None = None, strokes: int = 20,
                 orbit_seconds: float = 5.0, quiet: bool = False) -> dict:
    import httpx

    proc = None
    if port is None:
        port = _free_port()
        cmd = [sys.executable, "-m", "worker.cli", "serve", "--port", str(port)]
        if data_dir:
            cmd += ["--data-dir", data_dir]
        log = open(os.devnull, "w") if quiet else sys.stderr
        proc = subprocess.Popen(cmd, cwd=Path(__file__).resolve().parent.parent, stdout=log, stderr=log)
    base = f"http://127.0.0.1:{port}"
    try:
        for _ in range(600):
            try:
                if httpx.get(base + "/healthz", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                time.sleep(0.2)
            if proc is not None and proc.poll() is not None:
                raise RuntimeError("the server exited during start-up")
        scene = _wait_demo(base, quiet)
        ses = httpx.post(base + "/v1/sessions", json={"scene_id": scene}, timeout=60).json()
        res = asyncio.run(_run(f"ws://127.0.0.1:{port}", ses, strokes, orbit_seconds))
        res["scene"] = scene
        return res
    finally:
        if proc is not None:
            proc.terminate()
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
