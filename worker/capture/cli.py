"""``glint capture`` (photos → environment map) and ``glint capture-synth`` (synthetic captures
from an HDRI, for tests and benchmarks)."""
from __future__ import annotations

import json
import sys
from pathlib import Path


class _Bar:
    """tqdm progress bar on stderr driven by (fraction, message) callbacks."""

    def __init__(self, desc: str):
        from tqdm import tqdm

        self.bar = tqdm(total=1000, desc=desc, file=sys.stderr, unit="‰", leave=False,
                        bar_format="{desc}: {percentage:3.0f}%|{bar}| {postfix}")
        self.done = 0

    def __call__(self, f: float, msg: str) -> None:
        n = int(round(1000 * min(max(f, 0.0), 1.0)))
        if n > self.done:
            self.bar.update(n - self.done)
            self.done = n
        self.bar.set_postfix_str(msg, refresh=True)

    def close(self):
        self.bar.close()


def cmd_capture(args) -> int:
    from ..atomic import atomic_write
    from .pipeline import capture, exr_bytes, preview_png

    out = Path(args.out)
    if out.suffix.lower() != ".exr":
        from .manifest import CaptureError

        raise CaptureError(f"--out {out}: the environment map is written as OpenEXR (.exr)")
    bar = _Bar("capture")
    try:
        res = capture(args.manifest, width=args.width, remove_frame=not args.keep_frame, progress=bar)
    finally:
        bar.close()
    atomic_write(out, exr_bytes(res.envmap))
    if args.preview:
        atomic_write(Path(args.preview), preview_png(res.envmap))
    st = res.stats
    if args.json:
        print(json.dumps(st, indent=1))
    else:
        print(f"{out}: {st['width']}×{st['height']} from {st['photos']} photos in {st['seconds']:.1f} s; "
              f"dynamic range {st['dynamic_range_stops']:.1f} stops; lens frame: {st['frame_pixels_removed']} px "
              f"per photo removed ({100 * st['frame_fraction_of_circle']:.2f}% of the circle), "
              f"{100 * st['inpainted_fraction_of_sphere']:.2f}% of the sphere inpainted")
    return 0


def cmd_capture_synth(args) -> int:
    from ..envmap import load_envmap
    from .synth import synthesize

    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        from .manifest import CaptureError

        raise CaptureError(f"--size {args.size!r}: use WIDTHxHEIGHT, e.g. 600x400") from None
    env = load_envmap(args.hdri)
    bar = _Bar("synth")
    try:
        sc = synthesize(env, args.out, w, h, args.projection, args.fov, tuple(float(v) for v in args.yaws.split(",")),
                        args.brackets, False if args.no_frame else args.housing, args.jitter, args.seed, args.exposure_in_manifest,
                        progress=bar)
    finally:
        bar.close()
    info = {"manifest": str(sc.manifest), "shutter_s": sc.shutter_s.tolist(), "scale": sc.scale,
            "frame_pixels": int(sc.frame.sum())}
    print(json.dumps(info, indent=1) if args.json else f"wrote {sc.manifest}")
    return 0


def add_commands(sub) -> None:
    c = sub.add_parser("capture", help="bracketed fisheye photos (a capture manifest) → HDR environment map")
    c.add_argument("manifest", help="capture manifest v1 (JSON); photos are relative to it")
    c.add_argument("--out", required=True, help="environment map to write (.exr, linear radiance)")
    c.add_argument("--preview", help="also write a tone-mapped PNG of the map")
    c.add_argument("--width", type=int, help="map width (height = width/2); default: the photos' resolution, ≤ 4096")
    c.add_argument("--keep-frame", action="store_true", help="do not remove the lens frame (for comparison)")
    c.add_argument("--json", action="store_true", help="print statistics as JSON")
    c.set_defaults(fn=cmd_capture)

    s = sub.add_parser("capture-synth", help="synthesise a bracketed fisheye capture of an HDRI (tests, benchmarks)")
    s.add_argument("hdri", help="equirectangular .exr/.hdr to photograph")
    s.add_argument("--out", required=True, help="folder for the JPEGs, manifest.json, truth.json and frame.png")
    s.add_argument("--size", default="600x400", help="photo size WIDTHxHEIGHT (default 600x400; 4000x3000 is 12 Mpx)")
    s.add_argument("--projection", default="equidistant", choices=["equidistant", "equisolid"])
    s.add_argument("--fov", type=float, default=190.0, help="lens field of view, degrees (default 190)")
    s.add_argument("--yaws", default="0,180", help="shot yaw angles, degrees (default 0,180)")
    s.add_argument("--brackets", type=int, default=5)
    s.add_argument("--no-frame", action="store_true", help="no lens frame in the photos")
    s.add_argument("--housing", default="band", choices=["band", "clip", "vignette", "rim"],
                   help="the lens housing's kind (default band: a band along the rim and a clip arm)")
    s.add_argument("--jitter", type=int, default=0, help="hand-held shake: max bracket shift, pixels")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--exposure-in-manifest", action="store_true", help="write exposure_s (else only EXIF)")
    s.add_argument("--json", action="store_true")
    s.set_defaults(fn=cmd_capture_synth)
