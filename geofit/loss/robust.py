"""The pseudo-Huber (robust) loss of PyTorch3D's volume and NeRF tutorials, with its derivative.

``h(x, y) = s (sqrt(1 + (x - y)^2 / s^2) - 1)`` elementwise (the tutorials' ``huber`` clamps the
square root's argument at 1e-4, which never binds since the argument is at least 1); it is
quadratic, ``(x - y)^2 / (2 s)``, for small residuals and linear, ``|x - y| - s``, for large ones.
"""
from __future__ import annotations

import numpy as np

from .._validate import as_array, check_positive

__all__ = ["huber", "huber_residual"]


def huber(x, target, scaling: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """The tutorials' pseudo-Huber loss, elementwise, and its derivative.

    Parameters
    ----------
    x : (...) float64
        Prediction.
    target : (...) float64
        Target, broadcastable to ``x``.
    scaling : float
        ``s`` (0.1 in the tutorials), > 0.

    Returns
    -------
    values : (...) float64
        The loss of every element (take the mean as the tutorials do).
    grad : (...) float64
        ``d values / d x = (x - y) / (s sqrt(1 + (x - y)^2 / s^2))``.

    Raises
    ------
    ValueError
        If ``scaling`` is not positive or an input holds NaN or inf.

    Examples
    --------
    >>> v, g = huber(np.array([0.0, 0.1]), 0.0)
    >>> v.round(6).tolist(), g.round(6).tolist()
    ([0.0, 0.041421], [0.0, 0.707107])
    """
    s = check_positive(scaling, "scaling")
    x = as_array(x, "x")
    y = as_array(target, "target")
    return huber_residual(x - y, s)


def huber_residual(r: np.ndarray, scaling: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`huber` of residuals ``r = x - y`` without validation (for inner loops).

    Parameters
    ----------
    r : (...) float32 or float64
        Residuals.
    scaling : float
        ``s`` > 0 (not checked).

    Returns
    -------
    values, grad : (...) arrays of ``r``'s dtype
    """
    q = np.sqrt(1.0 + (r / scaling) ** 2)
    return scaling * (q - 1.0), r / (scaling * q)
