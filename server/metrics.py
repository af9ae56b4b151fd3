"""Prometheus metrics: ``GET /metrics`` in the text exposition format.

What an operator watches, all from this API process (workers report through frames and job
results, so nothing has to be scraped from them):

=====================================================  ==============================================
metric                                                 meaning
=====================================================  ==============================================
``glint_http_requests_total{method,route,status}``     requests by route template (not by raw path)
``glint_http_request_duration_seconds{method,route}``  time to the end of the response
``glint_sessions_open``                                open session streams
``glint_sessions_on_workers``                          sessions held by workers (streams + restoring)
``glint_frames_total``                                 frames sent to clients
``glint_frame_render_seconds`` / ``…encode_seconds``   the worker's render and JPEG time per frame
``glint_input_to_frame_seconds{type}``                 a client message reaching the server → the first
                                                       frame that shows it (``type="stroke"``: the
                                                       stroke latency; ``view``: orbit latency)
``glint_jobs_total{type,outcome}``                     precompute / render / fit jobs, ok or error
``glint_job_duration_seconds{type,outcome}``           their duration
``glint_precomputations_running``                      background precomputations in progress
``glint_workers`` / ``glint_workers_alive``            worker processes (or Ray session hosts)
``glint_worker_restarts_total``                        workers replaced after dying
``glint_ray_nodes``                                    alive nodes of the Ray cluster (Ray backend)
``glint_info{version,backend,database}``               always 1
=====================================================  ==============================================

One ``Metrics`` per app (its own registry, so several apps in one process do not collide).
"""
from __future__ import annotations

import asyncio
import threading
import time
from typing import Callable

from prometheus_client import CollectorRegistry, Counter, Histogram
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.exposition import CONTENT_TYPE_LATEST, generate_latest

# interactive latencies: frames are tens of milliseconds, strokes (a fit) up to seconds
LATENCY_BUCKETS = (0.005, 0.01, 0.02, 0.033, 0.05, 0.075, 0.1, 0.15, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)
JOB_BUCKETS = (0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 120, 300, 600, 1800)
CONTENT_TYPE = CONTENT_TYPE_LATEST
MAX_PENDING = 256           # unanswered messages remembered per session (latest wins drops the rest)


class _StateCollector:
    """Gauges read at scrape time from the app state and the pool's health."""

    def __init__(self, state: Callable[[], object], info: dict):
        self.state = state
        self.info = info

    def describe(self):
        return []                       # read at scrape time only (registering must not call collect)

    def collect(self):
        info = GaugeMetricFamily("glint_info", "Glint server", labels=list(self.info))
        info.add_metric(list(self.info.values()), 1)
        yield info
        st = self.state()
        if st is None:
            return
        h = st.pool.health() or {}
        for name, key, doc in (("glint_workers", "workers", "worker processes or Ray session hosts"),
                               ("glint_workers_alive", "workers_alive", "workers alive"),
                               ("glint_sessions_on_workers", "sessions", "sessions held by workers")):
            yield GaugeMetricFamily(name, doc, value=float(h.get(key, 0)))
        if "ray_nodes" in h:
            yield GaugeMetricFamily("glint_ray_nodes", "alive nodes of the Ray cluster", value=float(h["ray_nodes"]))
        yield CounterMetricFamily("glint_worker_restarts", "workers replaced after dying",
                                  value=float(h.get("worker_restarts", 0)))
        yield GaugeMetricFamily("glint_sessions_open", "open session streams", value=float(st.sessions.open_streams()))
        yield GaugeMetricFamily("glint_precomputations_running", "background precomputations in progress",
                                value=float(len(st.precompute_tasks)))


class Metrics:
    def __init__(self, state: Callable[[], object], info: dict[str, str]):
        self.registry = CollectorRegistry(auto_describe=True)
        r = self.registry
        self.http_requests = Counter("glint_http_requests", "HTTP requests and streams", ["method", "route", "status"], registry=r)
        self.http_seconds = Histogram("glint_http_request_duration_seconds", "HTTP request duration",
                                      ["method", "route"], registry=r)
        self.frames = Counter("glint_frames", "frames sent to clients", registry=r)
        self.frame_render = Histogram("glint_frame_render_seconds", "worker render time per frame",
                                      buckets=LATENCY_BUCKETS, registry=r)
        self.frame_encode = Histogram("glint_frame_encode_seconds", "worker JPEG encode time per frame",
                                      buckets=LATENCY_BUCKETS, registry=r)
        self.input_to_frame = Histogram("glint_input_to_frame_seconds", "client message to the first frame showing it",
                                        ["type"], buckets=LATENCY_BUCKETS, registry=r)
        self.jobs = Counter("glint_jobs", "worker jobs", ["type", "outcome"], registry=r)
        self.job_seconds = Histogram("glint_job_duration_seconds", "worker job duration", ["type", "outcome"],
                                     buckets=JOB_BUCKETS, registry=r)
        r.register(_StateCollector(state, info))
        self._pending: dict[str, dict[int, tuple[float, str]]] = {}
        self._lock = threading.Lock()

    # -- requests --------------------------------------------------------------------------------
    def http(self, method: str, route: str, status: int, seconds: float) -> None:
        self.http_requests.labels(method, route, str(status)).inc()
        if method != "WS":                      # a stream's duration is its session's, not a latency
            self.http_seconds.labels(method, route).observe(seconds)

    # -- sessions --------------------------------------------------------------------------------
    def message(self, sid: str, msg: dict) -> None:
        """A client message forwarded to the worker (its ``seq`` and ``type``)."""
        seq = msg.get("seq")
        if not isinstance(seq, int):
            return
        with self._lock:
            p = self._pending.setdefault(sid, {})
            if len(p) >= MAX_PENDING:
                p.pop(min(p))
            p[seq] = (time.perf_counter(), str(msg.get("type", "?")))

    def frame(self, sid: str, hdr: dict) -> None:
        """A frame sent to the client: every pending message it acknowledges is answered."""
        self.frames.inc()
        if isinstance(hdr.get("ms_render"), (int, float)):
            self.frame_render.observe(hdr["ms_render"] / 1000.0)
        if isinstance(hdr.get("ms_encode"), (int, float)):
            self.frame_encode.observe(hdr["ms_encode"] / 1000.0)
        ack = hdr.get("ack")
        if not isinstance(ack, int):
            return
        now = time.perf_counter()
        with self._lock:
            p = self._pending.get(sid)
            if not p:
                return
            done = [s for s in p if s <= ack]
            answered = [p.pop(s) for s in done]
        for t, typ in answered:
            self.input_to_frame.labels(typ).observe(now - t)

    def session_ended(self, sid: str) -> None:
        with self._lock:
            self._pending.pop(sid, None)

    # -- jobs ------------------------------------------------------------------------------------
    def wrap_job(self, run_job):
        """``pool.run_job`` timed by job type and outcome."""
        async def timed(job: dict, on_progress=None):
            t0 = time.perf_counter()
            outcome = "error"
            try:
                res = await run_job(job, on_progress)
                outcome = "ok"
                return res
            except asyncio.CancelledError:
                outcome = "cancelled"
                raise
            finally:
                typ = str(job.get("type", "?"))
                self.jobs.labels(typ, outcome).inc()
                self.job_seconds.labels(typ, outcome).observe(time.perf_counter() - t0)
        return timed

    def render(self) -> bytes:
        return generate_latest(self.registry)
