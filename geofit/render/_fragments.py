"""PyTorch3D's dense fragment images, built once for the hard and the soft rasterizer.

Both rasterizers store their results compactly, one entry per (pixel, face) pair kept; this mixin
scatters those entries into PyTorch3D's ``(N, H, W, K, ...)`` arrays on first access.
"""
from __future__ import annotations

from functools import cached_property

import numpy as np


class DenseFragmentImages:
    """``pix_to_face``, ``zbuf``, ``bary_coords`` and ``dists`` of sparse fragments.

    A subclass has ``n_views``, ``image_size`` ``(H, W)``, per-entry arrays ``face`` ``(m,)``,
    ``depth`` ``(m,)``, ``bary`` ``(m, 3)`` and the signed distances named by
    ``_ENTRY_DISTS``, and :meth:`_slots` placing each entry in the image.
    """

    _ENTRY_DISTS = "dist"

    def _slots(self) -> tuple[np.ndarray, np.ndarray | int, int]:  # pragma: no cover - abstract
        """``(flat pixel over all views, slot in 0..K-1, K)`` of every entry."""
        raise NotImplementedError

    def _image(self, values: np.ndarray, fill, dtype) -> np.ndarray:
        """``(N, H, W, K) + values.shape[1:]`` image of per-entry ``values``, ``fill`` elsewhere."""
        H, W = self.image_size
        pixel, slot, K = self._slots()
        tail = values.shape[1:]
        out = np.full((self.n_views * H * W, K) + tail, fill, dtype=dtype)
        out[pixel, slot] = values
        return out.reshape((self.n_views, H, W, K) + tail)

    @cached_property
    def pix_to_face(self) -> np.ndarray:
        """(N, H, W, K) int64 face index per slot, -1 where unused (packed over the meshes for
        the hard rasterizer, local faces for the soft one)."""
        return self._image(self.face, -1, np.int64)

    @cached_property
    def zbuf(self) -> np.ndarray:
        """(N, H, W, K) float64 view depth per slot, -1 where unused."""
        return self._image(self.depth, -1.0, np.float64)

    @cached_property
    def bary_coords(self) -> np.ndarray:
        """(N, H, W, K, 3) float64 barycentrics per slot, -1 where unused."""
        return self._image(self.bary, -1.0, np.float64)

    @cached_property
    def dists(self) -> np.ndarray:
        """(N, H, W, K) float64 signed squared NDC distance from the pixel centre to the
        projected face (negative inside) per slot, -1 where unused."""
        return self._image(getattr(self, self._ENTRY_DISTS), -1.0, np.float64)
