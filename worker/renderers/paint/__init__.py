"""The paint renderer (cacad-cosine-lobes §5): cosine lobes by prefiltered environment maps,
for the car-paint designer (worker/paint/).

Importing the package is light (its DECLARATION, read by the API process); the classes load
from renderer.py when first used."""
from ..declaration import RendererDeclaration, lazy_exports

DECLARATION = RendererDeclaration(
    kind="paint", controls=frozenset({"camera", "light", "materials", "environment"}),
    renderer="worker.renderers.paint.renderer:PaintRenderer",
    precomputation="worker.renderers.paint.renderer:PaintPrecomputation")

__getattr__ = lazy_exports(__name__, dict.fromkeys(
    ("PaintData", "PaintPrecomputation", "PaintRenderer", "as_basis", "basis_of"), ".renderer"))
