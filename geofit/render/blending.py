"""Turning per-hit colours into RGBA images (PyTorch3D's ``hard_rgb_blend`` and, for one face per
pixel, ``softmax_rgb_blend``)."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._validate import as_array, check_positive

__all__ = ["BlendParams", "hard_rgb_blend", "softmax_rgb_blend", "sigmoid_alpha"]


class BlendParams(NamedTuple):
    """Blending parameters (PyTorch3D's ``BlendParams``).

    Attributes
    ----------
    sigma : float
        Width of the soft alpha falloff in squared NDC units (``alpha = sigmoid(-dists /
        sigma)``); default 1e-4.
    gamma : float
        Depth-softmax temperature; default 1e-4 (with one face per pixel it only decides the
        negligible background weight).
    background_color : (3,) float
        RGB of pixels that no face covers; default white.
    """

    sigma: float = 1e-4
    gamma: float = 1e-4
    background_color: tuple = (1.0, 1.0, 1.0)


def _background(blend_params: BlendParams) -> np.ndarray:
    bg = as_array(blend_params.background_color, "blend_params.background_color", (3,))
    return bg.astype(np.float32)


def _check_blend(blend_params) -> BlendParams:
    if not isinstance(blend_params, BlendParams):
        raise TypeError(f"blend_params: expected a BlendParams, got {type(blend_params)!r}")
    check_positive(blend_params.sigma, "blend_params.sigma")
    check_positive(blend_params.gamma, "blend_params.gamma")
    _background(blend_params)
    return blend_params


def _scatter_rgba(fragments, rgb: np.ndarray, alpha: np.ndarray, bg: np.ndarray,
                  clip: bool) -> np.ndarray:
    N = fragments.n_views
    H, W = fragments.image_size
    out = np.empty((N * H * W, 4), dtype=np.float32)
    out[:, :3] = bg
    out[:, 3] = 0.0
    if clip:
        rgb = np.clip(rgb, 0.0, 1.0)
    out[fragments.pixel, :3] = rgb
    out[fragments.pixel, 3] = alpha
    return out.reshape(N, H, W, 4)


def hard_rgb_blend(colors: np.ndarray, fragments, blend_params: BlendParams = BlendParams(),
                   *, clip: bool = True) -> np.ndarray:
    """RGBA images: the hit colour where a face covers the pixel, the background elsewhere.

    Parameters
    ----------
    colors : (k, 3) float
        Colour of each covered pixel, in the order of ``fragments.pixel``.
    fragments : Fragments
    blend_params : BlendParams
        Only ``background_color`` is used.
    clip : bool
        Clip RGB to [0, 1] (PyTorch3D does not; with its default lights and materials the
        colours never exceed 1).

    Returns
    -------
    images : (N, H, W, 4) float32
        Alpha is 1 on covered pixels, 0 on the background.
    """
    bp = _check_blend(blend_params)
    return _scatter_rgba(fragments, colors, np.float32(1.0), _background(bp), clip)


def sigmoid_alpha(fragments, sigma: float) -> np.ndarray:
    """(k,) float32 soft coverage ``sigmoid(-dists / sigma)`` of the kept face at each hit."""
    d = fragments.hit_dists.astype(np.float64)
    return (1.0 / (1.0 + np.exp(np.minimum(d / sigma, 80.0)))).astype(np.float32)


def softmax_rgb_blend(colors: np.ndarray, fragments, blend_params: BlendParams = BlendParams(),
                      znear=1.0, zfar=100.0, *, clip: bool = True) -> np.ndarray:
    """PyTorch3D's ``softmax_rgb_blend`` for one face per pixel.

    With ``p = sigmoid(-dists / sigma)``, ``z' = (zfar - zbuf) / (zfar - znear)``,
    ``zm = max(z', 1e-10)``, ``w = p exp((z' - zm) / gamma)`` (``= p`` before ``zfar``) and
    ``delta = max(exp((1e-10 - zm) / gamma), 1e-10)``::

        RGB = (w c + delta bg) / (w + delta),   A = p.

    At ordinary depths ``delta`` is 1e-10, so RGB equals the face colour on covered pixels and the
    alpha channel is the soft coverage (between 0.5 and 1 inside a face, lowest next to its
    edges, including internal edges of the mesh: it is not a coverage mask).

    Parameters
    ----------
    colors : (k, 3) float
        Colour of each covered pixel (order of ``fragments.pixel``).
    fragments : Fragments
    blend_params : BlendParams
    znear, zfar : float or (N,) float
        The cameras' clipping planes.
    clip : bool
        Clip RGB to [0, 1].

    Returns
    -------
    images : (N, H, W, 4) float32
    """
    bp = _check_blend(blend_params)
    bg = _background(bp)
    view = fragments.view
    zn = np.broadcast_to(np.asarray(znear, np.float64).reshape(-1), (fragments.n_views,))[view]
    zf = np.broadcast_to(np.asarray(zfar, np.float64).reshape(-1), (fragments.n_views,))[view]
    p = sigmoid_alpha(fragments, bp.sigma).astype(np.float64)
    z = (zf - fragments.depth) / (zf - zn)
    zm = np.maximum(z, 1e-10)
    delta = np.maximum(np.exp(np.minimum((1e-10 - zm) / bp.gamma, 80.0)), 1e-10)
    w = p * np.exp((z - zm) / bp.gamma)  # = p unless the face lies beyond zfar
    rgb = (w[:, None] * colors + delta[:, None] * bg) / (w + delta)[:, None]
    return _scatter_rgba(fragments, rgb.astype(np.float32), p.astype(np.float32), bg, clip)
