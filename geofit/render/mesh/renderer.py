"""Mesh renderers: a rasterizer plus a shader (PyTorch3D's ``renderer/mesh/renderer.py``).

``MeshRenderer(rasterizer=MeshRasterizer(cameras, RasterizationSettings(...)),
shader=SoftPhongShader(cameras, lights))`` renders a mesh, a batch of meshes, or one mesh seen by
``N`` cameras; ``renderer(mesh, cameras=..., lights=..., materials=...)`` overrides the stored
objects for one call, as in PyTorch3D. With ``RasterizationSettings(supersample=s)`` the images
are rendered at ``s`` times the size and box-filtered down.
"""
from __future__ import annotations

import numpy as np

from .rasterizer import Fragments, MeshRasterizer

__all__ = ["MeshRenderer", "MeshRendererWithFragments"]


def downsample(images: np.ndarray, factor: int) -> np.ndarray:
    """Box-filter (N, sH, sW, C) images down to (N, H, W, C)."""
    if factor == 1:
        return images
    N, H, W, C = images.shape
    s = factor
    return images.reshape(N, H // s, s, W // s, s, C).mean(axis=(2, 4), dtype=np.float32)


class MeshRenderer:
    """Rasterizer plus shader: ``images = renderer(meshes, **kwargs)`` (PyTorch3D's class).

    Parameters
    ----------
    rasterizer : MeshRasterizer
    shader : a shader from :mod:`geofit.render.mesh.shading` (e.g. SoftPhongShader)

    Notes
    -----
    Keyword arguments of the call go to both: ``cameras=`` and ``raster_settings=`` to the
    rasterizer, ``cameras=``, ``lights=``, ``materials=`` and ``blend_params=`` to the shader,
    overriding the stored objects for that call only.
    """

    def __init__(self, rasterizer: MeshRasterizer, shader):
        if not isinstance(rasterizer, MeshRasterizer):
            raise TypeError(f"rasterizer: expected a MeshRasterizer, got {type(rasterizer)!r}")
        if not callable(shader):
            raise TypeError(f"shader: expected a shader, got {type(shader)!r}")
        self.rasterizer = rasterizer
        self.shader = shader

    def _render(self, meshes, **kwargs):
        fragments = self.rasterizer(meshes, **kwargs)
        images = self.shader(fragments, fragments.meshes, **kwargs)
        return downsample(images, fragments.supersample), fragments

    def __call__(self, meshes, **kwargs) -> np.ndarray:
        """Render.

        Parameters
        ----------
        meshes : Mesh, Meshes or list of Mesh
        **kwargs
            Overrides for this call (see the class notes).

        Returns
        -------
        images : (N, H, W, 4) float32
            RGBA in [0, 1]; row 0 is the top of the picture, column 0 its left.
        """
        return self._render(meshes, **kwargs)[0]


class MeshRendererWithFragments(MeshRenderer):
    """A MeshRenderer that also returns the fragments: ``images, fragments = renderer(mesh)``.

    The fragments give face ids, depth and normal images for free (see :class:`Fragments`);
    with ``supersample > 1`` they are at the supersampled size.
    """

    def __call__(self, meshes, **kwargs) -> tuple[np.ndarray, Fragments]:
        return self._render(meshes, **kwargs)
