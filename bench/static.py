"""Shoppers at scale through a static server: ``glint bench viewer --static``.

A shopper is what the viewer page does in a real browser: the requests Chromium makes when it
opens the published object's page and its player preloads the bundle (page, scripts, style,
manifest, then the frames, the one on screen first; turning afterwards swaps frames already
loaded and requests nothing). Those requests are recorded once from a real Chromium page load
(``shopper_requests``), not assumed.

The load: ``clients`` shoppers arriving at a fixed rate, each on one HTTP/2 connection with at
most six requests in flight (a browser's HTTP/2 connection to an HTTPS site or CDN; here
cleartext h2, nginx's ``listen … http2``), replaying that list, by h2load (nghttp2's load
generator, C: a Python client of a thousand connections spent more CPU than the server it
measured). nginx serves the bundle files and the web client from disk (server/static_site.py)
and proxies the page and the manifest to the service. Latency per request is h2load's own
(request sent → response complete, its per-request log); the server's time per request is
nginx's ``$request_time``. Both processes' CPU time is read from /proc, so what the client cost
is on the record next to what the server did.
"""
from __future__ import annotations

import os
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

from .stream import ROOT, pct


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def need(tool: str) -> str:
    path = shutil.which(tool) or (f"/usr/sbin/{tool}" if Path(f"/usr/sbin/{tool}").exists() else None)
    if path is None:
        pkg = {"nginx": "nginx", "h2load": "nghttp2-client"}[tool]
        raise RuntimeError(f"{tool} is not installed: apt-get install {pkg} (scripts/ensure-static)")
    return path


def proc_cpu(pids) -> float:
    """CPU seconds (user + system) of processes, including their reaped children."""
    tick = os.sysconf("SC_CLK_TCK")
    out = 0.0
    for pid in pids:
        try:
            f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            out += (int(f[11]) + int(f[12]) + int(f[13]) + int(f[14])) / tick
        except (OSError, ValueError, IndexError):
            pass
    return out


class Nginx:
    """nginx started on a data folder's published files in front of a service on ``upstream``,
    with the configuration ``glint nginx-conf`` writes (server/static_site.py; asked of the
    command line, as the service itself is started, since bench imports no server module), in
    a temporary folder of its own."""

    def __init__(self, data_dir: str, upstream: str, access_log: bool = True):
        import sys

        exe = need("nginx")
        self.dir = Path(tempfile.mkdtemp(prefix="glint-nginx-"))
        self.dir.chmod(0o755)                # nginx's workers run as another user
        self.port, self.port_h2 = _free_port(), _free_port()
        self.log = self.dir / "access.log"
        conf = self.dir / "nginx.conf"
        subprocess.run([sys.executable, "-m", "glint", "nginx-conf", "--data-dir", str(data_dir),
                        "--web-dir", str(ROOT / "web"), "--upstream", upstream, "--listen", f"127.0.0.1:{self.port}",
                        "--listen-h2", f"127.0.0.1:{self.port_h2}", "--run-dir", str(self.dir),
                        "--access-log", str(self.log) if access_log else "off", "--out", str(conf)]
                       # the data folder may be private to this user (e.g. under a 0700 temporary folder)
                       + (["--user", "root"] if os.geteuid() == 0 else []),
                       cwd=ROOT, check=True, capture_output=True)
        self._err = open(self.dir / "error.log", "wb")     # noqa: SIM115 (closed by close())
        self.proc = subprocess.Popen([exe, "-c", str(conf), "-p", str(self.dir), "-e", "stderr", "-g", "daemon off;"],
                                     stdout=subprocess.DEVNULL, stderr=self._err)
        for _ in range(100):
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.5).close()
                break
            except OSError:
                if self.proc.poll() is not None:
                    raise RuntimeError(f"nginx exited: {(self.dir / 'error.log').read_text(errors='replace')[-2000:]}")
                time.sleep(0.1)
        self.base = f"http://127.0.0.1:{self.port}"
        self.base_h2 = f"http://127.0.0.1:{self.port_h2}"

    def pids(self) -> list[int]:
        out = [self.proc.pid]
        for p in Path("/proc").iterdir():
            if p.name.isdigit():
                try:
                    if int((p / "stat").read_text().rsplit(")", 1)[1].split()[1]) == self.proc.pid:
                        out.append(int(p.name))
                except (OSError, ValueError, IndexError):
                    pass
        return out

    def cpu_seconds(self) -> float:
        return proc_cpu(self.pids())

    def rotate_log(self) -> list[str]:
        """The access log's lines so far (emptied for the next run; nginx reopens it on USR1)."""
        import signal

        os.kill(self.proc.pid, signal.SIGUSR1)      # flush buffered lines
        time.sleep(1.5)
        lines = self.log.read_text().splitlines() if self.log.exists() else []
        self.log.write_text("")
        return lines

    def close(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self._err.close()
        shutil.rmtree(self.dir, ignore_errors=True)


PRELOADED = ("() => { const p = window.glintViewer; if (!p || p.loading) return false;"
             " for (const u of p.wanted()) if (!p.images.has(u)) return false; return true; }")


# A shopper's fastest turn, driven by real pointer events on the stage inside the page (Playwright's
# mouse moves arrive at the Python client's pace, not the display's): one pointermove per
# animation frame, each far enough for one azimuth step, for two full turns. Per tick: the rAF
# interval, the time the handler takes (hit test, pick, drawImage) and whether the frame drawn
# is the requested azimuth (not a neighbour's stand-in).
TURN = """async () => {
  const p = window.glintViewer, stage = document.getElementById('stage');
  const r = stage.getBoundingClientRect(), step = (1.5 * r.width) / p.A + 0.01;
  const ev = (type, x) => new PointerEvent(type, {pointerId: 7, clientX: x, clientY: r.top + r.height / 2,
                                                  bubbles: true, isPrimary: true, pointerType: 'mouse'});
  const capture = stage.setPointerCapture;
  stage.setPointerCapture = () => {};             // synthetic pointers have no capture to take
  let x = r.left + r.width / 2;
  stage.dispatchEvent(ev('pointerdown', x));
  const ticks = [], handler = [], exact = [], drawn0 = p.drawn, n = 2 * p.A;
  await new Promise((resolve) => {
    const tick = (t) => {
      ticks.push(t);
      if (ticks.length > n) return resolve();
      const want = p.az, t0 = performance.now();
      x -= step;
      stage.dispatchEvent(ev('pointermove', x));
      handler.push(performance.now() - t0);
      exact.push(p.az !== want && p.shown === p.url(p.entry(p.v, p.e, p.el, p.az), p.hi) ? 1 : 0);
      requestAnimationFrame(tick);
    };
    requestAnimationFrame(tick);
  });
  stage.dispatchEvent(ev('pointerup', x));
  stage.setPointerCapture = capture;
  const iv = ticks.slice(1).map((t, i) => t - ticks[i]);
  return {ticks: n, drawn: p.drawn - drawn0, seconds: (ticks[n] - ticks[0]) / 1000,
          intervals_ms: iv, handler_ms: handler, exact: exact.reduce((a, b) => a + b, 0)};
}"""


def turn_rate(page) -> dict:
    """The viewer turning as fast as its bundle allows (``TURN``: one azimuth step per animation
    frame, two full turns, after the preload). Returns {"fps": frames drawn per second of the
    turn, "display_fps": the page's animation-frame rate meanwhile (the screen's rate in a
    browser that is keeping up), "handler_p50_ms" / "handler_p95_ms": pointer handler plus draw,
    "exact_fraction": ticks that showed the requested azimuth, "ticks", "drawn": frames drawn}."""
    r = page.evaluate(TURN)
    iv, h = sorted(r["intervals_ms"]), sorted(r["handler_ms"])
    q = lambda xs, f: round(xs[min(len(xs) - 1, int(f * len(xs)))], 2)  # noqa: E731
    return {"ticks": r["ticks"], "drawn": r["drawn"], "fps": round(r["drawn"] / r["seconds"], 1),
            "display_fps": round(r["ticks"] / r["seconds"], 1), "interval_p95_ms": q(iv, 0.95),
            "handler_p50_ms": q(h, 0.5), "handler_p95_ms": q(h, 0.95),
            "exact_fraction": round(r["exact"] / r["ticks"], 3)}


def shopper_requests(base: str, pid: str, viewport=(1280, 860), dpr: float = 1.0, settle_s: float = 60.0) -> dict:
    """The requests a real shopper's browser makes: Chromium opens ``/view/<pid>`` on ``base``
    (a cold cache), its player preloads the bundle, then the shopper picks the second variant
    and the player preloads that; recorded until the player has nothing left to load (turning
    afterwards requests nothing: ``turn_rate`` turns it between the two and counts its requests).
    Returns {"urls": [path?query in request order], "times_ms": when Chromium sent each (ms after
    the first: the player's own pacing, six in flight, the frame on screen first), "on_open":
    requests before the variant switch, "first_image_ms", "viewport", "dpr", "turn": turn_rate's
    figures and "requests"}."""
    from urllib.parse import urlsplit

    from playwright.sync_api import sync_playwright

    urls, sent = [], []

    def on_request(r):
        if urlsplit(r.url).netloc == urlsplit(base).netloc:
            urls.append(r.url)
            sent.append(time.perf_counter())

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=shutil.which("chromium") or "/usr/bin/chromium", headless=True,
                              args=["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"])
        try:
            ctx = b.new_context(viewport={"width": viewport[0], "height": viewport[1]}, device_scale_factor=dpr)
            page = ctx.new_page()
            page.on("request", on_request)
            page.goto(f"{base}/view/{pid}")
            page.wait_for_function("() => performance.getEntriesByName('glint-first-frame').length > 0",
                                   timeout=30_000)
            first = page.evaluate("() => performance.getEntriesByName('glint-first-frame')[0].startTime")
            # the player's preload is done when nothing loads and every wanted file is here
            page.wait_for_function(PRELOADED, timeout=int(settle_s * 1000))
            time.sleep(0.5)
            on_open = len(urls)
            turn = turn_rate(page)          # after the preload: turning requests nothing
            turned = len(urls) - on_open
            if page.locator(".swatch").count() > 1:
                page.locator(".swatch").nth(1).click()
                page.wait_for_function(PRELOADED, timeout=int(settle_s * 1000))
                time.sleep(0.5)
            ctx.close()
        finally:
            b.close()
    paths = []
    for u in urls:
        s = urlsplit(u)
        paths.append(s.path + (f"?{s.query}" if s.query else ""))
    times = [round(1e3 * (t - sent[0]), 3) for t in sent]
    return {"urls": paths, "times_ms": times, "on_open": on_open, "first_image_ms": round(first, 1), "viewport": list(viewport),
            "dpr": dpr, "turn": dict(turn, requests=turned)}


def h2load(base: str, paths: list[str], clients: int, rate: int, streams: int = 6, threads: int = 1,
           nice: int = 0, visit_s: float = 0.0, on_open: int | None = None,
           times_ms: list[float] | None = None) -> dict:
    """``clients`` shoppers replaying ``paths`` each, ``rate`` new ones a second, each on one
    HTTP/2 connection with ``streams`` requests in flight at most; the client runs at
    ``nice``. Returns latency percentiles (ms) over every request, the offered and served
    rates and the client's CPU seconds.

    visit_s > 0: each shopper stays on the page that long: its first ``on_open`` requests (the
    page and the preload) are sent when the recorded browser sent them (``times_ms``, ms after
    its first request), the rest (the variant switch) ``visit_s`` seconds later at their own
    recorded spacing, on the same open connection (an h2load timing script). Without it a
    shopper's requests run back to back and its visit lasts a fraction of a second, so the
    shoppers connected at once are about ``rate`` × that fraction, not ``clients``; with it,
    min(clients, rate × visit_s). h2load sends a timing script's requests at their time whatever
    is still in flight (an open loop: a loaded server does not slow the senders, as it would slow
    the player, which waits for one of its six before sending the next), so under load the
    latencies are an upper bound of the player's; without ``times_ms`` every opening request goes
    at once, the bound for a player that did not pace at all."""
    exe = need("h2load")
    with tempfile.TemporaryDirectory(prefix="glint-h2load-") as d:
        lst, log = Path(d) / "uris.txt", Path(d) / "requests.tsv"
        if visit_s > 0:
            k = len(paths) if on_open is None else on_open
            t = times_ms or [0.0] * len(paths)
            at = [t[i] if i < k else 1e3 * visit_s + t[i] - t[k] for i in range(len(paths))]
            lst.write_text("".join(f"{a:.3f}\t{base}{p}\n" for a, p in zip(at, paths)))
            script = ["--timing-script-file", str(lst)]
        else:
            lst.write_text("".join(f"{base}{p}\n" for p in paths))
            script = ["-i", str(lst)]
        hold = int(visit_s) + 60
        # -n: all requests, or with a timing script each client's
        n = len(paths) if visit_s > 0 else clients * len(paths)
        cmd = ["nice", "-n", str(nice), exe, "-c", str(clients), "-n", str(n),
               "-m", str(streams), "-t", str(threads), "-r", str(max(1, rate)), "--rate-period", "1s",
               "-T", f"{max(30, hold)}s", "-N", f"{max(60, hold)}s", *script, "--log-file", str(log)]
        out = Path(d) / "h2load.txt"
        t0 = time.perf_counter()
        with open(out, "wb") as fo:
            pr = subprocess.Popen(cmd, stdout=fo, stderr=subprocess.STDOUT)
            try:
                # the client's own CPU time: from its rusage when it is reaped
                _, status, ru = os.wait4(pr.pid, 0)
            except BaseException:
                pr.kill()
                raise
        pr.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - t0
        text = out.read_text(errors="replace")
        rows = []
        for line in log.read_text().splitlines() if log.exists() else []:
            f = line.split("\t")
            if len(f) >= 3:
                rows.append((int(f[0]), int(f[1]), int(f[2])))
    if not rows:
        raise RuntimeError(f"h2load logged no request:\n{text[-3000:]}")
    ms = [r[2] / 1e3 for r in rows]
    ok = sum(1 for r in rows if r[1] in (200, 304))
    span = (max(r[0] + r[2] for r in rows) - min(r[0] for r in rows)) / 1e6
    n_total = clients * len(paths)
    arrive = clients / max(1, rate)
    return {"clients": clients, "requests_per_shopper": len(paths), "arrival_per_s": rate,
            "arrival_seconds": round(arrive, 1), "visit_seconds": visit_s,
            "paced": bool(times_ms) and visit_s > 0,
            "shoppers_connected_at_once": int(min(clients, rate * visit_s)) if visit_s > 0 else None, "requests": len(rows), "ok": ok, "failed": n_total - ok,
            "seconds": round(span, 2), "wall_seconds": round(wall, 2),
            "offered_per_s": round(n_total / arrive, 1) if arrive else None,
            "served_per_s": round(len(rows) / span, 1) if span else None,
            "p50_ms": round(pct(ms, 50), 2), "p95_ms": round(pct(ms, 95), 2), "p99_ms": round(pct(ms, 99), 2),
            "max_ms": round(max(ms), 1), "client_cpu_seconds": round(ru.ru_utime + ru.ru_stime, 2),
            "client_nice": nice, "h2load_exit": pr.returncode,
            "h2load_summary": [x for x in text.splitlines() if x.startswith(("requests:", "status codes:", "finished in"))]}


def server_times(lines: list[str]) -> dict:
    """nginx's own time per request (``$request_time``, ms resolution; server/static_site.py's
    log format) of the frames (bundle files) and of everything it passed to the service."""
    frames, proxied = [], []
    for line in lines:
        f = line.split(" ", 6)
        if len(f) < 7:
            continue
        t = float(f[3]) * 1e3
        path = f[6].split(" ")[1] if " " in f[6] else ""
        (frames if path.startswith("/v1/bundle-files/") else proxied).append(t)
    out = {"frames": len(frames), "proxied": len(proxied)}
    if frames:
        out.update(frame_p50_ms=pct(frames, 50), frame_p95_ms=pct(frames, 95), frame_p99_ms=pct(frames, 99))
    if proxied:
        out.update(other_p95_ms=pct(proxied, 95))
    return out
