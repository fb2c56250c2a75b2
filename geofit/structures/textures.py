"""Surface colour for meshes: UV-mapped images and per-vertex colours (PyTorch3D semantics)."""
from __future__ import annotations

import numpy as np

from .._validate import as_array, as_faces

__all__ = ["TexturesUV", "TexturesVertex", "TexturesBase"]


class TexturesBase:
    """Common interface: sample colours at surface points given by face ids and barycentrics."""

    n_channels: int

    def sample(self, face_idx: np.ndarray, bary: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    def extend_faces(self, faces_offset: int) -> "TexturesBase":  # pragma: no cover
        raise NotImplementedError


class TexturesUV(TexturesBase):
    """A texture image addressed by per-corner UV coordinates.

    Parameters
    ----------
    maps : (H, W, C) float64
        The texture image, values in [0, 1]. Row 0 is the top of the image (v = 1).
    faces_uvs : (F, 3) int64
        For each face corner, an index into ``verts_uvs``.
    verts_uvs : (T, 2) float64
        UV coordinates; u runs left to right, v bottom to top.
    padding_mode : {"border"}
        What to sample outside [0, 1]^2: ``"border"`` clamps to the edge pixels (PyTorch3D's
        default). ``"repeat"`` wraps.
    align_corners : bool
        As in ``torch.nn.functional.grid_sample``: True maps u = 0 and u = 1 to the centres of the
        first and last columns (PyTorch3D's default).

    Notes
    -----
    Sampling is bilinear with PyTorch3D's convention ``grid = (2u - 1, 1 - 2v)``: with
    ``align_corners=True`` the pixel coordinates are ``x = u (W - 1)`` and ``y = (1 - v)(H - 1)``.
    """

    def __init__(self, maps, faces_uvs, verts_uvs, *, padding_mode: str = "border",
                 align_corners: bool = True):
        maps = np.asarray(maps)
        if maps.ndim == 2:
            maps = maps[:, :, None]
        self.maps = as_array(maps, "maps", (None, None, None), np.float64)
        if self.maps.shape[0] < 1 or self.maps.shape[1] < 1:
            raise ValueError(f"maps: expected a non-empty (H, W, C) image, got {self.maps.shape}")
        self.verts_uvs = as_array(verts_uvs, "verts_uvs", (None, 2), np.float64)
        self.faces_uvs = as_faces(faces_uvs, "faces_uvs", len(self.verts_uvs))
        if padding_mode not in ("border", "repeat"):
            raise ValueError(f"padding_mode: expected 'border' or 'repeat', got {padding_mode!r}")
        self.padding_mode = padding_mode
        self.align_corners = bool(align_corners)
        self.n_channels = self.maps.shape[2]

    def __repr__(self) -> str:
        H, W, C = self.maps.shape
        return f"TexturesUV(maps={H}x{W}x{C}, faces_uvs={len(self.faces_uvs)}, verts_uvs={len(self.verts_uvs)})"

    def face_uvs(self) -> np.ndarray:
        """(F, 3, 2) float64: the UV of every face corner."""
        return self.verts_uvs[self.faces_uvs]

    def sample_uv(self, uv: np.ndarray) -> np.ndarray:
        """Bilinearly sample the map at UV coordinates.

        Parameters
        ----------
        uv : (k, 2) float64
            Texture coordinates.

        Returns
        -------
        (k, C) float64
        """
        H, W, _ = self.maps.shape
        u, v = uv[:, 0], uv[:, 1]
        if self.padding_mode == "repeat":
            u = u - np.floor(u)
            v = v - np.floor(v)
        if self.align_corners:
            x = u * (W - 1)
            y = (1.0 - v) * (H - 1)
        else:
            x = u * W - 0.5
            y = (1.0 - v) * H - 0.5
        x = np.clip(x, 0.0, W - 1)
        y = np.clip(y, 0.0, H - 1)
        x0 = np.minimum(np.floor(x).astype(np.int64), max(W - 2, 0))
        y0 = np.minimum(np.floor(y).astype(np.int64), max(H - 2, 0))
        x1 = np.minimum(x0 + 1, W - 1)
        y1 = np.minimum(y0 + 1, H - 1)
        fx = (x - x0)[:, None]
        fy = (y - y0)[:, None]
        m = self.maps
        top = m[y0, x0] * (1 - fx) + m[y0, x1] * fx
        bot = m[y1, x0] * (1 - fx) + m[y1, x1] * fx
        return top * (1 - fy) + bot * fy

    def sample(self, face_idx: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """Colours at surface points.

        Parameters
        ----------
        face_idx : (k,) int64
            Face of each point (must be valid, >= 0).
        bary : (k, 3) float64
            Barycentric coordinates of each point in its face.

        Returns
        -------
        (k, C) float64
        """
        uv = np.einsum("kj,kjc->kc", bary, self.verts_uvs[self.faces_uvs[face_idx]])
        return self.sample_uv(uv)

    def take_faces(self, face_ids: np.ndarray) -> "TexturesUV":
        """The texture restricted to a subset of faces (same map and UVs)."""
        return TexturesUV(self.maps, self.faces_uvs[face_ids], self.verts_uvs,
                          padding_mode=self.padding_mode, align_corners=self.align_corners)


class TexturesVertex(TexturesBase):
    """Per-vertex features (colours), interpolated barycentrically.

    Parameters
    ----------
    verts_features : (V, C) float64
        One feature vector per vertex.
    """

    def __init__(self, verts_features):
        self.verts_features = as_array(verts_features, "verts_features", (None, None), np.float64)
        self.n_channels = self.verts_features.shape[1]

    def __repr__(self) -> str:
        return f"TexturesVertex(verts_features={self.verts_features.shape})"

    def sample_faces(self, faces: np.ndarray, face_idx: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """Interpolate at points on ``faces[face_idx]`` with barycentrics ``bary`` -> (k, C)."""
        return np.einsum("kj,kjc->kc", bary, self.verts_features[faces[face_idx]])
