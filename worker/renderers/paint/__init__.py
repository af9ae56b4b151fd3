"""The paint renderer (cacad-cosine-lobes §5): cosine lobes by prefiltered environment maps,
for the car-paint designer (worker/paint/). Importing registers it."""
from .. import register
from .renderer import PaintData, PaintPrecomputation, PaintRenderer, as_basis, basis_of  # noqa: F401

register(PaintRenderer, PaintPrecomputation())
