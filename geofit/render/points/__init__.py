"""Point clouds: PyTorch3D's points rasterizer, renderer and compositors, vectorised.

- :mod:`.rasterizer`: :class:`PointsRasterizer`, :class:`PointsRasterizationSettings`,
  :class:`PointFragments`, :class:`PointsRenderer`, :func:`rasterize_points`.
- :mod:`.compositing`: :class:`AlphaCompositor`, :class:`NormWeightedCompositor`.
"""
from .compositing import AlphaCompositor, NormWeightedCompositor, add_background_color
from .rasterizer import (
    PointFragments,
    PointsRasterizationSettings,
    PointsRasterizer,
    PointsRenderer,
    PointsRendering,
    rasterize_points,
)

__all__ = [
    "AlphaCompositor",
    "NormWeightedCompositor",
    "PointFragments",
    "PointsRasterizationSettings",
    "PointsRasterizer",
    "PointsRenderer",
    "PointsRendering",
    "add_background_color",
    "rasterize_points",
]
