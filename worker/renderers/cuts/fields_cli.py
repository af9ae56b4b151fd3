"""``glint field trace``: trace a mesh's visibility cut field (cyber-worlds §V).

    glint field trace MESH [--scale S] [--shells K] [--face N] [--rho-min A] [--rho-max B]
                           [--out DIR] [--threads T] [--json]

``trace`` stores the field content-keyed under DIR/fields (default $GLINT_DATA_DIR) and prints
seconds, rays traced, rays per second and sizes (raw, compressed, index-encoded).
Its benchmarks, ``glint field bench`` and ``glint bench move``, are the benchmark package's
(bench/fields.py).
"""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path


def grid_options(a) -> None:
    """The options of ``glint field trace`` (and ``glint field bench``, bench/fields.py)."""
    a.add_argument("mesh")
    a.add_argument("--scale", type=float, nargs="+", help="the object's scale (3 values: non-uniform)")
    a.add_argument("--shells", type=int, help="concentric spheres K (default 24)")
    a.add_argument("--face", type=int, help="cube-face cells per side n (default 24)")
    a.add_argument("--rho-min", type=float, help="innermost radius / bounding radius (default 0.25)")
    a.add_argument("--rho-max", type=float, help="outermost radius / bounding radius (default 8)")
    a.add_argument("--out", help="folder of stored fields (default: the data directory)")
    a.add_argument("--threads", type=int, default=2)
    a.add_argument("--json", action="store_true")


def add_commands(sub) -> None:
    p = sub.add_parser("field", help="visibility cut fields of movable objects (trace; bench: bench/fields.py)")
    fs = p.add_subparsers(dest="what", required=True)

    t = fs.add_parser("trace", help="trace and store the field of a mesh")
    grid_options(t)
    t.set_defaults(fn=cmd_trace)


def _spec(a):
    from .grid import GridSpec

    d = GridSpec()
    return GridSpec(a.shells or d.shells, a.face or d.face, a.rho_min or d.rho_min, a.rho_max or d.rho_max)


def traced_field(a):
    """(Field with its mesh attached, stats dict, mesh vertices) from the store or traced."""
    from tqdm import tqdm

    from ...artifacts import DirStore
    from ...core.directions import get_tree
    from ...errors import GlintError
    from ...scene import SceneError, Transform, load_mesh
    from .field import Field, field_key, trace_field

    scale = a.scale if a.scale else None
    if scale is not None and len(scale) not in (1, 3):
        raise GlintError("--scale: give 1 or 3 values")
    try:
        spec = _spec(a)
    except ValueError as e:
        raise GlintError(f"field grid: {e}") from None
    tr = Transform(scale=tuple(scale) if scale and len(scale) == 3 else 1.0)
    try:
        mesh = load_mesh(a.mesh, tr if scale and len(scale) == 3 else None)
    except SceneError as e:
        raise GlintError(str(e)) from None
    root = Path(a.out) if a.out else Path(os.environ.get("GLINT_DATA_DIR", Path.home() / ".cache" / "glint"))
    store = DirStore(root, "fields")
    key = field_key(mesh.vertices, mesh.faces, spec, get_tree().height)
    blob = store.get(key)
    if blob is not None:
        try:
            f = Field.decode(blob)
            return f.attach(mesh.vertices, mesh.faces), {"cached": True, **f.stats, **f.storage(len(blob)),
                                                         "path": str(store.path(key))}, mesh
        except ValueError:
            store.discard(key)
    bar = tqdm(total=spec.shells * (6 * spec.face ** 2 + 2), desc="field", unit="sample", file=sys.stderr,
               disable=a.json, smoothing=0.1)
    try:
        f = trace_field(mesh.vertices, mesh.faces, spec, threads=a.threads, progress=bar.update, key=key)
    finally:
        bar.close()
    blob = f.encode()
    store.put(key, blob)
    return f.attach(mesh.vertices, mesh.faces), {"cached": False, **f.stats, **f.storage(len(blob)),
                                                 "path": str(store.path(key))}, mesh


def cmd_trace(a) -> int:
    f, st, _ = traced_field(a)
    st.update({"grid": f.grid.spec.tag(), "radius": f.grid.radius})
    if a.json:
        print(json.dumps(st))
    else:
        print(f"field {st['path']}\n  {st['samples']} samples ({st['grid']}), mean cut {st['mean_cut_size']:.0f} nodes, "
              f"{st['bytes_raw'] / 1e6:.1f} MB raw, {st['bytes_compressed'] / 1e6:.1f} MB compressed"
              + ("" if st["cached"] else f", {st['seconds']:.1f} s, {st['rays_per_second'] / 1e6:.1f} M rays/s"))
    return 0
