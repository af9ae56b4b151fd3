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

from ..models.regions import Region, Regions, has_regions
from ..scene import SRBF
from .basis import DEFAULT_NL
from .brush import DEFAULT_UNPAINTED_WEIGHT, Stroke, apply_stroke, polyline_distance, stroke_effect, stroke_weights
from .fitter import FitError, Fitter
from .guidance import guidance_notes, highlight_guidance
from .solve import FitRows, SolveResult, solve

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
            vs = fx.renderer.vertex_samples(cam, fx.obj)
            xy, front = project(cam, vs.positions)
            seen[s.view] = (vs.pix[front].astype(np.int64) - off, xy[front])
        ids, xy = seen[s.view]
        d = polyline_distance(xy, np.asarray(s.points))
        np.maximum.at(w, ids, region_weight(s, d).astype(np.float32))
    return w


@dataclass
class RegionOutcome:
    """A region fit's result. material : the object's new material (``regions``); region : the
    region made or extended; achieved : share of the requested change delivered on the painted
    pixels; spill : relative change of every unpainted pixel; spill_far : that of the pixels
    farther than one brush diameter from every stroke (brush.stroke_effect; vertex-mode
    radiance, as the cut renderer draws the object)."""
    material: Regions
    region: Region
    solve: SolveResult
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

    def report(self) -> dict:
        """The ``regions`` entry of ``glint fit --json``."""
        r = self.region
        w = np.asarray(r.weights)
        return {"name": r.name, "extended": self.extended, "vertices": len(r.vertices),
                "full_weight_vertices": int((w >= 0.999).sum()), "model": r.material.model}


def _below(material, name: str):
    """What lies under a region named ``name`` once it is (re)painted on top: the material
    without that region (its base when it was the only one)."""
    if not has_regions(material):
        return material
    rest = [r for r in material.regions if r.name != name]
    if not rest:
        return material.base
    return Regions(base=material.base, vertex_count=material.vertex_count, regions=rest)


def _strokes_by_view(fx: Fitter):
    out = {}
    for s in fx.history.strokes:
        out.setdefault(s.view, []).append(s)
    return out


def fit_region(fx: Fitter, name: str = "region 1", unpainted_weight: float = DEFAULT_UNPAINTED_WEIGHT,
               fit_albedo: bool = DEFAULT_REGION_ALBEDO, constrained: bool = True, n_l: int = DEFAULT_NL) -> RegionOutcome:
    """Make (or extend, when the fitter's base material has a region of that name) a region from
    the fitter's strokes and fit its material (module doc). The rest of the object keeps the
    fitter's base material. Returns a RegionOutcome whose ``material`` is the object's new
    material: the base with the region on top."""
    if not fx.views:
        raise FitError("no view saved: add_view() first")
    strokes = fx.history.strokes
    if not strokes:
        raise FitError("no stroke to make a region from")
    if unpainted_weight < 0:
        raise FitError("unpainted_weight must be ≥ 0")
    r = fx.renderer
    off, n_o = object_range(r, fx.obj)
    cur = fx.base_material
    old = next((g for g in cur.regions if g.name == name), None) if has_regions(cur) else None
    w = footprint_weights(fx, strokes)
    if old is not None:                           # extending: the old footprint stays painted
        w = np.maximum(w, old.dense(n_o))
    if not np.any(w > 0):
        raise FitError(f"the strokes touch no vertex of object {fx.object_name!r} the views see")
    below = _below(cur, name)
    by_view = _strokes_by_view(fx)
    rows, views, t_transfer = [], [], 0.0
    n_painted = n_pix = 0
    uncovered = 0
    for vi, v in enumerate(fx.views):
        t0 = time.perf_counter()
        verts = v.samples.verts.astype(np.int64)              # (N, 3) global vertex (cut) ids
        wc = w[verts - off]                                   # (N, 3) the corners' region weights
        R = np.nonzero((wc > 0).any(1))[0]
        K, inv = np.unique(verts[R], return_inverse=True)     # the corner vertices of those pixels
        inv = inv.reshape(-1, 3)
        vs = _vertex_samples(r, v.camera, fx.obj, K)
        L_cur = r.shade_samples(vs, cur, fx.obj, v.lighting)
        L_below = L_cur if below is cur else r.shade_samples(vs, below, fx.obj, v.lighting)
        wk = w[K - off]
        live = np.nonzero(wk > 0)[0]                          # transfer rows only where the region is
        T, E = r.transfer(_take(vs, live), fx.basis, v.lighting)
        b = v.samples.bary[R].astype(np.float64)
        bw = b * wc[R]
        nR = len(R)
        rowsR = np.repeat(np.arange(nR), 3)
        # pixels × corner vertices: barycentric weight, and times the region's weight
        Pb = sp.csr_matrix((b.reshape(-1), (rowsR, inv.reshape(-1))), shape=(nR, len(K)))
        pos = np.full(len(K), -1)
        pos[live] = np.arange(len(live))
        kk = pos[inv.reshape(-1)]
        keep = kk >= 0
        Pw = sp.csr_matrix((bw.reshape(-1)[keep], (rowsR[keep], kk[keep])), shape=(nR, len(live)))
        cur_R = Pb @ L_cur                                     # what the pixel shows now (vertex mode)
        fixed = Pb @ L_below - Pw @ L_below[live]              # Σ b (1 − w) L_below
        Tp = np.stack([np.asarray(Pw @ T[c].astype(np.float64), np.float32) for c in range(3)])
        Ep = np.asarray(Pw @ E.astype(np.float64), np.float32)
        t_transfer += time.perf_counter() - t0
        base = v.base.copy()
        base[R] = cur_R
        tgt = base.copy()
        painted = np.zeros(v.n, bool)
        far = np.ones(v.n, bool)
        for s in by_view.get(vi, []):
            sw = stroke_weights(s, v.xy, v.footprint)
            apply_stroke(tgt, s, sw)
            painted |= sw > 0
            far &= polyline_distance(v.xy, np.asarray(s.points)) > s.diameter
        uncovered += int((painted & ~(wc > 0).any(1)).sum())
        wt = np.where(painted[R], 1.0, unpainted_weight)
        rows.append(FitRows(Tp, Ep, tgt[R] - fixed, wt))
        views.append([base, tgt, painted, far, R, fixed, Tp, Ep])
        n_painted += int(painted.sum())
        n_pix += v.n
    if not any(np.any(x.weight > 0) for x in rows if len(x.weight)):
        raise FitError("nothing to fit: the region covers no painted pixel and unpainted_weight is 0")
    rows = [x for x in rows if len(x.weight)]
    albedo = np.asarray(below.albedo, np.float64)
    res = solve(rows, fx.basis, albedo, constrained=constrained, n_l=n_l, prior=None, fit_albedo=fit_albedo)
    mat = SRBF.model_validate(fx.basis.to_material(res.coefficients, res.albedo))
    ids = np.nonzero(w > 0)[0]
    region = Region(name=name, material=mat, vertices=ids.tolist(), weights=np.round(w[ids].astype(np.float64), 6).tolist())
    base_mat = cur if has_regions(cur) else None
    material = (base_mat.with_region(region) if base_mat is not None
                else Regions(base=cur, vertex_count=n_o, regions=[region]))
    preds, out_views = [], []
    for base, tgt, painted, far, R, fixed, Tp, Ep in views:
        pred = base.copy()
        pred[R] = fixed + res.albedo * Ep + np.stack([Tp[c] @ res.coefficients[:, c] for c in range(3)], 1)
        preds.append(pred)
        out_views.append((base, tgt, painted, far, pred))
    bases, tgts, pnt, fars = ([x[i] for x in out_views] for i in range(4))
    achieved, spill = stroke_effect(bases, tgts, pnt, preds)
    _, spill_far = stroke_effect(bases, tgts, [~f for f in fars], preds)
    guide = _guidance(fx, out_views)
    told = guidance_notes(guide, achieved)
    notes = region_notes(achieved, res, uncovered, n_painted, guided=bool(told)) + told
    return RegionOutcome(material, region, res, n_pix, n_painted, int(sum(len(x.weight) for x in rows)), notes,
                         t_transfer, achieved, spill, spill_far, old is not None, out_views, guide)


def _guidance(fx: Fitter, views) -> dict | None:
    """highlight_guidance over the painted pixels of the first view with any."""
    for v, (base, tgt, painted, _, _) in zip(fx.views, views):
        if painted.any():
            s = v.samples
            return highlight_guidance(fx.renderer.lighting.map, v.rotation_deg, v.intensity, s.normals[painted],
                                      s.wo[painted], tgt[painted], base[painted])
    return None


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
    return dataclasses.replace(smp, **{f.name: getattr(smp, f.name)[idx] for f in dataclasses.fields(smp)})


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
    from ..renderers import FrameRequest

    mats = list(renderer.scene.materials)
    frames = []
    for m in (before, after):
        mats[obj] = m
        frames.append(renderer.render(FrameRequest(camera=camera, lighting=lighting, materials=list(mats),
                                                   shading=shading)))
    on = frames[0].object_id.reshape(-1) == obj
    h, w = camera.height, camera.width
    yy, xx = np.divmod(np.nonzero(on)[0], w)
    xy = np.stack([xx + 0.5, yy + 0.5], 1).astype(np.float64)
    b = frames[0].radiance.reshape(-1, 3)[on].astype(np.float64)
    p = frames[1].radiance.reshape(-1, 3)[on].astype(np.float64)
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
            "far_pixels": int(far.sum()), "object_pixels": int(on.sum()),
            "ms_render": frames[1].timings}
