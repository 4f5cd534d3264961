"""Design-surface accuracy on STL: FIA finds the facets of analytic features (cylinders,
cones, spheres, tori), VTA splits them until their chordal error is within tolerance.

``refine_surfaces(vertices, faces, epsilon=..., mode=...)`` is the entry point; see
:mod:`repair.surface.features` for the definitions and the report.
"""

from repair.surface.features import (
    MODES,
    Feature,
    SurfaceResult,
    find_features,
    refine_surfaces,
    surface_tolerance,
)

__all__ = ["MODES", "Feature", "SurfaceResult", "find_features", "refine_surfaces",
           "surface_tolerance"]
