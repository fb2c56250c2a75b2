"""Differentiable soft mesh rendering with PyTorch3D's semantics: forward passes and vjps in numpy.

Three pieces, each a forward map with its vector-Jacobian product (vjp), composed by the chain
rule in plain sight:

1. :func:`rasterize_soft` -- PyTorch3D's CPU mesh rasterizer with a blur radius
   (``csrc/rasterize_meshes/rasterize_meshes_cpu.cpp``): for every pixel the ``K`` faces nearest
   in view depth among those whose projected triangle contains the pixel centre or lies within
   ``sqrt(blur_radius)`` of it (squared NDC distance ``< blur_radius``). Outputs
   :class:`SoftFragments`: signed squared NDC distances (negative inside), view depths and
   barycentrics per (pixel, face) entry, stored sparsely, with dense ``(N, H, W, K)`` views.
   :meth:`SoftFragments.vjp` carries gradients on the distances, depths and barycentrics back to
   the world vertex positions through the 2-D geometry and the projection Jacobians.
2. :func:`sigmoid_alpha_blend` (``SoftSilhouetteShader``): ``S = 1 - prod_k (1 - p_k)`` with
   ``p_k = sigmoid(-d_k / sigma)``; :func:`sigmoid_alpha_blend_vjp`.
3. :func:`phong_vertex_colors` (``SoftPhongShader`` with ``TexturesVertex``) and
   :func:`softmax_rgb_blend_soft` (``softmax_rgb_blend``): per-entry Phong colours from
   interpolated world positions, vertex normals and vertex colours, then the depth-softmax blend;
   each with its vjp (positions through the 2-D distances, barycentrics, depths *and* the shading
   normals; colours linearly).

The renderers :class:`SoftSilhouetteRenderer` and :class:`SoftPhongRenderer` chain them and return
a :class:`SoftRender` whose :meth:`~SoftRender.vjp` maps an image gradient to the vertex positions
(and colours). For fixed geometry the Phong image is affine in the vertex colours;
:meth:`SoftRender.color_operator` returns that map as scipy.sparse matrices (a least-squares
solve for colours is then one sparse solve).

How candidates are found (no dense pixels-by-faces array): each face's NDC bounding box, grown
by ``sqrt(blur_radius)``, gives a pixel rectangle; the (face, pixel) pairs of all rectangles are
enumerated with ``np.repeat`` in chunks of at most ``max_pairs`` pairs, tested exactly, and the
survivors are sorted per pixel by depth (then face index, PyTorch3D's tie order) and cut at
``K``. Memory is bounded by the chunk size plus the kept entries; :attr:`SoftFragments.stats`
reports both.

Non-differentiable parts (gradients are those of the piecewise-smooth pieces, as in PyTorch3D):
which faces a pixel keeps (the blur cut-off, the top-K cut, the ``z >= 0`` test), the inside /
outside sign switch (continuous: ``d = 0`` on the edge), the choice of the nearest of the three
edges, the clamping of the segment parameter, the clipping of barycentrics, ``relu`` in the
diffuse term, the specular mask ``n . l > 0`` and the ``max`` over depths in the softmax blend.
Finite-difference tests must stay away from those switching points.

Differences from PyTorch3D, all documented where they act:

- geometry, shading and gradients are computed in float64; the per-entry arrays kept for the
  vjp and the images are stored in float32 by default as PyTorch3D's (about half the memory:
  a 20-view Phong pass at 128 px, forward + vjp, peaks at 0.49 GB traced against 0.79 GB in
  float64, ``benchmarks/soft_render_memory.py``), or in float64 with
  ``SoftRasterizationSettings(dtype=np.float64)`` (exactness and finite-difference tests);
- faces with a vertex in front of the clip depth (``z_clip_value``, default ``znear / 2`` when
  perspective-correct) are *dropped*, where PyTorch3D clips them into smaller triangles; the two
  agree whenever no face crosses that plane (the tutorial's cow at distance 2.7 is nowhere nearer
  than 1.6);
- a back face whose signed area is within 1e-12 of ``-1e-8`` is skipped: PyTorch3D adds 1e-8 to
  the area before dividing and would divide by almost 0 there;
- the distance to a degenerate edge (squared length <= 1e-8, distance taken to its second end,
  as PyTorch3D) gets the exact gradient of that distance, where PyTorch3D's backward divides by
  the near-zero length.

References
----------
S. Liu, T. Li, W. Chen, H. Li, "Soft Rasterizer: A Differentiable Renderer for Image-based 3D
Reasoning", ICCV 2019. PyTorch3D v0.7.9: ``renderer/mesh/rasterizer.py``, ``renderer/blending.py``,
``renderer/mesh/shading.py``, ``renderer/lighting.py``.

Modules: :mod:`.rasterizer` (settings, :func:`rasterize_soft`), :mod:`.fragments`
(:class:`SoftFragments` and its vjp), :mod:`.blending` (sigmoid silhouette and softmax RGB
blends), :mod:`.shading` (Phong shading of vertex colours), :mod:`.renderer` (the renderers),
:mod:`.contour` (a silhouette-contour loss by edge sampling).
"""
from .contour import ContourSamples, ContourSilhouetteLoss, contour_edges
from .blending import (
    SoftBlend,
    SoftSilhouetteShader,
    sigmoid_alpha_blend,
    sigmoid_alpha_blend_vjp,
    softmax_rgb_blend_soft,
)
from .fragments import SoftFragments
from .rasterizer import TUTORIAL_BLUR_RADIUS, SoftRasterizationSettings, rasterize_soft
from .renderer import (
    SoftGrads,
    SoftPhongRenderer,
    SoftRender,
    SoftSilhouetteRenderer,
    shade_soft_phong,
)
from .shading import PhongColors, phong_vertex_colors

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
    "shade_soft_phong",
    "sigmoid_alpha_blend",
    "sigmoid_alpha_blend_vjp",
    "softmax_rgb_blend_soft",
]
