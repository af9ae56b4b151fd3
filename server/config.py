"""Service settings: embedded defaults that run on a fresh machine, overridable by environment
variables (GLINT_<NAME>) or by the ``glint serve`` flags. Read once, in the server; workers get
what they need from it explicitly (``worker_settings``)."""
from __future__ import annotations

import os
from pathlib import Path

from pydantic import BaseModel, Field, field_validator


def _default_data_dir() -> Path:
    return Path(os.environ.get("GLINT_DATA_DIR", Path.home() / ".cache" / "glint"))


class Settings(BaseModel):
    data_dir: Path = Field(default_factory=_default_data_dir)
    database_url: str | None = Field(None, description="SQLAlchemy URL; default SQLite in data_dir")
    host: str = "127.0.0.1"
    port: int = 8000
    workers: int = Field(default_factory=lambda: os.cpu_count() or 1, ge=1, le=64)
    worker_threads: int = Field(0, ge=0, description="threads of a worker's jobs (precomputation's ray tracing); 0 = cores / "
                                "workers. Interactive sessions' kernels share the machine's cores among its busy "
                                "sessions instead (worker/jobs/runner.py Priority.kernel_threads)")
    kernels: str | None = Field(None, description="native, numpy, or unset (native when built)")
    worker_nice: int = Field(5, ge=0, le=19, description="scheduling niceness added to worker processes: under "
                             "load the server's message handling and frame sending go before rendering")
    shared_parts: Path | None = Field(None, description="a folder of precomputed parts shared with other data "
                                      "directories on this machine: a part (content-keyed) found there is copied "
                                      "instead of computed, and every computed part is written there too; unset: none")
    preview_min_vertices: int = Field(8000, ge=0, description="a precomputation of a scene with at least this many "
                                      "vertices first draws a quick preview (worker/renderers/cuts/preview.py); smaller "
                                      "ones are done in seconds without it")
    allow_anonymous_loopback: bool = True
    # DNS rebinding: requests must name one of these hosts (any port); the bind host is added
    allowed_hosts: list[str] = Field(default_factory=lambda: ["127.0.0.1", "localhost", "::1"])
    # browser origins allowed to change state and open streams (besides the allowed hosts')
    allowed_origins: list[str] = Field(default_factory=list)
    # proxies whose X-Forwarded-For / X-Forwarded-Proto are believed (none by default)
    trusted_proxies: list[str] = Field(default_factory=list)
    max_mesh_bytes: int = 256 * 1024 * 1024
    max_envmap_bytes: int = 256 * 1024 * 1024
    max_image_bytes: int = 64 * 1024 * 1024
    max_envmap_pixels: int = 8192 * 4096
    max_capture_bytes: int = Field(512 * 1024 * 1024, description="a capture zip (photos and manifest)")
    max_capture_files: int = Field(64, ge=2, description="files in a capture zip")
    max_mesh_faces: int = 8_000_000
    # JSON bodies the server validates itself, bounded so that validating one stays short (a
    # 20 000-object scene: ~2.6 MB, ~0.3 s in a thread) and the refusal names the limit
    max_scene_objects: int = Field(20_000, ge=1, description="objects in one scene")
    max_scene_body_bytes: int = Field(32 * 1024 * 1024, ge=1024, description="JSON body of POST /v1/scenes")
    max_json_body_bytes: int = Field(2 * 1024 * 1024, ge=1024, description="any other JSON request body (renders, fits, "
                                     "materials, sessions), which is validated as it arrives")
    max_capture_unpacked_bytes: int = Field(1024 ** 3, ge=1, description="a capture zip's files, uncompressed, in total")
    # who may frame the published viewer (/view/{id}, meant to be embedded): CSP frame-ancestors
    # sources ("*" anywhere, or origins such as https://blog.example); the studio only itself
    embed_origins: list[str] = Field(default_factory=lambda: ["*"])
    stale_temp_seconds: float = Field(3600.0, ge=0, description="at start, partial uploads older than this (or of a "
                                      "dead process) are deleted from the temporary folders")
    inspect_seconds: float = Field(300.0, gt=0, description="time limit for reading one upload")
    max_sessions: int = Field(64, ge=1, description="open streams in total")
    max_sessions_per_client: int = Field(8, ge=1, description="open streams per client (token or address)")
    session_idle_seconds: float = Field(900.0, gt=0, description="a stream with no message for this long is closed")
    # streams and public endpoints under abuse: message bounds, rate limits, viewer expiry, frame size
    max_stream_message_bytes: int = Field(1024 * 1024, ge=1024, description="a stream text message larger than this "
                                          "closes the stream (1009); a 10 000-point stroke is ~250 KB")
    max_stream_message_depth: int = Field(32, ge=4, description="JSON nesting depth of a stream message (deeper: "
                                          "closed with 4400); the deepest valid message nests ~6")
    viewer_sessions_per_minute: int = Field(60, ge=1, description="public viewer sessions one client address may "
                                            "create in any 60 s (moving window); more get 429")
    public_reads_per_minute: int = Field(600, ge=1, description="public publication reads per client address in "
                                         "any 60 s (moving window)")
    viewer_session_seconds: float = Field(300.0, gt=0, description="a viewer session without a stream (never "
                                          "opened, or ended) this long after its last activity is deleted")
    session_retention_seconds: float = Field(14 * 86400.0, gt=0, description="an editing session left without a "
                                             "stream for this long is closed (until then the studio's URL, a "
                                             "reload or another tab reopens it with its strokes, undo history, "
                                             "camera and material)")
    janitor_seconds: float = Field(60.0, gt=0, description="how often idle sessions are expired")
    max_frame_pixels: int = Field(2560 * 1600, ge=64 * 64, description="width × height of a session's camera at "
                                  "most; a frame costs ~FRAME_BYTES_PER_PIXEL bytes a pixel in its worker "
                                  "(server/routes/sessions.py)")
    # beyond one machine: "local" worker processes, or a Ray cluster (server/ray_pool.py)
    backend: str = Field("local", pattern="^(local|ray)$", description="worker backend: local or ray")
    ray_address: str | None = Field(None, description="Ray cluster to join (host:port of its GCS); unset: start one in-process")
    ray_node_ip: str | None = Field(None, description="this process's address as the Ray cluster sees it (e.g. 127.0.0.2 on loopback)")
    ray_chunks_per_cpu: float = Field(32.0, gt=0, description="pieces per cluster CPU a precomputation part is cut into, grouped into chunks of decreasing size (load balance vs overhead)")
    # operations
    log_format: str = Field("text", pattern="^(text|json)$", description="log lines as text or one JSON object per line")
    shutdown_grace_seconds: float = Field(0.0, ge=0, description="on SIGTERM, how long running precomputations may finish before they are failed")
    demo: bool = True
    demo_scene: Path | None = Field(None, description="scene file of the demo (default: the fetched oak chair)")
    web_dir: Path = Field(default_factory=lambda: Path(__file__).resolve().parent.parent / "web")

    @field_validator("allowed_hosts", "allowed_origins", "trusted_proxies", "embed_origins", mode="before")
    @classmethod
    def _split(cls, v):
        if isinstance(v, str):
            return [x.strip() for x in v.split(",") if x.strip()]
        return v

    @property
    def db_url(self) -> str:
        return self.database_url or f"sqlite:///{self.data_dir / 'glint.db'}"

    def threads_per_worker(self) -> int:
        return self.worker_threads or max(1, (os.cpu_count() or 1) // self.workers)

    def worker_settings(self, slot: int):
        """What worker ``slot`` needs, passed to it explicitly (workers read no environment)."""
        from worker.jobs.runner import WorkerSettings

        return WorkerSettings(blob_root=str(self.data_dir / "blobs"), tmp_dir=str(self.data_dir / "tmp" / f"worker-{slot}"),
                              threads=self.threads_per_worker(), kernels=self.kernels, nice=self.worker_nice,
                              preview_min_vertices=self.preview_min_vertices,
                              shared_parts=str(self.shared_parts) if self.shared_parts else None)

    @classmethod
    def from_env(cls, **overrides) -> "Settings":
        """Defaults ← GLINT_* environment variables ← explicit overrides (None ignored)."""
        vals = {}
        for name in cls.model_fields:
            env = os.environ.get(f"GLINT_{name.upper()}")
            if env is not None:
                vals[name] = env
        vals.update({k: v for k, v in overrides.items() if v is not None})
        return cls.model_validate(vals)
