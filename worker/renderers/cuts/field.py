"""A visibility cut field (VCF) of one rigid object: binary occlusion cuts at sample points around
it, in its local frame (cyber-worlds §V, Fig. 4; §V.A.1 "Next, VCF for each object is calculated").

At every sample point x_s of a ``FieldGrid`` the occlusion V_i(x_s, ω_j) by the object alone is
traced towards the 2^15 tree directions ω_j (0 = blocked, 1 = free). The leaves are clustered
only where the two children are equal, so the cut is lossless ("To render sharp shadows, our
method clusters the two child nodes only if the values of two child nodes are the same"): this is
``cuts.build_cuts`` with τ = 0. A node then needs its height (4 bits) and one bit.

Only rays that can hit are traced: from a point outside the bounding sphere (ρ > r), the
directions within the cone of half-angle asin(r/ρ) around the centre; from inside, all of them.
The rest are free.

The field depends on the mesh alone (local frame: the mesh file's coordinates; a non-uniform
scale is part of the shape), so its content key never changes when the object moves.
"""
from __future__ import annotations

import io
import json
import threading
import time
import zlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ...core.cuts import CutSet, build_cuts
from ...core.directions import DirectionTree, get_tree
from ...errors import GlintError
from ...keys import content_key
from ...trace.embree import Tracer
from .grid import FieldGrid, GridSpec

FORMAT_VERSION = 2
MAGIC = b"GLINTVCF2\n"


class FieldError(GlintError):
    """A field blob or mesh that cannot be used; the message says which."""


# The field's centre is nudged off the bounding box's centre by this fraction of r, in a fixed
# direction: a floor or wall passes through its own box centre, and the grid's equator would
# otherwise lie exactly in its plane, where occlusion is undefined (grazing rays at t = 0).
CENTRE_NUDGE = 1e-3 * np.array([0.48, 0.77, 0.42]) / np.linalg.norm([0.48, 0.77, 0.42])


def bounding_sphere(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre (3,) float64, radius) of a sphere holding every vertex: the bounding box's centre
    (nudged by CENTRE_NUDGE · r) and the largest distance to it."""
    v = np.asarray(vertices, np.float64)
    if len(v) == 0 or not np.isfinite(v).all():
        raise FieldError("mesh has no finite vertices")
    c = 0.5 * (v.min(axis=0) + v.max(axis=0))
    r = float(np.sqrt(((v - c) ** 2).sum(axis=1).max()))
    if r <= 0:
        raise FieldError("mesh is a single point")
    c = c + CENTRE_NUDGE * r
    return c, float(np.sqrt(((v - c) ** 2).sum(axis=1).max()))


def field_key(vertices: np.ndarray, faces: np.ndarray, spec: GridSpec, height: int) -> str:
    """Content key (worker/keys.py) of a mesh's cut field: its local geometry (as float32 and
    int32, the field's own precision), the grid and the direction tree's height."""
    return content_key("cut-field", FORMAT_VERSION, vertices=np.asarray(vertices, np.float32),
                       faces=np.asarray(faces, np.int32), grid=spec.tag(), height=int(height))


def pack_cuts(cs: CutSet) -> tuple[np.ndarray, np.ndarray]:
    """(heights packed two per byte, low nibble first; values as np.packbits of quant > 127)."""
    h = cs.heights.astype(np.uint8)
    if len(h) % 2:
        h = np.concatenate([h, [0]]).astype(np.uint8)
    return (h[0::2] | (h[1::2] << 4)).astype(np.uint8), np.packbits(cs.quant > 127)


@dataclass
class Field:
    """One object's visibility cut field, kept packed as stored (0.625 bytes per node).

    grid : FieldGrid (local frame).
    offsets : (S+1,) int64 node range of each sample (grid order).
    hpacked : (⌈M/2⌉,) uint8 node heights, 4 bits each (low nibble first).
    bits : (⌈M/8⌉,) uint8 node values, 1 = free, 0 = blocked (np.packbits order).
    height : tree height H. key : content key. stats : how it was made (seconds, rays, …).
    clearance : (S,) float32 distance from each sample to the nearest surface its rays met
        (local units; ∞ when none), or None.
    tracer : the object's mesh in the local frame (``attach``), for the renderer's segment tests.
    """
    grid: FieldGrid
    offsets: np.ndarray
    hpacked: np.ndarray
    bits: np.ndarray
    height: int = 15
    key: str = ""
    stats: dict = field(default_factory=dict)
    clearance: np.ndarray | None = None
    tracer: Tracer | None = field(default=None, repr=False)

    def attach(self, vertices: np.ndarray, faces: np.ndarray) -> Field:
        """Give the field its mesh (local frame), so receivers can test which samples they see."""
        self.tracer = Tracer(vertices, faces)
        return self

    @staticmethod
    def from_cuts(grid: FieldGrid, cs: CutSet, key: str = "", stats: dict | None = None) -> Field:
        hp, bits = pack_cuts(cs)
        return Field(grid, np.asarray(cs.offsets, np.int64), hp, bits, cs.height, key, dict(stats or {}))

    @property
    def n_samples(self) -> int:
        return len(self.offsets) - 1

    @property
    def n_nodes(self) -> int:
        return int(self.offsets[-1])

    def sizes(self) -> np.ndarray:
        return np.diff(self.offsets)

    def sample_cut(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(heights (K,) uint8, quant (K,) uint8 ∈ {0, 255}) of sample i."""
        a, b = int(self.offsets[i]), int(self.offsets[i + 1])
        k = np.arange(a, b)
        h = (self.hpacked[k >> 1] >> ((k & 1) * 4).astype(np.uint8)) & 15
        q = ((self.bits[k >> 3] >> (7 - (k & 7)).astype(np.uint8)) & 1) * 255
        return h.astype(np.uint8), q.astype(np.uint8)

    def cuts(self) -> CutSet:
        """All samples as a CutSet (unpacked: 2 bytes per node)."""
        k = np.arange(self.n_nodes)
        h = ((self.hpacked[k >> 1] >> ((k & 1) * 4).astype(np.uint8)) & 15).astype(np.uint8)
        q = np.unpackbits(self.bits)[: self.n_nodes] * np.uint8(255)
        return CutSet(self.offsets.copy(), h, q.astype(np.uint8), self.height)

    # -- storage ---------------------------------------------------------------------------
    def encode(self) -> bytes:
        """Height-based encoding (cyber-worlds §V.A.2) of binary cuts: per sample a uint16 node
        count; per node a 4-bit height and a 1-bit value, packed; then deflated (zlib). The
        header is JSON (grid, tree height, key, stats)."""
        return MAGIC + zlib.compress(self.raw_bytes(), 6)

    def raw_bytes(self) -> bytes:
        head = json.dumps({
            "version": FORMAT_VERSION, "key": self.key, "height": self.height,
            "samples": self.n_samples, "nodes": self.n_nodes,
            "center": [float(x) for x in self.grid.center], "radius": float(self.grid.radius),
            "grid": {"shells": self.grid.spec.shells, "face": self.grid.spec.face,
                     "rho_min": self.grid.spec.rho_min, "rho_max": self.grid.spec.rho_max},
            "stats": self.stats,
        }).encode()
        raw = io.BytesIO()
        raw.write(len(head).to_bytes(4, "little")); raw.write(head)
        raw.write(self.sizes().astype(np.uint16).tobytes()); raw.write(self.hpacked.tobytes()); raw.write(self.bits.tobytes())
        clr = self.clearance if self.clearance is not None else np.full(self.n_samples, np.inf, np.float32)
        raw.write(clr.astype(np.float16).tobytes())     # float16: 3 significant digits are plenty
        return raw.getvalue()

    @staticmethod
    def decode(blob: bytes) -> Field:
        if not blob.startswith(MAGIC):
            raise FieldError("not a Glint cut-field blob")
        try:
            raw = zlib.decompress(blob[len(MAGIC):])
            n = int.from_bytes(raw[:4], "little")
            head = json.loads(raw[4:4 + n])
        except (zlib.error, ValueError) as e:
            raise FieldError(f"damaged cut-field blob ({e})") from None
        if head.get("version") != FORMAT_VERSION:
            raise FieldError(f"cut-field format {head.get('version')} (this build reads {FORMAT_VERSION})")
        pos = 4 + n
        ns, nn = head["samples"], head["nodes"]
        if len(raw) != pos + 2 * ns + (nn + 1) // 2 + (nn + 7) // 8 + 2 * ns:
            raise FieldError("damaged cut-field blob (wrong length)")
        counts = np.frombuffer(raw, np.uint16, ns, pos); pos += 2 * ns
        hp = np.frombuffer(raw, np.uint8, (nn + 1) // 2, pos).copy(); pos += (nn + 1) // 2
        bits = np.frombuffer(raw, np.uint8, (nn + 7) // 8, pos).copy(); pos += (nn + 7) // 8
        clearance = np.frombuffer(raw, np.float16, ns, pos).astype(np.float32)
        offsets = np.zeros(ns + 1, np.int64)
        np.cumsum(counts, out=offsets[1:])
        g = head["grid"]
        grid = FieldGrid(np.array(head["center"], np.float64), float(head["radius"]),
                         GridSpec(g["shells"], g["face"], g["rho_min"], g["rho_max"]))
        if grid.n_samples != ns or offsets[-1] != nn:
            raise FieldError(f"cut-field blob holds {ns} samples, its grid {grid.n_samples}")
        return Field(grid, offsets, hp, bits, head["height"], head["key"], head.get("stats", {}), clearance)

    def storage(self, blob_bytes: int | None = None) -> dict:
        """Sizes in bytes: ``raw`` (4-bit heights + 1-bit values + 2-byte counts, the paper's
        representation; the 2-byte clearances are not counted), ``compressed`` (the stored blob),
        ``index_encoded`` (2-byte index + 1-bit value per node, the previous method [5, 6] in
        §V.A.2)."""
        nn, ns = self.n_nodes, self.n_samples
        raw = 2 * ns + (nn + 1) // 2 + (nn + 7) // 8
        idx = 2 * ns + 2 * nn + (nn + 7) // 8
        return {"samples": ns, "nodes": nn, "mean_cut_size": nn / max(ns, 1),
                "bytes_raw": int(raw), "bytes_index_encoded": int(idx),
                "bytes_compressed": int(blob_bytes if blob_bytes is not None else len(self.encode()))}


def cone_directions(tree: DirectionTree, origin: np.ndarray, center: np.ndarray, radius: float) -> np.ndarray:
    """Indices of the leaf directions from ``origin`` that can meet the sphere (center, radius):
    all of them from inside, else those within asin(radius / distance) of the centre."""
    d = center - origin
    dist = float(np.linalg.norm(d))
    if dist <= radius * (1 + 1e-9):
        return np.arange(tree.n_leaves)
    cos_half = np.sqrt(max(0.0, 1.0 - (radius / dist) ** 2))
    return np.nonzero(tree.leaves @ (d / dist).astype(np.float32) >= cos_half - 1e-6)[0]


def trace_field(vertices: np.ndarray, faces: np.ndarray, spec: GridSpec | None = None, tree: DirectionTree | None = None,
                threads: int = 2, batch: int = 32, progress=None, key: str = "") -> Field:
    """Trace the field of a mesh in its own frame.

    vertices (V, 3) float32, faces (F, 3) int32 (local frame). progress: callable(n samples done).
    Rays start exactly at the sample points. Each sample also records its clearance: the
    distance of the nearest hit over its rays (∞ if none), which tells the renderer when a
    receiver may see the sample's side of the surface (combine.validate).
    Returns a Field whose ``stats`` hold seconds, rays traced and rays per second.
    """
    tree = tree or get_tree()
    spec = spec or GridSpec()
    c, r = bounding_sphere(vertices)
    grid = FieldGrid(c, r, spec)
    pos = grid.positions()
    pos32 = pos.astype(np.float32)
    dist = np.linalg.norm(pos - c, axis=1)
    tracer = Tracer(vertices, faces)
    n = grid.n_samples
    starts = list(range(0, n, batch))
    parts: list[CutSet | None] = [None] * len(starts)
    rays = [0]
    lock = threading.Lock()
    t0 = time.perf_counter()

    N = tree.n_leaves
    all_leaves = np.arange(N)
    clearance = np.full(n, np.inf, np.float32)

    def work(k: int):
        s, e = starts[k], min(starts[k] + batch, n)
        vals = np.ones((e - s) * N, np.float32)
        cols = [all_leaves if dist[i] <= r else cone_directions(tree, pos[i], c, r) for i in range(s, e)]
        counts = np.array([len(x) for x in cols])
        cols = np.concatenate(cols)
        if len(cols):
            o = np.repeat(pos32[s:e], counts, axis=0)
            prim, _, t = tracer.first_hit(o, tree.leaves[cols])
            hit = prim >= 0
            flat = np.repeat(np.arange(e - s) * N, counts) + cols
            vals[flat[hit]] = 0.0
            row = np.repeat(np.arange(e - s), counts)
            tt = np.where(hit, t, np.inf).astype(np.float32)
            np.minimum.at(clearance[s:e], row, tt)
        parts[k] = build_cuts(vals.reshape(e - s, N), 0.0)     # τ = 0: merge only equal children (lossless)
        with lock:
            rays[0] += len(cols)
            if progress:
                progress(e - s)

    with ThreadPoolExecutor(max_workers=max(1, threads)) as ex:
        list(ex.map(work, range(len(starts))))
    secs = time.perf_counter() - t0
    cs = CutSet.concat(parts)
    stats = {"seconds": secs, "samples": n, "rays_traced": rays[0], "rays_per_second": rays[0] / max(secs, 1e-9),
             "samples_per_second": n / max(secs, 1e-9), "mean_cut_size": float(cs.sizes().mean()),
             "threads": threads, "triangles": len(faces)}
    f = Field.from_cuts(grid, cs, key, stats)
    f.clearance = clearance
    return f

