"""Monte Carlo precomputation of the multibounce tensors (polynomial-gi §5.1, eq. 19-24).

Paths start at the eye through pixel centres and are traced wavefront-style: all paths of a
tile of pixels advance one vertex at a time, with Embree tracing each wave's rays in two
threads. At every vertex the environment is sampled by luminance (next-event estimation) and a
continuation direction is drawn from the BRDF-independent mixture (sampling.py); both are
combined by multiple importance sampling, so each vertex k adds to the k-bounce tensor. Instead
of a pixel colour, a path adds to the tensor entry named by (eq. 22-24):

* its *slot* at the first vertex from the eye: the diffuse basis, or the half-angle band (and
  Fresnel layer) of (ωi, ωo) there, weighted by the basis function times cos θi (eq. 22);
* its *tail*: the multiset z of editable units at the further (diffuse-equivalent) vertices
  (eq. 23, 25), and for a (J, J2) series the unit and band of the second vertex (§4.3).

Fixed objects (``"editable": false``, §5.3) multiply the path by their full BRDF·cos instead
and add no index. Regions (H(x), eq. 5-6) are sampled per vertex with probability H(x) beyond
the first vertex; at the first vertex the weights are applied per pixel at runtime.

Each tile's tensor is accumulated in per-pixel hash tables (C) or densely (tile pixels × slots ×
tails × RGB, the NumPy reference), then compacted: zeros dropped, half floats with a float32
scale per pixel and bounce, entries sorted by (slot, tail). ``emit_numpy`` and
``sample_numpy`` are the references of the C kernels ``gi_emit`` / ``gi_sample`` (gi.c); the
random numbers are drawn per tile from a counter-keyed generator, so tiles are independent
and a precomputation is the same however it is split into chunks.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

from ...core.brdf import evaluate, onb
from ...core.render import camera_rays, env_lookup, facing_view
from ...trace.embree import Tracer
from . import zspace
from .basis import J2_NODES, QUOTIENTS, half_band, node_interp, quotient_s
from .options import GIOptions, UnitLayout
from .sampling import EnvDistribution, pdf_mixture, sample_mixture

WAVE_PATHS = 32768    # paths per tile: its pixel count is this / spp (a power of two, 16..2048)
N_UNIFORM = 8         # uniforms per path and vertex: light 4, mixture 3, region choice 1
SCALE_MAX = 16384.0   # the largest entry of a (pixel, bounce) is stored as this half float


# --- scene arrays -------------------------------------------------------------------------------


class Geometry:
    """The scene as the path tracer sees it: world triangles, face and vertex normals, the
    object of each face, an Embree tracer and the ray offset (1e-5 of the scene's diagonal)."""

    def __init__(self, scene):
        m = scene.mesh
        self.V = m.vertices.astype(np.float64)
        self.F = m.faces.astype(np.int64)
        self.N = m.normals.astype(np.float64)
        e1 = self.V[self.F[:, 1]] - self.V[self.F[:, 0]]
        e2 = self.V[self.F[:, 2]] - self.V[self.F[:, 0]]
        fn = np.cross(e1, e2)
        self.face_n = fn / np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-30)
        self.obj_of_face = scene.object_of_face.astype(np.int32)
        self.tracer = Tracer(m.vertices, m.faces)
        diag = float(np.linalg.norm(self.V.max(0) - self.V.min(0)))
        self.eps = 1e-5 * max(diag, 1e-6)
        self.lo = [self.V[np.unique(self.F[self.obj_of_face == i])].min(0) if (self.obj_of_face == i).any() else np.zeros(3)
                   for i in range(int(self.obj_of_face.max()) + 1)]
        self.hi = [self.V[np.unique(self.F[self.obj_of_face == i])].max(0) if (self.obj_of_face == i).any() else np.ones(3)
                   for i in range(int(self.obj_of_face.max()) + 1)]

    def surface(self, prim, uv, wo, graze: bool = False):
        """Hit points from Embree hits: (pos, ng, ns, obj, wo, ok). Surfaces are two-sided: the
        geometric normal is turned towards wo (the side the ray arrived on).

        graze False (a path's later vertices, as Mitsuba's twosided BSDF): the shading normal is
        turned towards wo; ok is False where wo grazes its plane.
        graze True (the camera's hits): the shading normal is turned to the geometric normal's
        side (a file's normals may disagree with its winding), and where it still faces away
        from wo (an interpolated normal at an outline, seen past its horizon) wo is taken just
        above its horizon (core.render.facing_view, as the cut renderer shades such points):
        the pixel gets its grazing radiance, not the back side's, whose light comes from inside
        the object (dark dots along outlines). At a path's later vertices the same nudge made
        glossy second bounces noisy (a near-grazing ωo where the flip gives a regular one)."""
        f = self.F[prim]
        u, v = uv[:, 0:1].astype(np.float64), uv[:, 1:2].astype(np.float64)
        w0 = 1.0 - u - v
        pos = w0 * self.V[f[:, 0]] + u * self.V[f[:, 1]] + v * self.V[f[:, 2]]
        ns = w0 * self.N[f[:, 0]] + u * self.N[f[:, 1]] + v * self.N[f[:, 2]]
        ns /= np.maximum(np.linalg.norm(ns, axis=1, keepdims=True), 1e-30)
        ng = self.face_n[prim]
        ng = ng * np.where((ng * wo).sum(1) < 0, -1.0, 1.0)[:, None]
        if graze:
            ns = ns * np.where((ns * ng).sum(1) < 0, -1.0, 1.0)[:, None]
            wo = facing_view(ns, wo)
        else:
            ns = ns * np.where((ns * wo).sum(1) < 0, -1.0, 1.0)[:, None]
        ok = (ns * wo).sum(1) > 1e-6
        return pos, ng, ns, self.obj_of_face[prim], wo, ok

    def trace(self, o, d, occluded: bool, threads: int = 2):
        """Embree in ``threads`` Python threads (it releases the GIL, docs/design/conventions.md, measured facts)."""
        n = len(o)
        if n == 0:
            return np.zeros(0, bool) if occluded else (np.zeros(0, np.int32), np.zeros((0, 2), np.float32))
        o = np.ascontiguousarray(o, np.float32); d = np.ascontiguousarray(d, np.float32)
        parts = np.linspace(0, n, min(threads, max(1, n // 4096)) + 1).astype(np.int64)
        res = [None] * (len(parts) - 1)

        def run(i):
            a, b = parts[i], parts[i + 1]
            if occluded:
                res[i] = self.tracer.occluded(o[a:b], d[a:b])
            else:
                prim, uv, _ = self.tracer.first_hit(o[a:b], d[a:b])
                res[i] = (prim, uv)

        th = [threading.Thread(target=run, args=(i,)) for i in range(1, len(res))]
        for t in th:
            t.start()
        run(0)
        for t in th:
            t.join()
        if occluded:
            return np.concatenate(res)
        return np.concatenate([r[0] for r in res]), np.concatenate([r[1] for r in res])


@dataclass
class Primary:
    """The camera's hits: pixel (P,) int64 flat indices of hit pixels (row-major), obj (P,),
    pos, ng, ns, wo (P, 3) float64 (wo towards the eye), object_id (H, W) int32 (−1 background),
    background (H, W, 3) float32 environment radiance along the camera rays, face (P,) int64 the
    scene face hit and bary (P, 3) float64 the hit's barycentric weights of its corners (painted
    regions' per-vertex weights are interpolated with them)."""
    pixel: np.ndarray
    obj: np.ndarray
    pos: np.ndarray
    ng: np.ndarray
    ns: np.ndarray
    wo: np.ndarray
    object_id: np.ndarray
    background: np.ndarray
    face: np.ndarray | None = None
    bary: np.ndarray | None = None

    @property
    def cos_o(self) -> np.ndarray:
        return np.clip((self.ns * self.wo).sum(1), 0.0, 1.0)


def primary_hits(geo: Geometry, scene, kernels=None) -> Primary:
    """The camera's hits and background (kernels: the backend; default: the process's)."""
    cam = scene.spec.camera
    env = scene.spec.environment
    o, d = camera_rays(cam.eye, cam.target, cam.up, cam.fov_y_deg, cam.width, cam.height, kernels=kernels)
    prim, uv = geo.trace(o, d, occluded=False)
    hit = np.nonzero(prim >= 0)[0]
    wo = -d[hit].astype(np.float64)
    pos, ng, ns, obj, wo, ok = geo.surface(prim[hit], uv[hit], wo, graze=True)
    oid = np.full(cam.width * cam.height, -1, np.int32)
    oid[hit] = obj
    bg = env_lookup(d, scene.envmap, env.rotation_deg, env.intensity, mask=(prim < 0).astype(np.uint8),
                    kernels=kernels)
    uv = uv[hit].astype(np.float64)
    bary = np.stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], 1)
    return Primary(hit.astype(np.int64), obj, pos, ng, ns, wo, oid.reshape(cam.height, cam.width),
                   bg.reshape(cam.height, cam.width, 3), prim[hit].astype(np.int64), bary)


# --- regions: H(x) -------------------------------------------------------------------------------


def load_weight_image(path) -> np.ndarray:
    """(h, w) float32 in [0, 1] from a greyscale/RGB PNG (8/16 bit), EXR or NPY."""
    from pathlib import Path

    from .options import GIOptionsError
    p = Path(path)
    if not p.is_file():
        raise GIOptionsError(f"{p}: weight map not found")
    try:
        if p.suffix.lower() == ".npy":
            a = np.load(p).astype(np.float32)
        elif p.suffix.lower() in (".exr", ".hdr"):
            from ...envmap import _read_exr, _read_hdr
            a = (_read_exr(p) if p.suffix.lower() == ".exr" else _read_hdr(p)).astype(np.float32)
        else:
            from PIL import Image
            im = Image.open(p)
            a = np.asarray(im).astype(np.float32)
            a = a / (65535.0 if a.max() > 255 else 255.0)
    except Exception as e:
        raise GIOptionsError(f"{p}: not a readable weight map ({e})") from None
    if a.ndim == 3:
        a = a[..., :3].mean(-1)
    if a.ndim != 2 or not np.isfinite(a).all():
        raise GIOptionsError(f"{p}: a weight map must be a finite 2D (greyscale) image")
    return np.clip(a, 0.0, 1.0)


class Regions:
    """Per object, the units covering it and their weights at world points (H(x), eq. 5-6):
    regions' images are projected along their axis over the object's bounding box (image
    columns along the first remaining axis, rows along the second, row 0 at its minimum),
    sampled bilinearly; the object's own unit takes 1 − ΣH (regions are renormalised where
    their sum exceeds 1). Fixed objects map to the pseudo-unit U (their baked BRDF).

    Painted regions traced into the tensors (options ``painted``) split what is left to the
    object's own unit by their layer weights (models/regions.py), interpolated from the corners
    of the face hit with the point's barycentric weights (``face``, ``bary``)."""

    def __init__(self, layout: UnitLayout, regions: list, geo: Geometry, images: list[np.ndarray],
                 scene=None, painted: list | None = None):
        self.layout = layout
        self.specs = regions
        self.U = len(layout.units)
        self.images = images
        self.geo = geo
        self.axis = {"x": 0, "y": 1, "z": 2}
        self.lmax = max([len(u) for u in layout.of_object] + [1])
        # object -> (effective layer weights (L, n_o) float32, first global vertex id)
        self.painted: dict[int, tuple[np.ndarray, int]] = {}
        if painted:
            from ...models.regions import layer_weights
            for k, p in enumerate(painted):
                o = [u.object for u in layout.units if u.painted is not None and u.painted[0] == k][0]
                off, end = np.searchsorted(scene.object_of_vertex, [o, o + 1])
                _, a = layer_weights(p.material, int(end - off), scene.vertex_source(o))
                self.painted[o] = (np.asarray(a, np.float32), int(off))

    def weights(self, obj: np.ndarray, pos: np.ndarray, face: np.ndarray | None = None,
                bary: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(units (R, L) int32, −1 padding; weights (R, L) float32) for points on objects; face
        (R,) the faces hit and bary (R, 3) their barycentric weights split the object's share
        among its traced painted regions (face None: not split, the object's own unit takes it:
        the renderer splits the camera hits' per frame, by the design it draws)."""
        R = len(obj)
        units = np.full((R, self.lmax), -1, np.int32)
        w = np.zeros((R, self.lmax), np.float32)
        for o, us in enumerate(self.layout.of_object):
            sel = np.nonzero(obj == o)[0]
            if len(sel) == 0:
                continue
            if not us:                                   # fixed object: its baked BRDF
                units[sel, 0] = self.U
                w[sel, 0] = 1.0
                continue
            img = [u for u in us[1:] if self.layout.units[u].painted is None]
            pnt = [u for u in us[1:] if self.layout.units[u].painted is not None]
            hs = []
            for u in img:
                r = self.layout.units[u].region
                hs.append(self._sample(r, self.specs[r], o, pos[sel]))
            H = np.stack(hs, 1) if hs else np.zeros((len(sel), 0))
            tot = H.sum(1, keepdims=True)
            H = np.where(tot > 1.0, H / np.maximum(tot, 1e-12), H)
            if face is None:
                pnt = []
            units[sel, :1 + len(img) + len(pnt)] = [us[0]] + img + pnt
            w[sel, 0] = 1.0 - H.sum(1)
            w[sel, 1:1 + len(img)] = H
            if pnt:
                a, off = self.painted[o]
                corners = self.geo.F[face[sel]] - off
                la = np.einsum("kc,lkc->lk", bary[sel], a[:, corners])          # (L, n_sel)
                own = w[sel, 0].copy()
                w[sel, 0] = own * la[0]
                for j in range(len(pnt)):
                    w[sel, 1 + len(img) + j] = own * la[1 + j]
        return units, w

    def _sample(self, r, spec, o, pos):
        img = self.images[r]
        ax = self.axis[spec.axis]
        a, b = [i for i in range(3) if i != ax]
        lo, hi = self.geo.lo[o], self.geo.hi[o]
        x = (pos[:, a] - lo[a]) / max(hi[a] - lo[a], 1e-12) * img.shape[1] - 0.5
        y = (pos[:, b] - lo[b]) / max(hi[b] - lo[b], 1e-12) * img.shape[0] - 0.5
        x = np.clip(x, 0, img.shape[1] - 1); y = np.clip(y, 0, img.shape[0] - 1)
        x0 = np.minimum(x.astype(np.int64), max(img.shape[1] - 2, 0)); y0 = np.minimum(y.astype(np.int64), max(img.shape[0] - 2, 0))
        x1 = np.minimum(x0 + 1, img.shape[1] - 1); y1 = np.minimum(y0 + 1, img.shape[0] - 1)
        fx, fy = x - x0, y - y0
        return ((img[y0, x0] * (1 - fx) + img[y0, x1] * fx) * (1 - fy) + (img[y1, x0] * (1 - fx) + img[y1, x1] * fx) * fy)

    def sample_unit(self, obj: np.ndarray, pos: np.ndarray, u: np.ndarray, face: np.ndarray | None = None,
                    bary: np.ndarray | None = None) -> np.ndarray:
        """One unit per point, chosen with probability H(x) (unbiased for the sum over layers);
        −1 on fixed objects."""
        units, w = self.weights(obj, pos, face, bary)
        c = np.cumsum(w, 1)
        k = (u[:, None] * c[:, -1:] >= c).sum(1)
        k = np.minimum(k, units.shape[1] - 1)
        out = units[np.arange(len(obj)), k]
        return np.where(out == self.U, -1, out).astype(np.int32)


# --- the path tracer ------------------------------------------------------------------------------


@dataclass
class Setup:
    """Everything a tile needs (built once per scene and options)."""
    geo: Geometry
    prim: Primary
    opts: GIOptions
    layout: UnitLayout
    regions: Regions
    env: EnvDistribution
    envmap: np.ndarray
    rotation: float
    intensity: float
    U: int
    J: int
    J2: int
    layers: int
    K1: int
    tails: list[int]            # tail-space size per bounce (1-based list index: bounce − 1)
    W2: int                     # second-vertex codes (J2 series): U·(1 + J2·J2_NODES) + 1 (last: fixed)
    aniso_nu: np.ndarray        # (objects,) float64, 0 where the object uses half-angle bands
    aniso_axis: np.ndarray      # (objects, 3) float64
    fixed: np.ndarray           # (objects,) bool
    fixed_materials: list = field(default_factory=list)
    qkind: np.ndarray = None    # (objects,) int32 quotient of the half-angle bands (basis.quotient_s)

    @property
    def N(self) -> int:
        return self.opts.bounces

    @property
    def tile(self) -> int:
        return tile_pixels(self.opts.spp)

    @property
    def n_tiles(self) -> int:
        return (len(self.prim.pixel) + self.tile - 1) // self.tile


def tile_pixels(spp: int) -> int:
    """Hit pixels per tile, the unit of random streams (a function of spp only, so results do
    not depend on how the work is split): about WAVE_PATHS paths per wave."""
    t = 1 << int(np.floor(np.log2(max(WAVE_PATHS // max(spp, 1), 1))))
    return int(min(max(t, 16), 2048))


def make_setup(scene, opts: GIOptions, layout: UnitLayout, images: list[np.ndarray], geo: Geometry | None = None,
               kernels=None) -> Setup:
    geo = geo or Geometry(scene)
    prim = primary_hits(geo, scene, kernels)
    reg = Regions(layout, opts.regions, geo, images, scene, opts.painted)
    U = len(layout.units)
    J, J2 = opts.J, opts.J2
    n_obj = len(scene.spec.objects)
    nu = np.zeros(n_obj); axis = np.zeros((n_obj, 3))
    for i, a in enumerate(layout.aniso_of_object):
        if a is not None:
            nu[i] = a.exponent
            axis[i] = np.asarray(a.tangent) / np.linalg.norm(a.tangent)
    layers = 2 if (opts.fresnel or (nu > 0).any()) else 1
    N = opts.bounces
    if J2 > 1:
        W2 = U * second_codes(J2) + 1
        tails = [1] + [W2 * zspace.size(U, k - 2) for k in range(2, N + 1)]
    else:
        W2 = 0
        tails = [zspace.size(U, k - 1) for k in range(1, N + 1)]
    env = scene.spec.environment
    return Setup(geo, prim, opts, layout, reg, EnvDistribution(scene.envmap, env.rotation_deg), scene.envmap,
                 float(env.rotation_deg), float(env.intensity), U, J, J2, layers, 1 + J * layers, tails, W2,
                 nu, axis, layout.fixed.copy(), [o.material for o in scene.spec.objects],
                 np.array([QUOTIENTS.index(q) for q in layout.quotients(scene, opts)], np.int32))


# --- per-vertex basis weights (NumPy references of gi.c) -----------------------------------------


def _normalize(v):
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-30)


def first_weights(ns, wo, d, nu, axis, J: int, layers: int, qkind=0):
    """Slot weights at a first vertex for incident direction d: (band (R,) int64,
    w (R, 3) float64 = [cos/π, qA·cos, qB·cos]) (eq. 22), zero below either horizon.
    nu (R,) > 0 selects the anisotropic bands over γ with tangent ``axis`` (R, 3)."""
    ci = (ns * d).sum(1); co = (ns * wo).sum(1)
    h = _normalize(d + wo)
    ch = np.clip((ns * h).sum(1), 1e-12, 1.0)
    cd = np.clip((d * h).sum(1), 0.0, 1.0)
    m5 = (1.0 - cd) ** 5
    band = half_band(ch, J)
    qA = quotient_s(np.maximum(ci, 0), np.maximum(co, 0), qkind)
    an = nu > 0
    if an.any():
        n = ns[an]
        t = axis[an] - (axis[an] * n).sum(1, keepdims=True) * n
        tl = np.linalg.norm(t, axis=1, keepdims=True)
        t0, _ = onb(n)
        t = np.where(tl > 1e-6, t / np.maximum(tl, 1e-30), t0)
        b = np.cross(n, t)
        hx = (h[an] * t).sum(1); hy = (h[an] * b).sum(1)
        s2 = hx * hx + hy * hy
        lc = np.log(ch[an])
        sin2 = np.where(s2 > 1e-24, hy * hy / np.maximum(s2, 1e-24), 0.0)
        g = np.exp(nu[an] * sin2 * lc)
        band[an] = np.clip((g * J).astype(np.int64), 0, J - 1)
        qA[an] = np.exp(nu[an] * (1.0 - sin2) * lc) / (np.maximum(cd[an], 1e-12) * np.maximum(np.maximum(ci[an], co[an]), 1e-12))
    ok = (ci > 0) & (co > 0)
    w = np.stack([ci / np.pi, qA * ci, (qA * m5 * ci) if layers == 2 else np.zeros_like(ci)], 1)
    return band, np.where(ok[:, None], w, 0.0)


def second_codes(J2: int) -> int:
    """Basis functions per unit at a second vertex: the diffuse one, then J2 half-angle bands
    × J2_NODES view-angle nodes (hat functions in θo, as the first vertex's coefficients)."""
    return 1 + J2 * J2_NODES


def second_weights(ns, wo, d, J2: int, qkind=0):
    """Slot weights at a second vertex (J2 series): (code (R,) = band·J2_NODES + k0 of the
    first spec function, w (R, 3) = [cos/π, s·cos·(1 − t), s·cos·t]) with (k0, t) the hat
    interpolation of θo over J2_NODES view-angle nodes."""
    ci = (ns * d).sum(1); co = (ns * wo).sum(1)
    h = _normalize(d + wo)
    band = half_band((ns * h).sum(1), J2)
    k0, t = node_interp(co, J2_NODES)
    sc = quotient_s(np.maximum(ci, 0), np.maximum(co, 0), qkind) * ci
    w = np.stack([ci / np.pi, sc * (1.0 - t), sc * t], 1)
    return band * J2_NODES + k0, np.where(((ci > 0) & (co > 0))[:, None], w, 0.0)


# --- kernels: sampling, and emission with the path update -----------------------------------------


def sample_numpy(S: Setup, pos, ng, ns, wo, u):
    """NumPy reference of gi_sample: light and mixture directions with both pdfs at both.

    Returns dl, db (R, 3) float64 unit; pdf_ll, pdf_bl (light / mixture pdf at dl); pdf_bb,
    pdf_lb (mixture / light pdf at db); valid_l, valid_b (above both horizons, pdf > 0)."""
    dl, pdf_ll = S.env.sample(u[:, 0:4])
    db, pdf_bb = sample_mixture(ns, wo, u[:, 4:7])
    pdf_bl = pdf_mixture(ns, wo, dl)
    pdf_lb = S.env.pdf(db)
    # as Mitsuba: the BRDF's side is the shading normal's; rays leave from the geometric side
    # they head to (offset_origins)
    valid_l = ((ns * dl).sum(1) > 0) & (pdf_ll > 0)
    valid_b = ((ns * db).sum(1) > 0) & (pdf_bb > 0)
    return dl, db, pdf_ll, pdf_bl, pdf_bb, pdf_lb, valid_l, valid_b


@dataclass
class PathState:
    """Paths alive at a vertex (R of them). pix: tile-local pixel; obj, unit (−1: fixed) at the
    vertex; beta (R, 3) throughput of the diffuse/fixed vertices so far (divided by their pdfs);
    p1b, p1w (R, 3): first-vertex band and slot weights (band −1: fixed, slot 0 with p1w[0]);
    p2c, p2b, p2w (R, 3): second-vertex unit code, band code, weights (J2 series, see
    second_weights); z (R, 3), zc: the
    multiset of units at diffuse-equivalent vertices."""
    path: np.ndarray
    pix: np.ndarray
    pos: np.ndarray
    ng: np.ndarray
    ns: np.ndarray
    wo: np.ndarray
    obj: np.ndarray
    unit: np.ndarray
    beta: np.ndarray
    p1b: np.ndarray
    p1w: np.ndarray
    p2c: np.ndarray
    p2b: np.ndarray
    p2w: np.ndarray
    z: np.ndarray
    zc: np.ndarray

    def take(self, idx) -> "PathState":
        return PathState(*[getattr(self, f)[idx] for f in self.__dataclass_fields__])


def fixed_values(S: Setup, st: PathState, d: np.ndarray) -> np.ndarray:
    """(R, 3) ρ(d, wo) of fixed objects at the vertices (0 elsewhere), any Glint model."""
    out = np.zeros((len(d), 3))
    for o in np.unique(st.obj[S.fixed[st.obj]]) if len(st.obj) else []:
        sel = np.nonzero(st.obj == o)[0]
        t, b = onb(st.ns[sel])
        n = st.ns[sel]

        def loc(v):
            return np.stack([(v * t).sum(1), (v * b).sum(1), (v * n).sum(1)], 1)
        out[sel] = evaluate(S.fixed_materials[o], loc(d[sel]), loc(st.wo[sel]))
    return out


def emit_numpy(S: Setup, k: int, st: PathState, ev: dict, dense: np.ndarray):
    """NumPy reference of gi_emit: adds vertex k's light (both MIS estimators) to the dense
    k-bounce tile tensor (tile pixels, K1, tails[k−1], 3), and returns the prefix of the paths
    continuing along db: (beta, p1b, p1w, p2c, p2b, p2w, z, zc) for all R (the caller keeps
    those with ev["cont"])."""
    J, J2, U = S.J, S.J2, S.U
    R = len(st.pix)
    fixed = st.unit < 0
    editable = ~fixed
    first = k == 1
    second = (J2 > 1) and k == 2
    diffuse_vertex = (k >= 2 and J2 == 1) or k >= 3
    nu = S.aniso_nu[st.obj]; ax = S.aniso_axis[st.obj]
    Zk = S.tails[k - 1]
    for d, L, wgt, f in ((ev["dl"], ev["Ll"], ev["wl"], ev["fl"]), (ev["db"], ev["Lb"], ev["wb"], ev["fb"])):
        ci = np.maximum((st.ns * d).sum(1), 0.0)
        val = L * (wgt[:, None] * st.beta)                                 # (R, 3)
        if first:
            band, w1 = first_weights(st.ns, st.wo, d, nu, ax, J, S.layers, S.qkind[st.obj])
            w1 = np.where(fixed[:, None], [1.0, 0.0, 0.0], w1)
            val = np.where(fixed[:, None], val * f * ci[:, None], val)
            b1 = np.where(fixed, -1, band)
        else:
            b1, w1 = st.p1b, st.p1w
        slots = [(np.zeros(R, np.int64), w1[:, 0]), (1 + b1, np.where(b1 >= 0, w1[:, 1], 0.0))]
        if S.layers == 2:
            slots.append((1 + J + b1, np.where(b1 >= 0, w1[:, 2], 0.0)))
        # tail
        if first:
            tails = [(np.zeros(R, np.int64), np.ones(R))]
        else:
            z, zc = st.z, st.zc
            if diffuse_vertex:
                val = np.where(fixed[:, None], val * f * ci[:, None], val * (ci / np.pi)[:, None])
                zn, zcn = zspace.insert(z, zc, np.maximum(st.unit, 0))
                z = np.where(editable[:, None], zn, z); zc = np.where(editable, zcn, zc)
            zi = zspace.index(z, zc, U)
            if J2 > 1:
                if second:
                    b2, w2 = second_weights(st.ns, st.wo, d, J2, S.qkind[st.obj])
                    code = np.where(fixed, S.W2 - 1, st.unit * second_codes(J2))
                    w2 = np.where(fixed[:, None], [1.0, 0.0, 0.0], w2)
                    val = np.where(fixed[:, None], val * f * ci[:, None], val)
                    b2 = np.where(fixed, -1, b2)
                else:
                    code, b2, w2 = st.p2c, st.p2b, st.p2w
                Zs = zspace.size(U, k - 2)
                tails = [(code * Zs + zi, w2[:, 0]),
                         (np.where(b2 >= 0, code + 1 + b2, 0) * Zs + zi, np.where(b2 >= 0, w2[:, 1], 0.0)),
                         (np.where(b2 >= 0, code + 2 + b2, 0) * Zs + zi, np.where(b2 >= 0, w2[:, 2], 0.0))]
            else:
                tails = [(zi, np.ones(R))]
        for sl, sw in slots:
            for tl, tw in tails:
                ww = sw * tw
                m = ww != 0
                if not m.any():
                    continue
                assert (tl[m] < Zk).all() and (sl[m] < S.K1).all()
                np.add.at(dense, (st.pix[m], sl[m], tl[m]), (val[m] * ww[m, None]).astype(np.float32))
    # the prefix of continuing paths (along db)
    d, inv = ev["db"], 1.0 / np.maximum(ev["pdf_bb"], 1e-300)
    ci = np.maximum((st.ns * d).sum(1), 0.0)
    beta, p1b, p1w = st.beta.copy(), st.p1b.copy(), st.p1w.copy()
    p2c, p2b, p2w, z, zc = st.p2c.copy(), st.p2b.copy(), st.p2w.copy(), st.z.copy(), st.zc.copy()
    fb = ev["fb"]
    if first:
        band, w1 = first_weights(st.ns, st.wo, d, nu, ax, J, S.layers, S.qkind[st.obj])
        p1b = np.where(fixed, -1, band)
        p1w = np.where(fixed[:, None], [1.0, 0.0, 0.0], w1 * inv[:, None])
        beta = np.where(fixed[:, None], beta * fb * (ci * inv)[:, None], beta)
    elif second:
        b2, w2 = second_weights(st.ns, st.wo, d, J2, S.qkind[st.obj])
        p2c = np.where(fixed, S.W2 - 1, st.unit * second_codes(J2))
        p2b = np.where(fixed, -1, b2)
        p2w = np.where(fixed[:, None], [1.0, 0.0, 0.0], w2 * inv[:, None])
        beta = np.where(fixed[:, None], beta * fb * (ci * inv)[:, None], beta)
    else:
        beta = np.where(fixed[:, None], beta * fb * (ci * inv)[:, None], beta * (ci / np.pi * inv)[:, None])
        zn, zcn = zspace.insert(z, zc, np.maximum(st.unit, 0))
        z = np.where(editable[:, None], zn, z); zc = np.where(editable, zcn, zc)
    return beta, p1b, p1w, p2c, p2b, p2w, z, zc


# --- a tile -------------------------------------------------------------------------------------


def offset_origins(S: Setup, st: PathState, d: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Ray origins off the surface, on the geometric side the rays head to (Embree's tnear is 0)."""
    ng = st.ng[idx]
    sgn = np.where((ng * d[idx]).sum(1) < 0, -1.0, 1.0)[:, None]
    return st.pos[idx] + ng * (sgn * S.geo.eps)


def trace_tile(S: Setup, tile: int, kernels=None, threads: int = 2) -> tuple[list[tuple], int]:
    """The tensors of one tile of hit pixels: (per bounce (counts (P,) int32, slot (n,) uint16,
    tail (n,) uint32, val (n, 3) float16, scale (P,) float32), rays traced). kernels: the
    backend whose ``gi`` family samples and accumulates (default: the process's); the "numpy"
    references are exact but slow (a dense tile tensor), for tiny scenes and tests."""
    from ...native.kernels import kernels as _kernels

    k_ = kernels or _kernels()
    gk = k_.gi
    p0 = tile * S.tile
    p1 = min(p0 + S.tile, len(S.prim.pixel))
    P, spp = p1 - p0, S.opts.spp
    n_paths = P * spp
    rng = np.random.default_rng([S.opts.seed, tile])
    pr = S.prim
    idx = np.repeat(np.arange(p0, p1), spp)
    R = n_paths
    st = PathState(np.arange(R), np.repeat(np.arange(P), spp), pr.pos[idx], pr.ng[idx], pr.ns[idx], pr.wo[idx],
                   pr.obj[idx], np.where(S.fixed[pr.obj[idx]], -1, 0).astype(np.int32), np.ones((R, 3)),
                   np.full(R, -1, np.int64), np.zeros((R, 3)), np.zeros(R, np.int64), np.full(R, -1, np.int64),
                   np.zeros((R, 3)), np.full((R, zspace.MAX_Z), zspace.EMPTY, np.int64), np.zeros(R, np.int64))
    acc = [gk.accumulator(P, S.K1, S.tails[k], spp) for k in range(S.N)]
    rays = 0
    for k in range(1, S.N + 1):
        u_all = rng.random((n_paths, N_UNIFORM))
        if len(st.pix) == 0:
            continue
        u = u_all[st.path]
        dl, db, pdf_ll, pdf_bl, pdf_bb, pdf_lb, valid_l, valid_b = gk.sample(S, st.pos, st.ng, st.ns, st.wo, u)
        vis = np.zeros(len(dl), bool)
        il = np.nonzero(valid_l)[0]
        vis[il] = ~S.geo.trace(offset_origins(S, st, dl, il), dl[il], occluded=True, threads=threads)
        ib = np.nonzero(valid_b)[0]
        prim = np.full(len(db), -1, np.int32); uv = np.zeros((len(db), 2), np.float32)
        prim[ib], uv[ib] = S.geo.trace(offset_origins(S, st, db, ib), db[ib], occluded=False, threads=threads)
        rays += len(il) + len(ib)
        esc = valid_b & (prim < 0)
        cont = valid_b & (prim >= 0)
        Ll = np.zeros((len(dl), 3)); Lb = np.zeros((len(db), 3))
        Ll[vis] = env_lookup(dl[vis].astype(np.float32), S.envmap, S.rotation, S.intensity, kernels=k_)
        Lb[esc] = env_lookup(db[esc].astype(np.float32), S.envmap, S.rotation, S.intensity, kernels=k_)
        ev = {"dl": dl, "db": db, "Ll": Ll, "Lb": Lb, "pdf_bb": pdf_bb,
              "wl": np.where(vis, 1.0 / np.maximum(pdf_ll + pdf_bl, 1e-300), 0.0),   # balance heuristic:
              "wb": np.where(esc, 1.0 / np.maximum(pdf_bb + pdf_lb, 1e-300), 0.0),   # w/pdf = 1/(p_l + p_b)
              "fl": fixed_values(S, st, dl), "fb": fixed_values(S, st, db)}
        nxt = gk.emit(S, k, st, ev, acc[k - 1])
        if k == S.N:
            break
        keep = np.nonzero(cont)[0]
        beta, p1b, p1w, p2c, p2b, p2w, z, zc = (a[keep] for a in nxt)
        wo = -db[keep]
        pos, ng, ns, obj, wo, ok = S.geo.surface(prim[keep], uv[keep], wo)
        uvk = uv[keep].astype(np.float64)
        unit = S.regions.sample_unit(obj, pos, u[keep, 7], prim[keep],
                                     np.stack([1.0 - uvk[:, 0] - uvk[:, 1], uvk[:, 0], uvk[:, 1]], 1))
        nst = PathState(st.path[keep], st.pix[keep], pos, ng, ns, wo, obj, unit, beta, p1b, p1w, p2c, p2b, p2w, z, zc)
        st = nst.take(np.nonzero(ok)[0])
    inv = np.float32(1.0 / spp)                        # eq. 21: the mean over the pixel's paths
    return [gk.compact(a, inv) for a in acc], rays


def compact(dense: np.ndarray):
    """Drop zeros of a dense tile tensor (P, K1, T, 3) float32 -> (counts (P,) int32, slot
    (n,) uint16, tail (n,) uint32, val (n, 3) float16, scale (P,) float32): values are stored
    divided by their pixel's scale, the largest as SCALE_MAX."""
    P, K1, T, _ = dense.shape
    flat = dense.reshape(P, K1 * T, 3)
    amax = np.abs(flat).max(axis=(1, 2)) if flat.size else np.zeros(P, np.float32)
    scale = np.where(amax > 0, amax / SCALE_MAX, 1.0).astype(np.float32)
    q = (flat / scale[:, None, None]).astype(np.float16)
    nz = (q != 0).any(-1)
    p_idx, cell = np.nonzero(nz)
    counts = np.bincount(p_idx, minlength=P).astype(np.int32)
    return counts, (cell // T).astype(np.uint16), (cell % T).astype(np.uint32), q[p_idx, cell], scale
