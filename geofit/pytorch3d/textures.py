"""PyTorch3D's textures (``pytorch3d.renderer.TexturesVertex`` / ``TexturesUV``), batched.

Each converts to geofit's per-mesh :class:`geofit.TexturesVertex` / :class:`geofit.TexturesUV`
for rendering. ``TexturesVertex.verts_features`` may be a tensor that requires a gradient (the
fit_textured_mesh tutorial's ``sphere_verts_rgb``): the soft Phong renderer and
``sample_points_from_meshes(..., return_textures=True)`` record their gradients to it.
"""
from __future__ import annotations

import numpy as np

from .. import structures as _gs
from ._common import to_padded, np_
from .tensor import Tensor, cat

__all__ = ["TexturesUV", "TexturesVertex"]


def _feature_list(x, name: str) -> list:
    if isinstance(x, (list, tuple)):
        out = [v if isinstance(v, Tensor) else Tensor(np.asarray(v, np.float64)) for v in x]
    else:
        t = x if isinstance(x, Tensor) else Tensor(np.asarray(x, np.float64))
        if t.ndim != 3:
            raise ValueError(f"{name}: expected a list of (V, C) arrays or a (N, V, C) tensor, "
                             f"got shape {t.shape}")
        out = [t[i] for i in range(t.shape[0])]
    for i, v in enumerate(out):
        if v.ndim != 2:
            raise ValueError(f"{name}[{i}]: expected shape (V, C), got {v.shape}")
    return out


class _BatchedTextures:
    """What both batched textures share: one entry per mesh in ``self._parts`` (a tensor of
    features for TexturesVertex, a geofit TexturesUV for TexturesUV), batch length, repetition,
    selection and joining (``_of`` builds one from its parts)."""

    _parts: list

    @classmethod
    def _of(cls, parts: list):
        obj = cls.__new__(cls)
        obj._parts = parts
        return obj

    def __len__(self) -> int:
        return len(self._parts)

    def extend(self, N: int):
        return self._of([p for p in self._parts for _ in range(N)])

    def _take(self, idx):
        return self._of([self._parts[int(i)] for i in idx])

    @classmethod
    def _join(cls, textures):
        return cls._of([p for t in textures for p in t._parts])

    def to(self, *args, **kwargs):
        return self


class TexturesVertex(_BatchedTextures):
    """Per-vertex features interpolated over the faces (PyTorch3D's ``TexturesVertex``).

    Parameters
    ----------
    verts_features : (N, V, C) array / Tensor, or list of (V_i, C)
        E.g. ``full([1, V, 3], 0.5, requires_grad=True)`` (the tutorial's learnt colours).
    """

    _source = None  # the tensor given to the constructor, if any

    def __init__(self, verts_features):
        self._source = verts_features if isinstance(verts_features, Tensor) else None
        self._parts = _feature_list(verts_features, "verts_features")

    def _check(self, counts, fcounts) -> None:
        got = [len(v) for v in self._parts]
        if got != list(counts):
            raise ValueError(f"textures: expected per-vertex features for {list(counts)} "
                             f"vertices, got {got}")

    def verts_features_list(self) -> list:
        return list(self._parts)

    def verts_features_packed(self) -> Tensor:
        """(sum V, C)."""
        return cat(self._parts)

    def verts_features_padded(self) -> Tensor:
        """(N, max V, C), zeros as padding."""
        return to_padded(self.verts_features_packed(), np.array([len(v) for v in self._parts]))

    def _geofit(self, i: int) -> _gs.TexturesVertex:
        return _gs.TexturesVertex(self._parts[i].data)

    def clone(self) -> TexturesVertex:
        return self._of([v.clone() for v in self._parts])

    def detach(self) -> TexturesVertex:
        return self._of([v.detach() for v in self._parts])

    def __repr__(self) -> str:
        return f"TexturesVertex(verts_features={[tuple(v.shape) for v in self._parts]})"


class TexturesUV(_BatchedTextures):
    """A texture image per mesh addressed by per-corner UVs (PyTorch3D's ``TexturesUV``).

    Parameters
    ----------
    maps : (N, H, W, C) array / Tensor, or list of (H, W, C)
    faces_uvs : (N, F, 3) int, or list of (F_i, 3)
    verts_uvs : (N, T, 2) float, or list of (T_i, 2)
    padding_mode : {"border", "repeat"}
    align_corners : bool
    sampling_mode : {"bilinear"}

    Notes
    -----
    Values only (no gradient to the maps); geofit's UV lookup is PyTorch3D's ``grid_sample``
    convention (``grid = (2u - 1, 1 - 2v)``).
    """

    def __init__(self, maps, faces_uvs, verts_uvs, padding_mode: str = "border",
                 align_corners: bool = True, sampling_mode: str = "bilinear", **kwargs):
        if sampling_mode != "bilinear":
            raise ValueError(f"sampling_mode: geofit samples textures bilinearly, expected "
                             f"'bilinear', got {sampling_mode!r}")
        maps_l = [np_(m, np.float64) for m in maps] if isinstance(maps, (list, tuple)) else \
            list(np_(maps, np.float64))
        fl = [np_(f, np.int64) for f in faces_uvs] if isinstance(faces_uvs, (list, tuple)) else \
            list(np_(faces_uvs, np.int64))
        vl = [np_(v, np.float64) for v in verts_uvs] if isinstance(verts_uvs, (list, tuple)) \
            else list(np_(verts_uvs, np.float64))
        if not len(maps_l) == len(fl) == len(vl):
            raise ValueError(f"maps, faces_uvs, verts_uvs: expected one of each per mesh, got "
                             f"{len(maps_l)}, {len(fl)} and {len(vl)}")
        self._parts = [_gs.TexturesUV(m, f, v, padding_mode=padding_mode,
                                    align_corners=align_corners)
                     for m, f, v in zip(maps_l, fl, vl)]  # loop over batch members

    def _check(self, counts, fcounts) -> None:
        got = [len(t.faces_uvs) for t in self._parts]
        if got != list(fcounts):
            raise ValueError(f"textures: expected faces_uvs for {list(fcounts)} faces, got {got}")

    def maps_list(self) -> list:
        return [Tensor(t.maps) for t in self._parts]

    def maps_padded(self) -> Tensor:
        """(N, H, W, C) texture images (all maps must have one size, as in PyTorch3D)."""
        shapes = {t.maps.shape for t in self._parts}
        if len(shapes) > 1:
            raise ValueError(f"maps_padded: the maps have different sizes {sorted(shapes)}")
        return Tensor(np.stack([t.maps for t in self._parts]))

    def faces_uvs_list(self) -> list:
        return [Tensor(t.faces_uvs) for t in self._parts]

    def verts_uvs_list(self) -> list:
        return [Tensor(t.verts_uvs) for t in self._parts]

    def faces_uvs_padded(self) -> Tensor:
        n = max(len(t.faces_uvs) for t in self._parts)
        out = np.full((len(self), n, 3), -1, np.int64)
        for i, t in enumerate(self._parts):  # loop over batch members
            out[i, :len(t.faces_uvs)] = t.faces_uvs
        return Tensor(out)

    def verts_uvs_padded(self) -> Tensor:
        n = max(len(t.verts_uvs) for t in self._parts)
        out = np.zeros((len(self), n, 2))
        for i, t in enumerate(self._parts):  # loop over batch members
            out[i, :len(t.verts_uvs)] = t.verts_uvs
        return Tensor(out)

    def _geofit(self, i: int) -> _gs.TexturesUV:
        return self._parts[i]

    def clone(self) -> TexturesUV:
        return self._of(list(self._parts))

    detach = clone

    def __repr__(self) -> str:
        return f"TexturesUV(maps={[t.maps.shape for t in self._parts]})"


def _convert_textures(textures: list):
    """Per-mesh geofit textures (or None) to one batched texture of this module, or None."""
    if not textures or any(t is None for t in textures):
        return None
    if all(isinstance(t, _gs.TexturesUV) for t in textures):
        return TexturesUV._of(list(textures))
    if all(isinstance(t, _gs.TexturesVertex) for t in textures):
        return TexturesVertex._of([Tensor(t.verts_features) for t in textures])
    return None
