"""Environment maps prefiltered per cosine lobe (cacad-cosine-lobes §5.1, eq. 7-9).

For a basis exponent E, the prefiltered map is the environment convolved with the normalised
cosine lobe:
    P_E(R) = (E+1)/(2π) ∫_{ω·R>0} (ω·R)^E L(ω) dω        (a constant map stays unchanged)
stored as an equirectangular map (docs/design/conventions.md mapping) and read bilinearly at R. The diffuse
map of eq. 9 is P_1: albedo·P_1(N) is exactly the Lambertian radiance albedo/π·E(N).

How (hierarchical, direct convolution; why not spherical harmonics: below):
  * the map is area-averaged into a pyramid (2×2 blocks, weighted by solid angle so a sun keeps
    its energy). Lobe E is computed at the coarsest level fine enough for it (``level_for``: at
    least 3 pixels per lobe width σ = 1/√E, 6 below the first downsampled level, 64 rows at
    least): wide lobes on a 128×64 map, the sharpest ones at the map's own resolution.
  * on an equirectangular grid, the kernel between an output row θo and an input row θj
    depends only on the column offset, so each (output row, input row) pair is a 1D circular
    convolution with a kernel tabulated once: no power function in the inner loop. Rows and
    columns beyond the lobe's support (cos^E < 1e-3 of its peak, 3.7σ) are skipped.
  * the result is normalised by the discrete kernel sum of its row, so a constant map is
    reproduced exactly (white furnace) whatever the resolution.
Spherical harmonics for the wide lobes would need (3√E)² coefficients and a projection of the
full map, and the clamped lobe converges slowly in them; the widest lobe runs on the 64-row level
(8K pixels), where the direct sum costs ~0.05 s and has no truncation error.
Wide lobes (E ≤ VECTOR_MAX_E) also get vector maps P_E[L·ω] (``LobeMaps.vec``, render.py).
Rotation about +Y commutes with a zonal convolution: maps are prefiltered once per environment
and rotated at lookup (a column offset), so the light slider costs nothing.

``prefilter_numpy`` is the reference (per output row, FFT over columns); the C kernel
``glp_prefilter`` (worker/native/src/paint.c) computes the same sums directly.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.lighting import prepare_map

SUPPORT = 1e-3           # kernel support: cos^E ≥ SUPPORT (must match GLP_SUPPORT in paint.c)
MIN_ROWS = 64
PIXELS_PER_SIGMA = 3.0

def _c(a, dtype) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=dtype)


def downsample(img: np.ndarray) -> np.ndarray:
    """2×2 area average of an equirectangular (H, W, 3) map, weighted by row solid angle."""
    h = img.shape[0]
    th = np.linspace(0, np.pi, h + 1)
    w = (np.cos(th[:-1]) - np.cos(th[1:]))[:, None, None]
    num = (img * w).reshape(h // 2, 2, img.shape[1] // 2, 2, 3).sum(axis=(1, 3))
    den = w.reshape(h // 2, 2, 1, 1).sum(axis=1) * 2
    return (num / den).astype(np.float32)


def pyramid(envmap: np.ndarray) -> list[np.ndarray]:
    """Level 0 = the prepared map (width ≤ 2048), each next level half the size, down to 8 rows."""
    lv = [prepare_map(envmap)]
    while lv[-1].shape[0] % 2 == 0 and lv[-1].shape[0] > 8 and lv[-1].shape[1] % 2 == 0:
        lv.append(downsample(lv[-1]))
    return lv


def level_for(exponent: float, levels: list[np.ndarray]) -> int:
    """The coarsest level with at least MIN_ROWS rows whose pixels are small enough for the lobe:
    σ/h ≥ PIXELS_PER_SIGMA at the map's own resolution and the first downsampled level, twice
    that on coarser levels (σ = 1/√E, h = π/rows). Deep box-averaging moves a bright source up to
    half a coarse pixel from where it is (the prefilter treats a coarse pixel as a point at its
    centre), which costs ~3% at σ/h = 4 three levels down, 0.4% one level down (tests/paint)."""
    sigma = 1.0 / np.sqrt(max(exponent, 1e-6))
    best = 0
    for i, m in enumerate(levels):
        need = PIXELS_PER_SIGMA * (1.0 if i <= 1 else 2.0)
        if sigma / (np.pi / m.shape[0]) >= need and m.shape[0] >= min(MIN_ROWS, levels[0].shape[0]):
            best = i
    return best


def support_cos(exponent: float) -> float:
    """cos of the kernel's support radius (cos^E = SUPPORT); 0 for wide lobes (hemisphere)."""
    return float(max(SUPPORT ** (1.0 / max(exponent, 1e-6)), 0.0))


def prefilter_numpy(img: np.ndarray, exponent: float) -> np.ndarray:
    """Reference: (H, W, 3) float32 map convolved with the normalised cosine lobe of exponent E
    (see module doc), per output row: kernels of every input row in the support, FFT-convolved
    over columns."""
    h, w, _ = img.shape
    th_e = np.linspace(0, np.pi, h + 1)
    th = 0.5 * (th_e[:-1] + th_e[1:])
    sa = (2 * np.pi / w) * (np.cos(th_e[:-1]) - np.cos(th_e[1:]))          # (H,) sr per pixel
    dphi = 2 * np.pi / w * np.arange(w)
    cmin = support_cos(exponent)
    rmax = np.arccos(cmin)
    F = np.fft.rfft(img.astype(np.float64), axis=1)                        # (H, W/2+1, 3)
    out = np.zeros((h, w, 3))
    for i in range(h):
        rows = np.nonzero(np.abs(th - th[i]) <= rmax + np.pi / h)[0]
        c = np.sin(th[i]) * np.sin(th[rows])[:, None] * np.cos(dphi)[None, :] + \
            np.cos(th[i]) * np.cos(th[rows])[:, None]
        k = np.where(c >= cmin, np.maximum(c, 0.0) ** exponent, 0.0) * sa[rows, None]   # (J, W)
        norm = k.sum()
        if norm <= 0:
            out[i] = img[i]
            continue
        # out[i, l] = Σ_j Σ_d k[j, d] img[j, l + d]  (correlation; k is even in d)
        kf = np.fft.rfft(k, axis=1)                                          # (J, W/2+1)
        acc = (np.conj(kf)[:, :, None] * F[rows]).sum(axis=0)
        out[i] = np.fft.irfft(acc, n=w, axis=0) / norm
    return out.astype(np.float32)


def prefilter(img: np.ndarray, exponent: float, kernels=None) -> np.ndarray:
    """One prefiltered map: img (H, W, 3) float32 -> (H, W, 3) float32 (glp_prefilter, or
    prefilter_numpy; kernels: the backend, default the process's)."""
    from ...native.kernels import kernels as _kernels

    img = np.ascontiguousarray(img, np.float32)
    if img.ndim != 3 or img.shape[-1] != 3:
        raise ValueError("img must be an (H, W, 3) map")
    return (kernels or _kernels()).paint.prefilter(img, float(exponent))


# Lobes this wide also get vector maps (render.py, cosine="vector"). 46 is the widest lobe that
# level_for still puts on the 128-row level ((128 / (6π))² = 46): a narrower lobe goes to the
# 256-row level, where its three vector channels cost 3× its map again (E = 55 and 75 took 3.8 of
# the basis's 6.6 CPU-seconds with 100 here), while its cosine varies little across it (σ ≤ 8.4°):
# the brute-force sphere test reads 1.23% at 46 against 1.24% at 100.
VECTOR_MAX_E = 46.0


@dataclass
class LobeMaps:
    """Prefiltered maps of one environment: ``maps[0]`` is the diffuse map P_1, ``maps[1:]`` the
    basis exponents' maps, each (H_i, W_i, 3) float32 at its own pyramid level.

    ``vec[i]`` (for the wide lobes, E ≤ VECTOR_MAX_E) is the (H_i, W_i, 9) float32 vector map
    P_E[L·ω] = (E+1)/(2π) ∫ max(0, ω·R)^E ω L(ω) dω, channels (x, y, z) × RGB: dotted with the
    normal it gives the lobe's cosine-weighted integral without approximating the cosine."""
    exponents: tuple[float, ...]          # (1, E_1, …, E_M)
    maps: list[np.ndarray]
    vec: dict = None

    def __post_init__(self):
        if self.vec is None:
            self.vec = {}

    def to_bytes(self) -> bytes:
        import io
        buf = io.BytesIO()
        np.savez(buf, exponents=np.asarray(self.exponents), **{f"m{i}": m for i, m in enumerate(self.maps)},
                 **{f"v{i}": v for i, v in self.vec.items()})
        return buf.getvalue()

    @staticmethod
    def from_bytes(b: bytes) -> "LobeMaps":
        import io
        z = np.load(io.BytesIO(b))
        ex = tuple(float(x) for x in z["exponents"])
        vec = {int(k[1:]): z[k] for k in z.files if k.startswith("v")}
        return LobeMaps(ex, [z[f"m{i}"] for i in range(len(ex))], vec)


def prefilter_all(envmap: np.ndarray, exponents, kernels=None, progress=None) -> LobeMaps:
    """The diffuse map, every basis exponent's map, and the wide lobes' vector maps (kernels:
    the backend, default the process's)."""
    from ...core.lighting import pixel_directions
    levels = pyramid(envmap)
    ex = (1.0,) + tuple(float(e) for e in exponents)
    maps, vec = [], {}
    for i, e in enumerate(ex):
        img = levels[level_for(e, levels)]
        maps.append(prefilter(img, e, kernels))
        if i > 0 and e <= VECTOR_MAX_E:
            d, _ = pixel_directions(img.shape[0], img.shape[1], 1)
            vec[i] = np.concatenate([prefilter(np.ascontiguousarray(img * d[..., c:c + 1], np.float32), e, kernels)
                                     for c in range(3)], axis=-1)
        if progress:
            progress(1)
    return LobeMaps(ex, maps, vec)
