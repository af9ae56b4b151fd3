"""The ground shadow: an invisible shadow-catcher plane under the objects.

What a shopper knows from product viewers (model-viewer's ``shadow-intensity``): the object
stands on an invisible floor that only darkens the background where the object shades it.
Here the darkening is physical: on a diffuse plane, the background seen through a point x of the
plane is scaled by the ratio of the irradiance the object lets through to the irradiance of the
open sky (differential rendering, Debevec 1998, with the plane's own radiance cancelled):

    shadow(x) = E_occ(x) / E_open,   E_occ(x) = ∫ L(ω) V(x, ω) cosθ dω,   E_open = ∫ L(ω) cos⁺θ dω

per colour channel, computed by the same visibility machinery as the objects' shading: ground
sample points on a G × G grid are traced against the scene once (precompute, a content-keyed
part of the cut precomputation), their cosine-weighted visibility clustered into cuts at the
same τ; per lighting, E is the cut sum Σ_k l_k v_k (the Lambert shading of a white plane, times π)
and E_open the same sum over the cut of the unoccluded cosine (the grid's last cut). Both are
quantised alike, so an unoccluded point is exactly 1. ``intensity`` k in [0, 1] blends towards no
shadow (1 − k(1 − shadow)), as model-viewer's shadow-intensity does; k = 1 is the physical ratio.

The plane is y = the scene's lowest vertex (``ground.height`` to override); the grid is centred on
the bounding box, half-size max(half-width, half-depth) + height, so it covers what the object
shades for a sun above ~45° and a soft sky; beyond it the shadow is cut off, faded to none over
the outer quarter of the grid so that no edge shows (the one non-physical step).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core import cuts as cutmod
from ...core.cuts import CutSet
from ...core.directions import DirectionTree, get_tree
from ...keys import content_key

GRID = 64          # ground sample points per side (4,096 points: ~4% of a 100K-vertex precompute)
FADE = 0.25        # the outer quarter of the grid fades the shadow to none


@dataclass(frozen=True)
class GroundGrid:
    """The shadow plane y = y and its G × G sample grid: node (i, j) at (x0 + i·step, y, z0 + j·step)."""
    y: float
    x0: float
    z0: float
    step: float
    n: int

    def points(self) -> np.ndarray:
        """(G·G, 3) float32 grid nodes, i-major (node (i, j) is row i·G + j)."""
        i, j = np.meshgrid(np.arange(self.n), np.arange(self.n), indexing="ij")
        p = np.stack([self.x0 + i * self.step, np.full(i.shape, self.y), self.z0 + j * self.step], -1)
        return p.reshape(-1, 3).astype(np.float32)

    def geometry(self) -> tuple[float, float, float, float]:
        """(x0, z0, step, y) as the background kernel takes it."""
        return (self.x0, self.z0, self.step, self.y)

    def fade(self) -> np.ndarray:
        """(G, G) float64 weight of the shadow: 1 inside, smoothly 0 at the grid's border."""
        t = np.abs(np.linspace(-1.0, 1.0, self.n))
        w = np.clip((1.0 - t) / FADE, 0.0, 1.0)
        w = w * w * (3 - 2 * w)                            # smoothstep
        return np.outer(w, w)


def ground_grid(vertices: np.ndarray, height: float | None = None, n: int = GRID) -> GroundGrid:
    """The shadow grid under a scene's (V, 3) world-space vertices."""
    lo, hi = vertices.min(0).astype(np.float64), vertices.max(0).astype(np.float64)
    y = float(lo[1]) if height is None else float(height)
    cx, cz = 0.5 * (lo[0] + hi[0]), 0.5 * (lo[2] + hi[2])
    half = max(0.5 * (hi[0] - lo[0]), 0.5 * (hi[2] - lo[2])) + max(hi[1] - y, 0.0)
    half = max(half, 1e-6)
    return GroundGrid(float(y), float(cx - half), float(cz - half), float(2.0 * half / (n - 1)), int(n))


GROUND_VERSION = 2  # of the stored ground cuts' key (worker/keys.py)


def ground_key(vertices, faces, grid: GroundGrid, tau: float, height: int) -> str:
    """Content key of the ground cuts: the geometry that casts the shadow and the grid."""
    return content_key("ground", GROUND_VERSION, vertices=vertices, faces=faces,
                       grid=[grid.y, grid.x0, grid.z0, grid.step, grid.n], tau=float(tau), height=int(height))


def open_sky_cut(tau: float, tree: DirectionTree | None = None, kernels=None) -> CutSet:
    """The cut of the unoccluded cosine cos⁺θ of an upward normal (one vertex)."""
    tree = tree or get_tree()
    v = np.maximum(tree.leaves.astype(np.float32) @ np.array([0, 1, 0], np.float32), 0.0)[None, :]
    return cutmod.build_cuts(v, tau, kernels)


def precompute_ground(tracer, grid: GroundGrid, tau: float, threads: int = 2, progress=None, kernels=None):
    """Cuts of the grid's points looking up (G·G cuts) and, last, the open-sky cut: a CutSet of
    G·G + 1 vertices. Returns (CutSet, rays traced, seconds)."""
    from .precompute import precompute_cuts

    pts = grid.points()
    up = np.tile(np.array([[0, 1, 0]], np.float32), (len(pts), 1))
    cs, rays, secs = precompute_cuts(pts, None, up, tau=tau, threads=threads, progress=progress, tracer=tracer,
                                     kernels=kernels)
    return CutSet.concat([cs, open_sky_cut(tau, kernels=kernels)]), rays, secs


@dataclass(eq=False)
class GroundData:
    """What the renderer draws the ground shadow from: the grid and its cuts (G·G + 1)."""
    grid: GroundGrid
    cuts: CutSet

    def shadow(self, node_l, node_w, node8, tree, kernels) -> np.ndarray:
        """(G, G, 3) float32 E_occ / E_open per grid node for one lighting (1 where the open sky
        is dark), before fading and intensity."""
        from ...core.render import MaterialTable, shade_points
        from ...models import Lambert

        g = self.grid.n
        m = g * g + 1
        up = np.tile(np.array([[0, 1, 0]], np.float32), (m, 1))
        white = MaterialTable([Lambert(albedo=(1.0, 1.0, 1.0)).pack()])
        b = shade_points(up, up, np.arange(m, dtype=np.int32), np.zeros(m, np.int32), self.cuts, node_l, node_w,
                         tree, white, kernels, node8=node8).astype(np.float64)
        sky = b[-1]
        ratio = np.where(sky > 0, b[:-1] / np.where(sky > 0, sky, 1.0), 1.0)
        return np.clip(ratio, 0.0, 1.0).reshape(g, g, 3).astype(np.float32)

    def factor(self, shadow: np.ndarray, intensity: float) -> np.ndarray:
        """(G, G, 3) float32 background factor 1 − k·fade·(1 − shadow)."""
        k = float(np.clip(intensity, 0.0, 1.0))
        return (1.0 - k * self.grid.fade()[:, :, None] * (1.0 - shadow)).astype(np.float32)
