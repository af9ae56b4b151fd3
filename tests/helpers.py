"""Helpers the test modules share (a module, not conftest: conftest names are ambiguous across
folders)."""
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CACHE = ROOT / "tests" / ".cache"


def open_renderer(scene, kernels=None, kind=None):
    """A renderer for a loaded scene, its precomputation cached in tests/.cache (by content key)."""
    from worker.artifacts import DirStore
    from worker.native.kernels import kernels as get_kernels
    from worker.renderers import prepare

    CACHE.mkdir(parents=True, exist_ok=True)
    kind = kind or scene.spec.renderer
    r, _ = prepare(scene, DirStore(CACHE, kind), kind, kernels=get_kernels(kernels))
    return r


def render(r, material, shading="pixel", camera=None):
    """(radiance (H, W, 3), object index (H, W)) of a one-object scene with a material."""
    from worker.renderers import FrameRequest

    out = r.render(FrameRequest(camera=camera or r.scene.spec.camera, materials=[material], shading=shading))
    return out.radiance, out.object_id
