"""The differentiable mesh renderers: soft rasterizer + shader, with one ``vjp``.

:class:`SoftSilhouetteRenderer` and :class:`SoftPhongRenderer` return a :class:`SoftRender`
whose :meth:`~SoftRender.vjp` maps an image gradient to the vertex positions (and colours).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from ..._validate import as_array
from ...structures import Mesh
from ..blending import BlendParams
from ..lighting import PointLights
from ..materials import Materials
from .blending import (
    SoftBlend,
    _check_blend,
    _softmax_weights,
    sigmoid_alpha_blend,
    sigmoid_alpha_blend_vjp,
    softmax_rgb_blend_soft,
)
from .fragments import _NEGLIGIBLE, SoftFragments
from .rasterizer import SoftRasterizationSettings, _check_cameras, _check_settings, rasterize_soft
from .shading import PhongColors, phong_vertex_colors

__all__ = [
    "SoftGrads",
    "SoftPhongRenderer",
    "SoftRender",
    "SoftSilhouetteRenderer",
    "shade_soft_phong",
]

# ------------------------------------------------------------------------------------------
# Renderers
# ------------------------------------------------------------------------------------------


class SoftGrads(NamedTuple):
    """Gradients of a scalar loss with respect to the inputs of a soft render.

    Attributes
    ----------
    verts : (V, 3) float64
    colors : (V, 3) float64 or None
        Per-vertex colours (Phong renders only).
    """

    verts: np.ndarray
    colors: np.ndarray | None


@dataclass(eq=False)
class SoftRender:
    """Images of a soft render and the means to differentiate them.

    Attributes
    ----------
    images : (N, H, W, 4) float32 or float64
        RGBA (RGB = 1 for silhouettes); Phong images in the settings' ``dtype``.
    fragments : SoftFragments
    """

    images: np.ndarray
    fragments: SoftFragments
    _kind: str = "silhouette"
    _saved: dict = field(default_factory=dict, repr=False)

    @property
    def silhouettes(self) -> np.ndarray:
        """(N, H, W) float64 alpha channel."""
        return self.images[..., 3]

    def vjp(self, grad_images) -> SoftGrads:
        """Gradient of ``L`` from ``dL/d images``.

        Parameters
        ----------
        grad_images : (N, H, W, 4) or (N, H, W) float64
            dL/d images; an ``(N, H, W)`` array is the gradient on the alpha channel only.

        Returns
        -------
        SoftGrads
        """
        shape = self.images.shape
        g = np.asarray(grad_images, dtype=np.float64)
        if g.shape == shape[:3]:
            g4 = np.zeros(shape)
            g4[..., 3] = g
            g = g4
        g = as_array(g, "grad_images", shape)
        fr = self.fragments
        if self._kind == "silhouette":
            sigma = self._saved["sigma"]
            gd = sigmoid_alpha_blend_vjp(fr, g[..., 3], sigma, self.images[..., 3])
            return SoftGrads(fr.vjp(grad_dists=gd), None)
        blend: SoftBlend = self._saved["blend"]
        shading: PhongColors = self._saved["shading"]
        g_col, g_d, g_z = blend.vjp(g)
        g_col = g_col[shading.entries]
        gv, gcol, gb = shading.vjp(g_col)
        del g_col
        gbary = np.zeros((len(fr), 3), g_d.dtype)
        gbary[shading.entries] = gb
        del gb
        gv = gv + fr.vjp(grad_dists=g_d, grad_zbuf=g_z, grad_bary=gbary)
        return SoftGrads(gv, gcol)

    def color_operator(self) -> tuple[list, np.ndarray]:
        """The render's RGB as an affine map of the vertex colours (geometry held fixed).

        ``rgb[..., c].ravel() == A[c] @ vertex_colors[:, c] + b[..., c].ravel()`` exactly (up to
        rounding), because the blend weights and the shading do not depend on the colours.

        Returns
        -------
        A : list of 3 scipy.sparse.csr_matrix, each (N * H * W, V)
        b : (N, H, W, 3) float64
            The specular and background part.

        Raises
        ------
        ValueError
            For a silhouette render.
        """
        if self._kind != "phong":
            raise ValueError("color_operator: only a SoftPhongRenderer render has colours")
        fr = self.fragments
        blend: SoftBlend = self._saved["blend"]
        shading: PhongColors = self._saved["shading"]
        V = fr._ctx["n_verts"]
        H, W = fr.image_size
        G = fr.n_views * H * W
        e = shading.entries
        gp = fr.global_pixel[e]
        tri = fr._ctx["faces"][fr.face[e]]
        rows = np.repeat(gp, 3)
        cols = tri.ravel()
        wts = blend.weights[e]
        bary = fr.bary[e]
        mats = []
        for c in range(3):  # colour channels
            data = (wts[:, None] * shading.shade[:, c:c + 1] * bary).ravel()
            mats.append(sp.csr_matrix((data, (rows, cols)), shape=(G, V)))
        bg = np.asarray(self._saved["bg"], np.float64)
        b = np.stack([np.bincount(gp, wts * shading.specular[:, c], G) for c in range(3)],
                     1).astype(np.float64)  # float even when no pixel is covered
        b += blend.background_weight[:, None] * bg[None, :]
        return mats, b.reshape(fr.n_views, H, W, 3)


class SoftSilhouetteRenderer:
    """Soft rasterizer + :class:`SoftSilhouetteShader` (the tutorial's ``renderer_silhouette``).

    Parameters
    ----------
    cameras : camera batch
        ``N`` cameras (can be overridden per call).
    raster_settings : SoftRasterizationSettings, optional
    blend_params : BlendParams, optional
        ``sigma`` (default 1e-4).

    Examples
    --------
    >>> from geofit import FoVPerspectiveCameras, ico_sphere, look_at_view_transform
    >>> R, T = look_at_view_transform(2.7, 0.0, [0.0, 90.0])
    >>> r = SoftSilhouetteRenderer(FoVPerspectiveCameras(R=R, T=T),
    ...                            SoftRasterizationSettings.tutorial(32))
    >>> out = r(ico_sphere(2))
    >>> out.images.shape, out.vjp(out.silhouettes).verts.shape
    ((2, 32, 32, 4), (162, 3))
    """

    def __init__(self, cameras=None, raster_settings: SoftRasterizationSettings | None = None,
                 blend_params: BlendParams | None = None):
        self.cameras = cameras
        self.raster_settings = _check_settings(raster_settings)
        self.blend_params = _check_blend(blend_params)

    def __call__(self, mesh: Mesh, cameras=None) -> SoftRender:
        cameras = _check_cameras(cameras if cameras is not None else self.cameras)
        fr = rasterize_soft(mesh, cameras, self.raster_settings)
        sigma = float(self.blend_params.sigma)
        a = sigmoid_alpha_blend(fr, sigma)
        images = np.ones(a.shape + (4,))
        images[..., 3] = a
        return SoftRender(images, fr, "silhouette", {"sigma": sigma})


class SoftPhongRenderer:
    """Soft rasterizer + Phong shading of vertex colours + softmax blend (``SoftPhongShader``).

    Parameters
    ----------
    cameras : camera batch
        ``N`` cameras (can be overridden per call).
    lights : PointLights, DirectionalLights or AmbientLights, optional
        Default ``PointLights()`` (location (0, 1, 0)).
    materials : Materials, optional
        Default ``Materials()``.
    raster_settings : SoftRasterizationSettings, optional
    blend_params : BlendParams, optional

    Notes
    -----
    ``znear`` and ``zfar`` of the blend come from the cameras (1 and 100 for cameras without
    them), as PyTorch3D's ``SoftPhongShader``. Entries whose softmax factor
    ``exp((z_k - zm) / gamma)`` is below 1e-20 (faces far behind the nearest one of their
    pixel; about half of them for a closed mesh) are not shaded: their colour would move the
    pixel by less than 1e-20 of its nearest face's share (1e-16 relative in the worst case of a
    nearest face barely inside the blur radius). Their distances and depths still enter the
    alpha channel and the blend's normaliser exactly.

    Examples
    --------
    >>> import numpy as np
    >>> from geofit import FoVPerspectiveCameras, ico_sphere, look_at_view_transform
    >>> R, T = look_at_view_transform(2.7, 0.0, 0.0)
    >>> r = SoftPhongRenderer(FoVPerspectiveCameras(R=R, T=T),
    ...                       raster_settings=SoftRasterizationSettings.tutorial(16))
    >>> out = r(ico_sphere(2), np.full((162, 3), 0.5))
    >>> g = out.vjp(np.ones(out.images.shape))
    >>> out.images.shape, g.verts.shape, g.colors.shape
    ((1, 16, 16, 4), (162, 3), (162, 3))
    """

    def __init__(self, cameras=None, lights=None, materials=None,
                 raster_settings: SoftRasterizationSettings | None = None,
                 blend_params: BlendParams | None = None):
        self.cameras = cameras
        self.lights = lights if lights is not None else PointLights()
        self.materials = materials if materials is not None else Materials()
        self.raster_settings = _check_settings(raster_settings)
        self.blend_params = _check_blend(blend_params)

    def __call__(self, mesh: Mesh, vertex_colors, cameras=None, lights=None) -> SoftRender:
        cameras = _check_cameras(cameras if cameras is not None else self.cameras)
        lights = lights if lights is not None else self.lights
        fr = rasterize_soft(mesh, cameras, self.raster_settings)
        return shade_soft_phong(fr, mesh, vertex_colors, lights, cameras, self.materials,
                                self.blend_params)


def shade_soft_phong(fragments: SoftFragments, mesh: Mesh, vertex_colors, lights, cameras,
                     materials, blend_params: BlendParams | None = None) -> SoftRender:
    """Phong shading of vertex colours + the depth-softmax blend of soft fragments.

    PyTorch3D's ``SoftPhongShader`` on fragments of the soft rasterizer (what
    :class:`SoftPhongRenderer` and :class:`geofit.render.SoftPhongShader` on
    :class:`SoftFragments` run).

    Parameters
    ----------
    fragments : SoftFragments
        From :func:`rasterize_soft` of ``mesh`` seen by ``cameras``.
    mesh : Mesh
    vertex_colors : (V, 3) float64
    lights, cameras, materials
        As :class:`SoftPhongRenderer`.
    blend_params : BlendParams, optional

    Returns
    -------
    SoftRender
        Images ``(N, H, W, 4)`` and the ``vjp`` to positions and colours.
    """
    fr = fragments
    blend_params = _check_blend(blend_params)
    znear = getattr(cameras, "znear", 1.0)
    zfar = getattr(cameras, "zfar", 100.0)
    # faces far behind the nearest one of their pixel get a softmax weight below
    # _NEGLIGIBLE of its weight: their colour is not computed (it would change the pixel by
    # less than that relative amount)
    E = _softmax_weights(fr, blend_params, znear, zfar)["E"]
    active = np.flatnonzero(E >= _NEGLIGIBLE)
    shading = phong_vertex_colors(fr, mesh, vertex_colors, lights, cameras, materials,
                                  entries=active)
    colors = np.zeros((len(fr), 3), fr.dist.dtype)
    colors[active] = shading.colors
    blend = softmax_rgb_blend_soft(colors, fr, blend_params, znear, zfar)
    return SoftRender(blend.images, fr, "phong",
                      {"blend": blend, "shading": shading, "bg": blend_params.background_color})
