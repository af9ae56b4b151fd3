"""Storage of the per-pixel multibounce tensors (polynomial-gi §6.2: "we simply drop zero
values"): per bounce, a pixel-major sparse list of (slot uint16, tail uint32, RGB float16)
entries with a float32 scale per pixel, in one binary blob.

Blob layout: b"GIT1", uint32 header length, a JSON header {"meta": {...}, "arrays": [{name,
dtype, shape, offset}]}, then the raw arrays, each 64-byte aligned; ``unpack`` returns
zero-copy views of the bytes.
"""
from __future__ import annotations

import json
import struct
from dataclasses import dataclass

import numpy as np

from ...errors import GlintError

MAGIC = b"GIT1"


def pack(meta: dict, arrays: dict[str, np.ndarray]) -> bytes:
    specs, blobs, off = [], [], 0
    for name, a in arrays.items():
        a = np.ascontiguousarray(a)
        pad = (-off) % 64
        off += pad
        blobs.append(b"\0" * pad)
        specs.append({"name": name, "dtype": a.dtype.str, "shape": list(a.shape), "offset": off})
        blobs.append(a.tobytes())
        off += a.nbytes
    head = json.dumps({"meta": meta, "arrays": specs}).encode()
    pre = MAGIC + struct.pack("<I", len(head)) + head
    pre += b"\0" * ((-len(pre)) % 64)
    return pre + b"".join(blobs)


def unpack(blob: bytes) -> tuple[dict, dict[str, np.ndarray]]:
    if blob[:4] != MAGIC:
        raise GlintError("not a GI tensor blob (bad magic)")
    (n,) = struct.unpack("<I", blob[4:8])
    head = json.loads(blob[8:8 + n])
    base = 8 + n + ((-(8 + n)) % 64)
    mv = memoryview(blob)
    arrays = {}
    for s in head["arrays"]:
        dt = np.dtype(s["dtype"])
        cnt = int(np.prod(s["shape"])) if s["shape"] else 1
        a = np.frombuffer(mv, dtype=dt, count=cnt, offset=base + s["offset"]).reshape(s["shape"])
        arrays[s["name"]] = a
    return head["meta"], arrays


@dataclass
class Bounce:
    """The k-bounce tensor of all hit pixels: offsets (P + 1,) int64 into the entries; slot
    (n,) uint16; tail (n,) uint32; val (n, 3) float16; scale (P,) float32 (value = val·scale)."""
    offsets: np.ndarray
    slot: np.ndarray
    tail: np.ndarray
    val: np.ndarray
    scale: np.ndarray

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.offsets, self.slot, self.tail, self.val, self.scale))

    @property
    def entries(self) -> int:
        return int(len(self.slot))


def join_tiles(tiles: list[list[tuple]], N: int) -> list[Bounce]:
    """Concatenate per-tile compact tensors (trace.trace_tile) into one Bounce per bounce."""
    out = []
    for k in range(N):
        parts = [t[k] for t in tiles]
        counts = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, np.int32)
        offsets = np.concatenate([[0], np.cumsum(counts, dtype=np.int64)])
        out.append(Bounce(offsets, np.concatenate([p[1] for p in parts]) if parts else np.zeros(0, np.uint16),
                          np.concatenate([p[2] for p in parts]) if parts else np.zeros(0, np.uint32),
                          np.concatenate([p[3] for p in parts]) if parts else np.zeros((0, 3), np.float16),
                          np.concatenate([p[4] for p in parts]) if parts else np.zeros(0, np.float32)))
    return out


def bounce_arrays(bounces: list[Bounce]) -> dict[str, np.ndarray]:
    d = {}
    for k, b in enumerate(bounces, start=1):
        d[f"b{k}.offsets"] = b.offsets
        d[f"b{k}.slot"] = b.slot
        d[f"b{k}.tail"] = b.tail
        d[f"b{k}.val"] = b.val
        d[f"b{k}.scale"] = b.scale
    return d


def bounces_from(arrays: dict[str, np.ndarray], N: int) -> list[Bounce]:
    return [Bounce(arrays[f"b{k}.offsets"], arrays[f"b{k}.slot"], arrays[f"b{k}.tail"], arrays[f"b{k}.val"],
                   arrays[f"b{k}.scale"]) for k in range(1, N + 1)]
