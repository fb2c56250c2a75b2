"""Surface colour at ray hits: UV maps, per-vertex colours and flat colours.

:func:`sample_texels` is the renderer's texture lookup. It gives the same colours as
``Mesh.sample_textures`` (PyTorch3D's convention for UV maps: ``grid = (2u - 1, 1 - 2v)``,
bilinear, border padding, ``align_corners=True``, so ``x = u (W - 1)`` and
``y = (1 - v)(H - 1)`` in pixels) but works on flat arrays of hits in component-first layout,
reading each pair of horizontally adjacent texels with one gather.

:class:`TexturesFlat` colours a mesh with one colour, or one colour per face.
"""
from __future__ import annotations

import numpy as np

from ..._validate import as_array
from ...structures.textures import TexturesBase, TexturesUV, TexturesVertex

__all__ = ["TexturesFlat", "sample_texels"]


class TexturesFlat(TexturesBase):
    """A flat colour: one for the whole mesh or one per face.

    Parameters
    ----------
    colors : (C,) or (F, C) float64
        One colour for every face, or one colour per face (``F`` must then equal the mesh's
        number of faces; checked when rendering).

    Examples
    --------
    >>> import numpy as np
    >>> from geofit import Mesh
    >>> m = Mesh(np.eye(3), [[0, 1, 2]], TexturesFlat([0.2, 0.4, 0.6]))
    >>> m.sample_textures(np.array([0]), np.array([[1.0, 0.0, 0.0]]))
    array([[0.2, 0.4, 0.6]])
    """

    def __init__(self, colors):
        c = as_array(colors, "colors")
        if c.ndim == 1:
            c = c[None]
            self.per_face = False
        elif c.ndim == 2:
            self.per_face = True
        else:
            raise ValueError(f"colors: expected shape (C,) or (F, C), got {c.shape}")
        if c.shape[1] == 0 or c.shape[0] == 0:
            raise ValueError(f"colors: expected at least one colour and channel, got {c.shape}")
        self.colors = c
        self.n_channels = c.shape[1]

    def __repr__(self) -> str:
        kind = f"per_face={len(self.colors)}" if self.per_face else "uniform"
        return f"TexturesFlat({kind}, channels={self.n_channels})"

    def sample(self, face_idx: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """(k, C) float64 colours of points on faces ``face_idx (k,)`` (``bary`` is unused)."""
        if self.per_face:
            return self.colors[face_idx]
        return np.repeat(self.colors, len(face_idx), axis=0)

    def take_faces(self, face_ids: np.ndarray) -> TexturesFlat:
        return TexturesFlat(self.colors[face_ids] if self.per_face else self.colors[0])


class UVTables:
    """Per-render lookup tables of a TexturesUV: per-face corner UVs and the map as items.

    Parameters
    ----------
    tex : TexturesUV
    float32_map : bool
        Copy the map to float32 (worth it when many texels are read: half the memory
        traffic); otherwise read the float64 map in place.
    """

    def __init__(self, tex: TexturesUV, float32_map: bool = False):
        uv = tex.verts_uvs[tex.faces_uvs]                            # (F, 3, 2)
        self.FU = np.ascontiguousarray(uv[..., 0].T, dtype=np.float32)  # (3, F)
        self.FV = np.ascontiguousarray(uv[..., 1].T, dtype=np.float32)
        H, W, C = tex.maps.shape
        self.H, self.W, self.C = H, W, C
        flat = np.ascontiguousarray(tex.maps).reshape(H * W, C)
        if float32_map:
            flat = flat.astype(np.float32)
        self.dtype = flat.dtype
        # One item per texel: a gather copies C values at once.
        self.items = flat.view(np.dtype((np.void, flat.itemsize * C))).reshape(-1)
        self.repeat = tex.padding_mode == "repeat"
        self.align_corners = tex.align_corners


def _bilinear_t(tb: UVTables, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear lookup at float32 ``u, v (k,)`` -> (C, k) float32."""
    H, W, C = tb.H, tb.W, tb.C
    if tb.repeat:
        u = u - np.floor(u)
        v = v - np.floor(v)
    if tb.align_corners:
        x = u * np.float32(W - 1)
        y = (np.float32(1.0) - v) * np.float32(H - 1)
    else:
        x = u * np.float32(W) - np.float32(0.5)
        y = (np.float32(1.0) - v) * np.float32(H) - np.float32(0.5)
    x = np.clip(x, 0.0, W - 1)
    y = np.clip(y, 0.0, H - 1)
    x0 = np.minimum(x.astype(np.int64), max(W - 2, 0))  # x >= 0: truncation is floor
    y0 = np.minimum(y.astype(np.int64), max(H - 2, 0))
    fx = (x - x0).astype(np.float32)
    fy = (y - y0).astype(np.float32)
    i00 = y0 * W + x0
    dx = 1 if W > 1 else 0
    dy = W if H > 1 else 0

    def texel(idx):
        return np.take(tb.items, idx).view(tb.dtype).reshape(-1, C).T.astype(np.float32)

    a, b = texel(i00), texel(i00 + dx)
    top = a + (b - a) * fx
    a, b = texel(i00 + dy), texel(i00 + dy + dx)
    bot = a + (b - a) * fx
    return top + (bot - top) * fy


def sample_texels(textures, faces: np.ndarray, face_idx: np.ndarray, bary: np.ndarray,
                  default=(1.0, 1.0, 1.0)) -> np.ndarray:
    """Colours at surface points of one mesh, float32.

    Parameters
    ----------
    textures : TexturesUV, TexturesVertex, TexturesFlat or None
        The mesh's textures; ``None`` gives the ``default`` colour everywhere.
    faces : (F, 3) int64
        The mesh's faces (for per-vertex colours).
    face_idx : (k,) int64
        Face of each point (valid indices).
    bary : (k, 3) float
        Barycentrics of each point in its face, corner order ``(w0, w1, w2)``.
    default : (C,) float
        Colour of untextured meshes.

    Returns
    -------
    texels : (k, C) float32

    Raises
    ------
    ValueError
        For a per-face TexturesFlat whose length differs from the number of faces.
    """
    w = np.ascontiguousarray(np.asarray(bary).T, dtype=np.float32)
    return np.ascontiguousarray(
        sample_texels_t(textures, faces, np.asarray(face_idx), w, default).T)


def sample_texels_t(textures, faces: np.ndarray, face_idx: np.ndarray, w: np.ndarray,
                    default=(1.0, 1.0, 1.0), tables: UVTables | None = None) -> np.ndarray:
    """:func:`sample_texels` in component-first layout: ``w (3, k)`` -> ``(C, k)`` float32.

    ``tables`` (for a TexturesUV) are built on the fly when not given.
    """
    k = len(face_idx)
    if textures is None:
        d = np.asarray(default, np.float32)
        return np.ascontiguousarray(np.broadcast_to(d[:, None], (len(d), k)))
    if isinstance(textures, TexturesUV):
        tb = UVTables(textures) if tables is None else tables
        FU, FV = tb.FU, tb.FV
        u = w[0] * FU[0][face_idx] + w[1] * FU[1][face_idx] + w[2] * FU[2][face_idx]
        v = w[0] * FV[0][face_idx] + w[1] * FV[1][face_idx] + w[2] * FV[2][face_idx]
        return _bilinear_t(tb, u, v)
    if isinstance(textures, TexturesVertex):
        tri = faces[face_idx]
        f = textures.verts_features.astype(np.float32)
        return (w[0][:, None] * f[tri[:, 0]] + w[1][:, None] * f[tri[:, 1]]
                + w[2][:, None] * f[tri[:, 2]]).T
    if isinstance(textures, TexturesFlat):
        if textures.per_face and len(textures.colors) != len(faces):
            raise ValueError(f"textures.colors: expected shape ({len(faces)}, "
                             f"{textures.n_channels}) for a mesh with {len(faces)} faces, got "
                             f"{textures.colors.shape}")
        c = textures.colors.astype(np.float32)
        if textures.per_face:
            return np.ascontiguousarray(c[face_idx].T)
        return np.ascontiguousarray(np.broadcast_to(c[0][:, None], (c.shape[1], k)))
    bary = np.ascontiguousarray(w.T, dtype=np.float64)
    return np.asarray(textures.sample(face_idx, bary), dtype=np.float32).T
