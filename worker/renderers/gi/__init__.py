"""The GI renderer (polynomial-gi): multibounce tensors precomputed by path tracing, BRDFs edited
live with interreflections under a fixed view and lighting. Importing registers it."""
from .. import register
from .renderer import GIData, GIPrecomputation, GIRenderer  # noqa: F401

register(GIRenderer, GIPrecomputation())
