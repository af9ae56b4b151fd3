"""Materials with painted regions in the renderers that shade points (the cut renderer's vertices
and pixels, with or without movable objects; the paint renderer's pixels): each shading point of
such an object is shaded once per layer that has weight there, and the layers' radiance is
blended by the effective weights (models/regions.py: L(v) = Σ_l a_l(v) L_l(v)).

A frame's material table holds the objects' own materials first (a regions material's base in
its object's slot, so per-object lookups such as the refine radius keep working), then the
regions' materials. Points of objects without regions shade as before (one entry, weight 1);
a vertex inside a region at weight 1 shades only the region's material, so the extra cost is
the vertices of the soft edges (0 < w < 1), where two materials are shaded.

The blend is a scatter-add (``np.bincount``) over the expanded points: the shading itself stays
in the C kernel (glk_shade_points), which takes one material per point already.
"""
from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

from ..models.regions import has_regions, layer_weights


class Layers:
    """The layers of one frame's materials (one per object, scene order).

    flat : the material table's entries (the objects' materials with a regions material's base
        in its object's slot, then every region's material).
    objects : object index -> (slots (L,) int32 into ``flat``, a (L, n_o) float32 effective
        weights over the object's vertices, first global vertex id of the object).
    """

    def __init__(self, materials, object_of_vertex: np.ndarray, sources=None):
        self._memo = None           # (vids, expansion, blend matrix) of the last frame's points
        self.gathered = None        # the renderer's gathered inputs of those points (renderer.py)
        self.flat = []
        self.objects: dict[int, tuple[np.ndarray, np.ndarray, int]] = {}
        offsets = None
        for o, m in enumerate(materials):
            if not has_regions(m):
                self.flat.append(m)
                continue
            if offsets is None:
                offsets = np.searchsorted(object_of_vertex, np.arange(len(materials) + 1))
            n_o = int(offsets[o + 1] - offsets[o])
            # RegionsError: painted on another mesh (sources: scene.LoadedScene.vertex_source)
            mats, a = layer_weights(m, n_o, None if sources is None else sources(o))
            self.flat.append(mats[0])
            self.objects[o] = (np.zeros(len(mats), np.int32), a, int(offsets[o]))
        for o, (slots, a, off) in self.objects.items():
            slots[0] = o
            for k, m in enumerate(materials[o].layers()[0][1:], 1):
                slots[k] = len(self.flat)
                self.flat.append(m)

    @property
    def any(self) -> bool:
        return bool(self.objects)

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays it holds: the weights, and the last frame's expansion, blend
        matrix and gathered inputs (those grow with the points a view sees)."""
        arrays = [a for _, a, _ in self.objects.values()]
        if self._memo is not None:
            _, exp, B = self._memo
            arrays += [*exp, B.data, B.indices, B.indptr]
        if self.gathered is not None:
            arrays += [x for x in self.gathered[2:] if isinstance(x, np.ndarray)]
        return sum(int(x.nbytes) for x in arrays)

    def needed(self, objects) -> list[int]:
        """The table slots the points of these objects are shaded with."""
        out = set(int(o) for o in objects)
        for o in list(out):
            if o in self.objects:
                out.update(int(s) for s in self.objects[o][0])
        return sorted(out)

    def expand_cached(self, vids: np.ndarray, obj_of: np.ndarray, slot_of: np.ndarray):
        """``expand`` and the blend as a matrix (n, M), kept for the same ``vids`` array (a
        view's visible vertices, the same object from frame to frame): a frame of the same view
        then costs the layers' shading alone."""
        m = self._memo
        if m is not None and m[0] is vids:
            return m[1], m[2]
        import scipy.sparse as sp

        src, slot, wt = self.expand(vids, obj_of, slot_of)
        B = sp.csr_matrix((wt.astype(np.float32), (src, np.arange(len(src)))), shape=(len(vids), len(src)))
        self._memo = (vids, (src, slot, wt), B)
        return self._memo[1], B

    def expand(self, vids: np.ndarray, obj_of: np.ndarray, slot_of: np.ndarray):
        """Points (P,) with vertex ids ``vids`` (global), objects ``obj_of`` and their plain
        material slots ``slot_of``, as the layer points to shade: (src (M,) int64 the point
        each comes from, slot (M,) int32, weight (M,) float32). Points of objects without
        regions are one entry each; a region object's point one entry per layer of weight > 0."""
        return self._expand(obj_of, slot_of, lambda sel, a, off: a[:, vids[sel] - off])

    def expand_faces(self, obj_of: np.ndarray, corners: np.ndarray, bary: np.ndarray):
        """``expand`` for points inside faces (the paint renderer's pixels, the GI renderer's
        camera hits): obj_of (P,) their objects, corners (P, 3) global vertex ids of their faces,
        bary (P, 3) their barycentric weights. A point of an object with regions takes each layer
        whose weight, interpolated from the corners, is > 0; the others are one entry of weight 1
        with their object's slot. Returns (src (M,) int64, slot (M,) int32, weight (M,) float32)."""
        return self._expand(obj_of, obj_of,
                            lambda sel, a, off: np.einsum("kc,lkc->lk", bary[sel], a[:, corners[sel] - off]))

    def _expand(self, obj_of: np.ndarray, slot_of: np.ndarray, layer_weights):
        """The expansion of ``expand``: layer_weights(sel, a, off) gives the (L, n_sel) layer
        weights of the points ``sel`` of an object with effective weights a (L, n_o) from its
        first global vertex id off."""
        plain = np.ones(len(obj_of), bool)
        src, slot, wt = [], [], []
        for o, (slots, a, off) in self.objects.items():
            sel = np.nonzero(obj_of == o)[0]
            if not len(sel):
                continue
            plain[sel] = False
            w = layer_weights(sel, a, off)                  # (L, n_sel)
            lay, col = np.nonzero(w > 0)
            src.append(sel[col]); slot.append(slots[lay]); wt.append(w[lay, col])
        rest = np.nonzero(plain)[0]
        src.insert(0, rest); slot.insert(0, np.asarray(slot_of)[rest].astype(np.int32))
        wt.insert(0, np.ones(len(rest), np.float32))
        return (np.concatenate(src).astype(np.int64), np.concatenate(slot).astype(np.int32),
                np.concatenate(wt).astype(np.float32))

    @staticmethod
    def blend(rad: np.ndarray, src: np.ndarray, wt: np.ndarray, n: int) -> np.ndarray:
        """Σ over each point's layers of weight × radiance: (n, 3) float32 from the layer
        points' radiance rad (M, 3)."""
        out = np.empty((n, 3), np.float32)
        for c in range(3):
            out[:, c] = np.bincount(src, weights=rad[:, c] * wt, minlength=n)
        return out


def frame_layers(materials, object_of_vertex, sources=None) -> Layers | None:
    """Layers of a frame's materials, or None when no object has regions (the common case costs
    one type check per object). sources : object index -> its vertex_source or None."""
    if not any(has_regions(m) for m in materials):
        return None
    return Layers(materials, object_of_vertex, sources)


# material lists whose layers a renderer keeps: sessions sharing a renderer (the load target's 8)
# and a benchmark's interleaved rounds alternate their lists frame by frame, and rebuilding a
# list's layers (weights, expansion, blend matrix) cost a region frame 1.2-1.4 ms of a 3 ms one
LAYERS_KEPT = 8
# ... while they weigh at most this much (a view of a million vertices gathers ~30 MB of inputs
# per list); the newest list's stay whatever their size
LAYERS_BYTES = 64 << 20


class LayersCache:
    """A renderer's layers of the last LAYERS_KEPT frames' material lists with painted regions
    over a scene (scene.LoadedScene; lists without regions have none and take no place), kept
    while the same material objects come back (keyed by their identities; each list is kept so
    that the ids stay unique), the least recently used going first, also while all weigh more
    than LAYERS_BYTES. Thread-safe: sessions on different threads share a renderer."""

    def __init__(self, scene, kept: int = LAYERS_KEPT, max_bytes: int | None = None):
        self.scene = scene
        self.kept = kept
        self.max_bytes = max_bytes
        self._entries: OrderedDict = OrderedDict()     # ids -> (Layers, the list)
        self._lock = threading.Lock()

    def get(self, materials) -> Layers | None:
        key = tuple(id(m) for m in materials)
        with self._lock:
            hit = self._entries.get(key)
            if hit is not None:
                self._entries.move_to_end(key)
                return hit[0]
        layers = frame_layers(materials, self.scene.object_of_vertex, self.scene.vertex_source)
        if layers is None:
            return None                  # no regions: one type check per object, nothing kept
        with self._lock:
            self._entries[key] = (layers, list(materials))
            self._entries.move_to_end(key)
            cap = LAYERS_BYTES if self.max_bytes is None else self.max_bytes
            while len(self._entries) > self.kept or (
                    len(self._entries) > 1 and sum(e[0].nbytes for e in self._entries.values()) > cap):
                self._entries.popitem(last=False)
        return layers

    def __len__(self) -> int:
        return len(self._entries)
