"""The cut renderer: direct environment light through per-vertex visibility cuts
(cyber-worlds §V, inverse-brdf-modeling §4), with cut fields for movable objects."""
