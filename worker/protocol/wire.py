"""The stream on the wire: binary frames (4-byte big-endian header length | JSON header |
JPEG), the stream's JSON Schema (``glint schema``, stream-schema.json), and the size and depth
checks a text message passes before it is parsed.
"""
from __future__ import annotations

import json
import re
from typing import Literal

from pydantic import BaseModel, Field

from . import events as _events
from .messages import client_msg


class FrameHeader(BaseModel):
    """The JSON header of a binary frame: 4-byte big-endian length | header | image."""
    frame: int
    ack: int = Field(description="the highest client seq whose effect the frame shows")
    width: int
    height: int
    format: Literal["jpeg"] = "jpeg"
    lod: bool = Field(description="drawn at the drag level of detail (coarser cuts, half resolution): chosen "
                                  "while the user drags only when full frames do not fit the frame budget")
    samples: int = Field(1, description="primary-visibility samples per pixel (anti-aliasing of still frames)")
    quick: bool = Field(False, description="a first frame shown at once (after a new fit, or when the user lets go "
                                           "of the camera): one sample, highlights slightly blurred; the anti-aliased "
                                           "still of the same state follows when the session is idle")
    settled: bool = Field(False, description="the settled image of the session's state: no further frame follows "
                                             "until a message changes it (false for quick and drag frames, and "
                                             "for one-sample frames whose anti-aliased still is still to come, and "
                                             "while a stroke's fit is being completed over the full view)")
    shadow: bool | None = Field(None, description="the ground shadow is drawn; null: the scene has no ground")
    ms_render: float = Field(description="rendering, not counting ms_paused")
    ms_encode: float
    ms_paused: float = Field(0.0, description="how long the rendering stood aside for strokes being handled "
                                               "elsewhere on the machine (strokes go before frames)")
    ms_wait: float = Field(0.0, description="how long the message this frame answers waited in the worker before it "
                                             "was handled (other sessions' work, this session's previous frame): its "
                                             "oldest stroke, undo, redo or fit if it has one, else its oldest message")
    ms_apply: float = Field(0.0, description="applying the messages (a stroke's fit view is built here)")
    ms_fit: float = Field(0.0, description="the BRDF fit the messages asked for (0: none)")
    skipped: int = Field(0, description="client messages folded into this frame without a frame of their own")


def stream_schema() -> dict:
    """JSON Schema of the stream (docs/design/conventions.md, streaming protocol): client messages, server events, frame header."""
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": "Glint session stream",
            "description": "WebSocket /v1/sessions/{id}/stream: JSON client messages with increasing seq; "
                           "JSON server events; binary frames of 4-byte big-endian header length | JSON "
                           "header | JPEG.",
            "client_message": client_msg.json_schema(), "server_event": _events.server_event.json_schema(),
            "frame_header": FrameHeader.model_json_schema()}


def encode_frame(header: dict, image: bytes) -> bytes:
    """Binary WebSocket frame: 4-byte big-endian header length | UTF-8 JSON header | image."""
    h = json.dumps(header, separators=(",", ":")).encode()
    return len(h).to_bytes(4, "big") + h + image


def decode_frame(data: bytes) -> tuple[dict, bytes]:
    n = int.from_bytes(data[:4], "big")
    return json.loads(data[4:4 + n]), data[4 + n:]


class BadMessage(Exception):
    """A stream message that ends the stream: ``code`` the WebSocket close code, ``http`` the
    error event's status, the message says what was wrong (with the limit and the measured value)."""

    def __init__(self, code: int, message: str, http: int):
        super().__init__(message)
        self.code, self.http = code, http


# a JSON string (its closing quote optional, so an unterminated one is consumed in one match and
# nothing is scanned twice) or a bracket: what json_depth walks over, in linear time
_JSON_TOKENS = re.compile(r'"(?:[^"\\]|\\.)*"?|[\[\]{}]', re.S)


def json_depth(text: str, limit: int) -> int:
    """How deep the arrays and objects of a JSON text nest (strings skipped), counted up to
    ``limit + 1`` at most: json.loads recurses once a level, so a message nested 10^5 deep
    raised RecursionError in the server before this was checked."""
    d = deepest = 0
    for m in _JSON_TOKENS.finditer(text):
        c = m.group()
        if c in "[{":
            d += 1
            if d > deepest:
                deepest = d
                if d > limit:
                    break
        elif c in "]}":
            d -= 1
    return deepest


def parse_message_text(text: str | None, size: int, max_bytes: int, max_depth: int):
    """A text stream message parsed: text None (a binary frame of ``size`` bytes: 1003), over
    ``max_bytes`` UTF-8 bytes (1009) or nested deeper than ``max_depth`` (4400) raises
    BadMessage; text that is not JSON raises json.JSONDecodeError (the stream can go on)."""
    if text is None:
        raise BadMessage(1003, f"a binary frame ({size} bytes) is not a stream message: send JSON text messages", 415)
    # a character is at most 4 UTF-8 bytes: only a text near the limit is encoded to measure it
    if len(text) > max_bytes or (4 * len(text) > max_bytes and len(text.encode("utf-8", "surrogatepass")) > max_bytes):
        n = len(text.encode("utf-8", "surrogatepass"))
        raise BadMessage(1009, f"a message of {n} bytes is over the limit of {max_bytes} bytes "
                               "(max_stream_message_bytes)", 413)
    depth = json_depth(text, max_depth)
    if depth > max_depth:
        raise BadMessage(4400, f"a message nested more than {max_depth} levels deep (at least "
                               f"{depth}) is refused (max_stream_message_depth)", 400)
    return json.loads(text)
