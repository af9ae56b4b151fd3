"""JSON encoding and decoding in small pieces, for documents large enough (a scene of 20 000
objects is ~2.6 MB) that one ``json.loads``/``json.dumps`` call would hold the GIL for 50-100 ms
and stall the event loop, and every stream, while a thread-pool thread runs it.

The top levels of a document (an object's members, an array's elements, down to ``depth``) are
walked in Python and everything below is handed to the C scanner/encoder one element at a time,
so the interpreter can switch threads between elements (every ``sys.getswitchinterval()``,
5 ms). The results are exactly ``json.loads``/``json.dumps``'s.
"""
from __future__ import annotations

import json
import re

_WS = re.compile(r"[ \t\n\r]*")
_DECODER = json.JSONDecoder()
_scan = _DECODER.scan_once
PIECE = 256                        # list elements encoded per json.dumps call


def loads(s: str | bytes, depth: int = 2):
    """``json.loads(s)``, walking the outer ``depth`` levels element by element. Raises
    json.JSONDecodeError (with line and column) as json.loads does."""
    if isinstance(s, (bytes, bytearray, memoryview)):
        s = bytes(s).decode("utf-8")
    v, end = _value(s, _WS.match(s, 0).end(), depth)
    end = _WS.match(s, end).end()
    if end != len(s):
        raise json.JSONDecodeError("Extra data", s, end)
    return v


def _value(s: str, i: int, depth: int):
    c = s[i:i + 1]
    if depth <= 0 or c not in ("{", "["):
        try:
            return _scan(s, i)
        except StopIteration as e:
            raise json.JSONDecodeError("Expecting value", s, e.value) from None
    close = "}" if c == "{" else "]"
    out: dict | list = {} if c == "{" else []
    i = _WS.match(s, i + 1).end()
    if s[i:i + 1] == close:
        return out, i + 1
    while True:
        if close == "}":
            if s[i:i + 1] != '"':
                raise json.JSONDecodeError("Expecting property name enclosed in double quotes", s, i)
            key, i = _scan(s, i)
            i = _WS.match(s, i).end()
            if s[i:i + 1] != ":":
                raise json.JSONDecodeError("Expecting ':' delimiter", s, i)
            val, i = _value(s, _WS.match(s, i + 1).end(), depth - 1)
            out[key] = val
        else:
            val, i = _value(s, i, depth - 1)
            out.append(val)
        i = _WS.match(s, i).end()
        c = s[i:i + 1]
        if c == close:
            return out, i + 1
        if c != ",":
            raise json.JSONDecodeError("Expecting ',' delimiter", s, i)
        i = _WS.match(s, i + 1).end()


def dumps(obj, depth: int = 2) -> str:
    """``json.dumps(obj, separators=(",", ":"))`` with the outer ``depth`` levels written piece
    by piece (lists in runs of PIECE elements)."""
    if depth <= 0:
        return json.dumps(obj, separators=(",", ":"))
    if isinstance(obj, dict):
        return "{" + ",".join(json.dumps(str(k)) + ":" + dumps(v, depth - 1) for k, v in obj.items()) + "}"
    if isinstance(obj, (list, tuple)):
        if depth == 1:
            parts = (json.dumps(list(obj[k:k + PIECE]), separators=(",", ":"))[1:-1] for k in range(0, len(obj), PIECE))
            return "[" + ",".join(p for p in parts if p) + "]"
        return "[" + ",".join(dumps(v, depth - 1) for v in obj) + "]"
    return json.dumps(obj, separators=(",", ":"))
