"""The cut renderer: direct environment light through per-vertex visibility cuts
(cyber-worlds §V, inverse-brdf-modeling §4), with cut fields for movable objects."""
from .. import register
from .precompute import DEFAULT_TAU, CutData, CutPrecomputation, precompute_cuts, storage_stats  # noqa: F401
from .renderer import DRAG_TAU, CutRenderer, Samples, View  # noqa: F401

register(CutRenderer, CutPrecomputation())
