"""Object freezing and the per-frame dot product (polynomial-gi §5.2, eq. 25-29).

While one unit i is edited, every other unit's coefficients are frozen, so each tensor entry's
tail (the multiset z of diffuse-equivalent units, and for a (J, J2) series the second vertex)
reduces to a power n of d_i times a constant A = d̄_z / d_i^n (eq. 27), times ĉ of the second
vertex unless it is on unit i (index k ≥ 1 then). Freezing sums the tensors accordingly:

* ``V`` (P, K2, NP, 3): for every hit pixel, the part whose first vertex is *not* unit i (other
  objects, other regions' weights, fixed objects): Σ cf_slot · A · T, contracted with the frozen
  first-vertex coefficients cf (the paper's V^i_n);
* for the pixels on unit i ("live"), F^i (eq. 27) as a sparse list of (slot, k, n) keys with
  half-float values and a scale per pixel.

A frame is then (eq. 28-29) B = Σ_{k,n} ĉ_k d_i^n V + h_i Σ_e c_slot(θo) ĉ_k d_i^n F_e, with
c_slot(θo) interpolated between the view-angle nodes of the unit's projection. ``freeze_numpy``
and ``frame_numpy`` are the references of the C kernels ``gi_freeze`` / ``gi_frame`` (gi.c).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import zspace
from .tensors import Bounce

SCALE_MAX = 16384.0


def tail_tables(i: int, N: int, U: int, J2: int, d: np.ndarray, second: np.ndarray | None):
    """Per bounce k (list index k − 1): (kk (T,) int32, n (T,) int32, A (T, 3) float32) for
    edited unit i. d (U, 3) diffuse equivalents; second (U, C2, 3) second-vertex coefficients
    (C2 = trace.second_codes(J2), J2 series) or None."""
    out = []
    for k in range(1, N + 1):
        if k == 1:
            out.append((np.zeros(1, np.int32), np.zeros(1, np.int32), np.ones((1, 3), np.float32)))
            continue
        S = k - 2 if J2 > 1 else k - 1
        zs = zspace.enumerate_all(U, S)
        nz = np.array([z.count(i) for z in zs], np.int32)
        Az = np.ones((len(zs), 3))
        for r, z in enumerate(zs):
            for u in z:
                if u != i:
                    Az[r] *= d[u]
        if J2 <= 1:
            out.append((np.zeros(len(zs), np.int32), nz, Az.astype(np.float32)))
            continue
        C2 = second.shape[1] if second is not None else 1
        W2 = U * C2 + 1
        kk_w = np.zeros(W2, np.int32)
        A_w = np.ones((W2, 3))
        for w in range(W2 - 1):
            u2, s2 = divmod(w, C2)
            if u2 == i:
                kk_w[w] = 1 + s2
            else:
                A_w[w] = second[u2, s2]
        kk = np.repeat(kk_w, len(zs))
        n = np.tile(nz, W2)
        A = (A_w[:, None, :] * Az[None, :, :]).reshape(-1, 3)
        out.append((kk, n, A.astype(np.float32)))
    return out


@dataclass
class PixelUnits:
    """First-vertex units of the hit pixels: units (P, L) int32 (−1 padding, U = the fixed
    pseudo-unit), weights (P, L) float32 (H(x)), k0 (P,) int32, t (P,) float32 view-angle
    interpolation (basis.theta_interp)."""
    units: np.ndarray
    weights: np.ndarray
    k0: np.ndarray
    t: np.ndarray


def lerp_coeffs(C1: np.ndarray, k0: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(P, K1, 3) coefficients of one unit's table C1 (Kθ, K1, 3) at pixels' view angles."""
    return C1[k0] * (1.0 - t)[:, None, None] + C1[k0 + 1] * t[:, None, None]


@dataclass
class Frozen:
    """Output of freezing unit i.

    V (P, K2, NP, 3) float32: every hit pixel's part with frozen first-vertex coefficients.
    live (Q,) int64 indices of the hit pixels on unit i, h (Q,) float32 its weight there,
    scale (Q,) float32 per live pixel, and F^i (eq. 27) in one of two layouts:

    * dense (K2 = 1, the (J, 1, …) series): ``dense`` (Q, Wd) uint16 half floats holding, for
      each power n < NPe of d_i, the slots lo[n] … lo[n] + width[n] − 1 only (width a multiple
      of 8 for SIMD, zero padded beyond the last slot): a block of 3·width[n] columns at
      ``block_offsets[n]``, [channel][slot − lo[n]]. Only the slots the live entries of each
      power reach are kept: with denoised tensors the powers ≥ 1 come from the indirect bounces
      alone, which live on a few hat components (denoise.py), so most of the (power, slot) grid
      is empty;
    * sparse (J2 series): offsets (Q + 1,) int64 into entries (m, 4) uint16 = [key, r, g, b],
      key = (slot·K2 + k)·NP + n, 8 bytes an entry.
    """
    unit: int
    K2: int
    NP: int
    V: np.ndarray
    live: np.ndarray
    h: np.ndarray
    scale: np.ndarray
    offsets: np.ndarray | None = None
    entries: np.ndarray | None = None
    dense: np.ndarray | None = None
    lo: np.ndarray | None = None
    width: np.ndarray | None = None
    # per-frame lookups derived once (qpos, dense_cells)
    _memo: dict = field(default_factory=dict, repr=False, compare=False)

    def qpos(self, P: int) -> np.ndarray:
        """(P,) int64 position of each hit pixel among the live ones, −1 elsewhere."""
        q = self._memo.get("qpos")
        if q is None or len(q) != P:
            q = np.full(P, -1, np.int64)
            q[self.live] = np.arange(len(self.live))
            self._memo["qpos"] = q
        return q

    @property
    def NPe(self) -> int:
        return len(self.lo) if self.dense is not None else self.NP

    @property
    def block_offsets(self) -> np.ndarray:
        """(NPe,) int32 first column of each power's block in ``dense``."""
        return np.concatenate([[0], np.cumsum(3 * self.width)[:-1]]).astype(np.int32)

    def dense_cells(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(slot, power, channel) (Wd,) int64 of each column of ``dense``; the padding columns
        past the last slot (slot ≥ K1) hold zeros and are masked by the callers."""
        if "cells" in self._memo:
            return self._memo["cells"]
        slot, pw, ch = [], [], []
        for n, (lo, w) in enumerate(zip(self.lo, self.width)):
            j = np.arange(int(w))
            for c in range(3):
                slot.append(lo + j); pw.append(np.full(len(j), n)); ch.append(np.full(len(j), c))
        cat = lambda x: np.concatenate(x).astype(np.int64) if x else np.zeros(0, np.int64)
        self._memo["cells"] = cat(slot), cat(pw), cat(ch)
        return self._memo["cells"]

    def dense_full(self, rows: np.ndarray, K1: int) -> np.ndarray:
        """(len(rows), NPe, 3, K1) float64 F^i of the live rows ``rows`` from the dense layout
        (scaled like ``dense``: times ``scale`` for the radiance)."""
        slot, pw, ch = self.dense_cells()
        ok = (slot >= 0) & (slot < K1)
        out = np.zeros((len(rows), self.NPe, 3, K1))
        out[:, pw[ok], ch[ok], slot[ok]] = self.dense.view(np.float16)[rows][:, ok].astype(np.float64)
        return out

    @property
    def key(self) -> np.ndarray:
        return self.entries[:, 0]

    @property
    def val(self) -> np.ndarray:
        return self.entries[:, 1:].copy().view(np.float16)

    @property
    def live_values(self) -> int:
        """Stored live values (entries, or dense cells), for benchmarks."""
        return int(self.dense.size // 3) if self.dense is not None else int(len(self.entries))

    @property
    def nbytes(self) -> int:
        arrs = [self.V, self.live, self.h, self.scale] + [a for a in (self.offsets, self.entries, self.dense) if a is not None]
        return sum(a.nbytes for a in arrs)


def dense_blocks(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The dense layout's slot ranges from the smallest and largest slot of each power's live
    entries, lo, hi (NPe,) (hi < 0: none): (lo (NPe,) int32, width (NPe,) int32 a multiple
    of 8, 0 for a power without entries)."""
    lo = np.where(hi >= 0, lo, 0).astype(np.int32)
    width = np.where(hi >= 0, (hi - lo + 1 + 7) // 8 * 8, 0).astype(np.int32)
    return lo, width


def use_dense(K2: int, width: np.ndarray, Q: int, sparse_bound: int) -> bool:
    """The dense live layout when it is possible (K2 = 1) and at most twice the bytes of the
    sparse one's upper bound (its SIMD loop streams about twice as fast per byte); sparse
    tensors from few paths per pixel stay sparse. width (NPe,) the blocks' slot counts."""
    return K2 == 1 and Q * 3 * int(np.sum(width)) * 2 <= 2 * 8 * sparse_bound


def sparse_bound(bounces, live: np.ndarray, K1: int, K2: int, NP: int) -> np.ndarray:
    """(Q + 1,) int64 prefix sums of an upper bound of each live pixel's sparse entries."""
    P = len(bounces[0].offsets) - 1 if bounces else 0
    cnt = sum(np.diff(b.offsets) for b in bounces) if bounces else np.zeros(P, np.int64)
    return np.concatenate([[0], np.cumsum(np.minimum(cnt[live], K1 * K2 * NP))]).astype(np.int64)


def pixel_weights(pu: PixelUnits, i: int):
    """(h (P,) weight of unit i at each pixel, mask of other units (P, L))."""
    is_i = pu.units == i
    return (pu.weights * is_i).sum(1).astype(np.float32), (pu.units >= 0) & ~is_i


def freeze_numpy(bounces: list[Bounce], tables, pu: PixelUnits, C1: np.ndarray, i: int, K1: int, K2: int, NP: int) -> Frozen:
    """NumPy reference of gi_freeze (see module docstring). C1 (U + 1, Kθ, K1, 3) float32."""
    P = len(pu.k0)
    h, other = pixel_weights(pu, i)
    cf = np.zeros((P, K1, 3))
    for l in range(pu.units.shape[1]):
        sel = np.nonzero(other[:, l])[0]
        if len(sel):
            cf[sel] += pu.weights[sel, l, None, None] * _lerp_rows(C1, pu.units[sel, l], pu.k0[sel], pu.t[sel])
    V = np.zeros((P, K2, NP, 3))
    live = np.nonzero(h > 0)[0]
    qpos = np.full(P, -1, np.int64); qpos[live] = np.arange(len(live))
    Fd = np.zeros((len(live), K1, K2, NP, 3))
    lo = np.full(NP, K1, np.int64); hi = np.full(NP, -1, np.int64)
    for b, (kk, n, A) in zip(bounces, tables):
        cnt = np.diff(b.offsets)
        pix = np.repeat(np.arange(P), cnt)
        v = b.val.astype(np.float64) * b.scale[pix, None] * A[b.tail]
        s = b.slot.astype(np.int64)
        k_, n_ = kk[b.tail], n[b.tail]
        np.add.at(V, (pix, k_, n_), cf[pix, s] * v)
        q = qpos[pix]
        m = q >= 0
        np.add.at(Fd, (q[m], s[m], k_[m], n_[m]), v[m])
        np.minimum.at(lo, n_[m], s[m]); np.maximum.at(hi, n_[m], s[m])
    # half floats with a scale per live pixel
    Q = len(live)
    flat = Fd.reshape(Q, K1 * K2 * NP, 3)
    amax = np.abs(flat).max(axis=(1, 2)) if Q else np.zeros(0)
    scale = np.where(amax > 0, amax / SCALE_MAX, 1.0).astype(np.float32)
    NPe = int(np.nonzero(hi >= 0)[0].max()) + 1 if (hi >= 0).any() else 1
    blo, width = dense_blocks(lo[:NPe], hi[:NPe])
    if use_dense(K2, width, Q, int(sparse_bound(bounces, live, K1, K2, NP)[-1])):
        fz = Frozen(i, K2, NP, V.astype(np.float32), live.astype(np.int64), h[live], scale, lo=blo, width=width)
        slot, pw, ch = fz.dense_cells()
        ok = (slot >= 0) & (slot < K1)
        dense = np.zeros((Q, len(slot)), np.float16)
        dense[:, ok] = (Fd[:, slot[ok], 0, pw[ok], ch[ok]] / scale[:, None]).astype(np.float16)
        fz.dense = dense.view(np.uint16)
        return fz
    qv = (flat / scale[:, None, None]).astype(np.float16)
    qi, cell = np.nonzero((qv != 0).any(-1))
    offsets = np.concatenate([[0], np.cumsum(np.bincount(qi, minlength=Q))]).astype(np.int64)
    entries = np.empty((len(cell), 4), np.uint16)
    entries[:, 0] = cell
    entries[:, 1:] = qv[qi, cell].view(np.uint16)
    return Frozen(i, K2, NP, V.astype(np.float32), live.astype(np.int64), h[live], scale, offsets, entries)


def _lerp_rows(C1, units, k0, t):
    """(R, K1, 3): C1[units] interpolated at (k0, t) per row."""
    return C1[units, k0] * (1.0 - t)[:, None, None] + C1[units, k0 + 1] * t[:, None, None]


def frame_numpy(fz: Frozen, pu: PixelUnits, C1i: np.ndarray, ck: np.ndarray, d: np.ndarray, K1: int) -> np.ndarray:
    """NumPy reference of gi_frame: (P, 3) float32 radiance of the hit pixels.

    C1i (Kθ, K1, 3) the edited unit's first-vertex table; ck (K2, 3) second-vertex factors
    (ck[0] = 1); d (3,) its diffuse equivalent."""
    dp = np.stack([d ** n for n in range(fz.NP)])                        # (NP, 3)
    ckn = ck[:, None, :] * dp[None, :, :]                                 # (K2, NP, 3)
    B = np.einsum("pknc,knc->pc", fz.V.astype(np.float64), ckn)
    if len(fz.live) and fz.dense is not None:
        c = lerp_coeffs(C1i.astype(np.float64), pu.k0[fz.live], pu.t[fz.live])   # (Q, K1, 3)
        slot, pw, ch = fz.dense_cells()
        ok = (slot >= 0) & (slot < K1)
        F = fz.dense.view(np.float16)[:, ok].astype(np.float64)                   # (Q, cells)
        term = F * c[:, slot[ok], ch[ok]] * dp[pw[ok], ch[ok]]
        acc = np.stack([term[:, ch[ok] == k].sum(1) for k in range(3)], 1)
        B[fz.live] += (fz.h * fz.scale)[:, None] * acc
    elif len(fz.live):
        c = lerp_coeffs(C1i.astype(np.float64), pu.k0[fz.live], pu.t[fz.live])   # (Q, K1, 3)
        cnt = np.diff(fz.offsets)
        q = np.repeat(np.arange(len(fz.live)), cnt)
        key = fz.key.astype(np.int64)
        s, rest = np.divmod(key, fz.K2 * fz.NP)
        k_, n_ = np.divmod(rest, fz.NP)
        v = fz.val.astype(np.float64) * fz.scale[q, None] * c[q, s] * ckn[k_, n_]
        acc = np.zeros((len(fz.live), 3))
        np.add.at(acc, q, v)
        B[fz.live] += fz.h[:, None] * acc
    return B.astype(np.float32)


def prune_sparse(fz: Frozen, pu: PixelUnits, C1i: np.ndarray, frac: float,
                 slot_weight: np.ndarray | None = None) -> tuple[Frozen, float]:
    """Re-sparsify the live rows of a sparse Frozen: drop every entry whose magnitude
    (Σ_rgb |F_e|) is below ``frac`` of its row's total, and fold what it contributes at the
    freeze-time material into V, so the frame at that material is unchanged up to float
    rounding and the error grows only with the edit's change of c_slot (eq. 28-29: the dropped
    term is h·scale·c_slot(θo)·ĉ_k·d^n·F_e, of which ĉ_k·d^n is V's factor already).

    C1i (Kθ, K1, 3) the edited unit's first-vertex table at freeze time; frac ≥ 0 (0: no-op).
    Returns (the pruned Frozen, the fraction of the live rows' total magnitude dropped).
    The dense layout is returned as is (its loop has no per-entry cost to save)."""
    if frac <= 0 or fz.dense is not None or fz.entries is None or not len(fz.entries):
        return fz, 0.0
    Q = len(fz.live)
    cnt = np.diff(fz.offsets)
    q = np.repeat(np.arange(Q), cnt)
    val = fz.val.astype(np.float64)                                   # (m, 3)
    mag = np.abs(val).sum(1)
    if slot_weight is not None:
        # what an entry can contribute: its magnitude times the largest coefficient its slot takes
        mag = mag * slot_weight[fz.key.astype(np.int64) // (fz.K2 * fz.NP)]
    row = np.bincount(q, weights=mag, minlength=Q)
    drop = mag < frac * row[q]
    if not drop.any():
        return fz, 0.0
    # fold the dropped entries into V at the current coefficients of the edited unit
    key = fz.key.astype(np.int64)[drop]
    s, rest = np.divmod(key, fz.K2 * fz.NP)
    qd = q[drop]
    # the edited unit's coefficient of each dropped entry's slot at its pixel's view angle (only
    # those: the full (Q, K1, 3) table would be most of the pass)
    k0, t = pu.k0[fz.live[qd]], pu.t[fz.live[qd]].astype(np.float64)[:, None]
    C = C1i.astype(np.float64)
    c = C[k0, s] * (1.0 - t) + C[k0 + 1, s] * t                                # (md, 3)
    add = val[drop] * (fz.h * fz.scale)[qd, None] * c                         # (md, 3)
    cell = fz.live[qd] * (fz.K2 * fz.NP) + rest                            # flat (pixel, k, n)
    V = fz.V.reshape(-1, 3).astype(np.float64)
    for ch in range(3):
        V[:, ch] += np.bincount(cell, weights=add[:, ch], minlength=len(V))
    keep = ~drop
    offsets = np.concatenate([[0], np.cumsum(np.bincount(q[keep], minlength=Q))]).astype(np.int64)
    out = Frozen(fz.unit, fz.K2, fz.NP, V.astype(np.float32).reshape(fz.V.shape), fz.live, fz.h, fz.scale,
                 offsets, np.ascontiguousarray(fz.entries[keep]))
    return out, float(mag[drop].sum() / max(mag.sum(), 1e-30))
