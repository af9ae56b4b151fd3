"""A new designer's first start: ``glint bench first-start``.

``glint serve`` on an empty data folder (its demo scene fetched, registered and precomputed, as
on a fresh machine) and the studio opened in Chromium as soon as the service answers. What the
designer sees is read from the page itself, every 0.1 s: the canvas's ``data-preview`` (the
precomputation's first look is drawn) and ``data-frame`` / ``data-samples`` / ``data-quick`` (a
session's frame, and the settled anti-aliased one); the demo's stage (fetching, precomputing,
ready) from ``GET /v1/status``. Times are seconds from the studio opening.
"""
from __future__ import annotations

import shutil
import tempfile
import time

from .stream import Server


def bench_first_start(data_dir: str | None = None, timeout: float = 900.0, quiet: bool = False) -> dict:
    import httpx
    from playwright.sync_api import sync_playwright

    tmp = None
    if data_dir is None:
        tmp = data_dir = tempfile.mkdtemp(prefix="glint-first-start-")
    t_start = time.monotonic()
    srv = Server(None, data_dir, quiet)
    t_open = time.monotonic()
    out: dict = {"service_start_s": round(t_open - t_start, 2)}
    stages: dict = {}
    try:
        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=shutil.which("chromium") or "/usr/bin/chromium", headless=True,
                                  args=["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"])
            page = b.new_page(viewport={"width": 1280, "height": 800})
            page.goto(srv.base + "/")
            seen: dict = {}
            while time.monotonic() - t_open < timeout:
                t = round(time.monotonic() - t_open, 2)
                d = page.evaluate("() => ({...document.getElementById('view').dataset})")
                if d.get("preview") == "1":
                    seen.setdefault("preview_s", t)
                if d.get("frame") is not None:
                    seen.setdefault("first_frame_s", t)
                    if d.get("quick") == "false" and int(d.get("samples") or 0) > 1:
                        seen["settled_frame_s"] = t
                        break
                demo = httpx.get(srv.base + "/v1/status", timeout=5).json()["demo"]
                stages.setdefault(demo["state"], t)
                if demo["state"] == "failed":
                    raise RuntimeError(f"the demo scene failed: {demo.get('message')}")
                time.sleep(0.1)
            else:
                raise TimeoutError(f"no settled frame within {timeout:.0f} s (seen: {seen})")
            b.close()
    finally:
        srv.close()
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
    out.update(seen)
    out["stages_s"] = stages
    if "ready" in stages:
        out["ready_to_first_frame_s"] = round(seen["first_frame_s"] - stages["ready"], 2)
    return out
