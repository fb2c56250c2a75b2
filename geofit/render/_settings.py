"""Validation shared by the rasterization settings (:mod:`.mesh`, :mod:`.soft`).

Why three settings classes, and not one: each is the contract of one rasterizer and validates at
construction what that rasterizer can do, so a setting it would ignore or cannot honour fails
where it is written, not deep inside a render.

- :class:`~geofit.render.mesh.RasterizationSettings`: the hard mesh rasterizer (Embree ray
  casting, one ray per pixel centre). It only does PyTorch3D's hard case (``blur_radius == 0``,
  ``faces_per_pixel == 1``) and has ray-casting knobs (``supersample``, PyTorch3D's binning
  fields accepted and ignored).
- :class:`~geofit.render.soft.SoftRasterizationSettings`: the differentiable soft rasterizer
  (projected triangles, ``K`` faces per pixel within ``blur_radius``, with vjps). Its knobs are
  the blur, ``K``, the candidate-pair memory bound ``max_pairs`` and the storage ``dtype``.
- :class:`~geofit.render.points.PointsRasterizationSettings`: points, not triangles (a radius per
  point in NDC or world units, ``points_per_pixel``), as PyTorch3D's class of the same name.

PyTorch3D has one ``RasterizationSettings`` for meshes because one CUDA kernel does both the hard
and the blurred case; :mod:`geofit.pytorch3d` keeps that single class and picks the hard or the
soft rasterizer from its ``blur_radius`` and ``faces_per_pixel``. What the classes share, the
``image_size`` rule and the float dtype, lives here.
"""
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
