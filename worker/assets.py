"""Real CC0 demo assets from package registries, with a procedural fallback scene.

Sources (the same as ../shared/assets/README.md), fetched with the registries' ordinary clients:
* HDRIs: npm ``@pmndrs/assets@1.7.0`` (``hdri/*.exr.js``: base64 data URLs of Poly Haven CC0
  EXRs), via ``npm pack``.
* Furniture: Debian ``sweethome3d-furniture`` (``BlendSwap-CC-0.sh3f``, a zip of OBJ + MTL +
  textures), via ``apt-get download``.
Every extracted file is checked against a SHA-256 recorded here; the cache is the target
folder, so a second fetch costs nothing. When neither client can reach its registry, ``demo_scene``
writes a procedural scene instead (an analytic sky with a sun, a sphere on a plinth) so that
Glint still starts.
"""
from __future__ import annotations

import base64
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from pathlib import Path

import numpy as np

NPM_PACKAGE = "@pmndrs/assets@1.7.0"
DEB_PACKAGE = "sweethome3d-furniture"
HDRIS = {  # name -> sha256 of the decoded .exr
    "apartment": "31c62c03b5686b3d899071070ec1bfc760a3ddc1e6a05915ebc28102fef2fb1c",
    "studio": "08038ed9159c24bb732d2218dafa09cef2abaa44f9ce11ec511d87c842d88fad",
    "sunset": "d09a4d7581f5454f13c3da3c323a231d00a34e60200de7654a895d2d41a7ceb7",
    "city": "82847b3f3e2073d16647be2eb5712dc0f7e37ddc9480a1d45f2270fe8cd048f6",
}
MESHES = {  # path inside BlendSwap-CC-0.sh3f -> sha256
    "blendswap-cc-0/oakChair/oakChair.obj": "6d1ab20387e2b87ce06afaff8fbefcf9036882f85e58f051d8d659f814e87beb",
    "blendswap-cc-0/oakChair/oakChair.mtl": "8cc9bcf69c23d90b13a3f5a576cc6dbeb4934065bb9d4fc9578dbf29b1d3eed8",
}
MESH_EXTRA = ["blendswap-cc-0/oakChair/BLENDSWAP_LICENSE.txt"]


def data_dir() -> Path:
    return Path(os.environ.get("GLINT_DATA_DIR", Path.home() / ".cache" / "glint"))


def _sha(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()


def _write_verified(path: Path, data: bytes, sha: str | None) -> None:
    if sha is not None and _sha(data) != sha:
        raise RuntimeError(f"checksum mismatch for {path.name}: registry content changed")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def _have(path: Path, sha: str) -> bool:
    return path.is_file() and _sha(path.read_bytes()) == sha


def fetch_hdris(dest: Path, log=print) -> list[str]:
    env = dest / "env"
    missing = [n for n, s in HDRIS.items() if not _have(env / f"{n}.exr", s)]
    if missing:
        if not shutil.which("npm"):
            raise RuntimeError("npm is not installed")
        with tempfile.TemporaryDirectory() as tmp:
            log(f"npm pack {NPM_PACKAGE} …")
            subprocess.run(["npm", "pack", NPM_PACKAGE, "--silent"], cwd=tmp, check=True,
                           capture_output=True, timeout=600)
            tgz = next(Path(tmp).glob("*.tgz"))
            with tarfile.open(tgz) as tar:
                for n in missing:
                    member = tar.extractfile(f"package/hdri/{n}.exr.js")
                    text = member.read().decode()
                    b64 = text.split("base64,", 1)[1].split("'", 1)[0].split('"', 1)[0]
                    _write_verified(env / f"{n}.exr", base64.b64decode(b64), HDRIS[n])
    return sorted(str(env / f"{n}.exr") for n in HDRIS)


def fetch_meshes(dest: Path, log=print) -> list[str]:
    out = dest / "meshes"
    targets = {k: out / Path(k).relative_to("blendswap-cc-0") for k in MESHES}
    if not all(_have(p, MESHES[k]) for k, p in targets.items()):
        if not shutil.which("apt-get"):
            raise RuntimeError("apt-get is not available")
        with tempfile.TemporaryDirectory() as tmp:
            log(f"apt-get download {DEB_PACKAGE} …")
            r = subprocess.run(["apt-get", "download", DEB_PACKAGE], cwd=tmp, capture_output=True, timeout=900)
            if r.returncode != 0:
                subprocess.run(["apt-get", "update", "-qq"], capture_output=True, timeout=900)
                subprocess.run(["apt-get", "download", DEB_PACKAGE], cwd=tmp, check=True, capture_output=True, timeout=900)
            deb = next(Path(tmp).glob("*.deb"))
            subprocess.run(["dpkg-deb", "-x", str(deb), str(Path(tmp) / "x")], check=True, capture_output=True)
            sh3f = next((Path(tmp) / "x").rglob("BlendSwap-CC-0.sh3f"))
            with zipfile.ZipFile(sh3f) as z:
                for k, p in targets.items():
                    _write_verified(p, z.read(k), MESHES[k])
                for k in MESH_EXTRA:
                    _write_verified(out / Path(k).relative_to("blendswap-cc-0"), z.read(k), None)
    return sorted(str(p) for p in targets.values())


def fetch_assets(dest: Path | None = None, progress: bool = True) -> dict:
    """Fetch and verify the demo assets into dest (default: <data dir>/assets)."""
    dest = Path(dest) if dest else data_dir() / "assets"
    log = (lambda m: print(m, file=sys.stderr)) if progress else (lambda m: None)
    info: dict = {"dir": str(dest), "ok": True}
    for name, fn in (("hdris", fetch_hdris), ("meshes", fetch_meshes)):
        try:
            info[name] = fn(dest, log)
        except Exception as e:  # offline, no client, changed upstream: say so, keep going
            info["ok"] = False
            info[f"{name}_error"] = f"{type(e).__name__}: {e}"
    return info


# ---- procedural fallback ---------------------------------------------------------------------

def procedural_sky(width: int = 512) -> np.ndarray:
    """(W/2, W, 3) float32 analytic sky: blue gradient above, grey ground, a sun of ~1° radius
    at 35° elevation carrying most of the energy, so shadows and highlights are visible."""
    from .core.lighting import pixel_directions

    h = width // 2
    d, _ = pixel_directions(h, width)
    y = d[..., 1]
    sky = np.where(y[..., None] > 0,
                   np.array([0.35, 0.55, 1.0]) * (0.4 + 0.6 * (1 - y[..., None])),
                   np.array([0.25, 0.23, 0.2]))
    sun_dir = np.array([np.cos(np.radians(35)) * 0.6, np.sin(np.radians(35)), np.cos(np.radians(35)) * 0.8])
    cosang = d @ sun_dir
    sun = np.where(cosang > np.cos(np.radians(1.5)), 2000.0, 0.0)
    return (sky + sun[..., None] * np.array([1.0, 0.95, 0.85])).astype(np.float32)


def write_procedural_scene(dest: Path) -> Path:
    import trimesh

    from .envmap import save_exr

    dest.mkdir(parents=True, exist_ok=True)
    save_exr(dest / "sky.exr", procedural_sky())
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    sphere.apply_translation([0, 0.9, 0])
    plinth = trimesh.creation.box(extents=[1.6, 0.4, 1.6])
    plinth.apply_translation([0, 0.2, 0])
    sphere.export(dest / "sphere.ply")
    plinth.export(dest / "plinth.ply")
    scene = {
        "version": 1,
        "environment": {"map": "sky.exr", "rotation_deg": 0.0, "intensity": 1.0},
        "camera": {"eye": [0, 1.6, 3.6], "target": [0, 0.7, 0], "up": [0, 1, 0], "fov_y_deg": 40, "width": 640, "height": 480},
        "objects": [
            {"name": "sphere", "mesh": "sphere.ply", "material": {"model": "ggx", "alpha": 0.2, "specular": [0.9, 0.75, 0.5], "albedo": [0.1, 0.05, 0.02]}},
            {"name": "plinth", "mesh": "plinth.ply", "material": {"model": "lambert", "albedo": [0.6, 0.6, 0.6]}},
        ],
    }
    path = dest / "scene.json"
    path.write_text(json.dumps(scene, indent=2))
    return path


def demo_scene(dest: Path | None = None) -> Path:
    """The demo scene file: the oak chair under a real HDRI when the assets can be had,
    otherwise the procedural fallback. Returns the scene path."""
    dest = Path(dest) if dest else data_dir() / "assets"
    info = fetch_assets(dest)
    if info.get("ok"):
        scene = {
            "version": 1,
            "environment": {"map": "env/apartment.exr", "rotation_deg": 0.0, "intensity": 1.0},
            "camera": {"eye": [0, 90, 230], "target": [0, 55, 0], "up": [0, 1, 0], "fov_y_deg": 35, "width": 640, "height": 480},
            "objects": [{"name": "chair", "mesh": "meshes/oakChair/oakChair.obj",
                         "transform": {"scale": 1.0, "rotate_deg": [0, 30, 0], "translate": [0, 0, 0]},
                         "material": {"model": "ggx", "alpha": 0.3, "specular": [0.04, 0.04, 0.04], "albedo": [0.55, 0.38, 0.22]}}],
        }
        path = dest / "demo.json"
        path.write_text(json.dumps(scene, indent=2))
        return path
    print("glint: demo assets unavailable, using the procedural scene: "
          + "; ".join(v for k, v in info.items() if k.endswith("_error")), file=sys.stderr)
    return write_procedural_scene(dest / "procedural")
