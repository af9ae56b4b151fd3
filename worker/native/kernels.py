"""The kernel backend, chosen once (as trimesh picks its Embree or its NumPy ray backend): the
multithreaded C kernels when the library is built, else the NumPy references. Both backends
have the same methods with the same arrays in and out; the tests check that they agree
(tests/core/test_native.py, tests/perf/test_kernels.py, tests/fields, tests/gi, tests/paint,
tests/capture, tests/fit).

    k = kernels()            # the process default: "native" when built, else "numpy"
    k = kernels("numpy")     # the references, e.g. to test or to debug

The core kernels (shading, light tables, frame assembly, cuts, tonemap, fit transfer) are
methods of the backend itself; the other families are sub-objects of the same backend, each
with the backend's ``name``:

    k.fields    cut fields of moving objects (src/fields.c; worker/native/fields.py)
    k.gi        GI path tracing, freezing and frames (src/gi.c; worker/native/gi.py)
    k.paint     paint prefiltering and shading (src/paint.c; worker/native/paint.py)
    k.capture   HDR merge and fisheye maps (src/capture.c; worker/native/capture.py)
    k.refine    where vertex shading needs per-pixel shading (src/refine.c; worker/native/refine.py)
    k.fit       SRBF transfer rows and energy rows (src/fit.c; the backend's own methods)

A renderer or a precomputation keeps the backend it was built with and passes it on; nothing
below it asks again, and no module decides on its own whether the library is there.

Each C kernel has one typed wrapper: it checks and converts the arrays (dtype, contiguity),
converts angles to the C side's radians, and names the parameters as the C prototype does
(``worker.native.bind``).
"""
from __future__ import annotations

import threading
from functools import cached_property, lru_cache

import numpy as np

from . import (
    available,
    bind,
    c,
    f32p,
    f64,
    f64p,
    i32,
    i32p,
    i64,
    i64p,
    lib,
    model_id,
    u8p,
    voidp,
)


class _Families:
    """The per-family sub-objects, made on first use (a paint worker never imports the GI code)."""
    name: str

    @cached_property
    def fields(self):
        from . import fields
        return fields.NativeFields() if self.name == "native" else fields.NumpyFields()

    @cached_property
    def gi(self):
        from . import gi
        return gi.NativeGI() if self.name == "native" else gi.NumpyGI()

    @cached_property
    def paint(self):
        from . import paint
        return paint.NativePaint() if self.name == "native" else paint.NumpyPaint()

    @cached_property
    def capture(self):
        from . import capture
        return capture.NativeCapture() if self.name == "native" else capture.NumpyCapture()

    @cached_property
    def refine(self):
        from . import refine
        return refine.NativeRefine() if self.name == "native" else refine.NumpyRefine()

    @property
    def fit(self):
        """The fit kernels (transfer, energy_rows) are the backend's own methods."""
        return self

    def families(self) -> dict:
        """Every sub-object by family name (each has the backend's ``name``)."""
        return {f: getattr(self, f) for f in ("fields", "gi", "paint", "capture", "refine", "fit")}


class NumpyKernels(_Families):
    """The NumPy references (worker/core, worker/fit), one method per kernel."""
    name = "numpy"

    def shade_points(self, normals, wo, cut_of, mat_of, cuts, node_l, node_w, tree, mats, node8=None):
        from ..core.render import shade_points_numpy
        return shade_points_numpy(normals, wo, cut_of, mat_of, cuts, node_l, node_w, tree, mats)

    def shade_blend(self, normals, wo, verts, bary, mat_of, cuts, node_l, node_w, tree, mats, node8=None, face=None):
        from ..core.render import shade_blend_numpy
        return shade_blend_numpy(normals, wo, verts, bary, mat_of, cuts, node_l, node_w, tree, mats)

    def light_tables(self, lighting, rotation_deg, intensity, tree):
        from ..core.lighting import light_tables_numpy
        return light_tables_numpy(lighting, rotation_deg, intensity, tree)

    def interpolate(self, tri, uv, faces, vert_rgb, out):
        from ..core.render import interpolate_numpy
        return interpolate_numpy(tri, uv, faces, vert_rgb, out)

    def background(self, sample, dirs, uv0, envmap, rotation_deg, intensity, out, shadow=None, eye=None):
        from ..core.render import background_numpy
        return background_numpy(sample, dirs, uv0, envmap, rotation_deg, intensity, out, shadow, eye)

    def resolve(self, tri, uv, faces, vert_rgb, bg, samples, out):
        from ..core.render import resolve_numpy
        return resolve_numpy(tri, uv, faces, vert_rgb, bg, samples, out)

    def primary_hits(self, vertices, faces, cam, dirs, width, height, samples, omax, into=None):
        from ..core.primary import primary_hits_numpy
        return primary_hits_numpy(vertices, faces, cam, dirs, width, height, samples, omax, into)

    def rotate_dirs(self, dirs, basis):
        from ..core.render import rotate_dirs_numpy
        return rotate_dirs_numpy(dirs, basis)

    def env_coords(self, dirs, rows=None):
        from ..core.render import env_coords_numpy
        return env_coords_numpy(dirs if rows is None else np.asarray(dirs)[rows])

    def env_lookup(self, dirs, envmap, rotation_deg, intensity, mask=None, out=None):
        from ..core.render import env_lookup_numpy
        return env_lookup_numpy(dirs, envmap, rotation_deg, intensity, mask, out)

    def build_cuts(self, values, tau):
        from ..core.cuts import build_cuts_numpy
        return build_cuts_numpy(values, tau)

    def coarsen(self, cs, tau):
        from ..core.cuts import coarsen_numpy
        return coarsen_numpy(cs, tau)

    def transfer(self, normals, wo, verts, bary, cuts, node_l, node_w, tree, basis):
        from ..fit.transfer import transfer_numpy
        return transfer_numpy(normals, wo, verts, bary, cuts, node_l, node_w, tree, basis)

    def energy_rows(self, basis, wo, nt, nphi):
        from ..fit.basis import energy_rows_numpy
        return energy_rows_numpy(basis, wo, nt, nphi)

    def tonemap(self, rgb, exposure, curve):
        from ..core.tonemap import tonemap_numpy
        return tonemap_numpy(rgb, exposure, curve)

    def tonemap_pair(self, rgb, exposure, curve):
        from ..core.tonemap import tonemap_pair_numpy
        return tonemap_pair_numpy(rgb, exposure, curve)


class NativeKernels(_Families):
    """Typed wrappers of the C kernels in src/*.c (glintk.c, shade.c, lighting.c, frame.c, fit.c)."""
    name = "native"

    def __init__(self):
        if lib is None:
            raise RuntimeError("the C kernels are not built (make build)")
        self._shade = bind(
            "glk_shade_points", None, P=i64, normals=f32p, wo_dirs=f32p, cut_of=i32p, mat_of=i32p,
            cut_off=i64p, cut_h=u8p, cut_q=u8p, node8=f32p, node_dir=f32p, node_radius=f32p, node_geo=f32p,
            level_off=i64p, H=i32, mat_kind=i32p, mat_params=f32p, mat_refine=f32p, mat_extent=f32p,
            tables=f32p, table_off=i64p, anc=f32p, alevel=i32, out=f32p)
        self._blend = bind(
            "glk_shade_blend", None, P=i64, normals=f32p, wo_dirs=f32p, verts=i32p, bary=f32p, mat_of=i32p,
            G=i64, group=i64p, cut_off=i64p, cut_h=u8p, cut_q=u8p, node8=f32p, node_radius=f32p, node_geo=f32p,
            level_off=i64p, H=i32, mat_kind=i32p, mat_params=f32p, mat_refine=f32p, mat_extent=f32p,
            tables=f32p, table_off=i64p, out=f32p)
        self._simd = bind("glk_shade_simd", i32, want=i32)
        self._light = bind(
            "glk_light_tables", None, N=i64, indptr=i64p, pix=i32p, wts=f32p, map=f32p, Hm=i32, Wm=i32,
            rot=f64, intensity=f64, H=i32, node_dir=f32p, scratch=f64p, node_l=f32p, node_w=f32p, node8=f32p, rmap=f32p)
        self._interp = bind("glk_interpolate", None, P=i64, tri=i32p, uv=f32p, faces=i32p, vert_rgb=f32p, out=f32p)
        self._background = bind(
            "glk_background", None, n=i64, sample=i64p, dirs=f32p, uv0=f32p, map=f32p, Hm=i32, Wm=i32, rot=f64,
            intensity=f64, shadow=voidp, G=i32, gx0=f64, gz0=f64, gstep=f64, gy=f64, ex=f64, ey=f64, ez=f64, out=f32p)
        self._primary = bind("glk_primary_hits", None, nv=i64, V=f32p, nf=i64, F=i32p, cam=f64p, dirs=f32p,
                             W=i32, H=i32, S=i32, omax=f64, tri=i32p, uv=f32p, t=f32p, box=i32p, init=i32,
                             fbase=i32)
        self._rotate = bind("glk_rotate_dirs", None, P=i64, src=f32p, basis=f32p, out=f32p)
        self._env_coords = bind("glk_env_coords", None, n=i64, dirs=f32p, out=f32p)
        self._env_coords_rows = bind("glk_env_coords_rows", None, n=i64, rows=i64p, dirs=f32p, out=f32p)
        self._env_simd = bind("glk_env_simd", i32, want=i32)
        self._resolve = bind("glk_resolve", None, P=i64, S=i32, tri=i32p, uv=f32p, faces=i32p, vert_rgb=f32p,
                             bg=f32p, out=f32p)
        self._env = bind("glk_env_lookup", None, P=i64, dirs=f32p, mask=voidp, map=f32p, Hm=i32, Wm=i32,
                         rot=f64, intensity=f64, out=f32p)
        self._build = bind("glk_build_cuts", None, vals=f32p, B=i64, H=i32, tau=f64, heights=u8p, quant=u8p,
                           counts=i32p)
        self._coarsen = bind("glk_coarsen", None, V=i64, offsets=i64p, heights=u8p, quant=u8p, tau=f64,
                             out_h=u8p, out_q=u8p, counts=i32p)
        self._transfer = bind(
            "glk_fit_transfer", None, P=i64, normals=f32p, wo_dirs=f32p, verts=i32p, bary=f32p, cut_off=i64p,
            cut_h=u8p, cut_q=u8p, node_l=f32p, node_w=f32p, node_dir=f32p, node_radius=f32p, node_cs=f32p,
            level_off=i64p, H=i32, n_ref=i32, refine_r=f64p, extent=f64p, J=i32, xcut=f64, static_kind=i32,
            static_alpha=f64, f0=f64, C=i32, cell_off=i32p, cell_idx=i32p, cell_cand=f32p, gtab=f32p, NG=i32,
            T=f32p, E=f32p)
        self._energy_rows = bind(
            "glk_energy_rows", None, K=i64, wo=f64p, J=i32, centers=f64p, lam=f64p, xcut=f64, static_kind=i32,
            static_alpha=f64, f0=f64, nt=i32, tn=f64p, tw=f64p, nphi=i32, out=f64p)
        self._tonemap = bind("glk_tonemap", None, P=i64, rgb=f32p, exposure=f64, curve=i32, out=u8p)
        self._tonemap_pair = bind("glk_tonemap_pair", None, H=i64, W=i64, rgb=f32p, lut=u8p, out2=u8p, out1=u8p)
        self._tonemap_lut = bind("glk_tonemap_lut", None, exposure=f64, curve=i32, lut=u8p)
        self._tonemap_apply = bind("glk_tonemap_apply", None, n=i64, rgb=f32p, lut=u8p, out=u8p)
        self._luts: dict = {}
        self._luts_lock = threading.Lock()       # sessions' threads share the kernels
        self._tonemap_lut_size = bind("glk_tonemap_lut_size", i64)

    def simd(self, want: int = -1) -> int:
        """The shading kernel's vector path: want −1 asks, 0 forces scalar, 1 the best the CPU
        has (AVX2 + FMA, chosen at run time). Returns the path in use (0 scalar, 1 AVX2)."""
        return int(self._simd(int(want)))

    def light_tables(self, lighting, rotation_deg, intensity, tree):
        """(node_l, node_w (2N−1, 3), node8 (2N−1, 8)) float32 (see core.lighting.light_tables_numpy)."""
        indptr, pix, wts = lighting.csr()
        env = lighting.map
        hm, wm = env.shape[:2]
        m = len(tree.node_dir)
        node_l = np.empty((m, 3), np.float32)
        node_w = np.empty((m, 3), np.float32)
        node8 = np.empty((m, 8), np.float32)
        scratch = np.empty((m, 6), np.float64)
        rmap = np.empty((hm * wm, 4), np.float32)
        self._light(tree.n_leaves, indptr, pix, wts, c(env, np.float32), hm, wm, float(np.radians(rotation_deg)), float(intensity),
                    tree.height, tree.node_dir, scratch, node_l, node_w, node8, rmap)
        return node_l, node_w, node8

    def shade_points(self, normals, wo, cut_of, mat_of, cuts, node_l, node_w, tree, mats, node8=None):
        """(P, 3) float32 radiance (see core.render.shade_points_numpy). Points whose material
        has no C kernel branch (kind −1) are shaded by the NumPy reference. node8: the packed
        node records (core.lighting.pack_nodes), made here when not given."""
        if node8 is None:
            from ..core.lighting import pack_nodes
            node8 = pack_nodes(node_l, node_w)
        p = len(normals)
        out = np.empty((p, 3), np.float32)
        mat_of = c(mat_of, np.int32)
        no_kernel = mats.kind[mat_of] < 0 if p else np.zeros(0, bool)
        kind = np.where(mats.kind < 0, 0, mats.kind).astype(np.int32)   # never read for those points
        cut_c = c(cut_of, np.int32)
        if no_kernel.any():
            cut_c = cut_c.copy()
            cut_c[no_kernel] = -1                                      # the kernel writes zeros there
        self._shade(p, c(normals, np.float32), c(wo, np.float32), cut_c, mat_of, c(cuts.offsets, np.int64),
                    c(cuts.heights, np.uint8), c(cuts.quant, np.uint8), c(node8, np.float32),
                    tree.node_dir, tree.node_radius, _node_geo(tree), c(tree.level_offset, np.int64),
                    tree.height, kind, mats.params, mats.refine, mats.extent, mats.tables, mats.table_off,
                    *_ancestor_bounds(tree), out)
        if no_kernel.any():
            from ..core.render import shade_points_numpy

            k = np.nonzero(no_kernel)[0]
            out[k] = shade_points_numpy(normals[k], wo[k], np.asarray(cut_of)[k], mat_of[k], cuts, node_l,
                                        node_w, tree, mats)
        return out

    def shade_blend(self, normals, wo, verts, bary, mat_of, cuts, node_l, node_w, tree, mats, node8=None, face=None):
        """(P, 3) float32 radiance at points inside faces from their three cuts blended (see
        core.render.shade_blend_numpy). face : (P,) the face of each point, if known (points of
        one face have the same three vertices; else they are grouped by their vertices): the
        kernel merges a face's cuts once for all its points. Points whose material has no C
        kernel branch are shaded by the NumPy reference."""
        if node8 is None:
            from ..core.lighting import pack_nodes
            node8 = pack_nodes(node_l, node_w)
        p = len(normals)
        out = np.empty((p, 3), np.float32)
        vc = np.asarray(verts, np.int32).reshape(-1, 3)
        mat_of = np.asarray(mat_of, np.int32)
        if p == 0:
            return out
        order = (np.argsort(np.asarray(face), kind="stable") if face is not None
                 else np.lexsort((vc[:, 2], vc[:, 1], vc[:, 0])))
        vs, ms = vc[order], mat_of[order]
        cuts_at = np.nonzero((vs[1:] != vs[:-1]).any(axis=1))[0] + 1
        group = np.concatenate([[0], cuts_at, [p]]).astype(np.int64)
        no_kernel = mats.kind[ms] < 0
        kind = np.where(mats.kind < 0, 0, mats.kind).astype(np.int32)
        if no_kernel.any():
            vs = vs.copy()
            vs[no_kernel, 0] = -1                                      # the kernel writes zeros there
        res = np.empty((p, 3), np.float32)
        self._blend(p, c(np.asarray(normals)[order], np.float32), c(np.asarray(wo)[order], np.float32), c(vs, np.int32),
                    c(np.asarray(bary, np.float32).reshape(-1, 3)[order], np.float32), c(ms, np.int32),
                    len(group) - 1, group, c(cuts.offsets, np.int64), c(cuts.heights, np.uint8), c(cuts.quant, np.uint8),
                    c(node8, np.float32), tree.node_radius, _node_geo(tree),
                    c(tree.level_offset, np.int64), tree.height, kind, mats.params, mats.refine, mats.extent, mats.tables, mats.table_off, res)
        out[order] = res
        if no_kernel.any():
            from ..core.render import shade_blend_numpy

            k = order[np.nonzero(no_kernel)[0]]
            out[k] = shade_blend_numpy(np.asarray(normals)[k], np.asarray(wo)[k], vc[k],
                                       np.asarray(bary)[k], mat_of[k], cuts, node_l, node_w, tree, mats)
        return out

    def interpolate(self, tri, uv, faces, vert_rgb, out):
        self._interp(len(tri), c(tri, np.int32), c(uv, np.float32), c(faces, np.int32), c(vert_rgb, np.float32), out)
        return out

    def background(self, sample, dirs, uv0, envmap, rotation_deg, intensity, out, shadow=None, eye=None):
        """out[sample] = environment (× ground shadow) along dirs (see core.render.background_numpy)."""
        if out.dtype != np.float32 or not out.flags.c_contiguous:
            raise ValueError("out must be C-contiguous float32")
        grid, geo, e = None, (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0)
        if shadow is not None:
            grid = c(shadow[0], np.float32)
            geo = tuple(float(x) for x in shadow[1])
            e = tuple(float(x) for x in eye)
        self._background(len(sample), c(sample, np.int64), c(dirs, np.float32), c(uv0, np.float32),
                         c(envmap, np.float32), envmap.shape[0], envmap.shape[1], float(np.radians(rotation_deg)),
                         float(intensity), grid.ctypes.data if grid is not None else None,
                         grid.shape[0] if grid is not None else 0, *geo, *e, out)
        return out

    def primary_hits(self, vertices, faces, cam, dirs, width, height, samples, omax, into=None):
        """(tri, uv, t) of the primary rays dirs (H·W·S, 3) by face projection (see
        core.primary.primary_hits_numpy); into: (tri, uv, t, fbase) to update in place."""
        W, H, S = int(width), int(height), int(samples)
        d = c(dirs, np.float32)
        if d.shape != (W * H * S, 3):
            raise ValueError(f"dirs: {d.shape}, expected ({W * H * S}, 3)")
        V, F = c(vertices, np.float32), c(faces, np.int32)
        P = W * H * S
        if into is None:
            tri, uv, t, fbase = np.empty(P, np.int32), np.empty((P, 2), np.float32), np.empty(P, np.float32), 0
        else:
            tri, uv, t, fbase = into
            for a, dt, shape in ((tri, np.int32, (P,)), (uv, np.float32, (P, 2)), (t, np.float32, (P,))):
                if a.dtype != dt or a.shape != shape or not a.flags.c_contiguous or not a.flags.writeable:
                    raise ValueError(f"into: a writeable contiguous {np.dtype(dt).name} array of shape {shape}")
        box = np.empty((len(F), 4), np.int32)
        self._primary(len(V), V, len(F), F, c(cam, np.float64), d, W, H, S, float(omax), tri, uv, t, box,
                      int(into is None), int(fbase))
        return tri, uv, t

    def rotate_dirs(self, dirs, basis):
        """(P, 3) float32 dirs @ basis (see core.render.rotate_dirs_numpy)."""
        src = c(dirs, np.float32)
        out = np.empty_like(src)
        self._rotate(len(src), src, c(basis, np.float32), out)
        return out

    def env_simd(self, want: int = -1) -> int:
        """env_coords' build: want −1 asks, 0 forces the baseline, 1 the best the CPU has
        (AVX2 + FMA, chosen at run time). Returns the one in use (0 baseline, 1 AVX2)."""
        return int(self._env_simd(int(want)))

    def env_coords(self, dirs, rows=None):
        """(n, 2) float32 map coordinates of directions, or of dirs[rows] (see
        core.render.env_coords_numpy)."""
        src = c(dirs, np.float32)
        if rows is None:
            out = np.empty((len(src), 2), np.float32)
            self._env_coords(len(src), src, out)
            return out
        rows = c(rows, np.int64)
        if len(rows) and (rows.min() < 0 or rows.max() >= len(src)):
            raise IndexError(f"rows out of range for {len(src)} directions")
        out = np.empty((len(rows), 2), np.float32)
        self._env_coords_rows(len(rows), rows, src, out)
        return out

    def resolve(self, tri, uv, faces, vert_rgb, bg, samples, out):
        """Per-pixel mean over samples (see core.render.resolve_numpy)."""
        if out.dtype != np.float32 or not out.flags.c_contiguous:
            raise ValueError("out must be C-contiguous float32")
        self._resolve(len(out), int(samples), c(tri, np.int32), c(uv, np.float32), c(faces, np.int32),
                      c(vert_rgb, np.float32), c(bg, np.float32), out)
        return out

    def env_lookup(self, dirs, envmap, rotation_deg, intensity, mask=None, out=None):
        if out is None:
            out = np.zeros((len(dirs), 3), np.float32)
        m = c(mask, np.uint8) if mask is not None else None
        self._env(len(dirs), c(dirs, np.float32), m.ctypes.data if m is not None else None, c(envmap, np.float32),
                  envmap.shape[0], envmap.shape[1], float(np.radians(rotation_deg)), float(intensity), out)
        return out

    def build_cuts(self, values, tau):
        from ..core.cuts import CutSet

        values = c(values, np.float32)
        b, n = values.shape
        hmax = int(np.log2(n))
        heights = np.empty((b, n), np.uint8)
        quant = np.empty((b, n), np.uint8)
        counts = np.empty(b, np.int32)
        self._build(values, b, hmax, float(tau), heights, quant, counts)
        mask = np.arange(n)[None, :] < counts[:, None]
        offsets = np.zeros(b + 1, np.int64)
        np.cumsum(counts, out=offsets[1:])
        return CutSet(offsets, heights[mask], quant[mask], hmax)

    def coarsen(self, cs, tau):
        from ..core.cuts import CutSet

        V = cs.n_vertices
        oh = np.empty_like(cs.heights)
        oq = np.empty_like(cs.quant)
        counts = np.empty(V, np.int32)
        self._coarsen(V, c(cs.offsets, np.int64), c(cs.heights, np.uint8), c(cs.quant, np.uint8), float(tau),
                      oh, oq, counts)
        off = np.zeros(V + 1, np.int64)
        off[1:] = np.cumsum(counts)
        # each vertex's coarse cut was written at the start of its input range
        keep = np.repeat(cs.offsets[:-1], counts) + (np.arange(off[-1]) - np.repeat(off[:-1], counts))
        return CutSet(off, oh[keep], oq[keep], cs.height)

    def transfer(self, normals, wo, verts, bary, cuts, node_l, node_w, tree, basis):
        """(T (3, P, J), E (P, 3)) float32 SRBF transfer rows (see fit.transfer.transfer_numpy)."""
        from ..fit.basis import CUBE_CELLS, XCUT
        from ..models.table import STATICS

        P, J = len(normals), basis.J
        T = np.empty((3, P, J), np.float32)
        E = np.empty((P, 3), np.float32)
        pairs = np.asarray(basis.refinement(), np.float64).reshape(-1, 2)
        cell_off, cell_idx, cell_cand, gtab = basis.kernel_tables()
        self._transfer(P, c(normals, np.float32), c(wo, np.float32), c(verts, np.int32), c(bary, np.float32),
                       c(cuts.offsets, np.int64), c(cuts.heights, np.uint8), c(cuts.quant, np.uint8),
                       c(node_l, np.float32), c(node_w, np.float32), tree.node_dir, tree.node_radius, _node_cs(tree),
                       c(tree.level_offset, np.int64), tree.height, len(pairs), c(pairs[:, 0], np.float64),
                       c(pairs[:, 1], np.float64), J, float(XCUT), STATICS[basis.static], float(basis.static_alpha),
                       float(basis.fresnel_f0), CUBE_CELLS, cell_off, cell_idx, cell_cand, gtab, len(gtab), T, E)
        return T, E

    def energy_rows(self, basis, wo, nt, nphi):
        """g_j(ωo) (K, J) float64 (see fit.basis.energy_rows_numpy)."""
        from ..fit.basis import ROW_TMAX, polar_nodes
        from ..models.table import STATICS

        wo = c(np.atleast_2d(np.asarray(wo, np.float64)), np.float64)
        tn, tw, _ = polar_nodes(nt, nphi)
        out = np.empty((len(wo), basis.J))
        self._energy_rows(len(wo), wo, basis.J, c(basis.centers, np.float64), c(basis.bandwidths, np.float64),
                          float(ROW_TMAX), STATICS[basis.static], float(basis.static_alpha), float(basis.fresnel_f0),
                          len(tn), c(tn, np.float64), c(tw, np.float64), int(nphi), out)
        return out

    def tonemap(self, rgb, exposure, curve):
        from ..core.tonemap import CURVES

        src = c(rgb, np.float32)
        out = np.empty(src.shape, np.uint8)
        key = (float(exposure), CURVES[curve])
        lut = self._luts.get(key)
        if lut is None and src.size >= TONEMAP_LUT_MIN:
            # a frame's worth of values: the table (as glk_tonemap_pair's) pays for itself at once,
            # and the next frames of the same exposure and curve read it
            lut = self.tonemap_lut(*key)
            with self._luts_lock:
                self._luts[key] = lut
                while len(self._luts) > 4:
                    self._luts.pop(next(iter(self._luts)))
        if lut is not None:
            self._tonemap_apply(src.size, src, lut, out)
        else:
            self._tonemap(src.size // 3, src, key[0], key[1], out)
        return out

    def tonemap_pair(self, rgb, exposure, curve):
        from ..core.tonemap import CURVES

        src = c(rgb, np.float32)
        h, w = src.shape[0] // 2, src.shape[1] // 2
        out2 = np.empty(src.shape, np.uint8)
        out1 = np.empty((h, w, 3), np.uint8)
        self._tonemap_pair(h, w, src, self.tonemap_lut(float(exposure), CURVES[curve]), out2, out1)
        return out2, out1

    @lru_cache(maxsize=8)
    def tonemap_lut(self, exposure: float, curve: int) -> np.ndarray:
        """The (2¹⁹,) uint8 table of glk_tonemap_pair for one exposure and curve (512 KB; the
        last few kept: a bundle uses one)."""
        lut = np.empty(int(self._tonemap_lut_size()), np.uint8)
        self._tonemap_lut(float(exposure), int(curve), lut)
        lut.setflags(write=False)
        return lut


TONEMAP_LUT_MIN = 1 << 18     # values (a 300×300 frame) from which tonemap goes through the 2¹⁹-entry table

_CS: dict = {}


def _node_cs(tree) -> np.ndarray:
    """(2N−1, 2) float32 (cos R, sin R) of every tree node's radius (the shading and transfer
    kernels' cluster walks compare cosines instead of taking a cos or acos per node); kept per tree."""
    if id(tree) not in _CS:
        r = tree.node_radius.astype(np.float64)
        _CS[id(tree)] = (tree, np.ascontiguousarray(np.stack([np.cos(r), np.sin(r)], 1), np.float32))
    return _CS[id(tree)][1]


_GEO: dict = {}


def _node_geo(tree) -> np.ndarray:
    """(2N−1, 8) float32 per tree node: cos R, sin R, its direction (x, y, z), R, 0, 0 (R its
    radius): what the shading kernel's cluster walk tests of a node, in one 32-byte row, so that
    eight nodes are eight row loads rather than six gathers from three arrays (shade.c
    cone_mask8); kept per tree."""
    if id(tree) not in _GEO:
        g = np.zeros((len(tree.node_radius), 8), np.float32)
        g[:, :2] = _node_cs(tree)
        g[:, 2:5] = tree.node_dir
        g[:, 5] = tree.node_radius
        _GEO[id(tree)] = (tree, g)
    return _GEO[id(tree)][1]


ANCESTORS = 32        # nodes of the level the shading kernel's ancestor test looks at (shade.c)
_ANC: dict = {}


def _ancestor_bounds(tree) -> tuple[np.ndarray, int]:
    """(NA, 3) float32 (cos B, sin B, B) per node of the level of NA = ANCESTORS nodes (fewer in a
    smaller tree), and that level: B (radians) bounds the cone of every descendant D of the node A
    (angle(dir_A, dir_D) + R_D, D = A included), so that no descendant can reach within e of a
    direction farther than B + e from dir_A (shade.c ancestors_reaching); kept per tree."""
    if id(tree) not in _ANC:
        H = tree.height
        la = max(0, H - int(np.log2(ANCESTORS)))
        lev = np.asarray(tree.level_offset, np.int64)
        d = tree.node_dir.astype(np.float64)
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-30)
        na = 1 << (H - la)
        da = d[lev[la] + np.arange(na)]
        b = np.zeros(na)
        for h in range(la + 1):
            k = np.arange(1 << (H - h))
            a = k >> (la - h)
            ang = np.arccos(np.clip((d[lev[h] + k] * da[a]).sum(1), -1.0, 1.0)) + tree.node_radius[lev[h] + k]
            np.maximum.at(b, a, ang)
        _ANC[id(tree)] = (tree, np.ascontiguousarray(np.stack([np.cos(b), np.sin(b), b], 1), np.float32), la)
    return _ANC[id(tree)][1], _ANC[id(tree)][2]


def kernels(name: str | None = None):
    """The backend: "native", "numpy", or None for the default (native when built); one object
    per backend and process (kernels() is kernels("native") when the library is built)."""
    if name is None:
        # the one place that asks whether the library is there
        name = "native" if available() else "numpy"
    return _backend(name)


@lru_cache(maxsize=None)
def _backend(name: str):
    if name == "native":
        return NativeKernels()
    if name == "numpy":
        return NumpyKernels()
    raise ValueError(f"unknown kernel backend {name!r} (native or numpy)")


__all__ = ["NativeKernels", "NumpyKernels", "kernels", "model_id"]
