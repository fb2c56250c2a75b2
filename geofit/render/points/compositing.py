"""Compositing of rasterized points (PyTorch3D's ``AlphaCompositor`` and ``NormWeightedCompositor``).

Both take, per pixel, the ``K`` points of a ``PointFragments`` (front to back, ``idx == -1`` for
empty slots), a weight per slot and a feature per point, and return ``(N, H, W, C)`` images:

- alpha (front to back): ``out = sum_k w_k prod_{l<k} (1 - w_l) f_k``;
- normalised weighted sum: ``out = sum_k w_k f_k / max(sum_k w_k, 1e-4)``.

Empty slots contribute nothing. With a ``background_color`` the colour **replaces** the pixels
that no point covers (``idx[..., 0] < 0``); the transmittance left over at covered pixels is not
blended with it (PyTorch3D's rule). Without one, empty pixels are 0. A background of ``C - 1``
channels gets an alpha of 1 appended (RGBA features with an RGB background).
"""
from __future__ import annotations

import numpy as np

from ..._validate import as_array

__all__ = ["AlphaCompositor", "NormWeightedCompositor", "add_background_color"]

# PyTorch3D's kEpsilon in csrc/compositing/norm_weighted_sum*.
_NORM_EPS = 1e-4


def _background(background_color, name: str = "background_color"):
    if background_color is None:
        return None
    if np.ndim(background_color) == 0:     # a scalar fills every channel
        v = as_array([background_color], name)[0]
        return np.asarray(v)
    bg = as_array(background_color, name)
    if bg.ndim > 1:
        raise ValueError(f"{name}: expected a scalar or shape (C,), got {bg.shape}")
    if bg.ndim == 1 and len(bg) == 0:
        raise ValueError(f"{name}: expected at least one channel, got shape (0,)")
    return bg


def add_background_color(images, idx, background_color) -> np.ndarray:
    """Replace the pixels no point covers by a background colour (PyTorch3D's rule).

    Parameters
    ----------
    images : (N, H, W, C) float64
        Composited images.
    idx : (N, H, W, K) int64
        Fragment indices; a pixel is background where ``idx[..., 0] < 0``.
    background_color : float or (C,) or (C - 1,) float64
        The colour; a scalar fills every channel; ``C - 1`` channels get alpha 1 appended.

    Returns
    -------
    images : (N, H, W, C) float64
        A copy with the background pixels replaced.
    """
    bg = _background(background_color)
    C = images.shape[-1]
    if bg.ndim == 0:
        bg = np.full(C, float(bg))
    if len(bg) + 1 == C:
        bg = np.concatenate([bg, [1.0]])
    if len(bg) != C:
        raise ValueError(f"background_color: expected {C} or {C - 1} channels to match the "
                         f"features, got {len(bg)}")
    out = np.array(images, dtype=np.float64)
    out[idx[..., 0] < 0] = bg
    return out


def _covered(idx, weights, C):
    """Zero images ``(N, H, W, C)``, the ``(n, K)`` rows of the covered pixels, and their mask."""
    out = np.zeros(idx.shape[:3] + (C,))
    covered = idx[..., 0] >= 0
    return out, (idx[covered], weights[covered]), covered


def _slots(idx, weights, features):
    """For each of the K slots of the ``(n, K)`` rows: the weights (0 where the slot is empty)
    ``(n,)`` and the features of the point in it ``(n, C)``."""
    for k in range(idx.shape[1]):   # loop over the K slots (layers), vectorised over pixels
        ik = idx[:, k]
        valid = ik >= 0
        yield np.where(valid, weights[:, k], 0.0), features[np.where(valid, ik, 0)]


class _Compositor:
    def __init__(self, background_color=None):
        self.background_color = _background(background_color)

    def _check(self, idx, weights, features):
        idx = as_array(idx, "idx", dtype=np.int64)
        if idx.ndim != 4:
            raise ValueError(f"idx: expected shape (N, H, W, K), got {idx.shape}")
        weights = as_array(weights, "weights", idx.shape)
        features = np.asarray(features)
        if features.ndim == 1:
            features = features[:, None]
        features = as_array(features, "features", (None, None))
        if idx.size and idx.max() >= len(features):
            raise ValueError(f"idx: point indices must be < {len(features)} (the number of "
                             f"features), got {int(idx.max())}")
        if idx.size and idx.min() < -1:
            raise ValueError(f"idx: expected -1 or point indices, got {int(idx.min())}")
        return idx, weights, features

    _UNSET = object()

    def __call__(self, idx, weights, features, background_color=_UNSET) -> np.ndarray:
        """Composite.

        Parameters
        ----------
        idx : (N, H, W, K) int64
            ``PointFragments.idx``: packed point per slot, front to back, -1 where empty.
        weights : (N, H, W, K) float64
            Weight (alpha) of each slot, e.g. ``PointFragments.weights()``; ignored where
            ``idx`` is -1.
        features : (P, C) float64
            Feature of each packed point (RGB, RGBA, ...).
        background_color : float or (C,) or (C - 1,) or None, optional
            Overrides the compositor's background colour for this call.

        Returns
        -------
        images : (N, H, W, C) float64
        """
        idx, weights, features = self._check(idx, weights, features)
        bg = self.background_color if background_color is self._UNSET else \
            _background(background_color)
        images = self._composite(idx, weights, features)
        if bg is not None:
            images = add_background_color(images, idx, bg)
        return images

    def _composite(self, idx, weights, features):
        out, (idx, weights), covered = _covered(idx, weights, features.shape[1])
        out[covered] = self._accumulate(idx, weights, features)
        return out

    def _accumulate(self, idx, weights, features):
        """``(n, C)`` colours of the covered pixels from their ``(n, K)`` slots."""
        raise NotImplementedError


class AlphaCompositor(_Compositor):
    """Front-to-back alpha compositing (PyTorch3D's ``AlphaCompositor``).

    ``out = sum_k w_k T_k f_k`` with ``T_k = prod_{l<k} (1 - w_l)`` over the filled slots.

    Parameters
    ----------
    background_color : float or (C,) or (C - 1,) float64, optional
        Colour of pixels no point covers; None (default) leaves them 0.

    Examples
    --------
    >>> idx = np.array([0, 1, -1]).reshape(1, 1, 1, 3)
    >>> w = np.array([0.5, 1.0, 0.3]).reshape(1, 1, 1, 3)
    >>> AlphaCompositor()(idx, w, np.array([[1.0], [3.0]]))[0, 0, 0]
    array([2.])
    """

    def _accumulate(self, idx, weights, features):
        T = np.ones(len(idx))
        acc = np.zeros((len(idx), features.shape[1]))
        for a, f in _slots(idx, weights, features):
            acc += (a * T)[:, None] * f
            T *= 1.0 - a
        return acc


class NormWeightedCompositor(_Compositor):
    """Normalised weighted sum (PyTorch3D's ``NormWeightedCompositor``).

    ``out = sum_k w_k f_k / max(sum_k w_k, 1e-4)`` over the filled slots; ``background_color``
    as :class:`AlphaCompositor`.

    Examples
    --------
    >>> half = np.full((1, 1, 1, 2), 0.5)
    >>> NormWeightedCompositor()(np.array([1, 0]).reshape(half.shape), half,
    ...                          np.array([[1.0], [4.0]]))[0, 0, 0]
    array([2.5])
    """

    def _accumulate(self, idx, weights, features):
        total = np.zeros(len(idx))
        acc = np.zeros((len(idx), features.shape[1]))
        for a, f in _slots(idx, weights, features):
            acc += a[:, None] * f
            total += a
        return acc / np.maximum(total, _NORM_EPS)[:, None]
