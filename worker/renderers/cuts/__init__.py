"""The cut renderer: direct environment light through per-vertex visibility cuts
(cyber-worlds §V, inverse-brdf-modeling §4), with cut fields for movable objects.

Importing the package is light (its DECLARATION, read by the API process); the classes and
functions below load from their modules when first used."""
from ..declaration import RendererDeclaration, lazy_exports

DECLARATION = RendererDeclaration(
    kind="cuts", controls=frozenset({"camera", "light", "materials", "environment", "ground", "move", "strokes"}),
    renderer="worker.renderers.cuts.renderer:CutRenderer",
    settings="worker.renderers.cuts.settings:CutSettings",  # the scene file's "cuts" object
    precomputation="worker.renderers.cuts.precompute:CutPrecomputation")

__getattr__ = lazy_exports(__name__, {
    **dict.fromkeys(("DEFAULT_TAU", "CutData", "CutPrecomputation", "precompute_cuts", "storage_stats"), ".precompute"),
    **dict.fromkeys(("DRAG_TAU", "CutRenderer", "Samples", "View"), ".renderer"),
})
