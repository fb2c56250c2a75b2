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
        Naming ``image_size``, for anything but an int or a pair of positive whole numbers (a
        string such as ``"16"`` included).
    """
    size = image_size
    if isinstance(size, (str, bytes)) or (not isinstance(size, (int, np.integer))
                                          and not hasattr(size, "__len__")):
        raise ValueError(f"image_size: expected an int or (H, W), got {type(size).__name__} "
                         f"{size!r:.40}")
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


def float_dtype(value, name: str = "dtype"):
    """``numpy.float32`` or ``numpy.float64`` from a dtype-like ``value``; ValueError otherwise
    (None, other types, names numpy does not know)."""
    try:
        dt = None if value is None else np.dtype(value)
    except TypeError:
        dt = None
    if dt is None or dt.type not in (np.float32, np.float64):
        raise ValueError(f"{name}: expected numpy.float32 or numpy.float64, got {value!r}")
    return dt.type
