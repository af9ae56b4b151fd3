"""Service settings: embedded defaults that run on a fresh machine, overridable by environment
variables (GLINT_<NAME>) or by the ``glint serve`` flags."""
from __future__ import annotations

import os
from pathlib import Path

from pydantic import BaseModel, Field


def _default_data_dir() -> Path:
    return Path(os.environ.get("GLINT_DATA_DIR", Path.home() / ".cache" / "glint"))


class Settings(BaseModel):
    data_dir: Path = Field(default_factory=_default_data_dir)
    database_url: str | None = Field(None, description="SQLAlchemy URL; default SQLite in data_dir")
    host: str = "127.0.0.1"
    port: int = 8000
    workers: int = Field(default_factory=lambda: os.cpu_count() or 1, ge=1, le=64)
    worker_threads: int = Field(0, ge=0, description="OpenMP threads per worker; 0 = cores / workers")
    allow_anonymous_loopback: bool = True
    max_mesh_bytes: int = 256 * 1024 * 1024
    max_envmap_bytes: int = 256 * 1024 * 1024
    max_image_bytes: int = 64 * 1024 * 1024
    max_envmap_pixels: int = 8192 * 4096
    max_mesh_faces: int = 8_000_000
    demo: bool = True
    web_dir: Path = Field(default_factory=lambda: Path(__file__).resolve().parent.parent / "web")

    @property
    def db_url(self) -> str:
        return self.database_url or f"sqlite:///{self.data_dir / 'glint.db'}"

    @classmethod
    def from_env(cls, **overrides) -> "Settings":
        """Defaults ← GLINT_* environment variables ← explicit overrides (None ignored)."""
        vals = {}
        for name, field in cls.model_fields.items():
            env = os.environ.get(f"GLINT_{name.upper()}")
            if env is not None:
                vals[name] = env
        vals.update({k: v for k, v in overrides.items() if v is not None})
        return cls.model_validate(vals)
