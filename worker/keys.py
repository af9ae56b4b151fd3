"""The content key of a precomputed part or a cached result: one function for every cache.

``content_key(kind, version, **parts)`` is the address under which a part is stored (a folder
store's file name, a blob store's key): it changes whenever anything the part depends on does,
and only then. It hashes, with SHA-256:

* ``kind`` (what the part is: "cuts", "ground", "gi", …) and ``version``, the format version of
  what is stored under the key: bump it when the bytes of a part change meaning or when the
  recipe that computes them changes, and old stored parts are no longer found (recomputed,
  never misread);
* each named part, in sorted name order, as its name and then
  - an array: its dtype, its shape and its bytes in C order (so float32 and float64 of the same
    values, or a (N, 3) and a (3, N) array of the same bytes, differ);
  - bytes: their length and the bytes;
  - anything else: canonical JSON (sorted keys, no whitespace; floats by ``repr``, which round-
    trips exactly; NumPy scalars as Python numbers; tuples as lists); a value JSON cannot say
    exactly (NaN, an object) is an error rather than a silent ``str``.
  Every field is length-prefixed, so no two different inputs are one byte stream.

Returns 32 lowercase hex digits (128 bits of the digest: collisions are out of reach for any
number of parts a store holds, and the folder stores' names stay short).

Not a content key: ``worker/blobs.py`` addresses blobs by the SHA-256 of their bytes (the
uploads' published checksum), which is a hash of the data itself, not of a recipe.
"""
from __future__ import annotations

import hashlib
import json
from typing import Any

import numpy as np

KEY_CHARS = 32


def _json_default(o: Any):
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"content_key: {type(o).__name__} is not a JSON value (pass plain data or an array)")


def _field(h, tag: bytes, payload: bytes) -> None:
    h.update(tag)
    h.update(len(payload).to_bytes(8, "little"))
    h.update(payload)


def content_key(kind: str, version: int, **parts: Any) -> str:
    """The content key (32 hex chars) of a part of ``kind`` in format ``version`` made from
    ``parts`` (arrays, bytes or JSON values, by name); see the module docstring."""
    if not isinstance(kind, str) or not kind:
        raise ValueError("content_key: kind must be a non-empty string")
    if not isinstance(version, int) or isinstance(version, bool):
        raise ValueError("content_key: version must be an int")
    h = hashlib.sha256()
    _field(h, b"k", kind.encode())
    _field(h, b"v", str(version).encode())
    for name in sorted(parts):
        value = parts[name]
        _field(h, b"n", name.encode())
        if isinstance(value, np.ndarray):
            a = np.ascontiguousarray(value)
            if a.dtype.hasobject:
                raise TypeError(f"content_key: array {name!r} holds Python objects")
            _field(h, b"a", f"{a.dtype.str};{a.shape}".encode())
            _field(h, b"b", memoryview(a).cast("B") if a.size else b"")
        elif isinstance(value, (bytes, bytearray, memoryview)):
            _field(h, b"b", bytes(value))
        else:
            text = json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False, default=_json_default)
            _field(h, b"j", text.encode())
    return h.hexdigest()[:KEY_CHARS]
