"""The GI renderer (polynomial-gi): multibounce tensors precomputed by path tracing, BRDFs edited
live with interreflections under a fixed view and lighting.

Importing the package is light (its DECLARATION, read by the API process); the classes load
from renderer.py when first used."""
from ..declaration import RendererDeclaration, lazy_exports

DECLARATION = RendererDeclaration(
    kind="gi", controls=frozenset({"materials", "strokes"}), bakes_fixed=True,
    renderer="worker.renderers.gi.renderer:GIRenderer",
    settings="builtins:dict",  # the scene file's "gi" object, validated by options.py
    precomputation="worker.renderers.gi.renderer:GIPrecomputation",
    why_not={"camera": "the global-illumination precomputation is for one view: the camera is fixed "
                       "(switch to direct light to orbit)",
             "light": "the light transport is precomputed for the scene's lighting: it cannot turn",
             "environment": "the light transport is precomputed for the scene's environment map",
             "move": "objects are baked into the interreflections: they cannot move",
             "ground": "the GI scene has no shadow-catcher ground"})

__getattr__ = lazy_exports(__name__, dict.fromkeys(("GIData", "GIPrecomputation", "GIRenderer"), ".renderer"))
