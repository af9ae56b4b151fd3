"""The capture kernels (src/capture.c) behind the backend's ``capture`` family: ``k.capture.merge``
(HDR merge of a bracket) and ``k.capture.fisheye_map`` (remap coordinates of one photo), the
same arrays in and out in both backends. The NumPy references are worker/capture/hdr.py
merge_numpy and worker/capture/stitch.py fisheye_map_numpy (tests/capture checks they agree);
the public functions hdr.merge and stitch.fisheye_map check the arrays and call these.
"""
from __future__ import annotations

import numpy as np

from . import bind, c, f32p, f64, i32, i64, lib, u8p, voidp


class NumpyCapture:
    """The references of the capture kernels."""
    name = "numpy"

    def merge(self, z, valid, val, wt):
        """(radiance (N, 3) float32, status (N,) uint8) of brackets z (K, N, 3) uint8, valid (K, N)
        uint8 or None, tables val, wt (K, 256, 3) float32 (hdr.merge_numpy)."""
        from ..capture.hdr import merge_numpy
        return merge_numpy(z, valid, val, wt)

    def fisheye_map(self, h: int, w: int, lens, yaw_deg: float):
        """(map_x, map_y) (h, w) float32 cv2.remap coordinates (stitch.fisheye_map_numpy)."""
        from ..capture.stitch import fisheye_map_numpy
        return fisheye_map_numpy(h, w, lens, yaw_deg)


class NativeCapture:
    """Typed wrappers of glk_hdr_merge and glk_fisheye_map (capture.c; the yaw in radians)."""
    name = "native"

    def __init__(self):
        if lib is None:
            raise RuntimeError("the C kernels are not built (make build)")
        self._merge = bind("glk_hdr_merge", None, n=i64, K=i32, z=u8p, valid=voidp, val=f32p, wt=f32p, out=f32p,
                           status=u8p)
        self._fisheye = bind("glk_fisheye_map", None, h=i32, w=i32, yaw=f64, projection=i32, focal=f64, cx=f64,
                             cy=f64, theta_max=f64, map_x=f32p, map_y=f32p)

    def merge(self, z, valid, val, wt):
        k_n, n = z.shape[0], z.shape[1]
        out = np.empty((n, 3), np.float32)
        st = np.empty(n, np.uint8)
        self._merge(n, k_n, c(z, np.uint8), valid.ctypes.data if valid is not None else None, c(val, np.float32),
                    c(wt, np.float32), out, st)
        return out, st

    def fisheye_map(self, h: int, w: int, lens, yaw_deg: float):
        mx = np.empty((h, w), np.float32)
        my = np.empty((h, w), np.float32)
        cx, cy = lens.centre
        self._fisheye(h, w, float(np.radians(yaw_deg)), 0 if lens.projection == "equidistant" else 1,
                      float(lens.focal), float(cx), float(cy), float(lens.theta_max), mx, my)
        return mx, my


__all__ = ["NativeCapture", "NumpyCapture"]
