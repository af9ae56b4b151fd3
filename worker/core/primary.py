"""Primary hits by face projection: the nearest face along every primary ray of a pinhole
camera, found by projecting the faces into the image instead of tracing the rays.

All primary rays start at the eye, so a face can only be met by the rays of the samples inside
its projection. Each face's projected bounds (the part of the face in front of the eye)
select those samples (the C kernel, row by row, only those within the projected polygon's span
on the row), and their rays are intersected with the face exactly (Möller–Trumbore,
double precision, with the very float32 directions ``core.render.camera_dirs`` gives the
tracer), keeping the nearest distance per sample: a z-buffer in ray distance t. The result is
the tracer's (face, Embree barycentrics (u, v), t) except for samples that lie on a shared edge
or a silhouette within rounding, where the neighbouring face (or a miss) may be reported
(tests/core/test_primary.py measures the agreement with Embree).

``primary_hits_numpy`` is the reference of the C kernel ``glk_primary_hits``
(worker/native/src/primary.c); ``primary_hits`` takes the kernel backend.
"""
from __future__ import annotations

import numpy as np

from ..native.kernels import kernels as _kernels
from .render import camera_axes, sample_offsets


def camera_params(eye, target, up, fov_y_deg: float, width: int, height: int) -> np.ndarray:
    """(14,) float64: eye, right, up, forward (unit world axes, the camera model of
    core.render.camera_rays) and the pixel scales W/(2·tan(fov/2)·aspect), H/(2·tan(fov/2))."""
    eye = np.asarray(eye, np.float64)
    right, true_up, fwd = camera_axes(eye, target, up)
    t = np.tan(np.radians(float(fov_y_deg)) / 2.0)
    w, h = float(width), float(height)
    return np.concatenate([eye, right, true_up, fwd, [w / (2.0 * t * (w / h)), h / (2.0 * t)]])


def primary_hits(vertices, faces, camera, samples: int, dirs, kernels=None, into=None):
    """(tri (H·W·S,) int32 face or −1, uv (H·W·S, 2) float32 Embree barycentrics
    (hit = (1−u−v)·v0 + u·v1 + v·v2), t (H·W·S,) float32 distance along the unit ray or +inf)
    of the primary rays ``dirs`` (H·W·S, 3) float32 of ``camera`` (eye, target, up, fov_y_deg,
    width, height) with ``samples`` S per pixel, against the mesh vertices (V, 3) float32,
    faces (F, 3) int32.

    into : (tri, uv, t, fbase) of hits already found (other geometry: C-contiguous arrays of
        the shapes above), updated in place where this mesh is nearer, its face f written as
        fbase + f; returned."""
    cam = camera_params(camera.eye, camera.target, camera.up, camera.fov_y_deg, camera.width, camera.height)
    omax = float(np.abs(sample_offsets(samples)).max())
    return (kernels or _kernels()).primary_hits(vertices, faces, cam, dirs, int(camera.width),
                                                int(camera.height), int(samples), omax, into)


def face_bounds_numpy(vertices, faces, cam) -> tuple[np.ndarray, np.ndarray]:
    """(box (F, 4) float64 x0, x1, y0, y1 continuous pixel coordinates of each face's projection
    clipped to the half-space in front of the eye; ok (F,) bool: some part is in front)."""
    v = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)] - cam[:3]      # (F, 3, 3)
    axes = cam[3:12].reshape(3, 3)                                                   # rows right, up, fwd
    q = v @ axes.T                                                                   # camera space
    near = 1e-7 * (np.abs(q[:, :, 2]).sum(1) + 1e-30)
    pts, oks = [], []
    for k in range(3):                     # Sutherland–Hodgman against z ≥ near: ≤ 2 points per edge
        a, b = q[:, k], q[:, (k + 1) % 3]
        ain, bin_ = a[:, 2] >= near, b[:, 2] >= near
        pts.append(a)
        oks.append(ain)
        s = (near - a[:, 2]) / np.where(ain != bin_, b[:, 2] - a[:, 2], 1.0)
        c = a + s[:, None] * (b - a)
        c[:, 2] = near
        pts.append(c)
        oks.append(ain != bin_)
    p = np.stack(pts, 1)                   # (F, 6, 3)
    ok = np.stack(oks, 1)                  # (F, 6)
    z = np.where(ok, p[:, :, 2], 1.0)
    px = (p[:, :, 0] / z) * cam[12]
    py = -(p[:, :, 1] / z) * cam[13]
    inf = np.inf
    box = np.stack([np.where(ok, px, inf).min(1), np.where(ok, px, -inf).max(1),
                    np.where(ok, py, inf).min(1), np.where(ok, py, -inf).max(1)], 1)
    return box, ok.any(1)


def primary_hits_numpy(vertices, faces, cam, dirs, width: int, height: int, samples: int, omax: float,
                       into=None):
    """Reference of glk_primary_hits: (tri, uv, t) as ``primary_hits``; cam (14,) float64 from
    ``camera_params``; omax the largest sub-pixel offset |x| or |y| of the samples, in pixels;
    into as ``primary_hits``'s (kept where not farther)."""
    if into is not None:
        tri0, uv0, t0, fbase = into
        tri, uv, t = primary_hits_numpy(vertices, faces, cam, dirs, width, height, samples, omax)
        p = np.nonzero((tri >= 0) & (t < t0))[0]
        tri0[p] = fbase + tri[p]
        uv0[p] = uv[p]
        t0[p] = t[p]
        return tri0, uv0, t0
    W, H, S = int(width), int(height), int(samples)
    V = np.asarray(vertices, np.float32)
    Fa = np.asarray(faces, np.int64)
    D = np.asarray(dirs, np.float32).astype(np.float64)
    P = W * H * S
    tri = np.full(P, -1, np.int32)
    uv = np.zeros((P, 2), np.float32)
    t = np.full(P, np.inf, np.float32)
    box, ok = face_bounds_numpy(V, Fa, cam)
    box[:, 0:2] += 0.5 * W
    box[:, 2:4] += 0.5 * H
    mg = omax + 0.01
    ok &= ~((box[:, 1] < -mg) | (box[:, 0] > W + mg) | (box[:, 3] < -mg) | (box[:, 2] > H + mg))
    fi = np.nonzero(ok)[0]
    if len(fi) == 0:
        return tri, uv, t
    # the pixels whose centre x + ½ lies within the bounds widened by mg (an empty range for a
    # face between two sample centres)
    c0 = np.clip(np.ceil(box[fi, 0] - 0.5 - mg), 0, None).astype(np.int64)
    c1 = np.clip(np.floor(box[fi, 1] - 0.5 + mg), None, W - 1).astype(np.int64)
    r0 = np.clip(np.ceil(box[fi, 2] - 0.5 - mg), 0, None).astype(np.int64)
    r1 = np.clip(np.floor(box[fi, 3] - 0.5 + mg), None, H - 1).astype(np.int64)
    nw, nh = np.maximum(c1 - c0 + 1, 0), np.maximum(r1 - r0 + 1, 0)
    cnt = nw * nh
    # every (face, pixel of its bounds) pair, then its S samples
    f = np.repeat(fi, cnt)
    start = np.repeat(np.cumsum(cnt) - cnt, cnt)
    j = np.arange(len(f)) - start
    w_ = np.repeat(nw, cnt)
    x = np.repeat(c0, cnt) + j % np.maximum(w_, 1)
    y = np.repeat(r0, cnt) + j // np.maximum(w_, 1)
    row = ((y * W + x)[:, None] * S + np.arange(S)[None, :]).ravel()
    f = np.repeat(f, S)
    A, B, C = (V[Fa[f, k]].astype(np.float64) for k in range(3))
    e1, e2 = B - A, C - A
    s = cam[:3] - A
    d = D[row]
    p = np.cross(d, e2)
    det = (p * e1).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        q = np.cross(s, e1)
        u = (p * s).sum(1) * inv
        v = (q * d).sum(1) * inv
        tt = (q * e2).sum(1) * inv
    hit = (det != 0) & (u >= 0) & (u <= 1) & (v >= 0) & (u + v <= 1) & (tt > 0)
    row, f, u, v, tt = row[hit], f[hit], u[hit], v[hit], tt[hit]
    # nearest per sample; equal distances: the lower face index (the C kernel's first-found order)
    o = np.lexsort((f, tt, row))
    row, f, u, v, tt = row[o], f[o], u[o], v[o], tt[o]
    first = np.ones(len(row), bool)
    first[1:] = row[1:] != row[:-1]
    row, f, u, v, tt = row[first], f[first], u[first], v[first], tt[first]
    tri[row] = f
    uv[row, 0], uv[row, 1] = u, v
    t[row] = tt
    return tri, uv, t
