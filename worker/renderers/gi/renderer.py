"""The GI renderer: interreflections with a fixed view and lighting, BRDFs edited live
(polynomial-gi). ``GIPrecomputation`` path-traces the per-pixel multibounce tensors (trace.py);
``GIRenderer`` projects the materials onto the basis (basis.py), freezes every unit but the one
being edited and draws each frame with one dot product per pixel (freeze.py).
"""
from __future__ import annotations

import contextlib
import hashlib
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any, Mapping

import numpy as np

from ...errors import GlintError
from ...models.regions import has_regions
from ..base import FrameRequest, Part, Precomputation, Progress, Rendered, Renderer, Unsupported
from ..layers import LayersCache
from . import denoise as dn
from . import DECLARATION
from . import freeze as fzm
from . import strokes as stm
from . import tensors
from .basis import QUOTIENTS, THETA_NODES, Projection, fixed_projection, project, theta_interp
from .options import GIOptions, UnitLayout, parse_options, tensor_key, unit_layout
from .trace import Geometry, Primary, make_setup, primary_hits, second_codes, trace_tile

KIND = DECLARATION.kind


def region_images(scene, opts: GIOptions) -> list[np.ndarray]:
    from .trace import load_weight_image
    return [load_weight_image(scene.resolve(r.weights)) for r in opts.regions]


def _label(opts: GIOptions) -> str:
    return f"GI tensors {','.join(map(str, opts.series))} ({opts.bounces} bounces, {opts.spp} spp)"


class GIPrecomputation(Precomputation):
    """One part: the tensors of all bounces, keyed by tensor_key (options.py). Chunks are
    ranges of tiles (trace.tile_pixels) with their own random streams, so any split assembles
    into the same bytes. ``work`` counts pixels.

    kernels : the backend that traces (worker/native/kernels.py; default: the process's, chosen
        when first needed). With kernels("numpy") the whole precomputation runs the NumPy
        references (exact, but far slower: for tiny scenes and tests).
    """

    kind = KIND

    def __init__(self, kernels=None):
        super().__init__(kernels)
        self._setups: dict[int, tuple[str, Any]] = {}

    def _setup(self, scene, opts: GIOptions, key: str):
        cached = self._setups.get(id(scene))
        if cached is not None and cached[0] == key:
            return cached[1]
        layout = unit_layout(scene, opts)
        S = make_setup(scene, opts, layout, region_images(scene, opts), kernels=self.kernels)
        self._setups = {id(scene): (key, S)}
        return S

    def parts(self, scene, options: Mapping[str, Any]) -> list[Part]:
        opts = parse_options(scene, options)
        unit_layout(scene, opts)                         # validates regions / anisotropy names
        key = tensor_key(scene, opts, region_images(scene, opts))
        cam = scene.spec.camera
        return [Part(key, _label(opts), work=cam.width * cam.height, meta={})]

    def chunks(self, scene, part: Part, options: Mapping[str, Any], n: int) -> list[Any]:
        opts = parse_options(scene, options)
        S = self._setup(scene, opts, part.key)
        edges = np.linspace(0, S.n_tiles, max(1, min(n, S.n_tiles)) + 1).astype(int)
        return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]

    def compute(self, scene, part: Part, options: Mapping[str, Any], chunk: Any = None,
                progress: Progress | None = None, threads: int = 2) -> Any:
        opts = parse_options(scene, options)
        S = self._setup(scene, opts, part.key)
        a, b = chunk if chunk is not None else (0, S.n_tiles)
        if progress and a == 0:
            cam = scene.spec.camera
            progress(cam.width * cam.height - len(S.prim.pixel))    # background pixels
        out = []
        for t in range(a, b):
            out.append(trace_tile(S, t, self.kernels, threads=threads))
            if progress:
                progress(min(S.tile, len(S.prim.pixel) - t * S.tile))
        return {"range": (a, b), "tiles": out}

    def assemble(self, scene, part: Part, options: Mapping[str, Any], results: list[Any]) -> tuple[bytes, dict]:
        opts = parse_options(scene, options)
        S = self._setup(scene, opts, part.key)
        results = sorted(results, key=lambda r: r["range"][0])
        tiles = [t for r in results for t in r["tiles"]]
        if len(tiles) != S.n_tiles:
            raise GlintError(f"GI precomputation: {len(tiles)} tiles assembled, {S.n_tiles} expected")
        bounces = tensors.join_tiles([t[0] for t in tiles], S.N)
        rays = int(sum(t[1] for t in tiles))
        layout = S.layout
        den = {}
        if opts.denoise:
            t0 = time.perf_counter()
            bounces, den = denoise_tensors(scene, S, bounces)
            den["seconds"] = time.perf_counter() - t0
        meta = {"denoise": den or None, "series": list(opts.series), "bounces": S.N, "spp": opts.spp, "fresnel": opts.fresnel,
                "J": S.J, "J2": S.J2, "U": S.U, "layers": S.layers, "K1": S.K1, "tails": S.tails,
                "units": layout.names, "width": scene.spec.camera.width, "height": scene.spec.camera.height,
                "pixels": int(len(S.prim.pixel)), "rays": rays + int(scene.spec.camera.width * scene.spec.camera.height)}
        arrays = {"pixel": S.prim.pixel, "obj": S.prim.obj.astype(np.int32), **tensors.bounce_arrays(bounces)}
        blob = tensors.pack(meta, arrays)
        stats = {"denoise": den or None, "pixels": meta["pixels"], "bounces": S.N, "series": list(opts.series), "spp": opts.spp,
                 "rays": meta["rays"], "entries_per_bounce": [b.entries for b in bounces],
                 "bytes_per_bounce": [b.nbytes for b in bounces]}
        return blob, stats

    def load(self, scene, blobs: Mapping[str, bytes], options: Mapping[str, Any]) -> "GIData":
        opts = parse_options(scene, options)
        (key,) = [p.key for p in self.parts(scene, options)]
        meta, arrays = tensors.unpack(blobs[key])
        return GIData(meta, arrays["pixel"], arrays["obj"], tensors.bounces_from(arrays, meta["bounces"]), opts)


def denoise_tensors(scene, S, bounces, denoiser=None, quality: str | None = None, together: bool = True):
    """Every basis image of the tensors denoised (denoise.py): direct light per slot, further
    bounces per hat component, their tails together (``together``, else one image per tail);
    returns (bounces, meta["denoise"]). ``denoiser(img, albedo, normal)`` replaces OIDN
    (tests); ``quality`` OIDN's (default denoise.QUALITY)."""
    cam = scene.spec.camera
    shape = (cam.height, cam.width)
    alb, nrm = dn.guides(S.prim, S.fixed, [getattr(m, "albedo", (1.0, 1.0, 1.0)) for m in S.fixed_materials], shape)
    out, images = [], 0
    phis = dn.component_sets(S.J, S.layers, S.N)
    offs = dn.component_offsets(S.K1, phis)
    quality = quality or dn.QUALITY
    c0 = time.process_time()
    editable = ~np.asarray(S.fixed, bool)
    qk = np.asarray(S.qkind)[editable] if editable.any() else [0]
    w = dn.slot_weights(S.J, S.layers, qk, phis)
    for k, b in enumerate(bounces, start=1):
        c = min(k - 2, len(phis) - 1)
        nb, n = dn.denoise_bounce(b, S.prim.pixel, shape, alb, nrm, None if k == 1 else phis[c], 0 if k == 1 else offs[c],
                                    quality=quality, denoiser=denoiser, obj=S.prim.obj if together else None,
                                    weights=w[0] if k == 1 else w[1 + c])
        out.append(nb)
        images += n
    return out, {"hats": list(dn.HATS[:len(phis)]), "components": [int(p.shape[1]) for p in phis], "images": images,
                 "quality": quality, "tails_together": bool(together), "cpu_seconds": time.process_time() - c0}


@dataclass
class GISamples:
    """Fit rows of the GI renderer: pix (N,) int64 (indices into the asked pixels, or image
    pixels), hit (N,) int64 indices into the precomputed hit pixels."""
    pix: np.ndarray
    hit: np.ndarray

    def __len__(self) -> int:
        return len(self.pix)


@dataclass
class GIData:
    """Loaded tensors: meta (series, units, sizes…), pixel (P,) int64 flat hit-pixel indices,
    obj (P,) int32, bounces (list of tensors.Bounce), opts (GIOptions)."""
    meta: dict
    pixel: np.ndarray
    obj: np.ndarray
    bounces: list
    opts: GIOptions

    @property
    def nbytes(self) -> int:
        return int(sum(b.nbytes for b in self.bounces))


# painted-region layouts whose freezes are kept (GIRenderer._stash): a region fit's two (below the
# region, with it) and the previous stroke's; and at most this many bytes of them, the newest kept
# whatever its size (a renderer is a session's: a freeze of the test sofa at 320×240 with the
# whole sofa live is 17 MB, most of it the live rows; with a region live, a few MB)
STASHED_FREEZES = 3
STASHED_BYTES = 64 << 20


def _same(a, b) -> bool:
    return a.model_dump(mode="json") == b.model_dump(mode="json")


class GIRenderer(Renderer):
    """Draws a GI scene with edited materials (fixed camera and lighting).

    ``render`` takes the materials of the scene's objects in order, optionally followed by the
    materials of the GI regions (options.regions order). The unit whose material changed is
    made live (freezing the others, eq. 27) when it is not already; every frame projects the
    live unit's material and evaluates eq. 28. ``max_bounces`` (1..N) limits the bounces drawn
    (1 = direct light only). The environment's intensity may change (radiance is linear in
    it); its rotation and the camera may not (``Unsupported``).

    Strokes (``stroke_fit`` with ``polynomial_transfer``): the fitter's rows are the edited
    object's pixels of the precomputed view, whose radiance is polynomial in its srbf
    coefficients (strokes.py); ``linearise`` gives the fitter its expansion at a material and
    ``shade_samples`` the exact GI radiance. The renderer is shared by the session's frames and
    the fitter's background builds: freezing and drawing hold ``_lock``.
    """

    kind = KIND
    controls = DECLARATION.controls
    capabilities = frozenset({"stroke_fit", "polynomial_transfer", "live_object"})
    # fit rows: every precomputed pixel of the object up to a grid of FIT_PIXELS, then every
    # other (or third…) one: a row costs a lookup into the frozen tensors, not a transfer, but
    # the painted rows are not bounded by the fitter (its bound is on the unpainted ones), and a
    # stroke at 640×480 paints 4× the pixels of the same stroke at 320×240 for the same
    # information; the instance sets it from the view's size
    stroke_fit_scale = 1.0
    FIT_PIXELS = 320 * 240

    def __init__(self, scene, data: GIData, kernels=None, max_bounces: int | None = None):
        super().__init__(scene, data, kernels)
        from ...native.kernels import kernels as _kernels

        # the backend it was built with (default: the process's), used for every kernel below
        self.k = kernels or _kernels()
        # re-sparsification of the live rows at freezing (freeze.prune_sparse): 0 keeps every
        # entry; last_pruned is the fraction of the live rows' magnitude folded into V
        self.prune = 0.0
        self.last_pruned = 0.0
        self._slot_weights: dict[int, np.ndarray] = {}
        self.opts = data.opts
        self.layout: UnitLayout = unit_layout(scene, self.opts)
        m = data.meta
        self.J, self.J2, self.U, self.K1, self.layers = m["J"], m["J2"], m["U"], m["K1"], m["layers"]
        # denoised tensors carry the indirect light on hat components in slots K1… (denoise.py)
        den = m.get("denoise") or {}
        self.phis = [dn.hat_basis(self.J, self.layers, h) for h in den.get("hats", [])]
        self._maps: dict[int, list] = {}
        self.K1 = self.K1 + sum(p.shape[1] for p in self.phis)
        self.N = m["bounces"]
        self.K2 = 1 if self.J2 <= 1 else 1 + second_codes(self.J2)
        self.max_bounces = self.N if max_bounces is None else int(max_bounces)
        cam = scene.spec.camera
        self.stroke_fit_scale = min(1.0, float(np.sqrt(self.FIT_PIXELS / (cam.width * cam.height))))
        geo = self.geo = Geometry(scene)
        self.prim: Primary = primary_hits(geo, scene, self.k)
        if len(self.prim.pixel) != len(data.pixel) or not np.array_equal(self.prim.pixel, data.pixel):
            raise GlintError("GI tensors do not match the scene's camera hits (precompute again)", status=409)
        from .trace import Regions
        reg = Regions(self.layout, self.opts.regions, geo, region_images(scene, self.opts), scene, self.opts.painted)
        # the camera hits' painted regions are split per frame by the design drawn (_set_painted)
        units, weights = reg.weights(self.prim.obj, self.prim.pos)
        k0, t = theta_interp(self.prim.cos_o)
        # the precomputed units' weights (pu0) and with the painted regions' pseudo-units (pu)
        self.pu0 = self.pu = fzm.PixelUnits(units, weights, k0, t)
        self.materials = [u.material for u in self.layout.units]
        self.objects_materials: list | None = None      # the scene-order materials last applied
        self.pseudo: list[tuple[int, str, Any]] = []    # painted regions: (object, name, material)
        self._painted_key = None
        self._last_layers = self._lay_key = None
        self._layers = LayersCache(scene)
        self._painting: dict[int, str] = {}             # object -> the region strokes fit (painting)
        self._region_units: dict[tuple[int, str], int] = {}   # (object, region) -> its unit now
        # object -> (its traced painted material, the units of its regions in order)
        self._traced: dict[int, tuple[Any, list[int]]] = {}
        for k, p in enumerate(self.opts.painted):
            us = [u for u, unit in enumerate(self.layout.units) if unit.painted is not None and unit.painted[0] == k]
            self._traced[self.layout.units[us[0]].object] = (p.material, us)
        self.qkind = [QUOTIENTS.index(q) for q in self.layout.quotients(scene, self.opts)]
        self._proj_cache: dict[tuple[int, str], Projection] = {}
        self.frozen: fzm.Frozen | None = None
        self._frozen_mats: list | None = None
        self._frozen_bounces = None
        self._frozen_pu: fzm.PixelUnits | None = None
        # the freezes of the last few painted-region layouts, by layout: a region fit alternates
        # between the look below the region and the region with the stroke's new weights, and
        # each stroke extends the region; a layout seen again takes its freeze back (still
        # checked against the materials as any freeze is), and a new one recomputes only the
        # pixels whose units changed since a kept freeze of the same live unit (``_freeze``)
        self._stash: OrderedDict = OrderedDict()
        self.last_freeze_pixels = 0
        self.last_timings: dict[str, float] = {}
        self._image = np.ascontiguousarray(self.prim.background.reshape(-1, 3), np.float32).copy()
        self._lock = threading.RLock()
        self.last_freeze_seconds = 0.0
        self._hit_of_pixel = np.full(data.meta["width"] * data.meta["height"], -1, np.int64)
        self._hit_of_pixel[self.prim.pixel] = np.arange(len(self.prim.pixel))
        self._sampled: list = []          # [(Frozen, hit bytes, Sampled)], the latest few
        if self._traced:
            self._apply(list(scene.materials))      # the scene's design, until a frame gives one

    # --- projections ----------------------------------------------------------------------------

    # --- units: the precomputed ones (0 … U − 1), the fixed pseudo-unit U, painted regions' ---------
    #
    # A painted region (models/regions.py, per-vertex weights) is a pseudo-unit U + 1 + k at the
    # first vertex only: its weight at a camera hit is the layer weight interpolated from the hit
    # face's corners, taken from its object's own unit there (polynomial-gi eq. 5-6, H(x) applied
    # per pixel at run time as the precomputed regions' are). The first vertex's transport does
    # not depend on which unit is there, so the region's look is exact; light it reflects on to
    # other surfaces is its object's own material's (the tensors' tails know the units they were
    # traced with). A design whose regions were traced into the tensors (options ``painted``)
    # draws them as those units instead, tails included (``_matches_traced``).

    def _n_units(self) -> int:
        return self.U + 1 + len(self.pseudo)

    def _mat(self, u: int):
        return self.materials[u] if u < self.U else (None if u == self.U else self.pseudo[u - self.U - 1][2])

    def _all_mats(self) -> list:
        return [self._mat(u) for u in range(self._n_units())]

    def _unit_object(self, u: int) -> int:
        return self.layout.units[u].object if u < self.U else self.pseudo[u - self.U - 1][0]

    def _unit_name(self, u: int) -> str | None:
        if u < 0 or u == self.U:
            return None
        return self.layout.units[u].name if u < self.U else self.pseudo[u - self.U - 1][1]

    def _unit_aniso(self, u: int):
        return self.layout.units[u].anisotropic if u < self.U else None

    def projection(self, u: int, material) -> Projection:
        key = (u, material.model_dump_json())
        p = self._proj_cache.get(key)
        if p is None:
            aniso = self._unit_aniso(u)
            unit = self.layout.units[u] if u < self.U else None
            name = unit.name if unit is not None else self._unit_name(u)
            nu = aniso.exponent if aniso is not None else None
            if nu is not None and getattr(material, "model", None) != "ashikhmin-shirley":
                raise GlintError(f"{name!r} was precomputed for anisotropy editing: give it an "
                                 f"ashikhmin-shirley material with exponent_u = {nu:g}")
            if nu is not None and abs(material.exponent_u - nu) > 1e-9:
                raise GlintError(f"{name!r}: exponent_u is fixed at {nu:g} by the precomputation "
                                 f"(got {material.exponent_u:g}); edit exponent_v (the anisotropy ratio)")
            if nu is None and getattr(material, "model", None) == "ashikhmin-shirley":
                raise GlintError(f"{name!r}: ashikhmin-shirley needs the object in gi.anisotropic")
            p = project(material, self.J, self.layers, self.J2, nu, self.qkind[self._unit_object(u)])
            if len(self._proj_cache) > 256:
                self._proj_cache.clear()
            self._proj_cache[key] = p
        return p

    def _first(self, p: Projection, qkind: int = 0) -> np.ndarray:
        """(Kθ, K1, 3) float32 first-vertex table of a projection, extended with the hat
        coefficients when the tensors are denoised (qkind: the unit's quotient)."""
        if not self.phis:
            return p.first
        maps = self._maps.get(qkind)
        if maps is None:
            w = dn.basis_weights(self.J, self.layers, qkind)
            maps = self._maps[qkind] = [dn.projectors(phi, w) for phi in self.phis]
        return np.ascontiguousarray(dn.extend_coefficients(p.first, maps), np.float32)

    def _unit_q(self, u: int) -> int:
        return self.qkind[self._unit_object(u)]

    def _tables(self, mats):
        """First-vertex tables C1 of every unit (the precomputed ones, the fixed pseudo-unit,
        the painted regions'), and the precomputed units' d and second-vertex coefficients
        (the tails'). mats: the precomputed units' materials."""
        projs = [self.projection(u, m) for u, m in enumerate(mats)]
        extra = [self._first(self.projection(self.U + 1 + k, m), self._unit_q(self.U + 1 + k))
                 for k, (_, _, m) in enumerate(self.pseudo)]
        C1 = np.stack([self._first(p, self._unit_q(u)) for u, p in enumerate(projs)]
                      + [self._first(fixed_projection(self.J, self.layers))] + extra).astype(np.float32)
        d = np.stack([p.d for p in projs]) if projs else np.zeros((0, 3))
        second = np.stack([p.second for p in projs]) if (self.J2 > 1 and projs) else None
        return projs, C1, d, second

    # --- freezing and frames ----------------------------------------------------------------------

    def freeze(self, i: int) -> float:
        """Make unit i live with every other unit frozen at its current material; seconds."""
        with self._lock:
            return self._freeze(i)

    def _freeze(self, i: int) -> float:
        t0 = time.perf_counter()
        _, C1, d, second = self._tables(self.materials)
        nb = self.max_bounces
        tables = fzm.tail_tables(i, nb, self.U, self.J2, d, second)
        bounces = self.data.bounces[:nb]
        pixels, V0 = self._refreeze_pixels(i, nb)
        self.frozen = self.k.gi.freeze(bounces, tables, self.pu, C1, i, self.K1, self.K2, self.N, pixels, V0)
        self.last_freeze_pixels = len(self.pu.k0) if pixels is None else len(pixels)
        self._frozen_pu = self.pu
        if self.prune > 0 and i >= 0:
            self.frozen, self.last_pruned = fzm.prune_sparse(self.frozen, self.pu, C1[i], self.prune,
                                                             self._slot_weight(i))
        else:
            self.last_pruned = 0.0
        self._frozen_mats = self._all_mats()
        self._frozen_bounces = nb
        self.last_freeze_seconds = time.perf_counter() - t0
        return self.last_freeze_seconds

    def _refreeze_pixels(self, i: int, nb: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(pixels, V0) for a freeze of unit i: when a kept freeze of another layout (``_stash``)
        had unit i live, the same bounces and every other unit's material the same, the hit
        pixels whose units or weights differ from its layout's and those on unit i in either,
        with its V. Elsewhere V, the part of the other units' frozen coefficients (eq. 27), is
        what it was: it does not depend on unit i's material, and a painted region's weights
        reach only the first vertex of its own pixels. (None, None): every pixel (no such
        freeze, or half the image changed)."""
        if i < 0 or not self._stash:
            return None, None
        mats = self._all_mats()
        P = len(self.pu.k0)
        for fz0, mats0, pu0, nb0 in reversed(self._stash.values()):
            if (fz0.unit != i or nb0 != nb or mats0 is None or len(mats0) != len(mats) or fz0.V.shape[0] != P
                    or any(v != i and v != self.U and not _same(mats[v], mats0[v]) for v in range(len(mats)))):
                continue
            L = max(pu0.units.shape[1], self.pu.units.shape[1])

            def wide(pu):
                u = np.full((P, L), -1, np.int32)
                w = np.zeros((P, L), np.float32)
                u[:, :pu.units.shape[1]], w[:, :pu.units.shape[1]] = pu.units, pu.weights
                return u, w
            (ua, wa), (ub, wb) = wide(pu0), wide(self.pu)
            changed = (ua != ub).any(1) | (wa != wb).any(1) | (ub == i).any(1) | (ua == i).any(1)
            if changed.sum() * 2 > P:
                return None, None
            return np.nonzero(changed)[0].astype(np.int64), fz0.V
        return None, None

    def _slot_weight(self, i: int) -> np.ndarray:
        """(K1,) the largest |first-vertex coefficient| of each basis slot of unit i over probe
        materials from rough to near-mirror (white GGX α 0.02-1; Ashikhmin-Shirley units keep
        their exponent_u), all view angles and channels: how much an entry of that slot can
        weigh in a frame, for freeze.prune_sparse."""
        from ...scene import GGX
        w = self._slot_weights.get(i)
        if w is None:
            aniso = self._unit_aniso(i)
            ws = []
            for al in (0.02, 0.05, 0.1, 0.2, 0.4, 1.0):
                if aniso is not None:
                    nu = aniso.exponent
                    m = self.materials[i].model_copy(update={"exponent_v": nu * al * 10})
                else:
                    m = GGX(alpha=al, specular=(1.0, 1.0, 1.0), albedo=(1.0, 1.0, 1.0))
                ws.append(np.abs(self._first(self.projection(i, m), self._unit_q(i))).max(axis=(0, 2)))
            w = self._slot_weights[i] = np.max(ws, 0)
        return w

    def set_unit_material(self, name_or_index, material) -> None:
        i = name_or_index if isinstance(name_or_index, int) else self.layout.index(name_or_index)
        self.materials[i] = material

    def apply_materials(self, materials) -> None:
        """The objects' materials (scene order, optionally followed by the GI regions'), as a
        frame request gives them: a material with painted regions draws them."""
        with self._lock:
            self._apply(list(materials))

    def _apply(self, materials) -> None:
        objs = self.scene.spec.objects
        n = len(objs)
        if len(materials) not in (0, n, n + len(self.opts.regions)):
            raise GlintError(f"{len(materials)} materials for {n} objects and {len(self.opts.regions)} regions")
        for oi, m in enumerate(materials[:n]):
            if self.layout.fixed[oi]:
                if not _same(m, objs[oi].material):
                    raise Unsupported(f"object {objs[oi].name!r} is fixed (\"editable\": false) in this GI "
                                      f"precomputation: its material is baked in and cannot change")
                continue
            traced = self._traced.get(oi)
            if has_regions(m):
                if self.layout.aniso_of_object and self.layout.aniso_of_object[oi] is not None:
                    raise Unsupported(f"object {objs[oi].name!r} is precomputed for anisotropy editing: "
                                      "painted regions on it are not drawn under GI")
                if traced is not None and self._matches_traced(oi, m):
                    for u, r in zip(traced[1], m.regions):
                        self.materials[u] = r.material
                    traced = None
                m = m.base
            if traced is not None:
                # regions traced into the tensors that this design does not have: their light
                # on to other surfaces is the object's own material's
                for u in traced[1]:
                    self.materials[u] = m
            self.materials[self.layout.of_object[oi][0]] = m
        for r, m in enumerate(materials[n:]):
            self.materials[self.layout.index(self.opts.regions[r].name)] = m
        if len(materials) >= n:
            self.objects_materials = list(materials[:n])
            self._set_painted(self.objects_materials)

    def _matches_traced(self, o: int, material) -> bool:
        """Whether a regions material on object o has the regions traced into the tensors (the
        same names, vertices and weights, in order; their materials may differ)."""
        traced = self._traced[o][0]
        if len(material.regions) != len(traced.regions) or material.vertex_count != traced.vertex_count:
            return False
        return all(a.name == b.name and a.vertices == b.vertices and a.weights == b.weights
                   for a, b in zip(material.regions, traced.regions))

    def _set_painted(self, materials) -> None:
        """The painted regions of the objects' materials as units (pseudo-units, or the traced
        ones, see ``_n_units``): their materials, and the camera hits' unit weights when the
        regions' weights changed (the frozen tensors then freeze again)."""
        lay = self._layers.get(materials)
        pseudo = []
        self._region_units = {}
        if lay is not None:
            for o, (slots, a, off) in sorted(lay.objects.items()):
                names = [r.name for r in materials[o].regions]
                traced = self._traced.get(o)
                if traced is not None and self._matches_traced(o, materials[o]):
                    # the design traced into the tensors: its regions are the traced units
                    for u, name in zip(traced[1], names):
                        self._region_units[(o, name)] = u
                    continue
                for s, name in zip(slots[1:], names):
                    self._region_units[(o, name)] = self.U + 1 + len(pseudo)
                    pseudo.append((o, name, lay.flat[s]))
        if lay is not self._last_layers:
            # the same weights under new region materials keep the frozen tensors: keyed by
            # content (hashed once per new layers object, not per frame)
            self._last_layers = lay
            self._lay_key = None if lay is None else tuple(
                (o, len(slots), hashlib.blake2b(np.ascontiguousarray(a).tobytes(), digest_size=16).hexdigest(),
                 tuple(self._region_units.get((o, r.name), -1) for r in materials[o].regions))
                for o, (slots, a, off) in sorted(lay.objects.items()))
        key = (self._lay_key, tuple((o, nm) for o, nm, _ in pseudo))
        if key == self._painted_key:
            self.pseudo = pseudo
            return
        self.pseudo = pseudo
        if self.frozen is not None and self._frozen_pu is self.pu:
            self._stash[self._painted_key] = (self.frozen, self._frozen_mats, self._frozen_pu, self._frozen_bounces)
            self._stash.move_to_end(self._painted_key)
            while len(self._stash) > STASHED_FREEZES or (
                    len(self._stash) > 1 and sum(v[0].nbytes for v in self._stash.values()) > STASHED_BYTES):
                self._stash.popitem(last=False)
        self._painted_key = key
        kept = self._stash.pop(key, None)
        self._sampled = []
        if kept is not None:
            self.frozen, self._frozen_mats, self.pu, self._frozen_bounces = kept
            self._frozen_pu = self.pu
            return
        self.pu = self.pu0 if lay is None else self._painted_units(lay, len(materials))
        self.frozen, self._frozen_mats = None, None

    def _painted_units(self, lay, n_objects: int) -> fzm.PixelUnits:
        """PixelUnits with each region object's own-unit weight at a camera hit split among its
        layers (weights interpolated from the hit face's corners, Layers.expand_faces)."""
        pr, pu0 = self.prim, self.pu0
        corners = self.geo.F[pr.face]
        src, slot, wt = lay.expand_faces(pr.obj, corners, pr.bary)
        P, L0 = pu0.units.shape
        is_region = slot >= n_objects
        extra = int(np.bincount(src[is_region], minlength=P).max(initial=0))
        units = np.full((P, L0 + extra), -1, np.int32)
        weights = np.zeros(units.shape, np.float32)
        units[:, :L0], weights[:, :L0] = pu0.units, pu0.weights
        # slot k of the layers table: an object's own slot (its base) or a region (its traced unit,
        # or a pseudo-unit)
        unit_of_slot = {}
        mats = self.objects_materials
        for o, (slots, a, off) in sorted(lay.objects.items()):
            for s, r in zip(slots[1:], mats[o].regions):
                unit_of_slot[int(s)] = self._region_units[(o, r.name)]
        # every layer's weight is a share of the object's own unit's (1 − ΣH of the precomputed
        # regions there), not of those regions'
        w_own = pu0.weights[:, 0].astype(np.float64)
        base_w = np.bincount(src, weights=np.where(is_region, 0.0, wt), minlength=P)
        on = np.zeros(P, bool)
        on[src[is_region]] = True
        weights[on, 0] = (w_own[on] * base_w[on]).astype(np.float32)
        r = np.nonzero(is_region)[0]
        r = r[np.argsort(src[r], kind="stable")]
        p = src[r]
        first = np.searchsorted(p, p)                     # each entry's rank among its pixel's
        col = L0 + (np.arange(len(r)) - first)
        lut = np.zeros(max(unit_of_slot, default=0) + 1, np.int32)
        for s_, u in unit_of_slot.items():
            lut[s_] = u
        units[p, col] = lut[slot[r]]
        weights[p, col] = (wt[r] * w_own[p]).astype(np.float32)
        return fzm.PixelUnits(units, weights, pu0.k0, pu0.t)

    def draw(self) -> np.ndarray:
        """(H, W, 3) float32 radiance with the current materials (freezing when needed). The
        array is the renderer's own buffer, overwritten by the next draw."""
        with self._lock:
            return self._draw()

    def _draw(self) -> np.ndarray:
        t0 = time.perf_counter()
        timings = {}
        mats = self._all_mats()
        changed = [] if self._frozen_mats is None else \
            [u for u in range(len(mats)) if u != self.U and not _same(mats[u], self._frozen_mats[u])]
        if self.frozen is not None and self.frozen.unit >= len(mats):
            self.frozen = None                    # frozen for painted regions no longer drawn
        live = None if self.frozen is None else self.frozen.unit
        need = self.frozen is None or self._frozen_bounces != self.max_bounces or any(u != live for u in changed)
        if need and self.U > 0:
            target = ([u for u in changed if u != live] or [live if live is not None else 0])[-1]
            timings["freeze"] = 1000 * self.freeze(target)
        elif need:
            timings["freeze"] = 1000 * self.freeze(-1)
        fz = self.frozen
        t1 = time.perf_counter()
        if fz.unit >= 0:
            p = self.projection(fz.unit, self._mat(fz.unit))
            C1i, d = self._first(p, self._unit_q(fz.unit)), p.d
            ck = np.ones((self.K2, 3), np.float32)
            if self.K2 > 1:
                ck[1:] = p.second
        else:
            C1i, d, ck = np.zeros((THETA_NODES, self.K1, 3), np.float32), np.zeros(3), np.ones((1, 3), np.float32)
        t2 = time.perf_counter()
        img = self._image                     # background pixels never change
        self.k.gi.frame(fz, self.pu, C1i, ck, d, self.K1, self.prim.pixel, img)
        t3 = time.perf_counter()
        timings.update({"project": 1000 * (t2 - t1), "frame": 1000 * (t3 - t2), "total": 1000 * (time.perf_counter() - t0)})
        self.last_timings = timings
        cam = self.scene.spec.camera
        return img.reshape(cam.height, cam.width, 3)

    def render(self, req: FrameRequest) -> Rendered:
        spec = self.scene.spec
        if req.camera is not None and not _same(req.camera, spec.camera):
            raise Unsupported("the GI renderer draws the precomputed view only: the camera is fixed by its "
                              "precomputation (use the direct-light renderer to move it)")
        env = spec.environment
        if abs(req.lighting.rotation_deg - env.rotation_deg) > 1e-9:
            raise Unsupported("the GI renderer's lighting is fixed by its precomputation: the environment "
                              "cannot rotate (use the direct-light renderer, or precompute again)")
        with self._lock:
            self._apply(list(req.materials or []))
            img = self._draw()
            scale = req.lighting.intensity / env.intensity if env.intensity > 0 else 0.0
            img = img * np.float32(scale) if scale != 1.0 else img.copy()
            return Rendered(img, self.prim.object_id.copy(), dict(self.last_timings),
                            {"live": self._unit_name(self.frozen.unit),
                             "bounces": self.max_bounces, "series": list(self.opts.series)})

    def make_live(self, object_index: int, materials=None) -> float:
        """Freeze every unit but the object's own (eq. 27) with the scene's materials as given
        (scene order, as FrameRequest.materials): the object a session picks is edited at frame
        cost from its first change on. Seconds (0 when it is live already)."""
        u = self._stroke_unit(object_index, strokes=False)
        with self._lock:
            if materials:
                self._apply(list(materials))
            before = self.frozen
            fz = self._live_frozen(u)
            return 0.0 if fz is before else self.last_freeze_seconds

    # --- strokes (strokes.py) -----------------------------------------------------------------------

    @contextlib.contextmanager
    def painting(self, object_index: int, region: str, materials):
        """Strokes on the object fit its painted region ``region`` (its unit: a pseudo-unit, or
        the traced one, see ``_n_units``) while inside, with ``materials`` (scene order) applied; holds the
        renderer's lock (frames of other sessions on it wait)."""
        with self._lock:
            self._apply(list(materials))
            if (object_index, region) not in self._region_units:
                raise GlintError(f"no painted region {region!r} on object {object_index}")
            self._painting[object_index] = region
            try:
                yield self
            finally:
                self._painting.pop(object_index, None)

    def region_traced(self, object_index: int, region: str) -> bool:
        """Whether the object's painted region ``region`` is drawn as a unit traced into the
        tensors (its light on to other surfaces its own), with the materials last applied."""
        u = self._region_units.get((object_index, region))
        return u is not None and u < self.U

    def _stroke_unit(self, object_index: int, strokes: bool = True) -> int:
        """The unit a stroke (or, ``strokes`` False, any edit) on an object changes: its own
        material's, or, while ``painting`` a region of it, the region's."""
        objs = self.scene.spec.objects
        if not 0 <= object_index < len(objs):
            raise GlintError(f"no object {object_index}", status=404)
        region = self._painting.get(object_index)
        if strokes and region is not None and (object_index, region) in self._region_units:
            return self._region_units[(object_index, region)]
        name = objs[object_index].name
        if self.layout.fixed[object_index]:
            raise GlintError(f"object {name!r} is fixed (\"editable\": false) in this GI precomputation: its "
                             "material is baked in and strokes cannot change it", status=409)
        if strokes and self.layout.aniso_of_object and self.layout.aniso_of_object[object_index] is not None:
            raise GlintError(f"object {name!r} is precomputed for anisotropy editing (ashikhmin-shirley): strokes "
                             "fit an isotropic srbf material", status=409)
        return self.layout.of_object[object_index][0]

    def _fixed_view(self, camera, lighting=None) -> float:
        """The intensity scale of a fit question, which must be about the precomputed view and
        lighting (Unsupported otherwise)."""
        spec = self.scene.spec
        if camera is not None and not _same(camera, spec.camera):
            raise Unsupported("the GI renderer's camera is fixed by its precomputation: strokes are painted "
                              "in its view")
        if lighting is None:
            return 1.0
        env = spec.environment
        if abs(lighting.rotation_deg - env.rotation_deg) > 1e-9:
            raise Unsupported("the GI renderer's lighting is fixed by its precomputation: the environment "
                              "cannot rotate")
        return lighting.intensity / env.intensity if env.intensity > 0 else 0.0

    def visible_vertices(self, camera, object_index: int):
        """The object's vertices the precomputed view sees (corners of the faces its camera
        rays hit): pix (K,) int64 global vertex ids (sorted), positions (K, 3) float64 world (a
        painted region's footprint, fit/regions.py; not the cut renderer's vertex samples, which
        shade)."""
        self._fixed_view(camera)
        vids = np.unique(self.geo.F[self.prim.face[self.prim.obj == object_index]])
        return SimpleNamespace(pix=vids.astype(np.int64), positions=self.geo.V[vids])

    def sample_corners(self, samples: "GISamples") -> np.ndarray:
        """(N, 3) int64 global vertex ids of the faces the samples' camera rays hit."""
        return self.geo.F[self.prim.face[samples.hit]]

    def sample_barycentrics(self, samples: "GISamples") -> np.ndarray:
        """(N, 3) float64 barycentric weights of the samples' hits in their faces (the corners
        of ``sample_corners``): a painted region's weight at a sample is their blend."""
        return self.prim.bary[samples.hit]

    def vertex_mirrors(self, ids: np.ndarray) -> np.ndarray:
        """(K, 3) float64 unit mirror directions of the precomputed view at vertices ``ids``
        (global): the direction to the eye reflected about the vertex normal."""
        n = self.geo.N[ids]
        wo = np.asarray(self.scene.spec.camera.eye, np.float64) - self.geo.V[ids]
        wo /= np.maximum(np.linalg.norm(wo, axis=1, keepdims=True), 1e-300)
        return 2.0 * (n * wo).sum(1, keepdims=True) * n - wo

    def surface_samples(self, camera, object_index: int, pixels: np.ndarray | None = None) -> "GISamples":
        """The object's hit pixels of the precomputed view (the fitter's rows). pixels : (M,)
        int64 flat image indices to look at; ``pix`` then indexes ``pixels``."""
        self._fixed_view(camera)
        self._stroke_unit(object_index)
        cam = self.scene.spec.camera
        img = np.arange(cam.width * cam.height) if pixels is None else np.asarray(pixels, np.int64)
        hp = self._hit_of_pixel[img]
        ok = hp >= 0
        ok[ok] = self.prim.obj[hp[ok]] == object_index
        sel = np.nonzero(ok)[0]
        return GISamples(sel.astype(np.int64), hp[sel])

    def _live_frozen(self, u: int):
        """The frozen tensors with unit u live and every other unit at its current material
        (freezing now when they are not)."""
        with self._lock:
            fz = self.frozen
            mats = self._all_mats()
            stale = fz is None or fz.unit != u or len(mats) != len(self._frozen_mats or []) or \
                self._frozen_bounces != self.max_bounces or \
                any(v != u and v != self.U and not _same(mats[v], self._frozen_mats[v]) for v in range(len(mats)))
            if stale:
                self._freeze(u)
            return self.frozen

    def _sampled_at(self, u: int, samples: "GISamples") -> stm.Sampled:
        fz = self._live_frozen(u)
        key = samples.hit.tobytes()
        for f, k, smp in self._sampled:
            if f is fz and k == key:
                return smp
        h, _ = fzm.pixel_weights(self.pu, u)
        smp = stm.Sampled(fz, self.pu, samples.hit, h, self.K1)
        self._sampled = [e for e in self._sampled[-3:] if e[0] is fz] + [(fz, key, smp)]
        return smp

    def _coefficients(self, u: int, material) -> stm.Coefficients:
        p = self.projection(u, material)
        ck = np.ones((self.K2, 3))
        if self.K2 > 1:
            ck[1:] = p.second
        return stm.Coefficients(self._first(p, self._unit_q(u)), np.asarray(p.d, np.float64), ck)

    def shade_samples(self, samples: "GISamples", material, object_index: int, lighting, coarse: bool = False) -> np.ndarray:
        """(N, 3) float64 GI radiance at the samples with the object's material replaced (every
        other unit at its current material): what a frame would show there."""
        scale = self._fixed_view(None, lighting)
        cur = self.objects_materials[object_index] if self.objects_materials else None
        if has_regions(material) or (has_regions(cur) and object_index not in self._painting):
            # painted regions: the frame with the material, read at the samples
            with self._lock:
                mats = list(self.objects_materials or [o.material for o in self.scene.spec.objects])
                mats[object_index] = material
                self._apply(mats)
                img = self._draw().reshape(-1, 3)
                return img[self.prim.pixel[samples.hit]].astype(np.float64) * scale
        u = self._stroke_unit(object_index)
        return self._sampled_at(u, samples).radiance(self._coefficients(u, material)) * scale

    def linearise(self, samples: "GISamples", basis, lighting, material, object_index: int, coarse: bool = False):
        """The fitter's rows around a material (strokes.Sampled.linearise): (T (3, N, J) float32,
        E (N, 3) float32, R (N, 3) float64) with radiance ≈ ρ_d E + T c + R for srbf coefficients
        c (J, 3) over ``basis`` (worker/fit/basis.py) near ``material``."""
        scale = self._fixed_view(None, lighting)
        with self._lock:
            cur = self.objects_materials[object_index] if self.objects_materials else None
            if has_regions(cur) and object_index not in self._painting:
                # one BRDF for an object that has regions: they give way to it (as the fit's
                # result does), so its rows are of the object without them
                mats = list(self.objects_materials)
                mats[object_index] = material.base if has_regions(material) else material
                self._apply(mats)
        u = self._stroke_unit(object_index)
        smp = self._sampled_at(u, samples)
        p = self.projection(u, material)
        q = self._unit_q(u)
        m = stm.srbf_map(basis, self.J, self.layers, self.J2, q, p.ok)
        ext = []
        if self.phis:
            maps = self._maps.get(q)
            if maps is None:
                self._first(p, q)                 # builds the hat projectors of this quotient
                maps = self._maps[q]
            ext = maps
        T, E, R, _ = smp.linearise(self._coefficients(u, material), m, stm.extend_map(m.first, ext))
        return T * np.float32(scale), E * np.float32(scale), R * scale

    def prepare_basis(self, basis) -> None:
        """The projection of a fitting basis's lobes (strokes.srbf_map) for every editable
        isotropic unit's quotient (without the Fresnel layer's split, which follows the
        material), so the first stroke does not pay it."""
        if self.layers != 1:
            return
        for u, unit in enumerate(self.layout.units):
            if unit.anisotropic is None:
                stm.srbf_map(basis, self.J, self.layers, self.J2, self._unit_q(u))

    def transfer(self, samples: "GISamples", basis, lighting, coarse: bool = False):
        """(T, E) of ``linearise`` around the object's current material: the Jacobian only (the
        image is not linear in the coefficients; the fitter uses ``linearise``)."""
        obj = int(self.prim.obj[samples.hit[0]]) if len(samples) else 0
        T, E, _ = self.linearise(samples, basis, lighting, self._mat(self._stroke_unit(obj)), obj)
        return T, E

    def object_mask(self, camera=None) -> np.ndarray:
        if camera is not None and not _same(camera, self.scene.spec.camera):
            raise Unsupported("the GI renderer's camera is fixed by its precomputation")
        return self.prim.object_id.copy()
