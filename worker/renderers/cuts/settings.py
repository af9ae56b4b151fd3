"""The cut renderer's scene-file settings (the scene file's optional ``cuts`` object).

Its DECLARATION names ``CutSettings``, and ``worker.scene.scene_model`` adds it to the scene file
under the renderer's kind. This module imports pydantic only, as the API process reads it.
"""
from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class FieldGridSettings(_Strict):
    """Sampling of the visibility cut fields of a scene with movable objects (cyber-worlds §V;
    worker/renderers/cuts/grid.py GridSpec, whose defaults BENCHMARKS.md justifies): ``shells``
    concentric spheres, ``face`` cube-face cells per side, radii from ``rho_min`` to ``rho_max``
    bounding radii. Coarser grids trace faster and blur shadows of moved objects more."""
    shells: int = Field(24, ge=2, le=64)
    face: int = Field(24, ge=1, le=64)
    rho_min: float = Field(0.25, gt=0.0)
    rho_max: float = Field(8.0, gt=0.0)

    @model_validator(mode="after")
    def _order(self):
        if not self.rho_min < self.rho_max:
            raise ValueError("rho_min must be below rho_max")
        return self


class CutSettings(_Strict):
    """The cut renderer's settings (optional): the field grid of movable objects."""
    field_grid: FieldGridSettings | None = None
