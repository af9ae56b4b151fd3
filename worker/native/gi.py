"""The GI kernels (src/gi.c) behind the backend's ``gi`` family: ``k.gi.sample``,
``accumulator`` / ``emit`` / ``compact`` (one tile's tensors), ``freeze`` and ``frame``, the same
arrays in and out in both backends. The NumPy references: trace.sample_numpy, trace.emit_numpy
with trace.compact, freeze.freeze_numpy, freeze.frame_numpy (tests/gi/test_gi_native.py checks
that they agree). The C kernels accumulate a tile into per-pixel hash tables (HashTensor), the
references into a dense tensor; ``compact`` gives the same sparse layout from either.
"""
from __future__ import annotations

import numpy as np

from . import lib as _lib
from . import (
    bind,
    f32,
    f32p,
    f64,
    f64p,
    i32,
    i32p,
    i64,
    i64p,
    u8p,
    u16p,
    u32p,
    u64p,
    voidp,
)
from ..renderers.gi import zspace
from ..renderers.gi.freeze import Frozen, PixelUnits, dense_blocks, sparse_bound, use_dense

if _lib is not None:
    # parameters named and ordered as the prototypes in gi.c
    bind("gi_sample", None, R=i64, pos=f64p, ng=f64p, ns=f64p, wo=f64p, u=f64p, nu=i32, row_cdf=f64p,
         col_cdf=f64p, tp=f64p, H=i32, W=i32, rot_rad=f64, dl=f64p, db=f64p, pdf_ll=f64p, pdf_bl=f64p, pdf_bb=f64p,
         pdf_lb=f64p, valid_l=u8p, valid_b=u8p)
    bind("gi_emit", None, P=i64, starts=i64p, k=i32, J=i32, J2=i32, layers=i32, oq=i32p, K1=i32, Tk=i64, W2=i64,
         Zs=i64, unit=i32p, obj=i32p, ns=f64p, wo=f64p, beta=f64p, p1b=i32p, p1w=f64p, p2c=i32p, p2b=i32p,
         p2w=f64p, z=i32p, zc=i32p, onu=f64p, oaxis=f64p, dl=f64p, db=f64p, Ll=f64p, Lb=f64p, wl=f64p, wb=f64p,
         pdf_bb=f64p, fl=f64p, fb=f64p, C=i64p, Crows=i64, zoff=i64p, hkeys=i32p, hvals=f32p, cap=i64,
         o_beta=f64p, o_p1b=i32p, o_p1w=f64p, o_p2c=i32p, o_p2b=i32p, o_p2w=f64p, o_z=i32p, o_zc=i32p)
    bind("gi_occupancy", None, P=i64, cap=i64, keys=i32p, occ=i32p)
    bind("gi_compact", None, P=i64, cap=i64, keys=i32p, vals=f32p, inv_spp=f32, Tk=i64, ub=i64p, cnt=i32p,
         slot=u16p, tail=u32p, val=u16p, scale=f32p)
    bind("gi_half", None, n=i64, in_=f32p, out=u16p, to_half=i32, back=f32p)  # in_: C's `in`
    # a_*: tables of addresses (uint64), one per bounce
    bind("gi_freeze", None, P=i64, nb=i32, a_off=u64p, a_slot=u64p, a_tail=u64p, a_val=u64p, a_scale=u64p,
         a_kk=u64p, a_pw=u64p, a_A=u64p, L=i32, units=i32p, weights=f32p, k0=i32p, tt=f32p, C1=f32p, KT=i32,
         K1=i32, K2=i32, NP=i32, iu=i32, qpos=i64p, ub=i64p, V=f32p, F=u16p, cnt=i32p, fscale=f32p, dense=i32,
         NB=i32, blo=i32p, bw=i32p, boff=i32p, Wd=i32, Fd=u16p, sel=voidp)
    bind("gi_powslots", i32, P=i64, nb=i32, a_off=u64p, a_slot=u64p, a_tail=u64p, a_pw=u64p, qpos=i64p, NP=i32,
         K1=i32, lo=i32p, hi=i32p)
    bind("gi_frame", None, P=i64, K2NP=i32, V=f32p, ckn=f32p, qpos=i64p, offs=i64p, F=u16p, fscale=f32p,
         hq=f32p, k0=i32p, tt=f32p, Tab=f32p, nkeys=i64, pix=i64p, out=f32p)
    bind("gi_frame_dense", None, P=i64, NP=i32, V=f32p, ckn=f32p, qpos=i64p, NB=i32, bw=i32p, boff=i32p, Wd=i32,
         Fd=u16p, fscale=f32p, hq=f32p, k0=i32p, tt=f32p, CT=f32p, dpow=f32p, pix=i64p, img=f32p)


def c(a, dt):
    return np.ascontiguousarray(a, dtype=dt)


class NumpyGI:
    """The references of the GI kernels."""
    name = "numpy"

    def sample(self, S, pos, ng, ns, wo, u):
        """(dl, db (R, 3), pdf_ll, pdf_bl, pdf_bb, pdf_lb (R,) float64, valid_l, valid_b (R,) bool)
        of R path vertices (trace.sample_numpy)."""
        from ..renderers.gi.trace import sample_numpy
        return sample_numpy(S, pos, ng, ns, wo, u)

    def accumulator(self, P: int, K1: int, Tk: int, spp: int):
        """A tile's bounce accumulator for ``emit``: dense (P, K1, Tk, 3) float32."""
        return np.zeros((P, K1, Tk, 3), np.float32)

    def emit(self, S, k: int, st, ev: dict, acc):
        """Vertex k's light into acc; the continuing prefix (trace.emit_numpy)."""
        from ..renderers.gi.trace import emit_numpy
        return emit_numpy(S, k, st, ev, acc)

    def compact(self, acc, inv_spp: float):
        """(counts (P,) int32, slot (n,) uint16, tail (n,) uint32, val (n, 3) float16, scale (P,)
        float32) of acc times inv_spp (trace.compact)."""
        from ..renderers.gi.trace import compact
        return compact(acc * np.float32(inv_spp))

    def freeze(self, bounces, tables, pu, C1, i, K1, K2, NP, pixels=None, V0=None):
        """Frozen of unit i live (freeze.freeze_numpy); ``pixels``, V0 as ``freeze``."""
        from ..renderers.gi.freeze import freeze_numpy
        fz = freeze_numpy(bounces, tables, pu, C1, i, K1, K2, NP)
        if pixels is not None:
            V = np.array(V0, np.float32, copy=True)
            V[pixels] = fz.V[pixels]
            fz.V = V
        return fz

    def frame(self, fz, pu, C1i, ck, d, K1, pix, img):
        """Writes the hit pixels' radiance into img (H·W, 3) float32 at pix (P,) int64; returns
        img (freeze.frame_numpy)."""
        from ..renderers.gi.freeze import frame_numpy
        img[pix] = frame_numpy(fz, pu, C1i, ck, d, K1)
        return img

    def to_half(self, x):
        """float32 -> float16 bits (uint16)."""
        return c(x, np.float32).reshape(-1).astype(np.float16).view(np.uint16)

    def from_half(self, h):
        return c(h, np.uint16).reshape(-1).view(np.float16).astype(np.float32)


class NativeGI:
    """Typed wrappers of gi_* (gi.c)."""
    name = "native"

    def __init__(self):
        if _lib is None:
            raise RuntimeError("the C kernels are not built (make build)")

    def sample(self, S, pos, ng, ns, wo, u):
        return sample(S, pos, ng, ns, wo, u)

    def accumulator(self, P: int, K1: int, Tk: int, spp: int):
        """A tile's bounce accumulator for ``emit``: per-pixel hash tables (HashTensor)."""
        return HashTensor(P, K1, Tk, spp)

    def emit(self, S, k: int, st, ev: dict, acc):
        return emit(S, k, st, ev, acc)

    def compact(self, acc, inv_spp: float):
        return acc.compact(inv_spp)

    def freeze(self, bounces, tables, pu, C1, i, K1, K2, NP, pixels=None, V0=None):
        return freeze(bounces, tables, pu, C1, i, K1, K2, NP, pixels, V0)

    def frame(self, fz, pu, C1i, ck, d, K1, pix, img):
        return frame(fz, pu, C1i, ck, d, K1, pix, img)

    def to_half(self, x):
        return to_half(x)

    def from_half(self, h):
        return from_half(h)


def sample(S, pos, ng, ns, wo, u):
    """gi_sample (reference: trace.sample_numpy); same returns."""
    R = len(pos)
    out = [np.empty((R, 3)), np.empty((R, 3))] + [np.empty(R) for _ in range(4)] + [np.empty(R, np.uint8) for _ in range(2)]
    e = S.env
    _lib.gi_sample(R, c(pos, np.float64), c(ng, np.float64), c(ns, np.float64), c(wo, np.float64), c(u, np.float64),
                   u.shape[1], e.row_cdf, c(e.col_cdf, np.float64), c(e.texel_pdf, np.float64), e.H, e.W,
                   float(np.radians(S.rotation)), *out)
    dl, db, pdf_ll, pdf_bl, pdf_bb, pdf_lb, vl, vb = out
    return dl, db, pdf_ll, pdf_bl, pdf_bb, pdf_lb, vl.astype(bool), vb.astype(bool)


class HashTensor:
    """A tile's k-bounce entries in per-pixel open-addressing tables: keys (P, cap) int32
    (slot·T_k + tail, −1 empty), vals (P, cap, 3) float32; cap is a power of two at least twice
    the distinct keys a pixel can reach (min(K1·T_k, 18·spp): each path adds at most 2 events ×
    3 slots × 3 tails at a bounce), so a table never fills."""

    def __init__(self, P: int, K1: int, Tk: int, spp: int):
        if K1 * Tk >= 2 ** 31:
            raise ValueError(f"GI key space {K1}×{Tk} does not fit 32 bits (fewer units, bands or bounces)")
        bound = min(K1 * Tk, 18 * spp)
        self.cap = 1 << int(np.ceil(np.log2(max(2 * bound, 2))))
        self.Tk = Tk
        self.keys = np.full((P, self.cap), -1, np.int32)
        self.vals = np.zeros((P, self.cap, 3), np.float32)

    def compact(self, inv_spp: float):
        """gi_compact (reference: trace.compact of the dense tensor times inv_spp)."""
        P = len(self.keys)
        occ = np.empty(P, np.int32)
        _lib.gi_occupancy(P, self.cap, self.keys, occ)
        ub = np.concatenate([[0], np.cumsum(occ, dtype=np.int64)])
        n = int(ub[-1])
        slot = np.empty(n, np.uint16); tail = np.empty(n, np.uint32); val = np.empty((n, 3), np.uint16)
        cnt = np.empty(P, np.int32); scale = np.empty(P, np.float32)
        _lib.gi_compact(P, self.cap, self.keys, self.vals, np.float32(inv_spp), self.Tk, ub, cnt, slot, tail, val, scale)
        offs = np.concatenate([[0], np.cumsum(cnt, dtype=np.int64)])
        sel = np.repeat(ub[:-1], cnt) + (np.arange(offs[-1]) - np.repeat(offs[:-1], cnt))
        return cnt, slot[sel], tail[sel], val[sel].view(np.float16), scale


def emit(S, k: int, st, ev: dict, table: HashTensor):
    """gi_emit (reference: trace.emit_numpy, which accumulates densely): accumulates vertex k's
    light into the tile's hash tensor; returns the continuing prefix (beta, p1b, p1w, p2c, p2b,
    p2w, z, zc)."""
    R = len(st.pix)
    P = len(table.keys)
    pix = c(st.pix, np.int64)
    if R and np.any(np.diff(pix) < 0):
        raise ValueError("gi_emit needs paths ordered by pixel")
    starts = np.searchsorted(pix, np.arange(P + 1)).astype(np.int64)
    U = S.U
    C = zspace.binom_table(U)
    zoff = zspace.offsets(U)
    Zs = zspace.size(U, k - 2) if (S.J2 > 1 and k >= 2) else 1
    o = [np.empty((R, 3)), np.empty(R, np.int32), np.empty((R, 3)), np.empty(R, np.int32), np.empty(R, np.int32),
         np.empty((R, 3)), np.empty((R, 3), np.int32), np.empty(R, np.int32)]
    _lib.gi_emit(P, starts, k, S.J, S.J2, S.layers, c(S.qkind, np.int32), S.K1, S.tails[k - 1], S.W2, Zs,
                 c(st.unit, np.int32), c(st.obj, np.int32), c(st.ns, np.float64), c(st.wo, np.float64),
                 c(st.beta, np.float64), c(st.p1b, np.int32), c(st.p1w, np.float64), c(st.p2c, np.int32),
                 c(st.p2b, np.int32), c(st.p2w, np.float64), c(st.z, np.int32), c(st.zc, np.int32),
                 c(S.aniso_nu, np.float64), c(S.aniso_axis, np.float64),
                 c(ev["dl"], np.float64), c(ev["db"], np.float64), c(ev["Ll"], np.float64), c(ev["Lb"], np.float64),
                 c(ev["wl"], np.float64), c(ev["wb"], np.float64), c(ev["pdf_bb"], np.float64),
                 c(ev["fl"], np.float64), c(ev["fb"], np.float64),
                 c(C, np.int64), len(C), c(zoff, np.int64), table.keys, table.vals, table.cap, *o)
    return tuple(o)


def to_half(x: np.ndarray) -> np.ndarray:
    """float32 -> float16 bits by gi.c's conversion (for testing it against NumPy's)."""
    x = c(x, np.float32).reshape(-1)
    out = np.empty(len(x), np.uint16)
    _lib.gi_half(len(x), x, out, 1, np.empty(1, np.float32))
    return out


def from_half(h: np.ndarray) -> np.ndarray:
    h = c(h, np.uint16).reshape(-1)
    out = np.empty(len(h), np.float32)
    _lib.gi_half(len(h), np.empty(1, np.float32), h, 0, out)
    return out


def freeze(bounces, tables, pu: PixelUnits, C1: np.ndarray, i: int, K1: int, K2: int, NP: int,
           pixels: np.ndarray | None = None, V0: np.ndarray | None = None) -> Frozen:
    """gi_freeze (reference: freeze.freeze_numpy), the same Frozen layout. ``pixels`` (n,) int64
    sorted: freeze only these hit pixels (every pixel on unit i among them) and take V's other
    rows from V0 (P, K2, NP, 3), a freeze of unit i whose pixel units were the same there."""
    P = len(pu.k0)
    h = (pu.weights * (pu.units == i)).sum(1).astype(np.float32)
    live = np.nonzero(h > 0)[0].astype(np.int64)
    qpos = np.full(P, -1, np.int64); qpos[live] = np.arange(len(live))
    if pixels is not None:
        pixels = c(pixels, np.int64)
        assert V0 is not None and V0.shape == (P, K2, NP, 3) and np.isin(live, pixels).all()
        V = V0.copy()
    else:
        V = np.empty((P, K2, NP, 3), np.float32)
    fscale = np.ones(len(live), np.float32)
    keep = []  # the arrays whose addresses C reads

    def addr(arrs, dt):
        a = [c(x, dt) for x in arrs]
        keep.extend(a)
        return np.array([x.ctypes.data for x in a], np.uint64)

    nb = len(bounces)
    a_off = addr([b.offsets for b in bounces], np.int64)
    a_tail = addr([b.tail for b in bounces], np.uint32)
    a_pw = addr([t[1] for t in tables], np.int32)
    a_slot = addr([b.slot for b in bounces], np.uint16)
    lo, hi = np.empty(NP, np.int32), np.empty(NP, np.int32)
    NPe = (_lib.gi_powslots(P, nb, a_off, a_slot, a_tail, a_pw, qpos, NP, K1, lo, hi) + 1) if len(live) else 1
    if not len(live):
        hi[:] = -1
    blo, width = dense_blocks(lo[:NPe], hi[:NPe])
    ub = sparse_bound(bounces, live, K1, K2, NP)
    dense = use_dense(K2, width, len(live), int(ub[-1]))
    fz = Frozen(int(i), K2, NP, V, live, h[live], fscale, lo=blo, width=width)
    boff = fz.block_offsets
    Wd = int(3 * width.sum())
    if dense:
        Fd = np.empty((len(live), Wd), np.uint16)
        Fub = np.empty((0, 4), np.uint16)
    else:
        Fd = np.empty(0, np.uint16)
        Fub = np.empty((int(ub[-1]), 4), np.uint16)
    counts = np.zeros(len(live), np.int32)
    C1 = c(C1, np.float32)
    _lib.gi_freeze(P if pixels is None else len(pixels), nb, a_off, a_slot, a_tail,
                   addr([b.val.view(np.uint16) for b in bounces], np.uint16),
                   addr([b.scale for b in bounces], np.float32), addr([t[0] for t in tables], np.int32), a_pw,
                   addr([t[2] for t in tables], np.float32),
                   pu.units.shape[1], c(pu.units, np.int32), c(pu.weights, np.float32), c(pu.k0, np.int32),
                   c(pu.t, np.float32), C1, C1.shape[1], K1, K2, NP, int(i), qpos, ub, V, Fub, counts, fscale,
                   int(dense), NPe, blo, width, boff, Wd, Fd, None if pixels is None else pixels.ctypes.data)
    if dense:
        fz.dense = Fd
        return fz
    # squeeze the upper-bound layout
    offsets = np.concatenate([[0], np.cumsum(counts, dtype=np.int64)])
    sel = np.repeat(ub[:-1], counts) + (np.arange(offsets[-1]) - np.repeat(offsets[:-1], counts))
    return Frozen(int(i), K2, NP, V, live, h[live], fscale, offsets, Fub[sel])


def frame(fz: Frozen, pu: PixelUnits, C1i: np.ndarray, ck: np.ndarray, d: np.ndarray, K1: int,
          pix: np.ndarray, img: np.ndarray) -> np.ndarray:
    """gi_frame / gi_frame_dense (reference: freeze.frame_numpy): writes the hit pixels'
    radiance into img (H·W, 3) float32 at the flat indices pix (P,) int64; returns img."""
    P = len(pu.k0)
    NP, K2 = fz.NP, fz.K2
    assert img.dtype == np.float32 and img.flags.c_contiguous and img.shape[-1] == 3
    dp = np.stack([np.asarray(d, np.float64) ** n for n in range(NP)])
    ckn = (ck[:, None, :].astype(np.float64) * dp[None]).astype(np.float32)        # (K2, NP, 3)
    qpos = fz.qpos(P)
    pix = c(pix, np.int64)
    if fz.dense is not None:
        # the coefficients in the dense columns' layout (Frozen), zero on padding
        slot, pw, ch = fz.dense_cells()
        ok = (slot >= 0) & (slot < K1)
        CT = np.zeros((C1i.shape[0], len(slot)), np.float32)
        CT[:, ok] = C1i[:, slot[ok], ch[ok]]
        _lib.gi_frame_dense(P, NP, c(fz.V, np.float32), c(ckn, np.float32), qpos, fz.NPe, fz.width,
                            fz.block_offsets, len(slot), fz.dense, c(fz.scale, np.float32), c(fz.h, np.float32),
                            c(pu.k0, np.int32), c(pu.t, np.float32), CT, c(dp[:fz.NPe], np.float32), pix, img)
        return img
    Tab = (C1i.astype(np.float32)[:, :, None, None, :] * ckn[None, None]).reshape(C1i.shape[0], -1, 3)
    _lib.gi_frame(P, K2 * NP, c(fz.V, np.float32), c(ckn, np.float32), qpos, c(fz.offsets, np.int64),
                  c(fz.entries, np.uint16), c(fz.scale, np.float32), c(fz.h, np.float32), c(pu.k0, np.int32),
                  c(pu.t, np.float32), c(Tab, np.float32), Tab.shape[1], pix, img)
    return img
