"""Denoising the multibounce tensors once, at precomputation, so that editing stays linear.

A frame is a dot product of per-pixel tensor entries with BRDF coefficients (polynomial-gi
eq. 20, 28): B(p) = Σ_{s,t} c_s(θo(p)) d̄_t T_{s,t}(p), with s the first-vertex slot (diffuse,
half-angle bands, Fresnel layer) and t the tail (the multiset of diffuse-equivalent units).
Each basis image T_{s,t}(·) is a path-traced image of the scene with the first vertex's BRDF
replaced by one basis function, so it carries Monte Carlo noise of its own. A denoiser D is not
linear, D(Σ a X) ≠ Σ a D(X); what this module keeps exact is the *structure*: it replaces
every basis image by its denoised version, T̃_{s,t} = D(T_{s,t}) (Intel Open Image Denoise,
the same albedo and normal guides for all), so the image stays exactly linear in the
first-vertex coefficients and polynomial in the diffuse equivalents. The approximation is that
Σ c D(T) stands for the denoised image of Σ c T.

Direct light (bounce 1, one tail) is denoised per slot. Bounces ≥ 2 would need slots × tails
images (65 × 34 for three units and four bounces): there the slot axis is first reduced to
a few non-negative hat functions over the half-angle bands (φ_r, a partition of unity,
nodes denser near the mirror direction), Y_{r,t} = Σ_s φ_r(s) T_{s,t}, and the Y are denoised.
A material's coefficients are mapped onto the hats by least squares weighted by each band's
measure (``projectors``, which keeps the energy Σ μ_j c_j), exact for coefficients that are
piecewise linear between the nodes; indirect light reflected
by a lobe narrower than the node spacing (a few bands near θh = 0 are kept as nodes) is
smoothed (bounce 2: 12 nodes per layer; bounces ≥ 3, a few percent of the image: 6). Per
bounce, the basis images holding ENERGY_SHARE of its energy under every probe material (white
GGX from α 0.02 to 1, and equal coefficients) are denoised, the many tiny rest keep their
noise. The hat components live in slots K1 … of the stored tensor, and the
renderer extends each unit's coefficient table with c̃ (``extend_coefficients``), so the
freeze and frame kernels are unchanged.

The tails of one hat component are denoised together: OIDN runs once on their sum
S_r = Σ_t Y_{r,t} (one image per component instead of one per component and tail: 82 OIDN
images instead of 208 on the sofa, half the CPU), and each tail takes the share of D(S_r)
that it has of the sum under a box filter B within objects,
Ỹ_{r,t} = D(S_r) · B(Y_{r,t}) / B(S_r) (``share_filter``, SHARE_WIDTH). The tails still sum to
the denoised sum exactly, so a frame whose tails weigh alike (every d̄_t equal) is exactly the
denoised image; otherwise the approximation is that the tails' mix varies slowly over the
object (it is the route the light took through the scene's objects, e.g. the sofa's floor-lit
underside against its wall-lit back), which it does at the box's scale.

Guides (OIDN ``albedo`` and ``normal``, noise-free, ``cleanAux``): the shading normal of the
first vertex, and an albedo of 1 on editable objects (the basis BRDFs are not the material) or
the fixed material's albedo on baked objects. Background pixels are zero in every basis image
and stay zero.
"""
from __future__ import annotations

import numpy as np

from ...errors import GlintError
from .tensors import Bounce

SCALE_MAX = 16384.0
# hat nodes over the bands per layer: bounce 2 (most of the indirect light, glossy reflections
# of nearby objects), bounces ≥ 3 (a few percent of the image; 2 nodes, a linear ramp over θh,
# made bounce 3 of a glossy floor 35 % wrong per pixel in tests/gi/test_gi_denoise.py)
HATS = (12, 6)
# per bounce, basis images are denoised in decreasing order of energy until this share of the
# bounce's energy is covered; the rest (many tiny tail images) keep their noise. The share is
# kept for every probe material (``slot_weights``: an image's energy is its magnitude times its
# slot's coefficient under the probe) as well as for equal coefficients: the near-mirror bands
# and hats hold little light but a glossy material multiplies them by hundreds (ranked by
# magnitude alone and left raw, they made a GGX α 0.1 floor sparkle at 640×480)
ENERGY_SHARE = 0.995
PROBE_ALPHAS = (0.02, 0.05, 0.1, 0.2, 0.4, 1.0)
# OIDN's quality: "fast" halves the CPU time of "balanced" but left 0.05 points more error
# against Mitsuba on the sofa (2.02 against 1.97 %, docs/benchmarks/history/
# 2026-12-06-gi-denoise-speed.md); with the tails denoised together the images are few enough
QUALITY = "balanced"
# box width (pixels at 320 wide) of the tails' shares when the indirect bounces' tails are
# denoised together (denoise_bounce): a wider box smooths the shares' noise and blurs where the
# tails' mix changes (bias), a narrower one the reverse, and a share is zero wherever its box
# saw none of the tail, so narrower boxes leave sparser tensors. Against Mitsuba, one render,
# 320×240: sofa 1.95 / 1.95 / 1.97 % and the Cornell box 2.61 / - / 2.62 % at 5 / 7 / 11 pixels
# (21: Cornell 2.79 %); bounce-4 entries 3.0 / 3.9 / 4.4 M on the sofa
SHARE_WIDTH = 5


def hat_nodes(J: int, count: int) -> np.ndarray:
    """(count,) int64 increasing band indices in [0, J − 1], first 0 and last J − 1: the
    first few consecutive (glossy lobes live there), then geometric spacing."""
    count = int(min(max(count, 2), J))
    dense = min(4, count - 1)
    rest = count - dense
    tail = np.geomspace(dense, J - 1, rest) if rest > 1 else np.full(rest, J - 1.0)
    nodes = np.unique(np.concatenate([np.arange(dense), np.round(tail)]).astype(np.int64))
    # rounding may merge nodes: fill the gaps with the first missing indices
    k = dense
    while len(nodes) < count:
        if k not in nodes:
            nodes = np.sort(np.append(nodes, k))
        k += 1
    return nodes


def hat_basis(J: int, layers: int, count: int) -> np.ndarray:
    """Φ (K1, R) float64, K1 = 1 + J·layers, R = 1 + count·layers: column 0 the diffuse slot,
    then per layer ``count`` hat functions over the J bands (each row of a layer sums to 1)."""
    nodes = hat_nodes(J, count)
    H = np.zeros((J, len(nodes)))
    b = np.arange(J)
    for r, n in enumerate(nodes):
        left = nodes[r - 1] if r > 0 else None
        right = nodes[r + 1] if r + 1 < len(nodes) else None
        w = np.zeros(J)
        w[b == n] = 1.0
        if left is not None:
            m = (b > left) & (b < n)
            w[m] = (b[m] - left) / (n - left)
        if right is not None:
            m = (b > n) & (b < right)
            w[m] = (right - b[m]) / (right - n)
        H[:, r] = w
    K1, R = 1 + J * layers, 1 + len(nodes) * layers
    Phi = np.zeros((K1, R))
    Phi[0, 0] = 1.0
    for l in range(layers):
        Phi[1 + l * J:1 + (l + 1) * J, 1 + l * len(nodes):1 + (l + 1) * len(nodes)] = H
    return Phi


def component_sets(J: int, layers: int, N: int, hats=HATS) -> list[np.ndarray]:
    """The hat bases Φ (K1, R) of the indirect bounces: one for bounce 2, one for bounces ≥ 3
    (as many as the bounces need)."""
    return [hat_basis(J, layers, h) for h in hats[:max(0, min(N - 1, 2))]]


def component_offsets(K1: int, phis: list[np.ndarray]) -> list[int]:
    """First slot of each component set: K1, K1 + R_2, …"""
    return [K1 + sum(p.shape[1] for p in phis[:i]) for i in range(len(phis))]


def projectors(phi: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(Kθ, R, K1) float64 weighted least-squares maps c ↦ c̃ per view-angle node:
    c̃ = argmin Σ_s w_s (c_s − (Φ c̃)_s)², weights (Kθ, K1) > 0 the measure of each basis
    function (μ_j = ∫_band q cos θi dωi, basis._iso_basis). With hats summing to 1 this keeps
    Σ_s w_s c_s, so a uniformly lit surface's indirect light is kept exactly (the
    white-furnace property of the projection, basis.py)."""
    out = np.zeros((weights.shape[0], phi.shape[1], phi.shape[0]))
    for k, w in enumerate(weights):
        A = phi.T @ (w[:, None] * phi)
        out[k] = np.linalg.solve(A, phi.T * w[None, :])
    return out


def extend_coefficients(C1: np.ndarray, maps: list[np.ndarray]) -> np.ndarray:
    """(Kθ, K1, 3) first-vertex coefficients -> (Kθ, K1 + ΣR, 3): the slots, then per component
    set its hat coefficients c̃ (``projectors``: maps [(Kθ, R, K1)])."""
    if not maps:
        return C1
    ext = [np.einsum("krs,ksc->krc", m, C1.astype(np.float64)).astype(C1.dtype) for m in maps]
    return np.concatenate([C1, *ext], axis=-2)


def basis_weights(J: int, layers: int, qkind: int) -> np.ndarray:
    """(Kθ, K1) the measure of every first-vertex basis function per view-angle node: 1 for the
    diffuse slot (its own component), μ(1) for the bands, μ(m5) for the Fresnel layer."""
    from .basis import THETA_NODES, _iso_basis
    *_, mu, a12, _ = _iso_basis(J, qkind)
    w = np.ones((THETA_NODES, 1 + J * layers))
    w[:, 1:1 + J] = mu
    if layers == 2:
        w[:, 1 + J:] = a12
    return np.maximum(w, 1e-9 * w.max())


def slot_weights(J: int, layers: int, qkinds, phis: list[np.ndarray]) -> list[np.ndarray]:
    """What an entry of each slot weighs in a frame under each probe material: equal
    coefficients, then white GGX probes (PROBE_ALPHAS, albedo 1) projected with each quotient
    in ``qkinds``, their |coefficient| maximised over view-angle nodes and channels. Returns
    [(M, K1) for the first-vertex slots, then (M, R) per hat set of ``phis``] float64, M
    probes (the first all ones)."""
    from ...scene import GGX
    from .basis import project
    K1 = 1 + J * layers
    w1 = [np.ones(K1)]
    wh = [[np.ones(p.shape[1])] for p in phis]
    for q in sorted(set(int(x) for x in qkinds)) or [0]:
        maps = [projectors(p, basis_weights(J, layers, q)) for p in phis]
        for a in PROBE_ALPHAS:
            first = project(GGX(alpha=a, specular=(1.0, 1.0, 1.0), albedo=(1.0, 1.0, 1.0)), J, layers, 1, None, q).first
            ext = np.abs(extend_coefficients(first.astype(np.float64), maps)).max(axis=(0, 2))
            w1.append(ext[:K1])
            off = K1
            for i, p in enumerate(phis):
                wh[i].append(ext[off:off + p.shape[1]])
                off += p.shape[1]
    return [np.stack(w1)] + [np.stack(w) for w in wh]


def guides(prim, fixed: np.ndarray, fixed_albedo: list, shape: tuple[int, int]):
    """(albedo, normal) (H, W, 3) float32 guide images (module docstring)."""
    H, W = shape
    alb = np.zeros((H * W, 3), np.float32)
    nrm = np.zeros((H * W, 3), np.float32)
    a = np.ones((len(prim.pixel), 3), np.float32)
    for o in np.nonzero(fixed)[0]:
        a[prim.obj == o] = np.clip(np.asarray(fixed_albedo[o], np.float32), 0.0, 1.0)
    alb[prim.pixel] = a
    nrm[prim.pixel] = prim.ns
    return alb.reshape(H, W, 3), nrm.reshape(H, W, 3)


def _oidn(img: np.ndarray, albedo: np.ndarray, normal: np.ndarray, quality: str) -> np.ndarray:
    try:
        import pyoidn
    except ImportError:  # pragma: no cover - a declared dependency
        raise GlintError("GI denoising needs Intel Open Image Denoise (pip install pyoidn)", status=500) from None
    return pyoidn.denoise(np.ascontiguousarray(img, np.float32), albedo, normal, hdr=True, clean_aux=True,
                          quality=quality)


def _entries(b: Bounce):
    """(pixel (n,) int64, slot, tail, value (n, 3) float32) of a bounce's entries."""
    P = len(b.offsets) - 1
    pix = np.repeat(np.arange(P), np.diff(b.offsets))
    return pix, b.slot.astype(np.int64), b.tail.astype(np.int64), b.val.astype(np.float32) * b.scale[pix, None]


def share_filter(obj_img: np.ndarray, width: int) -> "callable":
    """A box filter of ``width`` pixels that does not mix objects: f(img (H, W, C)) -> (H, W, C)
    = Σ over the box of the pixels of the centre's object / their count (0 off objects).
    obj_img (H, W) int object ids, −1 off objects."""
    from scipy.ndimage import uniform_filter
    objs = [int(o) for o in np.unique(obj_img) if o >= 0]
    masks = [(obj_img == o).astype(np.float32) for o in objs]
    dens = [uniform_filter(m, size=width, mode="constant") for m in masks]

    def f(img: np.ndarray) -> np.ndarray:
        out = np.zeros_like(img)
        for m, den in zip(masks, dens):
            num = uniform_filter(img * m[..., None], size=(width, width, 1), mode="constant")
            out += np.where((m > 0)[..., None], num / np.maximum(den, 1e-12)[..., None], 0.0)
        return out
    return f


def share_width(W: int) -> int:
    """Box width of the tails' shares (``denoise_bounce``): SHARE_WIDTH pixels at 320 wide, in
    proportion to the image (odd, at least 3)."""
    return 2 * max(1, round(W * SHARE_WIDTH / 320 / 2)) + 1


def denoise_bounce(b: Bounce, pixel: np.ndarray, shape: tuple[int, int], albedo: np.ndarray,
                   normal: np.ndarray, mix: np.ndarray | None, slot0: int, quality: str = QUALITY,
                   denoiser=None, obj: np.ndarray | None = None,
                   weights: np.ndarray | None = None) -> tuple[Bounce, int]:
    """One bounce's tensor with every basis image denoised: (new Bounce, images denoised).

    mix None: the slots themselves (entries keep their slots), one image each. mix (K1, R):
    component r is Σ_s mix[s, r] T_s, stored in slot slot0 + r; with ``obj`` (P,) the object
    of each hit pixel, the tails of a component are denoised together: D(Σ_t Y_t) once, split
    among the tails by their shares B(Y_t) / B(Σ_t Y_t) under a box filter B within objects
    (``share_filter``), so the tails sum to the denoised sum exactly and a frame at any
    diffuse equivalents weighs smooth images (module docstring); without ``obj``, one image
    per (component, tail). pixel (P,) flat hit-pixel indices of the (H, W) = shape image.
    weights (M, slots or components) per probe material the coefficient of each
    (``slot_weights``): an image is left raw only if, under every probe, the images left raw
    hold less than 1 − ENERGY_SHARE of the bounce's energy (None: magnitude alone).
    ``denoiser(img, albedo, normal) -> img`` replaces OIDN (tests)."""
    H, W = shape
    P = len(b.offsets) - 1
    pix, slot, tail, val = _entries(b)
    if mix is not None:
        nz = np.nonzero(mix)
        comp_of = [[] for _ in range(mix.shape[0])]
        for s, r in zip(*nz):
            comp_of[s].append((r, mix[s, r]))
        # expand each entry into its components (hats overlap: at most two per band)
        reps = np.array([len(c) for c in comp_of])[slot]
        e = np.repeat(np.arange(len(slot)), reps)
        rr = np.concatenate([[r for r, _ in comp_of[s]] for s in range(mix.shape[0])] or [[]]).astype(np.int64)
        ww = np.concatenate([[w for _, w in comp_of[s]] for s in range(mix.shape[0])] or [[]])
        start = np.concatenate([[0], np.cumsum([len(c) for c in comp_of])])
        k = np.arange(len(e)) - np.repeat(np.cumsum(reps) - reps, reps)
        sel = start[slot[e]] + k
        pix, slot, tail, val = pix[e], rr[sel], tail[e], val[e] * ww[sel, None].astype(np.float32)
    fn = denoiser or (lambda im, a, n: _oidn(im, a, n, quality))
    key = slot * (int(tail.max()) + 1 if len(tail) else 1) + tail
    T = int(tail.max()) + 1 if len(tail) else 1
    order = np.argsort(key, kind="stable")
    key_s = key[order]
    groups = np.flatnonzero(np.r_[True, key_s[1:] != key_s[:-1]]) if len(key_s) else np.zeros(0, np.int64)
    bounds = np.r_[groups, len(key_s)]
    energy = np.add.reduceat(np.abs(val[order]).sum(1), groups) if len(groups) else np.zeros(0)
    todo = np.zeros(len(groups), bool)
    probes = np.ones((1, 1)) if weights is None else np.asarray(weights, np.float64)
    for w in probes:
        e = energy * (w[key_s[groups] // T] if weights is not None and len(groups) else 1.0)
        rank = np.argsort(-e, kind="stable")
        cum = np.cumsum(e[rank]) / max(float(e.sum()), 1e-300)
        todo[rank[:int(np.searchsorted(cum, ENERGY_SHARE)) + 1]] = True
    img = np.zeros((H * W, 3), np.float32)
    images = 0

    def column(g):
        idx = order[bounds[g]:bounds[g + 1]]
        dense = np.zeros((P, 3), np.float32)
        np.add.at(dense, pix[idx], val[idx])
        return dense

    def denoised(dense):
        img[:] = 0.0
        img[pixel] = dense
        return np.maximum(fn(img.reshape(H, W, 3), albedo, normal).reshape(H * W, 3)[pixel], 0.0)

    cols: dict[int, np.ndarray] = {}               # group key -> per-pixel values (P, 3)
    merge = mix is not None and obj is not None
    if merge:
        oimg = np.full(H * W, -1, np.int64)
        oimg[pixel] = obj
        box = share_filter(oimg.reshape(H, W), share_width(W))
        comp = key_s[groups] // T
        for r in np.unique(comp[todo]):
            gs = np.nonzero(todo & (comp == r))[0]
            Y = np.stack([column(g) for g in gs], 1)                       # (P, n, 3)
            total = Y.sum(1)
            if not np.any(total):
                continue
            D = denoised(total)
            images += 1
            full = np.zeros((H * W, len(gs) * 3), np.float32)
            full[pixel] = Y.reshape(P, -1)
            Bt = box(full.reshape(H, W, -1)).reshape(H * W, len(gs), 3)[pixel]   # (P, n, 3)
            Bs = Bt.sum(1)
            # shares of the smoothed tails; where the box saw nothing, the pixel's own
            ok = Bs > 1e-30 * max(float(Bs.max()), 1e-30)
            own = total > 0
            share = np.where(ok[:, None], Bt / np.where(ok, Bs, 1.0)[:, None],
                             np.where(own[:, None], Y / np.where(own, total, 1.0)[:, None], 0.0))
            for j, g in enumerate(gs):
                cols[int(key_s[bounds[g]])] = D * share[:, j]
    for g in range(len(groups)):
        k = int(key_s[bounds[g]])
        if k in cols:
            continue
        dense = column(g)
        if not np.any(dense):
            continue
        if todo[g] and not merge:
            dense = denoised(dense)
            images += 1
        cols[k] = dense
    out_cols = sorted(cols.items())
    keys = np.array([k for k, _ in out_cols], np.int64)
    vals = np.stack([v for _, v in out_cols], 1) if out_cols else np.zeros((P, 0, 3), np.float32)  # (P, G, 3)
    amax = np.abs(vals).max(axis=(1, 2)) if vals.size else np.zeros(P, np.float32)
    scale = np.where(amax > 0, amax / SCALE_MAX, 1.0).astype(np.float32)
    q = (vals / scale[:, None, None]).astype(np.float16)
    p_idx, g_idx = np.nonzero((q != 0).any(-1))
    counts = np.bincount(p_idx, minlength=P)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    s_out = keys[g_idx] // T + slot0
    if s_out.size and s_out.max() >= 65536:
        raise GlintError("GI denoising: too many slots for the tensor format")
    return Bounce(offsets, s_out.astype(np.uint16), (keys[g_idx] % T).astype(np.uint32), q[p_idx, g_idx], scale), images
