"""``glint field``: trace a mesh's visibility cut field, and time the per-frame cut product.

    glint field trace MESH [--scale S] [--shells K] [--face N] [--rho-min A] [--rho-max B]
                           [--out DIR] [--threads T] [--json]
    glint field bench MESH [--receivers N] [--frames F] [--hmin H] [--out DIR] [--json]

``trace`` stores the field content-keyed under DIR/fields (default $GLINT_DATA_DIR) and prints
seconds, rays traced, rays per second and sizes (raw, compressed, index-encoded).
``bench`` shades nothing: it times ``Combiner.combine`` for N floor vertices around the object
(a square grid at its base, normals up, base cuts = unoccluded cosine), first while the object
slides 2 % of its radius per frame, then while it turns 3° per frame; medians of F frames each,
wall and process CPU time (on a loaded machine, CPU / threads is the better guess of quiet wall
time).
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path


def add_commands(sub) -> None:
    p = sub.add_parser("field", help="visibility cut fields of movable objects (trace, bench)")
    fs = p.add_subparsers(dest="what", required=True)

    def grid_opts(a):
        a.add_argument("mesh")
        a.add_argument("--scale", type=float, nargs="+", help="the object's scale (3 values: non-uniform)")
        a.add_argument("--shells", type=int, help="concentric spheres K (default 24)")
        a.add_argument("--face", type=int, help="cube-face cells per side n (default 24)")
        a.add_argument("--rho-min", type=float, help="innermost radius / bounding radius (default 0.25)")
        a.add_argument("--rho-max", type=float, help="outermost radius / bounding radius (default 8)")
        a.add_argument("--out", help="folder of stored fields (default: the data directory)")
        a.add_argument("--threads", type=int, default=2)
        a.add_argument("--json", action="store_true")

    t = fs.add_parser("trace", help="trace and store the field of a mesh")
    grid_opts(t)
    t.set_defaults(fn=cmd_trace)
    b = fs.add_parser("bench", help="per-frame cost of combining floor cuts with the field")
    grid_opts(b)
    b.add_argument("--receivers", type=int, default=10000)
    b.add_argument("--frames", type=int, default=10)
    b.add_argument("--hmin", type=int, default=None, help="field cut coarseness (default 3)")
    b.set_defaults(fn=cmd_bench)


def _spec(a):
    from .grid import GridSpec

    d = GridSpec()
    return GridSpec(a.shells or d.shells, a.face or d.face, a.rho_min or d.rho_min, a.rho_max or d.rho_max)


def _field(a):
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
    f, st, _ = _field(a)
    st.update({"grid": f.grid.spec.tag(), "radius": f.grid.radius})
    if a.json:
        print(json.dumps(st))
    else:
        print(f"field {st['path']}\n  {st['samples']} samples ({st['grid']}), mean cut {st['mean_cut_size']:.0f} nodes, "
              f"{st['bytes_raw'] / 1e6:.1f} MB raw, {st['bytes_compressed'] / 1e6:.1f} MB compressed"
              + ("" if st["cached"] else f", {st['seconds']:.1f} s, {st['rays_per_second'] / 1e6:.1f} M rays/s"))
    return 0


def cmd_bench(a) -> int:
    import numpy as np

    from ...core.cuts import build_cuts
    from ...core.directions import get_tree
    from .combine import DEFAULT_HMIN, Combiner

    f, st, mesh = _field(a)
    tree = get_tree()
    c, r = f.grid.center, f.grid.radius
    side = int(np.ceil(np.sqrt(a.receivers)))
    g = np.linspace(-2.8 * r, 2.8 * r, side)
    X, Z = np.meshgrid(g, g)
    x = np.stack([c[0] + X.ravel(), np.full(X.size, float(mesh.vertices[:, 1].min())), c[2] + Z.ravel()], 1)
    x = x[:a.receivers].astype(np.float32)
    nrm = np.tile(np.float32([0, 1, 0]), (len(x), 1))
    base = build_cuts(np.maximum(nrm[:1] @ tree.leaves.T, 0).astype(np.float32), 1.0)
    ids = np.zeros(len(x), np.int32)
    hmin = DEFAULT_HMIN if a.hmin is None else a.hmin
    cb = Combiner(hmin)

    def frame(k, turning):
        yaw = np.radians(30.0 + (3.0 * k if turning else 0.0))
        m = np.eye(4)
        m[:3, :3] = [[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]]
        m[:3, 3] = [0.02 * r * k, 0.0, 0.0]
        m[:3, 3] += c - m[:3, :3] @ c                       # turn about the object's centre
        t0, c0 = time.perf_counter(), time.process_time()
        cb.combine(base, ids, x, nrm, [(f, m)])
        return {"ms": 1e3 * (time.perf_counter() - t0), "cpu_ms": 1e3 * (time.process_time() - c0), **cb.last_stats}

    frame(0, False)                                          # warm-up: rotates every sample it needs
    out = {"receivers": len(x), "hmin": hmin, "grid": f.grid.spec.tag(), "field": st["path"]}
    for name, turning in (("translate", False), ("rotate", True)):
        rows = [frame(k + 1, turning) for k in range(a.frames)]
        med = {k: float(np.median([r_[k] for r_ in rows])) for k in rows[0] if isinstance(rows[0][k], (int, float))}
        out[name] = {"ms_per_frame": med["ms"], "cpu_ms_per_frame": med["cpu_ms"],
                     "ms_lookup": med["ms_lookup"], "ms_rotate_and_cells": med["ms_rotate_and_cells"],
                     "ms_product": med["ms_product"], "samples_rotated": med["samples_rotated"],
                     "cells_merged": med["cells_merged"], "segments_traced": med["segments_traced"],
                     "receivers_affected": med["receivers_affected"], "mean_cut_in": med["mean_cut_in"],
                     "mean_cut_out": med["mean_cut_out"]}
    out["threads"] = int(os.environ.get("GLINT_THREADS", "0") or 0) or 2
    if a.json:
        print(json.dumps(out))
    else:
        for name in ("translate", "rotate"):
            o = out[name]
            print(f"{name}: {o['ms_per_frame']:.1f} ms/frame (cpu {o['cpu_ms_per_frame']:.1f} ms) for {out['receivers']} "
                  f"receivers, {o['samples_rotated']:.0f} samples rotated, cut {o['mean_cut_in']:.0f} → {o['mean_cut_out']:.0f}")
    return 0
