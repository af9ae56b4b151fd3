"""The same scene in Mitsuba 3 (``scalar_rgb``, ``direct`` integrator, or ``path`` with a
``max_depth`` for global illumination): an independent reference.

Conventions match docs/design/conventions.md by construction: ``envmap`` with to_world = rotate(+Y, angle),
``perspective`` with fov_axis y and look_at(eye, target, up), meshes written as PLY with our
vertex normals so both renderers shade the same surface. Materials: ``lambert`` → ``diffuse``;
``ggx`` → ``roughconductor`` (distribution ggx, material none, specular_reflectance), with a
diffuse part added through ``blendbsdf`` ((1 − w)·diffuse(a/(1 − w)) + w·conductor(s/w) = a + s,
with w = max s / (max s + max a) so both scaled reflectances stay within Mitsuba's [0, 1]).
``two_sided`` wraps every BSDF in ``twosided`` (the GI renderer shades both sides of a surface).
``face_normals`` shades with the triangles' own normals instead of the vertex normals: with
``two_sided`` the image then does not depend on the mesh's winding or normals at all, which makes
it the reference for what a mesh's repair of winding and normals must produce.
Requires the optional dependency ``mitsuba`` (``pip install glint-studio[mitsuba]``).
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from .scene import GGX, Lambert, LoadedScene


def bsdf_dict(m) -> dict:
    """The Mitsuba 3 BSDF (as a load_dict dictionary) of a lambert or ggx material (module doc)."""
    if isinstance(m, Lambert):
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(m.albedo)}}
    if isinstance(m, GGX):
        spec = {"type": "roughconductor", "distribution": "ggx", "alpha": m.alpha, "material": "none",
                "specular_reflectance": {"type": "rgb", "value": list(m.specular)}}
        if max(m.albedo) <= 0:
            return spec
        w = max(m.specular) / (max(m.specular) + max(m.albedo))
        if max(m.specular) + max(m.albedo) > 1.0:
            raise ValueError("Mitsuba cannot blend reflectances whose maxima sum above 1")
        spec["specular_reflectance"]["value"] = [x / w for x in m.specular]
        return {"type": "blendbsdf", "weight": w,
                "bsdf_0": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [x / (1 - w) for x in m.albedo]}},
                "bsdf_1": spec}
    raise NotImplementedError(f"no Mitsuba equivalent wired for {type(m).__name__}")


def render_mitsuba(scene: LoadedScene, spp: int = 256, seed: int = 0, rotation_deg: float | None = None,
                   integrator: str = "direct", max_depth: int | None = None, two_sided: bool = False,
                   face_normals: bool = False) -> np.ndarray:
    """(H, W, 3) float32 linear radiance rendered by Mitsuba 3 for the loaded scene.

    integrator "path" with max_depth = bounces + 1 renders up to that many bounces."""
    import mitsuba as mi
    import trimesh

    mi.set_variant("scalar_rgb")
    spec = scene.spec
    cam = spec.camera
    env = spec.environment
    rot = env.rotation_deg if rotation_deg is None else rotation_deg
    with tempfile.TemporaryDirectory() as tmp:
        d = {"type": "scene",
             "integrator": {"type": integrator, **({"max_depth": int(max_depth)} if max_depth is not None else {})},
             "sensor": {"type": "perspective", "fov": cam.fov_y_deg, "fov_axis": "y",
                        "to_world": mi.ScalarTransform4f().look_at(origin=list(cam.eye), target=list(cam.target), up=list(cam.up)),
                        "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
                        "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height,
                                 "rfilter": {"type": "box"}, "pixel_format": "rgb"}},
             "env": {"type": "envmap", "bitmap": mi.Bitmap(np.ascontiguousarray(scene.envmap, np.float32)),
                     "scale": env.intensity,
                     "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], rot)}}
        mesh = scene.mesh
        for i, o in enumerate(spec.objects):
            fsel = scene.object_of_face == i
            faces = mesh.faces[fsel]
            used = np.unique(faces)
            remap = np.full(len(mesh.vertices), -1, np.int64); remap[used] = np.arange(len(used))
            tm = trimesh.Trimesh(mesh.vertices[used], remap[faces], vertex_normals=mesh.normals[used], process=False)
            path = Path(tmp) / f"obj{i}.ply"
            path.write_bytes(trimesh.exchange.ply.export_ply(tm, include_attributes=False, vertex_normal=True))
            bsdf = bsdf_dict(o.material)
            if two_sided:
                bsdf = {"type": "twosided", "bsdf": bsdf}
            d[f"obj{i}"] = {"type": "ply", "filename": str(path), "face_normals": bool(face_normals), "bsdf": bsdf}
        sc = mi.load_dict(d)
        img = mi.render(sc)
    return np.asarray(img, dtype=np.float32)[..., :3]
