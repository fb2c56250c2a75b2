"""Input validation shared by every public entry point.

Validate once at the public boundary, then trust the arrays inside. Every failure is a
``ValueError`` (or ``TypeError`` for a wrong kind of object) that names the argument, what was
expected and what was given.
"""
from __future__ import annotations

import numbers
from typing import Iterable, Sequence

import numpy as np

from ._foreign import ARRAY_HINTS, geometry_kind

__all__ = [
    "as_array",
    "as_points",
    "as_faces",
    "as_rng",
    "as_unit_images",
    "check_choice",
    "check_coordinates",
    "check_finite",
    "check_int",
    "check_positive",
    "shape_str",
]


def shape_str(shape: Sequence) -> str:
    """Render a shape spec such as ``(None, 3)`` as ``(n, 3)``."""
    names = iter("nmkijl")
    parts = [next(names, "?") if s is None else str(s) for s in shape]
    if len(parts) == 1:
        return f"({parts[0]},)"
    return "(" + ", ".join(parts) + ")"


def as_array(
    x,
    name: str,
    shape: Sequence | None = None,
    dtype=np.float64,
    *,
    finite: bool = True,
    allow_empty: bool = True,
) -> np.ndarray:
    """Return ``x`` as a C-contiguous array of ``dtype`` with the given shape.

    Parameters
    ----------
    x : array_like
        The input.
    name : str
        The argument's name, used in error messages.
    shape : sequence of int or None, optional
        Expected shape; ``None`` entries match any length. ``None`` skips the check.
    dtype : numpy dtype
        Target dtype (float inputs are cast, integer targets require integral values).
    finite : bool
        For float targets, reject NaN and inf.
    allow_empty : bool
        Whether a zero-length first axis is accepted.

    Raises
    ------
    ValueError
        On a shape mismatch, non-finite values, non-integral values for an integer dtype, or an
        empty array when ``allow_empty`` is False.
    TypeError
        For a mesh or point cloud object (geofit, trimesh, Open3D), saying how to convert it.
    """
    if not isinstance(x, (np.ndarray, list, tuple, numbers.Number)):
        kind = geometry_kind(x)
        if kind is not None:
            raise TypeError(f"{name}: expected an array, got a {kind}; {ARRAY_HINTS[kind]}")
    try:
        arr = np.asarray(x)
    except Exception as exc:  # ragged lists and the like
        raise ValueError(f"{name}: could not convert to an array ({exc})") from None
    if arr.dtype == object:
        raise ValueError(f"{name}: expected a numeric array, got ragged or object data")
    if shape is not None:
        ok = arr.ndim == len(shape) and all(
            s is None or s == a for s, a in zip(shape, arr.shape)
        )
        if not ok:
            raise ValueError(
                f"{name}: expected shape {shape_str(shape)}, got {tuple(arr.shape)}"
            )
    target = np.dtype(dtype)
    if target.kind in "iu":
        if arr.dtype.kind == "f":
            if arr.size and not np.all(np.isfinite(arr)):
                raise ValueError(f"{name}: expected integer indices, got non-finite values")
            if arr.size and not np.all(arr == np.round(arr)):
                raise ValueError(f"{name}: expected integer indices, got fractional values")
        elif arr.dtype.kind not in "iub" and arr.size:
            raise ValueError(f"{name}: expected integers, got dtype {arr.dtype}")
    elif target.kind == "f" and arr.dtype.kind not in "fiub" and arr.size:
        raise ValueError(f"{name}: expected real numbers, got dtype {arr.dtype}")
    arr = np.ascontiguousarray(arr, dtype=target)
    if not allow_empty and (arr.ndim == 0 or arr.shape[0] == 0):
        raise ValueError(f"{name}: expected a non-empty array, got shape {tuple(arr.shape)}")
    if finite and target.kind == "f" and arr.size and not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise ValueError(f"{name}: expected finite values, got {bad} NaN or inf entries")
    return arr


def as_unit_images(x, name: str, shape: Sequence | None = None) -> np.ndarray:
    """``as_array`` for float images with values in [0, 1]: integer (8-bit) data and values
    outside [-0.01, 1.01] (a 0-255 float image) are refused, naming ``name``."""
    dt = getattr(x, "dtype", None)
    if dt is not None and np.dtype(dt).kind in "iu":
        raise ValueError(f"{name}: expected float values in [0, 1], got integer dtype {dt} "
                         f"(divide 8-bit images by 255)")
    arr = as_array(x, name, shape)
    if arr.size and (arr.min() < -0.01 or arr.max() > 1.01):
        raise ValueError(f"{name}: expected values in [0, 1], got range [{arr.min():.4g}, "
                         f"{arr.max():.4g}] (divide 0-255 images by 255)")
    return arr


def as_points(x, name: str, *, allow_empty: bool = True, dtype=np.float64) -> np.ndarray:
    """Validate an ``(n, 3)`` array of finite coordinates."""
    return as_array(x, name, (None, 3), dtype, allow_empty=allow_empty)


def as_faces(F, name: str, n_verts: int, *, allow_empty: bool = True) -> np.ndarray:
    """Validate an ``(m, 3)`` int64 face array whose entries index ``n_verts`` vertices."""
    F = as_array(F, name, (None, 3), np.int64, allow_empty=allow_empty)
    if F.size:
        lo, hi = int(F.min()), int(F.max())
        if lo < 0 or hi >= n_verts:
            raise ValueError(
                f"{name}: vertex indices must lie in [0, {n_verts - 1}], got range [{lo}, {hi}]"
            )
    return F


def as_rng(seed) -> np.random.Generator:
    """Return a ``np.random.Generator`` from a seed, a Generator, or None (fresh entropy)."""
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None or isinstance(seed, (numbers.Integral, np.integer)):
        return np.random.default_rng(seed)
    raise TypeError(f"seed: expected an int, None or numpy.random.Generator, got {type(seed)!r}")


def as_instance(value, cls: type, name: str, expected: str | None = None):
    """Return ``value`` when it is a ``cls``, a default ``cls()`` when it is None.

    Raises TypeError naming ``name``, ``expected`` (default: the class name) and the type found
    for anything else (the settings objects of the rasterizers and renderers).
    """
    if value is None:
        return cls()
    if not isinstance(value, cls):
        raise TypeError(f"{name}: expected {expected or cls.__name__}, got {type(value)!r}")
    return value


def check_choice(value, name: str, choices: Iterable) -> None:
    """Raise ValueError unless ``value`` is one of ``choices``."""
    choices = tuple(choices)
    if value not in choices:
        raise ValueError(f"{name}: expected one of {choices}, got {value!r}")


def _as_float(value, name: str) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {value!r}") from None


def check_finite(value, name: str) -> float:
    """Return ``float(value)`` after checking it is a finite number."""
    v = _as_float(value, name)
    if not np.isfinite(v):
        raise ValueError(f"{name}: expected a finite number, got {value!r}")
    return v


def check_positive(value, name: str, *, strict: bool = True) -> float:
    """Return ``float(value)`` after checking it is finite and positive (or >= 0)."""
    v = _as_float(value, name)
    if not np.isfinite(v) or (v <= 0 if strict else v < 0):
        rel = "> 0" if strict else ">= 0"
        raise ValueError(f"{name}: expected a finite number {rel}, got {value!r}")
    return v


def check_int(value, name: str, low: int = 1, *, allow_none: bool = False,
              error: type[Exception] = ValueError) -> int | None:
    """Return ``int(value)`` after checking it is an integer (not a bool) ``>= low``.

    Parameters
    ----------
    value : object
        The input; Python and numpy integers are accepted.
    name : str
        The argument's name, used in error messages.
    low : int
        Smallest allowed value.
    allow_none : bool
        Pass None through (an optional count).
    error : {ValueError, TypeError}
        Raised for a value that is not an integer; a value below ``low`` is a ValueError.

    Raises
    ------
    ValueError or TypeError
        ``"{name}: expected an integer >= {low}, got {value!r}"``.
    """
    if value is None and allow_none:
        return None
    message = f"{name}: expected an integer >= {low}, got {value!r}"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Integral,
                                                                     np.integer)):
        raise error(message)
    if value < low:
        raise ValueError(message)
    return int(value)


#: Largest coordinate magnitude geofit accepts: beyond it areas, normals and float32 rendering
#: overflow.
MAX_COORD = 1e38


def check_coordinates(V, name: str, max_abs: float = MAX_COORD) -> None:
    """Refuse coordinates whose magnitude would overflow areas and normals (ValueError naming
    ``name``, the largest magnitude and the bound)."""
    m = float(np.abs(np.asarray(V)).max(initial=0.0))
    if not m <= max_abs:
        raise ValueError(f"{name}: coordinates up to {m:.3g} in absolute value overflow areas "
                         f"and normals (not finite in float64); expected at most {max_abs:g}: "
                         f"rescale the mesh")
