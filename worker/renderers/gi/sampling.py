"""Direction sampling for the tensor precomputation (polynomial-gi §5.1), NumPy references of
the sampling in worker/native/src/gi.c.

* The environment is importance-sampled by luminance at every path vertex: a piecewise-constant
  distribution over texels (luminance × sin θ), sampled by inverting the row marginal and the
  row's conditional CDF, then uniformly within the texel. The luminance is max-filtered over
  each texel's 3×3 neighbourhood, so the pdf is positive wherever the bilinear lookup is.
* The BRDF is unknown at precomputation, so continuation directions come from a fixed mixture:
  70 % cosine-weighted, 30 % a Blinn lobe of exponent 200 around the mirror direction (the
  paper's choice). Both pdfs are known for any direction, which makes multiple importance
  sampling (balance heuristic) between light and mixture samples BRDF-independent.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import maximum_filter

MIX_DIFFUSE = 0.7
GLOSS_EXPONENT = 200.0


class EnvDistribution:
    """Luminance distribution of an equirectangular map (docs/design/conventions.md mapping).

    row_cdf : (H + 1,) float64, col_cdf : (H, W + 1) float64, texel_pdf : (H, W) float64
    (probability of each texel, sums to 1); rotation_deg as Mitsuba's envmap to_world.
    """

    def __init__(self, envmap: np.ndarray, rotation_deg: float = 0.0):
        H, W, _ = envmap.shape
        lum = envmap[..., 0] * 0.2126 + envmap[..., 1] * 0.7152 + envmap[..., 2] * 0.0722
        lum = maximum_filter(np.maximum(lum, 0.0).astype(np.float64), size=3, mode=("nearest", "wrap"))
        theta = (np.arange(H) + 0.5) / H * np.pi
        w = lum * np.sin(theta)[:, None]
        if not np.isfinite(w).all() or w.sum() <= 0:
            w = np.sin(theta)[:, None] * np.ones((1, W))     # a black map: sample uniformly
        w = w + 1e-6 * w.mean()                              # every texel reachable
        self.H, self.W = H, W
        self.rotation = float(rotation_deg) / 360.0
        self.texel_pdf = w / w.sum()
        rows = self.texel_pdf.sum(1)
        self.row_cdf = np.concatenate([[0.0], np.cumsum(rows)])
        self.row_cdf /= self.row_cdf[-1]
        cc = np.cumsum(self.texel_pdf, axis=1)
        self.col_cdf = np.concatenate([np.zeros((H, 1)), cc / cc[:, -1:]], axis=1)
        self._flat = (self.col_cdf[:, 1:] + np.arange(H)[:, None]).ravel()
        for a in (self.texel_pdf, self.row_cdf, self.col_cdf):
            a.setflags(write=False)

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """u (R, 4) uniforms -> (directions (R, 3) float64 unit, pdf (R,) per steradian)."""
        r = np.clip(np.searchsorted(self.row_cdf, u[:, 0], side="right") - 1, 0, self.H - 1)
        # every row's CDF shifted by its row index makes one increasing array
        c = np.searchsorted(self._flat, r + u[:, 1], side="right") - r * self.W
        c = np.clip(c, 0, self.W - 1)
        uu = (c + u[:, 2]) / self.W
        vv = (r + u[:, 3]) / self.H
        d = self.direction(uu, vv)
        return d, self.pdf(d)

    def direction(self, uu, vv) -> np.ndarray:
        """Map coordinates (u, v) ∈ [0, 1)² -> world directions (inverse of env_lookup)."""
        th = vv * np.pi
        ph = 2 * np.pi * (uu - self.rotation)
        st = np.sin(th)
        return np.stack([st * np.sin(ph), np.cos(th), -st * np.cos(ph)], -1)

    def pdf(self, d: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (R,) of world directions d (R, 3)."""
        y = np.clip(d[:, 1], -1.0, 1.0)
        th = np.arccos(y)
        st = np.sin(th)
        uu = np.mod(np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi) + self.rotation, 1.0)
        c = np.clip((uu * self.W).astype(np.int64), 0, self.W - 1)
        r = np.clip((th / np.pi * self.H).astype(np.int64), 0, self.H - 1)
        return np.where(st > 1e-9, self.texel_pdf[r, c] * self.W * self.H / (2 * np.pi ** 2 * np.maximum(st, 1e-9)), 0.0)


def local_frame(n: np.ndarray):
    """(t, b) tangents of unit normals (R, 3), the frame of worker.core.brdf.onb."""
    from ...core.brdf import onb
    return onb(n)


def sample_mixture(n: np.ndarray, wo: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directions from the BRDF-independent mixture at shading normals n (R, 3) seen from wo
    (R, 3): u (R, 3) uniforms (choice, u1, u2) -> (d (R, 3) world unit, pdf (R,))."""
    t, b = local_frame(n)
    phi = 2 * np.pi * u[:, 2]
    diff = u[:, 0] < MIX_DIFFUSE
    # cosine: z = sqrt(1 - u1); gloss: h with cos θh = u1^(1/(e+1)), d = reflect(wo, h)
    z_c = np.sqrt(np.maximum(1.0 - u[:, 1], 0.0))
    z_g = u[:, 1] ** (1.0 / (GLOSS_EXPONENT + 1.0))
    z = np.where(diff, z_c, z_g)
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    loc = r[:, None] * (np.cos(phi)[:, None] * t + np.sin(phi)[:, None] * b) + z[:, None] * n
    refl = 2.0 * (wo * loc).sum(1, keepdims=True) * loc - wo
    d = np.where(diff[:, None], loc, refl)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-30)
    return d, pdf_mixture(n, wo, d)


def pdf_mixture(n: np.ndarray, wo: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Solid-angle pdf of the mixture for directions d (R, 3); 0 below the shading horizon."""
    cd = (n * d).sum(1)
    hv = d + wo
    h = hv / np.maximum(np.linalg.norm(hv, axis=1, keepdims=True), 1e-30)
    ch = np.clip((n * h).sum(1), 0.0, 1.0)
    oh = (wo * h).sum(1)
    pg = (GLOSS_EXPONENT + 1.0) / (2 * np.pi) * ch ** GLOSS_EXPONENT / np.maximum(4.0 * oh, 1e-12)
    p = MIX_DIFFUSE * np.maximum(cd, 0.0) / np.pi + (1.0 - MIX_DIFFUSE) * np.where(oh > 0, pg, 0.0)
    return np.where(cd > 0, p, 0.0)
