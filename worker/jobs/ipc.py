"""The worker's end of its two pipes to the server.

Requests (server → worker):
    ("job", job_id, {"type": "precompute" | "render" | "fit" | "capture" | "bundle_frames", ...})
    ("open", session_id, {"scene": {...}, "state": {...}, "strokes": [...], "ack": int})
    ("msg", session_id, {client message})
    ("close", session_id, None)
    ("stop", None, None)
Replies (worker → server):
    ("progress", job_id, {"progress": 0..1, "message": str})
    ("result", job_id, {...}) / ("error", job_id, {"message": str, "status": int})
    ("frame", session_id, (header, jpeg bytes)) / ("event", session_id, {...})
    ("closed", session_id, None)   (the session's thread has ended and released what it held)
"""
from __future__ import annotations

import threading
from typing import Any, Literal, NamedTuple

RequestKind = Literal["job", "open", "msg", "close", "stop"]
ReplyKind = Literal["progress", "result", "error", "frame", "event", "closed"]


class Request(NamedTuple):
    """Server → worker. key : the job or session id (None for "stop"); payload : as listed
    above. A tuple (so it pickles small and unpacks as ``kind, key, payload``)."""
    kind: RequestKind
    key: str | None
    payload: Any = None


class Reply(NamedTuple):
    """Worker → server. key : the job or session id; payload : as listed above."""
    kind: ReplyKind
    key: str
    payload: Any = None


class PipeOut:
    """The writing end of a pipe, shared by threads (the server's event loop and monitor; the
    worker's job and session threads): one send at a time."""

    def __init__(self, conn):
        self.conn = conn
        self.lock = threading.Lock()

    def put(self, item) -> None:
        with self.lock:
            self.conn.send(item)

    def close(self) -> None:
        self.conn.close()


class JobError(Exception):
    """A job that cannot be done as asked (bad input): reported with an HTTP-like status."""

    def __init__(self, message: str, status: int = 422):
        super().__init__(message)
        self.status = status
