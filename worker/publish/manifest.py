"""A bundle's plan (every view with its content key) and its manifest.

The manifest is the one file a viewer reads first (docs/guides/publishing.md documents it):

.. code-block:: text

    {"format": "glint-bundle", "version": 1, "name": str, "publication": id,
     "width": W, "height": H,                      # the 1× frame; 2× frames are 2W × 2H
     "azimuths_deg": [A floats], "elevations_deg": [E floats],
     "start": {"elevation": index, "azimuth": index},
     "variants": [{"label": str, "swatch": "#rrggbb"}], "environments": [{"label": str}],
     "ground_shadow": bool, "live": bool,
     "frames": [[[[{"avif1": file, "jpeg1": file, "avif2": file} × A] × E] × environments] × variants],
     "model": {"glb": file, "bytes": n, "summary": str} or None,   # every variant in one glTF binary
     "files": count, "bytes": total}

A file is named ``<sha256 of its bytes>.<ext>``; the service serves it at
``/v1/bundle-files/<file>`` and a downloaded bundle holds it at ``files/<file>``.
"""
from __future__ import annotations

from .keys import FILES, frame_key, scene_inputs
from .turntable import azimuths, default_elevations, turntable_camera


def plan(scene: dict, obj: str, variants: list[dict], environments: list[dict], opts: dict) -> dict:
    """Every view of a bundle, camera-major (the frames of one camera are rendered together).

    scene : the scene payload; variants : scene material dicts; environments : {"sha256",
    "filename", "rotation_deg", "intensity"}; opts : the bundle options (width, height,
    azimuths, elevations_deg, samples, antialias, shading, tone, exposure, ground_shadow, encode).
    Returns {"azimuths_deg", "elevations_deg", "width", "height", "render", "encode",
    "views": [{"key", "variant", "environment", "elevation", "azimuth", "camera"}]}."""
    cam = scene["spec"]["camera"]
    w, h = int(opts.get("width") or cam["width"]), int(opts.get("height") or cam["height"])
    els = list(opts.get("elevations_deg") or default_elevations(cam))
    azs = azimuths(cam, int(opts["azimuths"]))
    render = {"samples": int(opts["samples"]), "shading": opts["shading"], "tone": opts["tone"],
              "exposure": float(opts["exposure"]), "ground_shadow": opts["ground_shadow"]}
    if render["samples"] > 1:       # where the samples go (a one-sample bundle's keys stay as they were)
        render["antialias"] = opts.get("antialias") or "full"
    enc = dict(opts["encode"])
    inputs = [scene_inputs(scene, obj, m) for m in variants]
    envs = [{"sha256": e["sha256"], "rotation_deg": float(e["rotation_deg"]), "intensity": float(e["intensity"])}
            for e in environments]
    views = []
    for ei, el in enumerate(els):
        for ai, az in enumerate(azs):
            c2 = turntable_camera(cam, az, el, 2 * w, 2 * h)
            for ej, env in enumerate(envs):
                for vi, inp in enumerate(inputs):
                    views.append({"key": frame_key(inp, env, c2, render, enc), "variant": vi, "environment": ej,
                                  "elevation": ei, "azimuth": ai, "camera": c2})
    return {"azimuths_deg": azs, "elevations_deg": els, "width": w, "height": h, "render": render, "encode": enc,
            "views": views}


def file_name(sha: str, name: str) -> str:
    """The published name of one encoded file (its digest and extension)."""
    return sha + FILES[name]


def manifest(pl: dict, files: dict, meta: dict, info: dict) -> dict:
    """The manifest of a plan whose views are all stored. files : key -> {name: sha256};
    meta : key -> frames.py meta; info : {"name", "publication", "variants": [labels],
    "environments": [labels], "live", "model": {"glb", "bytes", "summary"} or {"error"} or None}."""
    nv, ne = len(info["variants"]), len(info["environments"])
    ne_l, na = len(pl["elevations_deg"]), len(pl["azimuths_deg"])
    frames = [[[[None] * na for _ in range(ne_l)] for _ in range(ne)] for _ in range(nv)]
    swatches = [None] * nv
    total, names = 0, set()
    for v in pl["views"]:
        f = files[v["key"]]
        frames[v["variant"]][v["environment"]][v["elevation"]][v["azimuth"]] = {n: file_name(f[n], n) for n in FILES}
        m = meta[v["key"]]
        for n in FILES:
            if f[n] not in names:
                names.add(f[n])
                total += m["bytes"][n]
        if v["environment"] == 0 and v["elevation"] == 0 and v["azimuth"] == 0:
            swatches[v["variant"]] = "#%02x%02x%02x" % tuple(m["swatch"])
    model = info.get("model")
    model = {k: model[k] for k in ("glb", "bytes", "summary")} if model and model.get("glb") else None
    return {"format": "glint-bundle", "version": 1, "name": info["name"], "publication": info["publication"],
            "width": pl["width"], "height": pl["height"], "azimuths_deg": pl["azimuths_deg"],
            "elevations_deg": pl["elevations_deg"], "start": {"elevation": 0, "azimuth": 0},
            "variants": [{"label": lab, "swatch": swatches[i]} for i, lab in enumerate(info["variants"])],
            "environments": [{"label": lab} for lab in info["environments"]],
            "ground_shadow": bool(info.get("ground_shadow")), "live": bool(info.get("live")),
            "frames": frames, "model": model, "files": len(names) + (model is not None),
            "bytes": total + (model["bytes"] if model else 0)}
