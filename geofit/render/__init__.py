"""Rendering, in subpackages by primitive as PyTorch3D's ``renderer/``.

- :mod:`geofit.render.mesh` -- hard mesh rendering by Embree ray casting:
  :class:`MeshRenderer`, :class:`MeshRendererWithFragments`, :class:`MeshRasterizer`,
  :class:`RasterizationSettings`, :class:`Fragments` (one ray per pixel centre, K = 1); shaders
  :class:`HardPhongShader`, :class:`SoftPhongShader`, :class:`HardGouraudShader`,
  :class:`SoftGouraudShader`, :class:`HardFlatShader`; :class:`TexturesFlat`. Beyond
  PyTorch3D: supersampled antialiasing (``RasterizationSettings(supersample=s)``) and hard
  shadows (``shadows=True`` on Phong / flat shaders).
- :mod:`geofit.render.soft` -- differentiable mesh rendering (PyTorch3D's blur radius and K
  faces per pixel, with vector-Jacobian products): :func:`rasterize_soft`,
  :class:`SoftRasterizationSettings`, :class:`SoftSilhouetteShader`,
  :class:`SoftSilhouetteRenderer`, :class:`SoftPhongRenderer`, :class:`ContourSilhouetteLoss`.
- :mod:`geofit.render.points` -- :class:`PointsRasterizer`, :class:`PointsRenderer`,
  :class:`AlphaCompositor`, :class:`NormWeightedCompositor`.
- :mod:`geofit.render.volume` -- ray samplers (:class:`NDCMultinomialRaysampler`,
  :class:`MonteCarloRaysampler`), raymarchers (:class:`EmissionAbsorptionRaymarcher`,
  :class:`AbsorptionOnlyRaymarcher`), :class:`VolumeRenderer`, :class:`ImplicitRenderer`,
  :class:`NeuralRadianceField`, :class:`HarmonicEmbedding`.
- Shared: lights (:class:`PointLights`, :class:`DirectionalLights`, :class:`AmbientLights`),
  :class:`Materials`, :class:`BlendParams` and the blend functions, :func:`image_grid`,
  :func:`make_grid`, :func:`plot_texture_uv`; Open3D's renderer for comparison in
  :mod:`geofit.render.open3d`.

*Names and PyTorch3D.* A shader here means what it means in PyTorch3D: ``SoftPhongShader`` is
Phong shading with ``softmax_rgb_blend`` of the fragments it is given. On the hard rasterizer's
fragments (K = 1, the render tutorial's setting) it is a forward renderer; on
:class:`SoftFragments` from :func:`rasterize_soft` (K faces, blur) it is the differentiable
blend, and :class:`SoftPhongRenderer` bundles that path with its ``vjp``.
"""
from __future__ import annotations

from . import mesh, points, soft, volume
from .blending import BlendParams, hard_rgb_blend, sigmoid_alpha, softmax_rgb_blend
from .lighting import AmbientLights, DirectionalLights, PointLights
from .materials import Materials
from .mesh import *  # noqa: F403 - the renderers of each primitive, listed in its __all__
from .points import *  # noqa: F403
from .soft import *  # noqa: F403
from .utils import image_grid, make_grid, plot_texture_uv, texturesuv_image_matplotlib
from .volume import *  # noqa: F403

_SHARED = ["AmbientLights", "BlendParams", "DirectionalLights", "Materials", "PointLights",
           "hard_rgb_blend", "image_grid", "make_grid", "plot_texture_uv", "sigmoid_alpha",
           "softmax_rgb_blend", "texturesuv_image_matplotlib"]
__all__ = _SHARED + mesh.__all__ + soft.__all__ + points.__all__ + volume.__all__
