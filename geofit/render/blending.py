"""Turning per-hit colours into RGBA images (PyTorch3D's ``hard_rgb_blend`` and, for one face per
pixel, ``softmax_rgb_blend``)."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._threads import parallel_map
from .._validate import as_array, check_positive

__all__ = ["BlendParams", "hard_rgb_blend", "sigmoid_alpha", "softmax_rgb_blend"]


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


def check_blend(blend_params) -> tuple[BlendParams, np.ndarray]:
    """Validate a BlendParams; returns it and the (3,) float32 background colour."""
    if not isinstance(blend_params, BlendParams):
        raise TypeError(f"blend_params: expected a BlendParams, got {type(blend_params)!r}")
    check_positive(blend_params.sigma, "blend_params.sigma")
    check_positive(blend_params.gamma, "blend_params.gamma")
    bg = as_array(blend_params.background_color, "blend_params.background_color", (3,))
    return blend_params, bg.astype(np.float32)


def new_images(fragments, bg: np.ndarray, n_threads: int = 1) -> np.ndarray:
    """(N * H * W, 4) float32 filled with the background colour and alpha 0."""
    N = fragments.n_views
    H, W = fragments.image_size
    out = np.empty((N * H * W, 4), dtype=np.float32)
    fill = np.append(bg, np.float32(0.0))
    if n_threads > 1 and len(out) >= 1 << 20:
        bounds = np.linspace(0, len(out), n_threads + 1).astype(np.int64)

        def run(i):
            out[bounds[i]:bounds[i + 1]] = fill

        parallel_map(run, range(n_threads), n_threads)
    else:
        out[:] = fill
    return out


def scatter(out: np.ndarray, pixel: np.ndarray, rgb_t: np.ndarray, alpha, clip: bool) -> None:
    """Write colours ``rgb_t (3, k)`` and ``alpha`` (scalar or (k,)) at flat ``pixel (k,)``."""
    if clip:
        rgb_t = np.clip(rgb_t, 0.0, 1.0)
    for c in range(3):  # the three colour channels
        out[pixel, c] = rgb_t[c]
    out[pixel, 3] = alpha


def soft_rgba_t(rgb_t: np.ndarray, dists: np.ndarray, depth: np.ndarray, bg: np.ndarray,
                blend_params: BlendParams, znear, zfar):
    """softmax_rgb_blend at K = 1 for a chunk: returns ``(rgb_t (3, k), alpha (k,))`` float32.

    ``znear``, ``zfar`` are scalars or ``(k,)`` arrays.
    """
    sigma, gamma = float(blend_params.sigma), float(blend_params.gamma)
    p = 1.0 / (1.0 + np.exp(np.minimum(dists / sigma, 80.0)))
    z = (zfar - depth) / (zfar - znear)
    zm = np.maximum(z, 1e-10)
    delta = np.maximum(np.exp(np.minimum((1e-10 - zm) / gamma, 80.0)), 1e-10)
    w = p * np.exp((z - zm) / gamma)  # = p unless the face lies beyond zfar
    den = w + delta
    a = (w / den).astype(np.float32)
    b = (delta / den).astype(np.float32)
    rgb = a * rgb_t + b * bg[:, None]
    return rgb.astype(np.float32, copy=False), p.astype(np.float32)


def hard_rgb_blend(colors: np.ndarray, fragments, blend_params: BlendParams | None = None,
                   *, clip: bool = True) -> np.ndarray:
    """RGBA images: the hit colour where a face covers the pixel, the background elsewhere.

    Parameters
    ----------
    colors : (k, 3) float
        Colour of each covered pixel, in the order of ``fragments.pixel``.
    fragments : Fragments
    blend_params : BlendParams, optional
        Only ``background_color`` is used (default ``BlendParams()``: white).
    clip : bool
        Clip RGB to [0, 1] (PyTorch3D does not; with its default lights and materials the
        colours never exceed 1).

    Returns
    -------
    images : (N, H, W, 4) float32
        Alpha is 1 on covered pixels, 0 on the background.
    """
    _, bg = check_blend(BlendParams() if blend_params is None else blend_params)
    out = new_images(fragments, bg)
    scatter(out, fragments.pixel, np.asarray(colors, np.float32).T, np.float32(1.0), clip)
    H, W = fragments.image_size
    return out.reshape(fragments.n_views, H, W, 4)


def sigmoid_alpha(fragments, sigma: float = 1e-4) -> np.ndarray:
    """(k,) float32 soft coverage ``sigmoid(-dists / sigma)`` of the kept face at each hit."""
    sigma = check_positive(sigma, "sigma")
    d = fragments.hit_dists
    return (1.0 / (1.0 + np.exp(np.minimum(d / sigma, 80.0)))).astype(np.float32)


def softmax_rgb_blend(colors: np.ndarray, fragments, blend_params: BlendParams | None = None,
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
    blend_params : BlendParams, optional
        Default ``BlendParams()``.
    znear, zfar : float or (N,) float
        The cameras' clipping planes.
    clip : bool
        Clip RGB to [0, 1].

    Returns
    -------
    images : (N, H, W, 4) float32
    """
    bp, bg = check_blend(BlendParams() if blend_params is None else blend_params)
    view = fragments.view
    n = fragments.n_views
    zn = np.broadcast_to(np.asarray(znear, np.float64).reshape(-1), (n,))[view]
    zf = np.broadcast_to(np.asarray(zfar, np.float64).reshape(-1), (n,))[view]
    rgb, alpha = soft_rgba_t(np.asarray(colors, np.float32).T, fragments.hit_dists,
                             fragments.depth, bg, bp, zn, zf)
    out = new_images(fragments, bg)
    scatter(out, fragments.pixel, rgb, alpha, clip)
    H, W = fragments.image_size
    return out.reshape(n, H, W, 4)
