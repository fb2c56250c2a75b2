"""What the two batches (``Meshes``, ``Pointclouds``) share: the list of items behind them,
indexing, repetition, the packed/padded index arithmetic and the door that accepts a batch,
one item or a list of items."""
from __future__ import annotations

from typing import Callable

import numpy as np


class Batch:
    """A list of items (meshes or clouds) with PyTorch3D's batch indexing.

    Subclasses are built from a sequence of items and keep them in ``self._items``.
    """

    _items: list

    def __len__(self) -> int:
        return len(self._items)

    def __getitem__(self, i):
        if isinstance(i, (int, np.integer)):
            return self._items[i]
        if isinstance(i, slice):
            return type(self)(self._items[i])
        idx = np.atleast_1d(np.asarray(i))
        if idx.dtype == bool:
            idx = np.flatnonzero(idx)
        return type(self)([self._items[int(j)] for j in idx])

    def __iter__(self):
        return iter(self._items)

    def extend(self, n: int):
        """Repeat each item ``n`` times consecutively (x0, x0, ..., x1, x1, ...)."""
        if not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"n: expected an integer >= 1, got {n!r}")
        return type(self)([x for x in self._items for _ in range(int(n))])


def first_index(counts: np.ndarray) -> np.ndarray:
    """(N,) int64 index of each item's first element in the packed array, from (N,) counts."""
    return np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64) if len(counts) else counts


def packed_to_item(counts: np.ndarray) -> np.ndarray:
    """(sum counts,) int64 item index of every packed element."""
    return np.repeat(np.arange(len(counts)), counts)


def padded(arrays: list, counts: np.ndarray, pad_value: float) -> np.ndarray:
    """(N, max counts, 3) float64: the (counts[i], 3) ``arrays`` padded with ``pad_value``."""
    out = np.full((len(arrays), int(counts.max()) if len(counts) else 0, 3), pad_value,
                  dtype=np.float64)
    for i, a in enumerate(arrays):  # loop over the items of the batch, not their elements
        out[i, : len(a)] = a
    return out


def as_batch(items, batch_type: type, as_item: Callable, name: str, expected: str):
    """``items`` as a ``batch_type``: a batch as it is, a list or tuple item by item through
    ``as_item``, anything else as a batch of one; a TypeError says ``expected`` otherwise."""
    if isinstance(items, batch_type):
        return items
    if isinstance(items, (list, tuple)):
        return batch_type([as_item(x, f"{name}[{i}]") for i, x in enumerate(items)])
    try:
        return batch_type([as_item(items, name)])
    except TypeError:
        raise TypeError(f"{name}: expected {expected}, got {type(items)!r}") from None
