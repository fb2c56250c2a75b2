"""Rendering. Meshes: Embree ray casting with PyTorch3D's renderer API and shading formulas.

- :class:`MeshRenderer`, :class:`MeshRendererWithFragments`, :class:`MeshRasterizer`,
  :class:`RasterizationSettings`, :class:`Fragments`: one ray per pixel centre, all views in one
  threaded cast; face ids, barycentrics, depth and normals per pixel (K = 1).
- Shaders: :class:`HardPhongShader`, :class:`SoftPhongShader`, :class:`HardGouraudShader`,
  :class:`SoftGouraudShader`, :class:`HardFlatShader`; lights :class:`PointLights`,
  :class:`DirectionalLights`, :class:`AmbientLights`; :class:`Materials`; :class:`BlendParams`.
- Beyond PyTorch3D: supersampled antialiasing (``RasterizationSettings(supersample=s)``), hard
  shadows (``shadows=True`` on Phong / flat shaders), :class:`TexturesFlat`.
- Points: :class:`PointsRasterizer`, :class:`PointsRenderer`, :class:`AlphaCompositor`,
  :class:`NormWeightedCompositor` (PyTorch3D semantics, vectorised).
- Helpers: :func:`image_grid`, :func:`make_grid`, :func:`plot_texture_uv`; Open3D comparison in
  :mod:`geofit.render.open3d`.
"""
from .compositing import AlphaCompositor, NormWeightedCompositor, add_background_color
from .blending import BlendParams, hard_rgb_blend, sigmoid_alpha, softmax_rgb_blend
from .lighting import AmbientLights, DirectionalLights, PointLights
from .materials import Materials
from .mesh import (
    Fragments,
    MeshRasterizer,
    MeshRenderer,
    MeshRendererWithFragments,
    RasterizationSettings,
)
from .points import (
    PointFragments,
    PointsRasterizationSettings,
    PointsRasterizer,
    PointsRenderer,
    PointsRendering,
    rasterize_points,
)
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
from .textures import TexturesFlat
from .utils import image_grid, make_grid, plot_texture_uv, texturesuv_image_matplotlib

__all__ = [
    "AlphaCompositor",
    "NormWeightedCompositor",
    "add_background_color",
    "PointFragments",
    "PointsRasterizationSettings",
    "PointsRasterizer",
    "PointsRenderer",
    "PointsRendering",
    "rasterize_points",
    "AmbientLights",
    "BlendParams",
    "DirectionalLights",
    "Fragments",
    "HardFlatShader",
    "HardGouraudShader",
    "HardPhongShader",
    "Materials",
    "MeshRasterizer",
    "MeshRenderer",
    "MeshRendererWithFragments",
    "PointLights",
    "RasterizationSettings",
    "SoftGouraudShader",
    "SoftPhongShader",
    "TexturesFlat",
    "apply_lighting",
    "flat_shading",
    "gouraud_shading",
    "hard_rgb_blend",
    "image_grid",
    "make_grid",
    "phong_shading",
    "plot_texture_uv",
    "sample_textures",
    "shadow_visibility",
    "sigmoid_alpha",
    "softmax_rgb_blend",
    "texturesuv_image_matplotlib",
]
