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
from ..core.render import cluster_directions
from .basis import SRBFBasis


def _local(v, t, b, n):
    return np.stack([(v * t).sum(1), (v * b).sum(1), (v * n).sum(1)], 1)


def expand_cut_entries_multi(cut_of, cuts: CutSet, tree: DirectionTree, mirror, pairs):
    """The cluster list each point evaluates: its cut's nodes with non-zero visibility, split
    while any (refine radius, extent) pair of ``pairs`` asks for it (children inherit the
    parent's visibility); ``core.render.expand_cut_entries`` with several pairs.

    cut_of : (P,) cut index per point (≥ 0). mirror : (P, 3) float64 mirror directions.
    Returns (pt, idx, q): (M,) point index, flat tree-node index and visibility in [0, 1].
    """
    a = cuts.offsets[cut_of]
    b = cuts.offsets[cut_of + 1]
    cnt = (b - a).astype(np.int64)
    pt = np.repeat(np.arange(len(cut_of)), cnt)
    node = np.concatenate([np.arange(x, y) for x, y in zip(a, b)]) if len(a) else np.zeros(0, np.int64)
    h = cuts.heights[node].astype(np.int64)
    w = np.int64(1) << h
    csum = np.cumsum(w)
    first = np.repeat(np.cumsum(cnt) - cnt, cnt)
    start = csum - w - (csum[first] - w[first])
    q = cuts.quant[node].astype(np.float64) / 255.0
    keep = q > 0
    pt, h, start, q = pt[keep], h[keep], start[keep], q[keep]
    while True:
        idx = tree.level_offset[h] + (start >> h)
        R = tree.node_radius[idx].astype(np.float64)
        nd = tree.node_dir[idx].astype(np.float64)
        ang = np.arccos(np.clip((nd * mirror[pt]).sum(1), -1.0, 1.0))
        ref = np.zeros(len(pt), bool)
        for r, e in pairs:
            ref |= (R > r) & ((R + e >= np.pi) | (ang < R + e))
        ref &= h > 0
        if not ref.any():
            return pt, idx, q
        k = np.nonzero(ref)[0]
        half = np.int64(1) << (h[k] - 1)
        stay = ~ref
        pt = np.concatenate([pt[stay], pt[k], pt[k]])
        q = np.concatenate([q[stay], q[k], q[k]])
        start = np.concatenate([start[stay], start[k], start[k] + half])
        h = np.concatenate([h[stay], h[k] - 1, h[k] - 1])


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
    co = (n * wo).sum(1)
    live = np.nonzero(co > 0)[0]
    if len(live) == 0:
        return T, E
    k = np.repeat(live, 3)                                   # (pixel, corner) pairs
    cut_of = verts[live].reshape(-1)
    r = 2.0 * co[k, None] * n[k] - wo[k]
    pair, idx, q = expand_cut_entries_multi(cut_of, cuts, tree, r, pairs)
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
