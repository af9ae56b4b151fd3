"""The paint kernels (src/paint.c) behind the backend's ``paint`` family: ``k.paint.prefilter``,
``background`` and ``shade`` take and return the same arrays in both backends. The NumPy
references are worker/renderers/paint/prefilter.py prefilter_numpy and worker/renderers/paint/render.py
background_numpy / shade_numpy (tests/paint checks they agree); the public functions
(prefilter.prefilter, render.background, render.shade) check the arrays and call these.
"""
from __future__ import annotations

import numpy as np

from . import bind, c, f32p, f64, i32, i32p, i64, i64p, lib, voidp


class NumpyPaint:
    """The references of the paint kernels."""
    name = "numpy"

    def prefilter(self, img, exponent: float):
        """(H, W, 3) float32 map prefiltered by the normalised Phong lobe of the exponent."""
        from ..renderers.paint.prefilter import prefilter_numpy
        return prefilter_numpy(img, exponent)

    def background(self, uv, envmap, rotation_deg: float, intensity: float, buf, dst):
        """Environment radiance at unrotated map coordinates uv (P, 2) float32 into buf (P, 3)
        float32, or into rows dst (P,) int64 of buf (N, 3) when dst is given; returns buf."""
        from ..renderers.paint.render import background_numpy
        return background_numpy(uv, envmap, rotation_deg, intensity, buf, dst)

    def shade(self, normals, views, mat_of, rows, maps, cosine: str, fresnel: bool, vsh,
              rotation_deg: float, intensity: float, buf, dst):
        """Radiance of P points into buf (as ``background``); see render.shade_numpy."""
        from ..renderers.paint.render import shade_numpy
        val = shade_numpy(normals, views, mat_of, rows, maps, cosine, fresnel, vsh, rotation_deg, intensity)
        if dst is None:
            buf[:] = val
        else:
            buf.reshape(-1, 3)[dst] = val
        return buf


class NativePaint:
    """Typed wrappers of glp_* (paint.c); vsh, dst and out are passed as addresses (dst, vsh may
    be NULL), hence voidp. Rotations are passed to C in radians."""
    name = "native"

    def __init__(self):
        if lib is None:
            raise RuntimeError("the C kernels are not built (make build)")
        self._prefilter = bind("glp_prefilter", None, img=f32p, H=i32, W=i32, E=f64, out=f32p)
        self._shade = bind(
            "glp_shade", None, P=i64, normals=f32p, views=f32p, mat_of=i32p, mats=f32p, n_mat=i32, M=i32,
            maps=f32p, offs=i64p, hs=i32p, ws=i32p, vmaps=f32p, voffs=i64p, tables=f32p, T=i32, mode=i32,
            expo=f32p, fresnel=i32, f0=f64, vsh=voidp, zonal=f32p, rot=f64, intensity=f64, dst=voidp, out=voidp)
        self._background = bind("glp_background", None, P=i64, uv=f32p, map=f32p, Hm=i32, Wm=i32, rot=f64,
                                intensity=f64, dst=voidp, out=voidp)

    def prefilter(self, img, exponent: float):
        img = c(img, np.float32)
        out = np.zeros_like(img)
        self._prefilter(img, img.shape[0], img.shape[1], float(exponent), out)
        return out

    def background(self, uv, envmap, rotation_deg: float, intensity: float, buf, dst):
        envmap = c(envmap, np.float32)
        self._background(len(uv), c(uv, np.float32), envmap, envmap.shape[0], envmap.shape[1],
                         float(np.radians(rotation_deg)), float(intensity),
                         None if dst is None else dst.ctypes.data, buf.ctypes.data)
        return buf

    def shade(self, normals, views, mat_of, rows, maps, cosine: str, fresnel: bool, vsh,
              rotation_deg: float, intensity: float, buf, dst):
        from ..renderers.paint.render import COSINE_MODES, F0, TABLE_N, _packed

        ex = maps.exponents
        flat, offs, hs, ws, tabs, zon, ex32, vflat, voffs = _packed(maps)
        rows = c(rows, np.float32)
        vptr = None
        if vsh is not None:
            vsh = c(vsh, np.float32)
            vptr = vsh.ctypes.data
        self._shade(len(normals), c(normals, np.float32), c(views, np.float32), c(mat_of, np.int32),
                    rows, rows.shape[0], len(ex) - 1, flat, offs, hs, ws, vflat, voffs,
                    tabs, TABLE_N, COSINE_MODES[cosine], ex32, int(bool(fresnel)), F0, vptr, zon,
                    float(np.radians(rotation_deg)), float(intensity),
                    None if dst is None else dst.ctypes.data, buf.ctypes.data)
        return buf


__all__ = ["NativePaint", "NumpyPaint"]
