"""Transfer functions of the SRBF basis at the pixels of one view (inverse-brdf-modeling eq. 6, 21).

    T_j(x) = Σ_k l_k v_k(x) s(ω_k, ω_o(x)) G_j(h_k)                 (eq. 21)
    E(x)   = Σ_k l_k v_k(x) / π                                      (eq. 3: B_d = ρ_d E)

over the clusters k of the point's cut, with l_k the light integral over the cluster (radiance ×
sr), v_k the mean cosine-weighted visibility and ω_k the light-weighted centroid direction, the
same quantities the renderer shades with (core/render.py), refined for every level of the basis
(``SRBFBasis.refinement``), so a fitted material re-renders as the fit predicted. A pixel's
visibility is the barycentric blend of its triangle's three vertex cuts (§4.1); its normal and
view direction are its own.

``transfer_numpy`` is the reference of the C kernel ``glk_fit_transfer`` (native/src/fit.c).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..core.brdf import onb
from ..core.cuts import CutSet
from ..core.directions import DirectionTree
from ..core.render import cluster_directions, expand_cut_entries, facing_view
from .basis import SRBFBasis


def _local(v, t, b, n):
    return np.stack([(v * t).sum(1), (v * b).sum(1), (v * n).sum(1)], 1)


def transfer_numpy(normals, wo, verts, bary, cuts: CutSet, node_l, node_w, tree: DirectionTree,
                   basis: SRBFBasis, chunk: int = 16):
    """Transfer matrix at P points.

    normals, wo : (P, 3) unit shading normals and directions towards the eye.
    verts : (P, 3) int32 vertex (cut) indices of the triangle; bary : (P, 3) barycentric weights.
    node_l, node_w : (2N-1, 3) float32 per-node light and direction (lighting.node_lighting).
    Returns T (3, P, J) float32 (channel-major: radiance per unit coefficient, per RGB channel
    of the light) and E (P, 3) float32 (radiance of a white Lambertian surface, ρ_d = 1).
    """
    P, J = len(normals), basis.J
    T = np.zeros((3, P, J), np.float32)
    E = np.zeros((P, 3), np.float32)
    pairs = basis.refinement()
    for s in range(0, P, chunk):
        e = min(s + chunk, P)
        T[:, s:e], E[s:e] = _transfer_chunk(normals[s:e].astype(np.float64), wo[s:e].astype(np.float64),
                                            verts[s:e], bary[s:e].astype(np.float64), cuts, node_l, node_w,
                                            tree, basis, pairs)
    return T, E


def _transfer_chunk(n, wo, verts, bary, cuts, node_l, node_w, tree, basis, pairs):
    p_n, J = len(n), basis.J
    T = np.zeros((3, p_n, J))
    E = np.zeros((p_n, 3))
    wo = facing_view(n, wo)
    co = (n * wo).sum(1)
    live = np.nonzero(co > 0)[0]
    if len(live) == 0:
        return T, E
    k = np.repeat(live, 3)                                   # (pixel, corner) pairs
    cut_of = verts[live].reshape(-1)
    r = 2.0 * co[k, None] * n[k] - wo[k]
    pair, idx, q = expand_cut_entries(cut_of, cuts, tree, r, pairs)
    px = k[pair]
    wgt = bary[live].reshape(-1)[pair] * q
    l = node_l[idx].astype(np.float64)
    lit = ~(l <= 0).all(1)
    px, idx, wgt, l = px[lit], idx[lit], wgt[lit], l[lit]
    npx = n[px]
    wi = cluster_directions(node_w, idx, npx)
    t, b = onb(npx)
    wi_l, wo_l = _local(wi, t, b, npx), _local(wo[px], t, b, npx)
    hv = wi_l + wo_l
    h = hv / np.linalg.norm(hv, axis=1, keepdims=True)
    ci, cw = wi_l[:, 2], wo_l[:, 2]
    s_static = basis.static_fn(ci, cw, (wi_l * h).sum(1))   # eq. 4's static function
    a = l * wgt[:, None]                                     # (M, 3) light × visibility × bary
    for c in range(3):
        E[:, c] = np.bincount(px, weights=a[:, c], minlength=p_n) / np.pi
    G = basis.G(h)                                           # (M, J)
    S = sp.csr_matrix((s_static, (px, np.arange(len(px)))), shape=(p_n, len(px)))
    for c in range(3):
        T[c] = S @ (G * a[:, c:c + 1])
    return T, E


def transfer(normals, wo, verts, bary, cuts: CutSet, node_l, node_w, tree: DirectionTree,
             basis: SRBFBasis, kernels=None):
    """Transfer matrix (T (3, P, J), E (P, 3)) float32 (see transfer_numpy); kernels: the backend
    (worker/native/kernels.py; the C kernel is glk_fit_transfer in native/src/fit.c)."""
    from ..native.kernels import kernels as _kernels

    return (kernels or _kernels()).transfer(normals, wo, verts, bary, cuts, node_l, node_w, tree, basis)
