"""The GI renderer (polynomial-gi): multibounce tensors precomputed by path tracing, BRDFs edited
live with interreflections under a fixed view and lighting.

Importing the package is light (its DECLARATION, read by the API process); the classes load
from renderer.py when first used."""
from ..declaration import RendererDeclaration, lazy_exports

DECLARATION = RendererDeclaration(
    kind="gi", controls=frozenset({"materials"}),
    renderer="worker.renderers.gi.renderer:GIRenderer",
    precomputation="worker.renderers.gi.renderer:GIPrecomputation")

__getattr__ = lazy_exports(__name__, dict.fromkeys(("GIData", "GIPrecomputation", "GIRenderer"), ".renderer"))
