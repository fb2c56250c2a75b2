"""Validation shared by the rasterization settings (:mod:`.mesh`, :mod:`.soft`)."""
from __future__ import annotations

import numpy as np


def image_hw(image_size) -> tuple[int, int]:
    """``(H, W)`` of an ``image_size`` setting: an int (square) or a pair of whole numbers.

    Parameters
    ----------
    image_size : int or (2,) int
        The setting as given.

    Returns
    -------
    (H, W) : tuple of int

    Raises
    ------
    ValueError
        Naming ``image_size``, for anything but an int or a pair of positive whole numbers.
    """
    size = image_size
    if isinstance(size, (int, np.integer)) and not isinstance(size, (bool, np.bool_)):
        size = (int(size), int(size))
    try:
        H, W = (int(v) for v in size)
        bad = not all(float(v) == int(v) for v in size)
    except (TypeError, ValueError):
        raise ValueError(f"image_size: expected an int or (H, W), got {image_size!r}") from None
    if bad or H < 1 or W < 1:
        raise ValueError(f"image_size: expected positive integers, got {image_size!r}")
    return H, W
