"""The paint renderer (cacad-cosine-lobes §5): cosine lobes by prefiltered environment maps,
for the car-paint designer (worker/paint/).

Importing the package is light (its DECLARATION, read by the API process); the classes load
from renderer.py when first used."""
from ..declaration import RendererDeclaration, lazy_exports

DECLARATION = RendererDeclaration(
    kind="paint", controls=frozenset({"camera", "light", "materials", "environment"}),
    renderer="worker.renderers.paint.renderer:PaintRenderer",
    settings="builtins:dict",  # the scene file's "paint" object
    precomputation="worker.renderers.paint.renderer:PaintPrecomputation",
    why_not={"strokes": "strokes fit a BRDF through the direct-light transfer, which the paint "
                        "renderer does not have (switch to direct light to paint)",
             "move": "the paint renderer has no precomputed visibility of moving objects",
             "ground": "the paint renderer draws no shadow-catcher ground"})

__getattr__ = lazy_exports(__name__, dict.fromkeys(
    ("PaintData", "PaintPrecomputation", "PaintRenderer", "as_basis", "basis_of"), ".renderer"))
