"""Per-pixel shading by summing prefiltered lobe maps (cacad-cosine-lobes §5.2, eq. 7-9).

For a pixel with unit normal N and unit view direction V (towards the eye), R = 2(N·V)N − V,
μ = N·V = N·R, and a lobes material (albedo, gloss g_i, directional diffuse dd_i, exponents E_i):

    L = albedo · P_1(N) · V_0                                                      (eq. 9)
      + Σ_i (g_i·Fg + dd_i·Fd) · c_i(μ) · P_Ei(R) · V_i                              (eq. 7-8)

P_E are the prefiltered maps (prefilter.py). The exact lobe term is
    w (E+2)/(2π) ∫_{ω·N>0} max(0, ω·R)^E (ω·N) L(ω) dω,
and a 2D map cannot hold a function of both R and N, so the cosine (ω·N) is approximated:
  * ``cosine="paper"`` — the paper's eq. 7: the cosine is taken at the lobe's centre,
    ω·N ≈ R·N, and the horizon is ignored: c(μ) = (E+2)/(E+1)·μ. For narrow lobes this is exact
    in the limit; for wide ones it overestimates by up to (E+2)/(E+1) (1.5× for E = 1: the
    cosine averaged over a wide lobe is smaller than at its centre) and misses the horizon.
  * ``cosine="albedo"`` — the cosine and the horizon are averaged over the lobe:
    c(μ) = A_E(μ) = (E+2)/(2π) ∫_{ω·N>0} max(0, ω·R)^E (ω·N) dω, the lobe's directional albedo,
    tabulated per exponent (64 values of μ, closed-form inner integral). It is exact for any
    lobe under uniform light (white furnace) and equal to the paper's factor for sharp lobes; it
    misses the correlation between the light and the cosine inside a wide lobe (a low sun).
  * ``cosine="vector"`` (default) — as "albedo" for the sharp lobes; the wide ones
    (E ≤ prefilter.VECTOR_MAX_E) use vector maps P_E[L·ω] (prefilter.py), so the cosine is exact
    on the part of the lobe above the horizon:
        ∫ lobe·max(0, ω·N)·L = N·∫ lobe·ω·L + ∫ lobe·max(0, −ω·N)·L
                             ≈ (E+2)/(E+1)·N·P_E[L·ω](R) + (A_E(μ) − μ)·P_E(R)
    (the lobe's part below the horizon, A_E(μ) − μ of its albedo, keeps the averaged form).
The paper's gloss (eq. 8) has no cosine because its gloss lobe is not reciprocal; Glint's lobes
are, so the gloss takes the same factor as the directional diffuse.
Fresnel (§5.3, "increase the weights of the high-exponent maps at grazing angles"): the gloss
(first-surface) weights are scaled by F(μ)/F0 and the directional-diffuse ones (light that
crossed the clearcoat) by (1 − F(μ))/(1 − F0), Schlick's F with F0 = 0.04 (index 1.5). The fitted
weights then hold at the measurement geometries (F(20°) ≈ F(45°) ≈ F0 within 5%).
V_i is the lobe-weighted visibility (visibility.py), 1 without it.

``shade_numpy`` is the reference of the C kernel ``glp_shade`` (worker/native/src/paint.c).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from .prefilter import LobeMaps

F0 = 0.04
TABLE_N = 64
COSINE_MODES = {"albedo": 0, "paper": 1, "vector": 2}


@lru_cache(maxsize=64)
def lobe_albedo(exponent: float, n: int = TABLE_N) -> np.ndarray:
    """(n,) A_E(μ) at μ = linspace(0, 1, n): (E+2)/(2π) ∫_{ω·N>0} max(0, ω·R)^E (ω·N) dω.

    In coordinates about R (t = ω·R, β the azimuth), ω·N = μ t + √(1−μ²)√(1−t²) cos β; the β
    integral of max(0, a + b cos β) is closed-form, t is integrated by Gauss-Legendre in
    s = t^(E+1) (which absorbs the t^E weight)."""
    mu = np.linspace(0.0, 1.0, n)
    x, w = np.polynomial.legendre.leggauss(200)
    s = 0.5 * (x + 1.0); ws = 0.5 * w
    t = s ** (1.0 / (exponent + 1.0))
    a = mu[:, None] * t[None, :]
    b = np.sqrt(1 - mu[:, None] ** 2) * np.sqrt(np.maximum(1 - t[None, :] ** 2, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        b0 = np.arccos(np.clip(-a / np.where(b > 0, b, 1.0), -1.0, 1.0))
        inner = np.where(a >= b, 2 * np.pi * a, np.where(a <= -b, 0.0, 2 * (a * b0 + b * np.sin(b0))))
    return (exponent + 2.0) / (2.0 * np.pi * (exponent + 1.0)) * (inner * ws[None, :]).sum(axis=1)


def cosine_tables(exponents) -> np.ndarray:
    """(len(exponents), TABLE_N) float32 tables A_E(μ) for the maps' exponents."""
    return np.stack([lobe_albedo(float(e)) for e in exponents]).astype(np.float32)


def zonal(exponents) -> np.ndarray:
    """(len, 3) float32 normalised zonal SH coefficients (l = 0, 1, 2) of the cosine lobes
    max(0, t)^E: 1, (E+1)/(E+2), (3(E+1)/(E+3) − 1)/2."""
    e = np.asarray(exponents, np.float64)
    return np.stack([np.ones_like(e), (e + 1) / (e + 2), 0.5 * (3 * (e + 1) / (e + 3) - 1)], axis=1).astype(np.float32)


def material_rows(materials, exponents) -> np.ndarray:
    """(n_mat, 3 + 4M) float32 table: albedo, then per lobe (g, dd_r, dd_g, dd_b). Every material
    must be a scene.Lobes on exactly these exponents (renderer.as_basis converts the others)."""
    m = len(exponents)
    rows = np.zeros((len(materials), 3 + 4 * m), np.float32)
    for k, mat in enumerate(materials):
        if tuple(float(e) for e in mat.exponents) != tuple(float(e) for e in exponents):
            raise ValueError("material exponents differ from the renderer's basis")
        rows[k, :3] = mat.albedo
        for i in range(m):
            rows[k, 3 + 4 * i] = mat.gloss[i]
            rows[k, 4 + 4 * i: 7 + 4 * i] = mat.directional_diffuse[i]
    return rows


def _lookup(img: np.ndarray, d: np.ndarray, rot_rad: float) -> np.ndarray:
    u = np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi)
    v = np.arccos(np.clip(d[:, 1], -1, 1)) / np.pi
    return _bilerp(img, u, v, rot_rad)


def _bilerp(img: np.ndarray, u: np.ndarray, v: np.ndarray, rot_rad: float) -> np.ndarray:
    hm, wm = img.shape[:2]
    u = u + rot_rad / (2 * np.pi)
    u = u - np.floor(u)
    fx, fy = u * wm - 0.5, v * hm - 0.5
    x0, y0 = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
    ax, ay = (fx - x0)[:, None], (fy - y0)[:, None]
    x1 = (x0 + 1) % wm; x0 = x0 % wm
    y1 = np.clip(y0 + 1, 0, hm - 1); y0 = np.clip(y0, 0, hm - 1)
    a = img[y0, x0] * (1 - ax) + img[y0, x1] * ax
    b = img[y1, x0] * (1 - ax) + img[y1, x1] * ax
    return a * (1 - ay) + b * ay


def sh9(d: np.ndarray) -> np.ndarray:
    """(…, 9) real SH basis l ≤ 2 at unit directions (…, 3) (order as glp_sh9 in paint.c)."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.stack([np.full_like(x, 0.28209479177387814), 0.4886025119029199 * y, 0.4886025119029199 * z,
                     0.4886025119029199 * x, 1.0925484305920792 * x * y, 1.0925484305920792 * y * z,
                     0.31539156525252005 * (3 * z * z - 1), 1.0925484305920792 * x * z,
                     0.5462742152960396 * (x * x - y * y)], axis=-1)


def _vis(vsh: np.ndarray, y: np.ndarray, zon: np.ndarray) -> np.ndarray:
    zl = zon[[0, 1, 1, 1, 2, 2, 2, 2, 2]]
    num = (zl * vsh[:, :9] * y).sum(1)
    den = (zl * vsh[:, 9:] * y).sum(1)
    r = np.clip(num / np.where(den > 1e-6, den, 1.0), 0.0, 1.0)
    return np.where(den > 1e-6, r, 1.0)


def _map_normal(n: np.ndarray, rot_rad: float) -> np.ndarray:
    """World normals in the rotated map's frame (φ + rotation), for dotting with vector maps."""
    c, s = np.cos(rot_rad), np.sin(rot_rad)
    return np.stack([n[:, 0] * c - n[:, 2] * s, n[:, 1], n[:, 2] * c + n[:, 0] * s], axis=1)


def shade_numpy(normals, views, mat_of, rows, maps: LobeMaps, cosine: str = "vector", fresnel: bool = False,
                vsh=None, rotation_deg: float = 0.0, intensity: float = 1.0) -> np.ndarray:
    """Reference of glp_shade: (P, 3) float32 radiance for unit normals and view directions
    (P, 3), material index per pixel (P,) (−1: not shaded), material rows (material_rows),
    optional per-pixel visibility SH (P, 18)."""
    n = np.asarray(normals, np.float64); v = np.asarray(views, np.float64)
    out = np.zeros((len(n), 3))
    sel = np.asarray(mat_of) >= 0
    n, v, w = n[sel], v[sel], np.asarray(rows, np.float64)[np.asarray(mat_of)[sel]]
    nv = (n * v).sum(1)
    r = 2 * nv[:, None] * n - v
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    mu = np.clip(nv, 0.0, 1.0)
    rot = np.radians(rotation_deg)
    fg = fd = np.ones_like(mu)
    if fresnel:
        F = F0 + (1 - F0) * (1 - mu) ** 5
        fg, fd = F / F0, (1 - F) / (1 - F0)
    ex = maps.exponents
    zon = zonal(ex).astype(np.float64)
    vs = None if vsh is None else np.asarray(vsh, np.float64)[sel]
    v0 = 1.0 if vs is None else _vis(vs, sh9(n), zon[0])[:, None]
    acc = w[:, :3] * _lookup(maps.maps[0], n, rot) * v0
    tabs = cosine_tables(ex)
    for i in range(len(ex) - 1):
        e = ex[i + 1]
        wgt = w[:, 3 + 4 * i: 4 + 4 * i] * fg[:, None] + w[:, 4 + 4 * i: 7 + 4 * i] * fd[:, None]
        vi = 1.0 if vs is None else _vis(vs, sh9(r), zon[i + 1])[:, None]
        a = np.interp(mu, np.linspace(0, 1, TABLE_N), tabs[i + 1])
        if cosine == "paper":
            val = ((e + 2) / (e + 1) * mu)[:, None] * _lookup(maps.maps[i + 1], r, rot)
        elif cosine == "vector" and (i + 1) in maps.vec:
            iv = _lookup(maps.vec[i + 1], r, rot).reshape(-1, 3, 3)          # (P, xyz, rgb)
            nd = (_map_normal(n, rot)[:, :, None] * iv).sum(1)
            val = (e + 2) / (e + 1) * nd + (a - mu)[:, None] * _lookup(maps.maps[i + 1], r, rot)
        else:
            val = a[:, None] * _lookup(maps.maps[i + 1], r, rot)
        acc += wgt * val * vi
    out[sel] = intensity * acc
    return out.astype(np.float32)


def _into(out: np.ndarray | None, dst: np.ndarray | None, n: int):
    """The (…, 3) float32 buffer a kernel writes (out, whole) and its destination rows (dst)."""
    if out is None:
        return np.zeros((n, 3), np.float32), None
    if out.dtype != np.float32 or not out.flags.c_contiguous or out.shape[-1] != 3:
        raise ValueError("out must be a C-contiguous float32 (…, 3) array")
    if dst is None or len(dst) != n:
        raise ValueError("out needs dst: one destination row per point")
    return out, np.ascontiguousarray(dst, np.int64)


def background(uv: np.ndarray, envmap: np.ndarray, rotation_deg: float = 0.0, intensity: float = 1.0,
               kernels=None, out: np.ndarray | None = None, dst: np.ndarray | None = None) -> np.ndarray:
    """(P, 3) float32 environment radiance at precomputed unrotated map coordinates uv (P, 2)
    (a camera's background pixels: only the rotation changes between frames; degrees about +Y).
    With ``out`` (an image as (N, 3) float32) and ``dst`` (P,) pixel indices, written straight
    into it. kernels: the backend (glp_background or background_numpy), default the process's."""
    from ...native.kernels import kernels as _kernels

    buf, d = _into(out, dst, len(uv))
    return (kernels or _kernels()).paint.background(uv, envmap, float(rotation_deg), float(intensity), buf, d)


def background_numpy(uv, envmap, rotation_deg: float, intensity: float, buf: np.ndarray, d) -> np.ndarray:
    """Reference of glp_background (``background`` with its buffer and destination rows)."""
    uv = np.asarray(uv, np.float64)
    val = intensity * _bilerp(envmap, uv[:, 0], uv[:, 1], np.radians(rotation_deg))
    if d is None:
        buf[:] = val
    else:
        buf.reshape(-1, 3)[d] = val
    return buf


def _packed(maps: LobeMaps):
    """The maps concatenated for the kernel, with offsets, sizes, cosine tables and zonal factors;
    built once per LobeMaps (a frame must not copy the maps)."""
    cached = getattr(maps, "_packed", None)
    if cached is None:
        flat = np.concatenate([np.ascontiguousarray(m, np.float32).reshape(-1) for m in maps.maps])
        sizes = [m.size for m in maps.maps]
        offs = np.zeros(len(sizes), np.int64); offs[1:] = np.cumsum(sizes)[:-1]
        hs = np.array([m.shape[0] for m in maps.maps], np.int32)
        ws = np.array([m.shape[1] for m in maps.maps], np.int32)
        ex = maps.exponents
        vparts, voffs, pos = [], np.full(len(maps.maps), -1, np.int64), 0
        for i, v in sorted(maps.vec.items()):
            voffs[i] = pos
            vparts.append(np.ascontiguousarray(v, np.float32).reshape(-1))
            pos += v.size
        vflat = np.concatenate(vparts) if vparts else np.zeros(1, np.float32)
        cached = (flat, offs, hs, ws, np.ascontiguousarray(cosine_tables(ex), np.float32),
                  np.ascontiguousarray(zonal(ex), np.float32), np.asarray(ex, np.float32), vflat, voffs)
        maps._packed = cached
    return cached


def shade(normals, views, mat_of, rows, maps: LobeMaps, cosine: str = "vector", fresnel: bool = False,
          vsh=None, rotation_deg: float = 0.0, intensity: float = 1.0, kernels=None,
          out: np.ndarray | None = None, dst: np.ndarray | None = None) -> np.ndarray:
    """(P, 3) float32 radiance (glp_shade or shade_numpy, by the backend ``kernels``, default
    the process's; rotation in degrees about +Y). With ``out`` (an image as (N, 3) float32) and
    ``dst`` (P,) pixel indices, written straight into it."""
    from ...native.kernels import kernels as _kernels

    if cosine not in COSINE_MODES:
        raise ValueError(f"cosine must be one of {sorted(COSINE_MODES)}")
    buf, d = _into(out, dst, len(normals))
    return (kernels or _kernels()).paint.shade(normals, views, mat_of, rows, maps, cosine, fresnel, vsh,
                                               float(rotation_deg), float(intensity), buf, d)
