"""PyTorch3D's point-cloud rendering API over geofit's vectorised points renderer."""
from __future__ import annotations

import numpy as np

from ... import render as _gr
from .._common import drop_device
from ..structures import Pointclouds
from ..tensor import Tensor, _tracks

__all__ = ["AlphaCompositor", "NormWeightedCompositor", "PointsRasterizationSettings",
           "PointsRasterizer", "PointsRenderer"]

PointsRasterizationSettings = _gr.PointsRasterizationSettings
AlphaCompositor = drop_device(_gr.AlphaCompositor)
NormWeightedCompositor = drop_device(_gr.NormWeightedCompositor)


def _clouds(point_clouds):
    if isinstance(point_clouds, Pointclouds):
        if _tracks(point_clouds.points_packed(), point_clouds.features_packed()):
            raise NotImplementedError(
                "PointsRenderer: geofit's points renderer has no gradient; render detached "
                "clouds (point_clouds.detach())")
        return point_clouds._geofit()
    raise TypeError(f"point_clouds: expected geofit.pytorch3d.structures.Pointclouds, got "
                    f"{type(point_clouds)!r}")


class PointsRasterizer(_gr.PointsRasterizer):
    """PyTorch3D's ``PointsRasterizer`` (geofit's, taking this module's ``Pointclouds``)."""

    def __init__(self, cameras=None, raster_settings=None, device=None):
        super().__init__(cameras, raster_settings)

    def __call__(self, point_clouds, cameras=None, **kwargs):
        if isinstance(point_clouds, Pointclouds):
            point_clouds = _clouds(point_clouds)
        return super().__call__(point_clouds, kwargs.get("cameras", cameras),
                                raster_settings=kwargs.get("raster_settings"))

    def to(self, *args, **kwargs):
        return self


class PointsRenderer(_gr.PointsRenderer):
    """Rasterize and composite: ``images = renderer(point_clouds)`` ((N, H, W, C) Tensor)."""

    def __call__(self, point_clouds, **kwargs) -> Tensor:
        clouds = _clouds(point_clouds)
        kw = {}
        if "background_color" in kwargs:
            kw["background_color"] = kwargs["background_color"]
        out = _gr.PointsRenderer.render(self, clouds, kwargs.get("cameras"),
                                        raster_settings=kwargs.get("raster_settings"), **kw)
        return Tensor(np.asarray(out.images, np.float64))

    def to(self, *args, **kwargs):
        return self
