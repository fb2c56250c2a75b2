"""Caps on the arrays of ``.npz`` / ``.npy`` files, checked from the headers before decoding
(issue 28 point 2).

An ``.npz`` entry is a zip member holding a ``.npy`` file; its header gives the shape and dtype,
so the decoded size is known before a byte of data is inflated. An array is refused when it
would decode to more than ``max_bytes`` (default :data:`DEFAULT_MAX_ARRAY_BYTES`, 1 GiB), or to
more than :data:`MAX_RATIO` times the bytes it takes in the file (a 700 KB file of zeros holding
a 720 MB array is a compression bomb); arrays up to :data:`FREE_BYTES` (64 MiB) are allowed
whatever their ratio, so small files of repeated values still load.
"""
from __future__ import annotations

import numpy as np

__all__ = ["DEFAULT_MAX_ARRAY_BYTES", "FREE_BYTES", "MAX_RATIO", "check_array_size",
           "read_npy_header"]

DEFAULT_MAX_ARRAY_BYTES = 1 << 30
MAX_RATIO = 100
FREE_BYTES = 64 << 20


def read_npy_header(fh):
    """``(shape, fortran_order, dtype)`` from an open ``.npy`` stream, nothing decoded."""
    version = np.lib.format.read_magic(fh)
    if version == (1, 0):
        return np.lib.format.read_array_header_1_0(fh)
    return np.lib.format.read_array_header_2_0(fh)


def check_array_size(shape, dtype, stored: int, where: str, max_bytes=None) -> int:
    """The decoded bytes of an array; ValueError naming ``where`` when over the caps.

    Parameters
    ----------
    shape : tuple of int
        From the ``.npy`` header.
    dtype : numpy.dtype
        From the ``.npy`` header.
    stored : int
        Bytes the array takes in the file (compressed size of the zip member).
    where : str
        The file and key, for messages.
    max_bytes : int, optional
        The absolute cap (default 1 GiB).
    """
    cap = DEFAULT_MAX_ARRAY_BYTES if max_bytes is None else int(max_bytes)
    n = int(np.prod(shape, dtype=object)) * dtype.itemsize
    if n > cap:
        raise ValueError(f"{where}: the array {tuple(shape)} {dtype} would decode to {n:,} "
                         f"bytes, over the cap of {cap:,} (checked from its header; pass "
                         f"max_bytes= to raise it)")
    if n > FREE_BYTES and n > MAX_RATIO * max(stored, 1):
        raise ValueError(f"{where}: the array {tuple(shape)} {dtype} would decode to {n:,} "
                         f"bytes from {stored:,} bytes in the file (ratio over {MAX_RATIO}: a "
                         f"compression bomb?)")
    return n
