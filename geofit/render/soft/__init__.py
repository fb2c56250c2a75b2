"""Differentiable (soft) mesh rendering with PyTorch3D's semantics: forward passes and vjps.

:func:`rasterize_soft` is PyTorch3D's rasterizer with a blur radius and K faces per pixel;
:class:`SoftSilhouetteShader` / :func:`sigmoid_alpha_blend` and :func:`phong_vertex_colors` +
:func:`softmax_rgb_blend_soft` are PyTorch3D's ``SoftSilhouetteShader`` and ``SoftPhongShader``
on those fragments, each with its vector-Jacobian product; :class:`SoftSilhouetteRenderer` and
:class:`SoftPhongRenderer` chain them and return a :class:`SoftRender` whose ``vjp`` maps an image
gradient to the vertices. :mod:`.contour` adds a silhouette-contour loss.
"""
from .contour import ContourSamples, ContourSilhouetteLoss, contour_edges
from .rasterizer import (
    TUTORIAL_BLUR_RADIUS,
    PhongColors,
    SoftBlend,
    SoftFragments,
    SoftGrads,
    SoftPhongRenderer,
    SoftRasterizationSettings,
    SoftRender,
    SoftSilhouetteRenderer,
    SoftSilhouetteShader,
    phong_vertex_colors,
    rasterize_soft,
    sigmoid_alpha_blend,
    sigmoid_alpha_blend_vjp,
    softmax_rgb_blend_soft,
)

__all__ = [
    "TUTORIAL_BLUR_RADIUS",
    "ContourSamples",
    "ContourSilhouetteLoss",
    "PhongColors",
    "SoftBlend",
    "SoftFragments",
    "SoftGrads",
    "SoftPhongRenderer",
    "SoftRasterizationSettings",
    "SoftRender",
    "SoftSilhouetteRenderer",
    "SoftSilhouetteShader",
    "contour_edges",
    "phong_vertex_colors",
    "rasterize_soft",
    "sigmoid_alpha_blend",
    "sigmoid_alpha_blend_vjp",
    "softmax_rgb_blend_soft",
]
