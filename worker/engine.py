"""The rendering engine of one scene: cuts, lighting, hit buffer, materials, with caching so
only what changed is recomputed (a BRDF or light change reuses the hit buffer and the cuts; a
view change reuses the cuts and the lighting).
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .atomic import atomic_write  # noqa: F401  (re-exported: the CLI and tests use it here)
from .core import cuts as cutmod
from .core.brdf import pack
from .core.directions import get_tree
from .core.lighting import LeafLighting, node_lighting
from .core.render import MaterialTable, camera_rays, env_lookup, interpolate, shade_points
from .precompute import DEFAULT_TAU, precompute_cuts
from .scene import Camera, LoadedScene
from .trace.embree import Tracer


def geometry_key(scene: LoadedScene, tau: float, height: int) -> str:
    """Content hash of everything the cuts depend on (world-space geometry, normals, τ, H)."""
    h = hashlib.sha256()
    for a in (scene.mesh.vertices, scene.mesh.faces, scene.mesh.normals):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(f"tau={tau};H={height};v1".encode())
    return h.hexdigest()[:32]


def default_cache_dir() -> Path:
    return Path(os.environ.get("GLINT_DATA_DIR", Path.home() / ".cache" / "glint")) / "cuts"


@dataclass
class View:
    camera: Camera
    tri: np.ndarray        # (P,) int32 face index per pixel, -1 background
    uv: np.ndarray         # (P, 2) float32 Embree barycentrics
    dirs: np.ndarray       # (P, 3) float32 primary ray directions
    visible: np.ndarray    # (K,) int32 vertices of the faces seen


class Engine:
    """Renders one loaded scene.

    Parameters
    ----------
    scene : LoadedScene
    cuts : CutSet for scene.mesh (from ``precompute`` or ``load_or_precompute``).
    use_native : use the C kernels when built (else the NumPy references).
    """

    def __init__(self, scene: LoadedScene, cuts: cutmod.CutSet, use_native: bool = True):
        self.scene = scene
        self.cuts = cuts
        self.tree = get_tree(cuts.height)
        self.use_native = use_native
        self.tracer = Tracer(scene.mesh.vertices, scene.mesh.faces)
        self.lighting = LeafLighting(scene.envmap, self.tree)
        self._view: View | None = None
        self._light_key = None
        self._node_light = None
        self.set_materials(scene.materials)

    # -- state ------------------------------------------------------------------------------
    def set_envmap(self, envmap: np.ndarray) -> None:
        """Light the scene with another equirectangular map (H, W, 3) float32 radiance. Cuts are
        geometry only, so they stay; the per-node light is rebuilt on the next frame."""
        self.lighting = LeafLighting(envmap, self.tree)
        self._light_key = None

    def set_materials(self, materials) -> None:
        self.materials = list(materials)
        self.mats = MaterialTable([pack(m) for m in self.materials])

    def view(self, camera: Camera) -> View:
        if self._view is not None and self._view.camera == camera:
            return self._view
        o, d = camera_rays(camera.eye, camera.target, camera.up, camera.fov_y_deg, camera.width, camera.height)
        tri, uv, _ = self.tracer.first_hit(o, d)
        seen = np.unique(tri[tri >= 0])
        visible = np.unique(self.scene.mesh.faces[seen]).astype(np.int32)
        self._view = View(camera, tri, uv, d, visible)
        return self._view

    def node_light(self, rotation_deg: float, intensity: float):
        key = (float(rotation_deg), float(intensity))
        if key != self._light_key:
            l, ld = self.lighting.leaf_radiance(rotation_deg, intensity)
            self._node_light = node_lighting(l, ld, self.tree)
            self._light_key = key
        return self._node_light

    # -- rendering --------------------------------------------------------------------------
    def render(self, camera: Camera | None = None, rotation_deg: float | None = None,
               intensity: float | None = None, mode: str = "vertex", vertex_override=None,
               cuts: cutmod.CutSet | None = None) -> np.ndarray:
        """(H, W, 3) float32 linear radiance. Defaults come from the scene file.

        cuts : optional cut set to shade with instead of the engine's (e.g. a coarsened one
            while the user drags, ``cuts.coarsen``).
        vertex_override : optional (ids (K,) int, radiance (K, 3) float32): vertex-mode radiance
            already known for these vertices (e.g. from a per-vertex transfer matrix), not shaded."""
        env = self.scene.spec.environment
        camera = camera or self.scene.spec.camera
        rot = env.rotation_deg if rotation_deg is None else rotation_deg
        inten = env.intensity if intensity is None else intensity
        v = self.view(camera)
        node_l, node_w = self.node_light(rot, inten)
        mesh = self.scene.mesh
        cuts = cuts if cuts is not None else self.cuts
        img = np.zeros((len(v.tri), 3), np.float32)
        bg = v.tri < 0
        env_lookup(v.dirs, self.lighting.map, rot, inten, mask=bg, out=img, use_native=self.use_native)
        if mode == "vertex":
            vi = v.visible
            if vertex_override is not None:
                vi = vi[~np.isin(vi, vertex_override[0])]
            eye = np.asarray(camera.eye, np.float32)
            wo = eye - mesh.vertices[vi]
            wo /= np.linalg.norm(wo, axis=1, keepdims=True)
            rad = shade_points(mesh.normals[vi], wo, vi, self.scene.object_of_vertex[vi], cuts,
                               node_l, node_w, self.tree, self.mats, self.use_native)
            vert = np.zeros((len(mesh.vertices), 3), np.float32)
            vert[vi] = rad
            if vertex_override is not None:
                vert[vertex_override[0]] = vertex_override[1]
            interpolate(v.tri, v.uv, mesh.faces, vert, img, self.use_native)
        elif mode == "pixel":
            hit = np.nonzero(~bg)[0]
            f = mesh.faces[v.tri[hit]]
            u, w2 = v.uv[hit, 0:1], v.uv[hit, 1:2]
            bary = np.concatenate([1 - u - w2, u, w2], axis=1)              # (K, 3)
            nrm = (bary[:, :, None] * mesh.normals[f]).sum(1)
            nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
            pos = (bary[:, :, None] * mesh.vertices[f]).sum(1)
            wo = np.asarray(camera.eye, np.float32) - pos
            wo /= np.linalg.norm(wo, axis=1, keepdims=True)
            k = len(hit)
            rad = shade_points(np.repeat(nrm, 3, 0), np.repeat(wo, 3, 0), f.reshape(-1).astype(np.int32),
                               self.scene.object_of_vertex[f.reshape(-1)], cuts, node_l, node_w, self.tree,
                               self.mats, self.use_native).reshape(k, 3, 3)
            img[hit] = (bary[:, :, None] * rad).sum(1)
        else:
            raise ValueError(f"unknown shading mode {mode!r} (vertex or pixel)")
        return img.reshape(camera.height, camera.width, 3)

    def object_mask(self, camera: Camera | None = None) -> np.ndarray:
        """(H, W) int32 object index per pixel, -1 background."""
        camera = camera or self.scene.spec.camera
        v = self.view(camera)
        m = np.where(v.tri >= 0, self.scene.object_of_face[np.maximum(v.tri, 0)], -1)
        return m.reshape(camera.height, camera.width)


def cut_cache_path(scene: LoadedScene, cache_dir: Path | None = None, tau: float = DEFAULT_TAU) -> Path:
    """Where the scene's cuts are (or will be) cached."""
    cache_dir = Path(cache_dir) if cache_dir else default_cache_dir()
    return cache_dir / f"{geometry_key(scene, tau, get_tree().height)}.cuts"


def load_or_precompute(scene: LoadedScene, cache_dir: Path | None = None, tau: float = DEFAULT_TAU,
                       progress=None, threads: int = 2):
    """Cuts for the scene, read from the content-addressed cache or traced and stored there.
    Returns (CutSet, stats dict or None when read from cache, path)."""
    tree = get_tree()
    path = cut_cache_path(scene, cache_dir, tau)
    if path.is_file():
        try:
            return cutmod.decode(path.read_bytes()), None, path
        except Exception:
            path.unlink(missing_ok=True)  # a damaged cache entry is rebuilt, not trusted
    m = scene.mesh
    cs, st = precompute_cuts(m.vertices, m.faces, m.normals, tau=tau, tree=tree, progress=progress, threads=threads)
    blob = cutmod.encode(cs)
    atomic_write(path, blob)
    stats = {
        "seconds": st.seconds, "rays_traced": st.rays,
        "samples_per_second": st.vertices * st.directions / max(st.seconds, 1e-9), "tau": tau,
        **storage_stats(cs, len(blob), path),
    }
    return cs, stats, path


def storage_stats(cs: cutmod.CutSet, blob_bytes: int, path: Path) -> dict:
    """Sizes of stored cuts: height-encoded (as stored) against index-encoded."""
    idx = cutmod.index_encoded_bytes(cs)
    return {"vertices": cs.n_vertices, "directions": 1 << cs.height, "mean_cut_size": float(cs.sizes().mean()),
            "bytes_height_encoded": blob_bytes, "bytes_index_encoded": idx,
            "bytes_index_encoded_deflated": cutmod.index_encoded_bytes(cs, deflate=True),
            "height_vs_index_saving": 1.0 - blob_bytes / idx, "path": str(path)}
