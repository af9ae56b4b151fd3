"""Content keys of turntable frames: the SHA-256 of exactly what a frame's pixels depend on.

A frame is a function of the scene's geometry and precomputed visibility (the precomputation's
part digests), every object's material and placement (the published object's replaced by the
variant's), the environment map's bytes (digest), rotation and intensity, the camera, the ground
shadow, the render settings (samples, shading, tone curve, exposure) and the encoder settings.
Two frames with equal keys are byte-identical, so a rebuild renders only frames whose key is
not stored yet (a changed variant re-renders that variant's frames alone), and the same design
published twice shares its files. ``FRAME_FORMAT`` is part of every key: bump it when the
renderer or the encoder changes what a frame looks like.
"""
from __future__ import annotations

import hashlib
import json

FRAME_FORMAT = 7          # 2: the 1× frame tone-mapped in the same pass as the 2× (glk_tonemap_pair); 3: AVIF;
# 4: refined faces also chosen by a centroid probe (a sun highlight between dark vertices); 5: shading
# normals facing away from the eye at silhouettes shaded at grazing (core.render.facing_view); 6: a
# half-angle curve refined at its peak's width, not its farthest bump's (models/curve.py); 7: the
# probe shades with the drag level's cuts (a few faces more or fewer refined)
# the encoded files of one frame: its name in the manifest -> (PartStore key suffix, extension)
FILES = {"avif1": ".avif", "jpeg1": ".jpg", "avif2": ".avif"}


def _digest(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def scene_inputs(scene: dict, obj: str, material: dict) -> dict:
    """What of a scene payload (server/state.py scene_payload) a frame depends on, with the
    material of object ``obj`` replaced: geometry by its precomputed parts, objects with their
    meshes (asset digests), materials and transforms, the ground."""
    spec = scene["spec"]
    files = scene["files"]
    objects = []
    for o in spec["objects"]:
        objects.append({"name": o["name"], "mesh": files[o["mesh"]]["sha256"], "transform": o.get("transform"),
                        "movable": o.get("movable", False),
                        "material": material if o["name"] == obj else o.get("material")})
    return {"renderer": scene.get("renderer") or "cuts", "parts": dict(sorted((scene.get("parts") or {}).items())),
            "objects": objects, "ground": spec.get("ground")}


def frame_key(scene_inputs_: dict, environment: dict, camera: dict, render: dict, encode: dict) -> str:
    """Hex key of one frame. environment : {"sha256", "rotation_deg", "intensity"};
    camera : the 2× camera (scene.Camera dict); render : {"samples", "antialias" (when samples
    > 1), "shading", "tone", "exposure", "ground_shadow"}; encode : the encoder settings."""
    return _digest({"format": FRAME_FORMAT, "scene": scene_inputs_, "environment": environment,
                    "camera": camera, "render": render, "encode": encode})


def file_key(key: str, name: str) -> str:
    """The PartStore key of one encoded file (``name`` of FILES, or "meta") of frame ``key``."""
    return hashlib.sha256(f"{key}/{name}".encode()).hexdigest()
