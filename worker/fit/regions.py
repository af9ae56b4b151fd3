"""Strokes that change what they cover: a region from the strokes' footprint and the fit of its
own BRDF (models/regions.py for the data model).

The region. Each object vertex the view sees is projected into the view image; at distance d
(view pixels) from a stroke's polyline it gets the brush's weight exp(−κ d) (eq. 23) times a
taper that is 1 inside the brush (d ≤ D/2) and falls smoothly to 0 one brush radius further
(d = D): the footprint dilated by the brush radius, so a painted pixel's triangle has its
corners in the region even where the brush edge crosses it, and the region's edge is soft.
Several strokes take the largest weight at each vertex.

The fit. In vertex mode a pixel's radiance is the barycentric blend of its corners' radiance
(cut renderer), and a corner c inside a region of weight w_c blends two materials:

    B(x) = Σ_c b_c [(1 − w_c) L_below(v_c) + w_c (ρ_d E(v_c) + Σ_j c_j T_j(v_c))]

with L_below the radiance of what lies under the region (the base, or the base with the other
regions), T_j, E the transfer functions at the vertex (inverse-brdf-modeling eq. 21, eq. 3 with
the vertex's own normal and view direction, as the renderer shades it). This is linear in the
region's coefficients (c, ρ_d): the paper's least squares (eq. 17-19, solve.py) over the pixels
the region touches, with rows Σ_c b_c w_c T_j(v_c) and the fixed part moved to the target.
Pixels the region does not touch keep their radiance exactly, so nothing spills beyond it.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..models.regions import Region, Regions, fit_mesh, has_regions, in_group, without_region
from ..scene import SRBF
from .basis import DEFAULT_NL
from .brush import DEFAULT_UNPAINTED_WEIGHT, Stroke, apply_stroke, polyline_distance, stroke_effect, stroke_weights
from .fitter import GN_STEPS, GN_TOL, FitError, Fitter
from .guidance import guidance_notes, stroke_guidance
from .solve import FitRows, SolveResult, solve, solve_blocks

# the region's weight falls from the brush edge (d = D/2) to zero at d = TAPER_END · D
# (smoothstep): one brush radius of dilation
TAPER_END = 1.0
# a region's fit solves its diffuse albedo too by default: a darkening or a colour change of a
# matte object needs it (the specular part only adds light, solve.py)
DEFAULT_REGION_ALBEDO = True


def project(camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """View-image pixel coordinates (K, 2) float64 (x right, y down, pixel (0, 0)'s centre at
    (0.5, 0.5), as strokes are given) of world points (K, 3), and (K,) bool: in front of the
    camera. The inverse of render.camera_rays' pinhole."""
    eye = np.asarray(camera.eye, np.float64)
    fwd = np.asarray(camera.target, np.float64) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(camera.up, np.float64))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    p = np.asarray(points, np.float64) - eye
    z = p @ fwd
    front = z > 1e-9
    zs = np.where(front, z, 1.0)
    t = np.tan(np.radians(camera.fov_y_deg) / 2.0)
    aspect = camera.width / camera.height
    x = (p @ right) / zs / (t * aspect)
    y = (p @ up) / zs / t
    return np.stack([(x + 1.0) * 0.5 * camera.width, (1.0 - y) * 0.5 * camera.height], 1), front


def region_weight(stroke: Stroke, d: np.ndarray) -> np.ndarray:
    """A region's weight (K,) at distances d (K,) view pixels from a stroke: the brush falloff
    exp(−κ d) inside the brush, tapered (smoothstep) to 0 at TAPER_END·D."""
    D = stroke.diameter
    r0, r1 = 0.5 * D, TAPER_END * D
    s = np.clip((r1 - d) / max(r1 - r0, 1e-9), 0.0, 1.0)
    taper = s * s * (3.0 - 2.0 * s)
    return np.where(d <= r1, np.exp(-stroke.kappa * d) * np.where(d <= r0, 1.0, taper), 0.0)


def object_range(renderer, obj: int) -> tuple[int, int]:
    """(first global vertex id, vertex count) of object ``obj`` (objects' vertices are contiguous)."""
    ov = renderer.scene.object_of_vertex
    a, b = np.searchsorted(ov, [obj, obj + 1])
    return int(a), int(b - a)


def footprint_weights(fx: Fitter, strokes: list[Stroke]) -> np.ndarray:
    """(n_o,) float32 region weights over the fitter's object's vertices from strokes painted in
    its saved views (vertices the view sees, projected; see the module doc)."""
    off, n_o = object_range(fx.renderer, fx.obj)
    w = np.zeros(n_o, np.float32)
    seen = {}
    for s in strokes:
        if s.view >= len(fx.views):
            raise FitError(f"stroke refers to view {s.view} but {len(fx.views)} view(s) are saved")
        if s.view not in seen:
            cam = fx.views[s.view].camera
            # the vertices the view sees: the cut renderer's vertex samples, the GI renderer's
            # camera hits' corners
            seen_by = getattr(fx.renderer, "visible_vertices", None) or fx.renderer.vertex_samples
            vs = seen_by(cam, fx.obj)
            xy, front = project(cam, vs.positions)
            seen[s.view] = (vs.pix[front].astype(np.int64) - off, xy[front])
        ids, xy = seen[s.view]
        d = polyline_distance(xy, np.asarray(s.points))
        np.maximum.at(w, ids, region_weight(s, d).astype(np.float32))
    return w


@dataclass
class RegionOutcome:
    """A region fit's result. material : the object's new material (``regions``); regions : the
    regions made or extended (one, or the parts of a split region, named ``name/1`` …);
    achieved : share of the requested change delivered on the painted pixels; spill : relative
    change of every unpainted pixel; spill_far : that of the pixels farther than one brush
    diameter from every stroke (brush.stroke_effect; vertex-mode radiance, as the cut renderer
    draws the object). solve : the solve.SolveResult (one part) or solve.BlockSolveResult."""
    material: Regions
    regions: list[Region]
    solve: object
    pixels: int
    painted: int
    rows: int
    notes: list[str]
    seconds_transfer: float
    achieved: float | None = None
    spill: float | None = None
    spill_far: float | None = None
    extended: bool = False
    views: list = field(default_factory=list, repr=False)   # per view: (base, target, painted, far, pred)
    guidance: dict | None = None        # guidance.highlight_guidance of a brightening stroke
    tried: list = field(default_factory=list)                # (parts, achieved) of each attempt
    # GI: relative RMS between the fit's model of the region's samples (its rows times the
    # solution) and the frame drawn there (0 up to the tensors' half floats where it is exact)
    model_gap: float | None = None

    @property
    def region(self) -> Region:
        return self.regions[0]

    @property
    def parts(self) -> int:
        return len(self.regions)

    @property
    def region_albedo(self) -> list[float]:
        return [float(x) for x in np.atleast_2d(self.solve.albedo)[0]]

    def report(self) -> dict:
        """The ``regions`` entries of ``glint fit --json``."""
        out = []
        for r in self.regions:
            w = np.asarray(r.weights)
            out.append({"name": r.name, "extended": self.extended, "vertices": len(r.vertices),
                        "full_weight_vertices": int((w >= 0.999).sum()), "model": r.material.model,
                        "albedo": [float(x) for x in r.material.albedo]})
        return out


def _below(material, name: str):
    """What lies under the painted region ``name`` once it is (re)painted on top: the material
    without it (its base when it was the only one)."""
    return without_region(material, name) if has_regions(material) else material


def _strokes_by_view(fx: Fitter):
    out = {}
    for s in fx.history.strokes:
        out.setdefault(s.view, []).append(s)
    return out


# parts tried by ``parts="auto"``: the fewest that achieve 80%, else the best (8 parts gained the
# bunny's highlight 3 more points than 4 for 4× the solve time: 12 s)
AUTO_PARTS = (1, 2, 4)


@dataclass
class _Footprint:
    """What both region fits start from: the object's vertex range (first global id off, count
    n_o), its material over today's vertices (cur), the regions of that name it had (olds), the
    region's weights (n_o,) (the strokes' footprint, the old one kept) and what lies below it."""
    off: int
    n_o: int
    cur: object
    olds: list
    w: np.ndarray
    below: object


def _footprint(fx: Fitter, name: str, unpainted_weight: float) -> _Footprint:
    if not fx.views:
        raise FitError("no view saved: add_view() first")
    strokes = fx.history.strokes
    if not strokes:
        raise FitError("no stroke to make a region from")
    if unpainted_weight < 0:
        raise FitError("unpainted_weight must be ≥ 0")
    r = fx.renderer
    off, n_o = object_range(r, fx.obj)
    # regions painted before the object's vertices were split at creases: over today's vertices
    cur = fit_mesh(fx.base_material, n_o, r.scene.vertex_source(fx.obj))
    olds = [g for g in cur.regions if in_group(g.name, name)] if has_regions(cur) else []
    w = footprint_weights(fx, strokes)
    for g in olds:                                # extending: the old footprint stays painted
        w = np.maximum(w, g.dense(n_o))
    if not np.any(w > 0):
        raise FitError(f"the strokes touch no vertex of object {fx.object_name!r} the views see")
    return _Footprint(off, n_o, cur, olds, w, _below(cur, name))


def fit_region(fx: Fitter, name: str = "region 1", unpainted_weight: float = DEFAULT_UNPAINTED_WEIGHT,
               fit_albedo: bool = DEFAULT_REGION_ALBEDO, constrained: bool = True, n_l: int = DEFAULT_NL,
               parts: int | str = 1) -> RegionOutcome:
    """Make (or extend, when the fitter's base material has a region of that name) a region from
    the fitter's strokes and fit its material (module doc). The rest of the object keeps the
    fitter's base material. Returns a RegionOutcome whose ``material`` is the object's new
    material: the base with the region on top.

    parts : split the region into this many parts, each with its own BRDF (its vertices grouped
        by their mirror directions in the view, k-means), fitted together (solve.solve_blocks):
        a highlight on a curved surface needs its lobe aimed differently where the mirror
        directions differ, and one BRDF shares its energy budget among all those lobes.
        "auto": the fewest of AUTO_PARTS that achieve 80% of the requested change, else the best
        (a part must gain 2 points over fewer parts to be kept).
    """
    _check_parts(parts)
    fp = _footprint(fx, name, unpainted_weight)
    off, n_o, cur, olds, w, below = fp.off, fp.n_o, fp.cur, fp.olds, fp.w, fp.below
    prep = [_prepare_view(fx, vi, v, w, off, cur, below, unpainted_weight) for vi, v in enumerate(fx.views)]
    if not any(np.any(p["weight"] > 0) for p in prep if len(p["R"])):
        raise FitError("nothing to fit: the region covers no painted pixel and unpainted_weight is 0")
    mirror = _mirror_directions(prep, off, n_o)
    counts = AUTO_PARTS if parts == "auto" else (parts,)
    best, tried = _best_parts(counts, parts, lambda k: _fit_parts(fx, name, prep, w, off, n_o, cur, below, k,
                                                                  fit_albedo, constrained, n_l, mirror))
    best.tried = tried
    best.extended = bool(olds)
    best.seconds_transfer = sum(p["seconds"] for p in prep)
    guide = stroke_guidance(fx, best.views)
    told = guidance_notes(guide, best.achieved)
    uncovered = sum(p["uncovered"] for p in prep)
    best.notes = region_notes(best.achieved, best.solve, uncovered, best.painted, guided=bool(told)) + told
    best.guidance = guide
    return best


def fit_region_gi(fx: Fitter, name: str = "region 1", unpainted_weight: float = DEFAULT_UNPAINTED_WEIGHT,
                  fit_albedo: bool = DEFAULT_REGION_ALBEDO, constrained: bool = True,
                  n_l: int = DEFAULT_NL, parts: int | str = 1) -> RegionOutcome:
    """``fit_region`` under global illumination (a renderer with ``polynomial_transfer``): the
    region from the strokes' footprint as in direct light, its material fitted through the GI
    tensors. The GI renderer draws a painted region at the camera hits as a unit of its own
    (renderers/gi/renderer.py ``_n_units``) whose weight is the region's, interpolated over the
    hit face; with every other unit frozen (polynomial-gi eq. 27) a pixel's radiance is linear
    in the region's first-vertex coefficients, so one least-squares solve (eq. 17-19 on the
    expansion of eq. 28, exact here) fits it. A region traced into the tensors (GI options
    ``painted``, its weights unchanged by the strokes) is that unit, tails included: the
    radiance is then polynomial in it, and Gauss-Newton steps re-expand it at each solution as
    the one-BRDF fit does. The rest keeps its material.

    parts : as ``fit_region`` (its vertices grouped by mirror direction in the precomputed view,
        a BRDF each). Each part is a unit drawn at the camera hits; its weight at a hit is its
        vertices' share of the region's interpolated weight, so a pixel's rows are the one-part
        rows times that share (the first vertex's transport does not depend on the unit). A
        region traced into the tensors stays one part (its unit is the traced one)."""
    _check_parts(parts)
    r = fx.renderer
    t0 = time.perf_counter()
    fp = _footprint(fx, name, unpainted_weight)
    off, n_o, olds, w, below = fp.off, fp.n_o, fp.olds, fp.w, fp.below
    plain_below = below.base if has_regions(below) else below
    start = olds[0].material if olds else plain_below
    ids = np.nonzero(w > 0)[0]
    rest = list(below.regions) if has_regions(below) else []

    def with_regions(regs):
        return Regions(base=plain_below, vertex_count=n_o, regions=rest + regs)

    one_region = Region(name=name, material=start, vertices=ids.tolist(),
                        weights=np.round(w[ids].astype(np.float64), 6).tolist())
    targets, _ = fx.targets()
    mats = list(r.objects_materials or [o.material for o in r.scene.spec.objects])
    mats[fx.obj] = with_regions([one_region])
    # only the pixels the region touches depend on its material (elsewhere a row is a constant):
    # the rows and the solve scale with the region, not the object
    inside = [np.nonzero((w[r.sample_corners(v.samples) - off] > 0).any(1))[0] for v in fx.views]
    counts = AUTO_PARTS if parts == "auto" else (parts,)
    lin, steps, first = start, 0, None
    with r.painting(fx.obj, name, mats):
        traced = r.region_traced(fx.obj, name)
        if traced:
            counts = (1,)
        while True:
            rows, lins = [], []
            for v, (tgt, painted), ins in zip(fx.views, targets, inside):
                smp = _take(v.samples, ins)
                T, E, R0 = r.linearise(smp, fx.basis, v.lighting, lin, fx.obj)
                rows.append(FitRows(T, E, tgt[ins] - R0, np.where(painted[ins], 1.0, unpainted_weight)))
                lins.append((smp, T, E, R0))
            if not any(np.any(x.weight > 0) for x in rows):
                raise FitError("nothing to fit: no painted pixel and unpainted_weight is 0")
            first = first or rows
            res = solve(rows, fx.basis, np.asarray(plain_below.albedo, np.float64), constrained=constrained,
                        n_l=n_l, prior=None, fit_albedo=fit_albedo)
            steps += 1
            mat = SRBF.model_validate(fx.basis.to_material(res.coefficients, res.albedo))
            # a region drawn at the camera hits only is linear in its coefficients (one step); one
            # traced into the tensors also lights the object through its tails (polynomial-gi
            # eq. 28): Gauss-Newton steps as the fitter's, until the expansion meets the exact
            # radiance
            num = den = 0.0
            for (smp, T, E, R0), v in zip(lins, fx.views):
                exact = r.shade_samples(smp, mat, fx.obj, v.lighting)
                alb = res.albedo if res.albedo is not None else np.asarray(plain_below.albedo, np.float64)
                pred = alb * E + np.stack([T[c] @ res.coefficients[:, c] for c in range(3)], 1) + R0
                num += float(((exact - pred) ** 2).sum())
                den += float((exact ** 2).sum())
            gap = float(np.sqrt(num / max(den, 1e-300)))
            if gap <= GN_TOL or steps >= GN_STEPS:
                break
            lin = mat
    n_rows = int(sum(len(x.weight) for x in first))
    mirror = np.zeros((n_o, 3))
    if any(k > 1 for k in counts):
        mirror[ids] = r.vertex_mirrors(ids + off)

    def one_part():
        region = Region(name=name, material=mat, vertices=one_region.vertices, weights=one_region.weights)
        out = _gi_outcome(fx, with_regions([region]), [region], res, n_rows, targets)
        out.model_gap = gap
        return out

    def attempt(k):
        if k == 1:
            return one_part()
        return _gi_parts(fx, first, inside, w, off, n_o, k, mirror, name, plain_below, with_regions, fit_albedo,
                         constrained, n_l, n_rows, targets)

    best, tried = _best_parts(counts, parts, attempt)
    if best is None:                                  # the partition left one part
        best = one_part()
        tried.append((1, best.achieved))
    best.tried = tried
    best.extended = bool(olds)
    best.seconds_transfer = time.perf_counter() - t0
    if not traced:
        best.notes.append("under global illumination this region is drawn where the camera sees it; the light it "
                          "reflects on to other surfaces is the object's own material's until the design's regions "
                          "are traced into the tensors (glint gi precompute --trace-regions)")
    return best


def _gi_parts(fx, rows, inside, w, off, n_o, k, mirror, name, plain_below, with_regions, fit_albedo, constrained,
              n_l, n_rows, targets):
    """The GI region fit in k parts (``fit_region_gi``): the one-part rows (FitRows per view over
    the samples ``inside``) times each part's share of the region's weight at the sample, one
    stacked solve (solve.solve_blocks). None when the partition leaves fewer than two parts."""
    r = fx.renderer
    lab, k = _partition(w, mirror, k)
    if k < 2:
        return None
    J = fx.basis.J
    As, tg, wt, r0 = [], [], [], []
    for v, ins, x, (tgt, _) in zip(fx.views, inside, rows, targets):
        smp = _take(v.samples, ins)
        corners = r.sample_corners(smp) - off                     # (n, 3) object vertex ids
        bw = r.sample_barycentrics(smp) * w[corners]              # (n, 3) each corner's weight there
        hp = np.stack([(bw * (lab[corners] == i)).sum(1) for i in range(k)], 1)
        share = hp / np.maximum(hp.sum(1, keepdims=True), 1e-300)  # (n, k)
        A = np.zeros((3, len(ins), k * (J + 1)), np.float32)
        for i in range(k):
            for c in range(3):
                A[c, :, i * (J + 1):i * (J + 1) + J] = share[:, i, None] * x.T[c]
                A[c, :, i * (J + 1) + J] = share[:, i] * x.E[:, c]
        As.append(A)
        tg.append(x.target)
        wt.append(x.weight)
        r0.append(tgt[ins] - x.target)                            # the part no region unit changes
    albedo = np.asarray(plain_below.albedo, np.float64)
    res = solve_blocks(np.concatenate(As, axis=1), np.concatenate(tg), np.concatenate(wt), fx.basis, k,
                       np.repeat(albedo[None], k, 0), constrained=constrained, n_l=n_l)
    regions = []
    for i in range(k):
        vid = np.nonzero(lab == i)[0]
        mat = SRBF.model_validate(fx.basis.to_material(res.coefficients[i], res.albedo[i]))
        regions.append(Region(name=f"{name}/{i + 1}", material=mat, vertices=vid.tolist(),
                              weights=np.round(w[vid].astype(np.float64), 6).tolist()))
    out = _gi_outcome(fx, with_regions(regions), regions, res, n_rows, targets)
    xs = np.concatenate([res.coefficients, res.albedo[:, None]], axis=1).reshape(k * (J + 1), 3)
    num = den = 0.0
    for A, R0, ins, view in zip(As, r0, inside, out.views):
        model = np.stack([A[c].astype(np.float64) @ xs[:, c] for c in range(3)], 1) + R0
        exact = view[4][ins]
        num += float(((exact - model) ** 2).sum())
        den += float((exact ** 2).sum())
    out.model_gap = float(np.sqrt(num / max(den, 1e-300)))
    return out


def _gi_outcome(fx, material, regions, res, n_rows, targets) -> RegionOutcome:
    """A GI region fit's outcome: the object's material drawn (exact GI frames at the views'
    samples), achieved and spill against the strokes' targets."""
    r = fx.renderer
    by_view = _strokes_by_view(fx)
    views = []
    for vi, (v, (tgt, painted)) in enumerate(zip(fx.views, targets)):
        pred = r.shade_samples(v.samples, material, fx.obj, v.lighting)
        far = np.ones(v.n, bool)
        for st in by_view.get(vi, []):
            far &= polyline_distance(v.xy, np.asarray(st.points)) > st.diameter
        views.append((v.base, tgt, painted, far, pred))
    bases, tgts, pnt, fars, preds = ([x[i] for x in views] for i in range(5))
    achieved, spill = stroke_effect(bases, tgts, pnt, preds)
    _, spill_far = stroke_effect(bases, tgts, [~f for f in fars], preds)
    n_painted = int(sum(p.sum() for p in pnt))
    out = RegionOutcome(material, regions, res, sum(v.n for v in fx.views), n_painted, n_rows, [], 0.0, achieved,
                        spill, spill_far, False, views)
    out.notes = region_notes(achieved, res, 0, n_painted)
    return out


def _prepare_view(fx: Fitter, vi: int, v, w: np.ndarray, off: int, cur, below, unpainted_weight: float) -> dict:
    """The rows a view gives a region fit: its pixels the region touches (R), their corner
    vertices' radiance now and under the region (vertex samples), the live corners' transfer,
    the pixel × live-vertex matrix of barycentric × region weights (Pw) and the fixed part."""
    r = fx.renderer
    t0 = time.perf_counter()
    verts = v.samples.verts.astype(np.int64)              # (N, 3) global vertex (cut) ids
    wc = w[verts - off]                                   # (N, 3) the corners' region weights
    R = np.nonzero((wc > 0).any(1))[0]
    K, inv = np.unique(verts[R], return_inverse=True)     # the corner vertices of those pixels
    inv = inv.reshape(-1, 3)
    vs = _vertex_samples(r, v.camera, fx.obj, K)
    L_cur = r.shade_samples(vs, cur, fx.obj, v.lighting)
    L_below = L_cur if below is cur else r.shade_samples(vs, below, fx.obj, v.lighting)
    live = np.nonzero(w[K - off] > 0)[0]                  # transfer rows only where the region is
    T, E = r.transfer(_take(vs, live), fx.basis, v.lighting)
    b = v.samples.bary[R].astype(np.float64)
    nR = len(R)
    rowsR = np.repeat(np.arange(nR), 3)
    # pixels × corner vertices: barycentric weight, and times the region's weight
    Pb = sp.csr_matrix((b.reshape(-1), (rowsR, inv.reshape(-1))), shape=(nR, len(K)))
    pos = np.full(len(K), -1)
    pos[live] = np.arange(len(live))
    kk = pos[inv.reshape(-1)]
    keep = kk >= 0
    Pw = sp.csr_matrix(((b * wc[R]).reshape(-1)[keep], (rowsR[keep], kk[keep])), shape=(nR, len(live)))
    fixed = Pb @ L_below - Pw @ L_below[live]              # Σ b (1 − w) L_below
    base = v.base.copy()
    base[R] = Pb @ L_cur                                   # what the pixels show now (vertex mode)
    tgt = base.copy()
    painted = np.zeros(v.n, bool)
    far = np.ones(v.n, bool)
    for s in _strokes_by_view(fx).get(vi, []):
        sw = stroke_weights(s, v.xy, v.footprint)
        apply_stroke(tgt, s, sw)
        painted |= sw > 0
        far &= polyline_distance(v.xy, np.asarray(s.points)) > s.diameter
    return {"R": R, "Pw": Pw, "T": T, "E": E, "live_ids": K[live], "fixed": fixed, "base": base, "target": tgt,
            "painted": painted, "far": far, "weight": np.where(painted[R], 1.0, unpainted_weight),
            "uncovered": int((painted & ~(wc > 0).any(1)).sum()), "n": v.n,
            "mirror": _mirror(vs.normals[live], vs.wo[live]), "seconds": time.perf_counter() - t0}


def _mirror(n, wo):
    n, wo = np.asarray(n, np.float64), np.asarray(wo, np.float64)
    return 2.0 * (n * wo).sum(1, keepdims=True) * n - wo


def _mirror_directions(prep, off: int, n_o: int) -> np.ndarray:
    """(n_o, 3) each region vertex's mirror direction in the first view that sees it (0 elsewhere)."""
    out = np.zeros((n_o, 3))
    done = np.zeros(n_o, bool)
    for p in prep:
        ids = p["live_ids"] - off
        new = ~done[ids]
        out[ids[new]] = p["mirror"][new]
        done[ids] = True
    return out


def _partition(w: np.ndarray, mirror: np.ndarray, k: int) -> tuple[np.ndarray, int]:
    """(lab (n_o,) int part of each region vertex, −1 outside; the number of parts used): k-means
    of the mirror directions (scipy.cluster.vq.kmeans2, seeded k-means++), vertices without one
    in part 0, the parts that took a vertex numbered 0 … in their order."""
    from scipy.cluster.vq import kmeans2

    lab = np.full(len(w), -1)
    ids = np.nonzero(w > 0)[0]
    lab[ids] = 0
    seen = ids[np.linalg.norm(mirror[ids], axis=1) > 0]
    if k > 1 and len(seen) >= 2 * k:
        _, lab[seen] = kmeans2(mirror[seen], k, minit="++", seed=1)
    used = np.unique(lab[lab >= 0])
    remap = np.full(k + 1, -1)
    remap[used] = np.arange(len(used))
    return np.where(lab >= 0, remap[lab], -1), len(used)


def _best_parts(counts, parts, attempt):
    """The region fit kept among ``attempt(k)`` for k in counts (an outcome, or None when the
    partition leaves fewer parts): the first, replaced by one that achieves 2 points more;
    ``parts`` "auto" stops at the first that achieves 80%. Returns (best or None, tried)."""
    best, tried = None, []
    for k in counts:
        out = attempt(k)
        if out is None:
            continue
        tried.append((out.parts, out.achieved))
        if best is None or (out.achieved or 0) > (best.achieved or 0) + 0.02:
            best = out
        if parts == "auto" and (best.achieved is None or best.achieved >= 0.8):
            break
    return best, tried


def _check_parts(parts) -> None:
    if parts != "auto" and not (isinstance(parts, int) and 1 <= parts <= 16):
        raise FitError(f"parts must be 1 to 16 or 'auto', got {parts!r}")


def _fit_parts(fx, name, prep, w, off, n_o, cur, below, k, fit_albedo, constrained, n_l, mirror):
    """One region fit with its vertices in k parts (k = 1: solve.solve; else solve_blocks)."""
    lab, k = _partition(w, mirror, k)
    J = fx.basis.J
    rows, mats_rows = [], []
    for p in prep:
        if not len(p["R"]):
            continue
        part = lab[p["live_ids"] - off]
        if k == 1:
            Tp = np.stack([np.asarray(p["Pw"] @ p["T"][c].astype(np.float64), np.float32) for c in range(3)])
            Ep = np.asarray(p["Pw"] @ p["E"].astype(np.float64), np.float32)
            rows.append(FitRows(Tp, Ep, p["target"][p["R"]] - p["fixed"], p["weight"]))
        else:
            A = np.zeros((3, len(p["R"]), k * (J + 1)), np.float32)
            for i in range(k):
                Pi = p["Pw"] @ sp.diags((part == i).astype(np.float64))
                for c in range(3):
                    A[c, :, i * (J + 1):i * (J + 1) + J] = Pi @ p["T"][c].astype(np.float64)
                    A[c, :, i * (J + 1) + J] = Pi @ p["E"][:, c].astype(np.float64)
            mats_rows.append((A, p["target"][p["R"]] - p["fixed"], p["weight"]))
    albedo = np.asarray(below.albedo, np.float64)
    if k == 1:
        res = solve(rows, fx.basis, albedo, constrained=constrained, n_l=n_l, prior=None, fit_albedo=fit_albedo)
        coefs, albs = res.coefficients[None], res.albedo[None]
    else:
        A = np.concatenate([m[0] for m in mats_rows], axis=1)
        res = solve_blocks(A, np.concatenate([m[1] for m in mats_rows]), np.concatenate([m[2] for m in mats_rows]),
                           fx.basis, k, np.repeat(albedo[None], k, 0), constrained=constrained, n_l=n_l)
        coefs, albs = res.coefficients, res.albedo
    regions = []
    for i in range(k):
        ids = np.nonzero(lab == i)[0]
        mat = SRBF.model_validate(fx.basis.to_material(coefs[i], albs[i]))
        regions.append(Region(name=name if k == 1 else f"{name}/{i + 1}", material=mat, vertices=ids.tolist(),
                              weights=np.round(w[ids].astype(np.float64), 6).tolist()))
    rest = list(below.regions) if has_regions(below) else []
    material = Regions(base=below.base if has_regions(below) else below, vertex_count=n_o, regions=rest + regions)
    preds, views = [], []
    for p in prep:
        pred = p["base"].copy()
        if len(p["R"]):
            part = lab[p["live_ids"] - off]
            rad = np.zeros((len(p["live_ids"]), 3))
            for i in range(k):
                m = part == i
                rad[m] = albs[i] * p["E"][m] + np.stack([p["T"][c][m] @ coefs[i][:, c] for c in range(3)], 1)
            pred[p["R"]] = p["fixed"] + p["Pw"] @ rad
        preds.append(pred)
        views.append((p["base"], p["target"], p["painted"], p["far"], pred))
    bases, tgts, pnt, fars = ([x[i] for x in views] for i in range(4))
    achieved, spill = stroke_effect(bases, tgts, pnt, preds)
    _, spill_far = stroke_effect(bases, tgts, [~f for f in fars], preds)
    return RegionOutcome(material, regions, res, sum(p["n"] for p in prep), int(sum(x.sum() for x in pnt)),
                         int(sum(len(p["R"]) for p in prep)), [], 0.0, achieved, spill, spill_far, False, views)


def region_notes(achieved, res: SolveResult, uncovered: int, painted: int, guided: bool = False) -> list[str]:
    """What a designer should know about a region fit that falls short."""
    notes = []
    if painted and uncovered > 0.2 * painted:
        notes.append(f"{uncovered} of {painted} painted pixels lie on triangles with no vertex under the brush: "
                     "a region is a per-vertex weight map, and the mesh is too coarse there for the stroke")
    if achieved is not None and achieved < 0.8 and res.constrained:
        hit = [ch for ch, a in zip("RGB", res.at_bound) if a]
        if hit:
            notes.append(f"{achieved * 100:.0f}% of the requested change: energy conservation caps the region's "
                         f"albedo in {'/'.join(hit)} (diffuse plus specular reflect at most all the light)")
        elif not guided:
            notes.append(f"{achieved * 100:.0f}% of the requested change: no non-negative BRDF of the region "
                         "reflects more of this lighting towards the eye there")
    return notes


def _take(smp, idx):
    return dataclasses.replace(smp, **{f.name: getattr(smp, f.name)[idx] for f in dataclasses.fields(smp)
                                       if getattr(smp, f.name) is not None})


def _vertex_samples(renderer, camera, obj: int, ids: np.ndarray):
    """The renderer's vertex samples (vertex-mode shading points) of vertices ``ids`` (global):
    vertex normal, direction to the eye, the vertex's own cut."""
    vs = renderer.vertex_samples(camera, obj)
    where = np.searchsorted(vs.pix, ids)
    where = np.minimum(where, len(vs.pix) - 1)
    if len(ids) and not np.array_equal(vs.pix[where], ids):
        raise FitError("a region pixel's corner is not among the vertices the view sees")
    return _take(vs, where)


def rendered_effect(renderer, obj: int, camera, lighting, before, after, strokes: list[Stroke],
                    shading: str = "vertex") -> dict:
    """How far a material change follows strokes in rendered frames (what the designer sees,
    not the fit's prediction): frames of the scene with the object in ``before`` and in
    ``after`` at the view's resolution; the target is ``before``'s frame with the strokes
    applied (eq. 23) at the object's pixel centres. Returns achieved (painted pixels), spill
    (every unpainted object pixel) and spill_far (object pixels farther than one brush diameter
    from every stroke), as brush.stroke_effect, and the pixel counts."""
    xy, (b, p), frames = object_frames(renderer, obj, camera, lighting, [before, after], shading)
    t = b.copy()
    painted = np.zeros(len(xy), bool)
    far = np.ones(len(xy), bool)
    for s in strokes:
        sw = stroke_weights(s, xy)
        apply_stroke(t, s, sw)
        painted |= sw > 0
        far &= polyline_distance(xy, np.asarray(s.points)) > s.diameter
    achieved, spill = stroke_effect([b], [t], [painted], [p])
    _, spill_far = stroke_effect([b], [t], [~far], [p])
    return {"achieved": achieved, "spill": spill, "spill_far": spill_far, "painted_pixels": int(painted.sum()),
            "far_pixels": int(far.sum()), "object_pixels": len(xy),
            "ms_render": frames[1].timings}


def object_frames(renderer, obj: int, camera, lighting, materials, shading: str = "vertex"):
    """Frames of the scene with object ``obj`` in each of ``materials`` (the other objects as
    the scene has them): ((P, 2) float64 centres of the pixels that see the object in the first
    frame, [(P, 3) float64 radiance there, one per material], [the Rendered frames])."""
    from ..renderers import FrameRequest

    mats = list(renderer.scene.materials)
    frames = []
    for m in materials:
        mats[obj] = m
        frames.append(renderer.render(FrameRequest(camera=camera, lighting=lighting, materials=list(mats),
                                                   shading=shading)))
    on = frames[0].object_id.reshape(-1) == obj
    yy, xx = np.divmod(np.nonzero(on)[0], camera.width)
    xy = np.stack([xx + 0.5, yy + 0.5], 1).astype(np.float64)
    return xy, [f.radiance.reshape(-1, 3)[on].astype(np.float64) for f in frames], frames
