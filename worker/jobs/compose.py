"""A session frame from the renderer's radiance: tone mapping, JPEG encoding, the frame header
(protocol/wire.py FrameHeader), and the clock that keeps a frame's pauses for strokes elsewhere
out of its own times.
"""
from __future__ import annotations

import io
import time

from PIL import Image

from ..core.tonemap import tonemap
from ..memory import trim_malloc

DRAG_QUALITY = 60           # JPEG quality at most while the user drags (docs/design/conventions.md, streaming protocol)
# a frame of at least this many pixels gives its transient memory back at once (trim_malloc),
# and a closed session's cached primary hits of such a camera are dropped (runtime ``close``):
# at ~410 bytes a pixel (server/routes/sessions.py FRAME_BYTES_PER_PIXEL) that is ~400 MB and up
BIG_FRAME_PIXELS = 1024 * 1024


class PauseClock:
    """Wraps a frame's ``cancelled`` checkpoint (renderers.base.FrameRequest.cancelled), which
    may block while strokes elsewhere go first, and adds up the time it blocked (``paused``,
    seconds): the frame header's ms_paused, not counted in ms_render or ms_encode."""

    def __init__(self, checkpoint):
        self.paused = 0.0
        self._checkpoint = checkpoint
        self.cancelled = None if checkpoint is None else self._timed

    def _timed(self) -> bool:
        c0 = time.perf_counter()
        try:
            return self._checkpoint()
        finally:
            self.paused += time.perf_counter() - c0

    def now(self) -> float:
        """perf_counter() less the pauses so far."""
        return time.perf_counter() - self.paused


def tone(radiance, exposure: float, tone_curve: str):
    """(H, W, 3) uint8 display image of an (H, W, 3) linear radiance image (counted in
    ms_render, as drawing)."""
    return tonemap(radiance, exposure, tone_curve)


def jpeg(rgb, quality: int, dragging: bool) -> tuple[int, int, bytes]:
    """(width, height, JPEG bytes) of a display image; lower quality while the user drags,
    full quality when still."""
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="JPEG", quality=min(quality, DRAG_QUALITY) if dragging else quality)
    h, w = rgb.shape[:2]
    return w, h, buf.getvalue()


def release_scratch(width: int, height: int) -> None:
    """After a big frame (timed without this): its scratch (shading, tone mapping, JPEG) was
    freed into malloc's arenas; give it back at once."""
    if width * height >= BIG_FRAME_PIXELS:
        trim_malloc()


def header(frame: int, ack: int, width: int, height: int, lod: str, info: dict, ms_render: float,
           ms_encode: float, ms_paused: float, skipped: int, settled: bool = False) -> dict:
    """The frame header (FrameHeader fields; the session thread adds ms_wait, ms_apply,
    ms_fit). lod : "full", "drag" or "quick"; info : the renderer's Rendered.info; settled :
    no still frame follows this one (FrameHeader.settled)."""
    return {"frame": frame, "ack": ack, "width": width, "height": height, "format": "jpeg",
            "ms_render": round(ms_render, 2), "lod": lod == "drag", "quick": lod == "quick",
            "samples": int(info.get("samples", 1)), "shadow": info.get("ground_shadow"),
            "ms_encode": round(ms_encode, 2), "ms_paused": round(ms_paused, 2), "skipped": skipped,
            "settled": bool(settled)}
