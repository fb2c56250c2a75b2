"""Plain JSON for geofit's records (layer 0: numpy only).

:func:`json_safe` turns numpy scalars and arrays, tuples, mappings with non-string keys, paths
and non-finite floats into values :func:`json.dumps` accepts (NaN and infinities become the
strings ``"nan"``, ``"inf"``, ``"-inf"``, since JSON has no such numbers); :func:`json_text` is
the one text layout of geofit's JSON files (indent 1, a final newline). Writing files (and
writing them atomically) is left to the callers.
"""
from __future__ import annotations

import json
import os
from collections.abc import Mapping

import numpy as np

__all__ = ["json_safe", "json_text"]


def json_safe(obj):
    """Convert numpy scalars/arrays, paths and non-finite floats into plain JSON values.

    Parameters
    ----------
    obj : object
        Nested mappings, lists and tuples of numbers, strings, booleans, None, numpy scalars or
        arrays and ``os.PathLike`` paths. Other objects are returned unchanged.

    Returns
    -------
    object
        The same structure with dicts (string keys), lists, ints, floats (finite), strings,
        booleans and None.

    Examples
    --------
    >>> import numpy as np
    >>> json_safe({"a": np.float32(0.5), 1: (np.int64(2), float("inf")), "b": np.arange(2)})
    {'a': 0.5, '1': [2, 'inf'], 'b': [0, 1]}
    """
    if isinstance(obj, Mapping):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [json_safe(v) for v in obj.tolist()]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        if np.isfinite(v):
            return v
        return "nan" if np.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return obj


def json_text(obj) -> str:
    """``obj`` as geofit's JSON text: :func:`json_safe`, indent 1, a final newline."""
    return json.dumps(json_safe(obj), indent=1) + "\n"
