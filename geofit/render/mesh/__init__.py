"""Meshes: hard rendering by Embree ray casting with PyTorch3D's rasterizer and shader API.

- :mod:`.rasterizer`: :class:`MeshRasterizer` (one ray per pixel centre, every view in one
  threaded cast; K = 1), :class:`Fragments`, :class:`RasterizationSettings`.
- :mod:`.renderer`: :class:`MeshRenderer`, :class:`MeshRendererWithFragments`.
- :mod:`.shading`: the shaders (:class:`HardPhongShader`, :class:`SoftPhongShader`, Gouraud,
  flat) and PyTorch3D's shading functions; hard shadows by shadow rays.
- :mod:`.image_term`: :class:`HardImageLoss`, the hard image's squared error with its analytic
  gradient (interior shading and barycentrics exactly, visibility by edge sampling).
- :mod:`.textures`: texture sampling at the hits (:class:`TexturesFlat`, :func:`sample_texels`).
- :mod:`._raycast`: the pixel rays, cast against :class:`geofit.raycast.EmbreeScene`.

The differentiable (soft) mesh renderer is :mod:`geofit.render.soft`.
"""
from .image_term import HardImageLoss, ImageLossValue
from .rasterizer import Fragments, MeshRasterizer, RasterizationSettings
from .renderer import MeshRenderer, MeshRendererWithFragments
from .shading import (
    HardFlatShader,
    HardGouraudShader,
    HardPhongShader,
    SoftGouraudShader,
    SoftPhongShader,
    apply_lighting,
    flat_shading,
    gouraud_shading,
    phong_shading,
    sample_textures,
    shadow_visibility,
)
from .textures import TexturesFlat, sample_texels

__all__ = [
    "Fragments",
    "HardFlatShader",
    "HardGouraudShader",
    "HardImageLoss",
    "HardPhongShader",
    "ImageLossValue",
    "MeshRasterizer",
    "MeshRenderer",
    "MeshRendererWithFragments",
    "RasterizationSettings",
    "SoftGouraudShader",
    "SoftPhongShader",
    "TexturesFlat",
    "apply_lighting",
    "flat_shading",
    "gouraud_shading",
    "phong_shading",
    "sample_textures",
    "sample_texels",
    "shadow_visibility",
]
