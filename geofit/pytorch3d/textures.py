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


class TexturesVertex:
    """Per-vertex features interpolated over the faces (PyTorch3D's ``TexturesVertex``).

    Parameters
    ----------
    verts_features : (N, V, C) array / Tensor, or list of (V_i, C)
        E.g. ``full([1, V, 3], 0.5, requires_grad=True)`` (the tutorial's learnt colours).
    """

    def __init__(self, verts_features):
        self._source = verts_features if isinstance(verts_features, Tensor) else None
        self._list = _feature_list(verts_features, "verts_features")

    @classmethod
    def _of(cls, parts: list) -> TexturesVertex:
        obj = cls.__new__(cls)
        obj._source = None
        obj._list = parts
        return obj

    def __len__(self) -> int:
        return len(self._list)

    def _check(self, counts, fcounts) -> None:
        got = [len(v) for v in self._list]
        if got != list(counts):
            raise ValueError(f"textures: expected per-vertex features for {list(counts)} "
                             f"vertices, got {got}")

    def verts_features_list(self) -> list:
        return list(self._list)

    def verts_features_packed(self) -> Tensor:
        """(sum V, C)."""
        return cat(self._list)

    def verts_features_padded(self) -> Tensor:
        """(N, max V, C), zeros as padding."""
        return to_padded(self.verts_features_packed(), np.array([len(v) for v in self._list]))

    def _geofit(self, i: int) -> _gs.TexturesVertex:
        return _gs.TexturesVertex(self._list[i].data)

    def extend(self, N: int) -> TexturesVertex:
        return self._of([v for v in self._list for _ in range(N)])

    def _take(self, idx) -> TexturesVertex:
        return self._of([self._list[int(i)] for i in idx])

    @classmethod
    def _join(cls, textures) -> TexturesVertex:
        return cls._of([v for t in textures for v in t._list])

    def clone(self) -> TexturesVertex:
        return self._of([v.clone() for v in self._list])

    def detach(self) -> TexturesVertex:
        return self._of([v.detach() for v in self._list])

    def to(self, *args, **kwargs) -> TexturesVertex:
        return self

    def __repr__(self) -> str:
        return f"TexturesVertex(verts_features={[tuple(v.shape) for v in self._list]})"


class TexturesUV:
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
        self._tex = [_gs.TexturesUV(m, f, v, padding_mode=padding_mode,
                                    align_corners=align_corners)
                     for m, f, v in zip(maps_l, fl, vl)]  # loop over batch members

    @classmethod
    def _of(cls, tex: list) -> TexturesUV:
        obj = cls.__new__(cls)
        obj._tex = tex
        return obj

    def __len__(self) -> int:
        return len(self._tex)

    def _check(self, counts, fcounts) -> None:
        got = [len(t.faces_uvs) for t in self._tex]
        if got != list(fcounts):
            raise ValueError(f"textures: expected faces_uvs for {list(fcounts)} faces, got {got}")

    def maps_list(self) -> list:
        return [Tensor(t.maps) for t in self._tex]

    def maps_padded(self) -> Tensor:
        """(N, H, W, C) texture images (all maps must have one size, as in PyTorch3D)."""
        shapes = {t.maps.shape for t in self._tex}
        if len(shapes) > 1:
            raise ValueError(f"maps_padded: the maps have different sizes {sorted(shapes)}")
        return Tensor(np.stack([t.maps for t in self._tex]))

    def faces_uvs_list(self) -> list:
        return [Tensor(t.faces_uvs) for t in self._tex]

    def verts_uvs_list(self) -> list:
        return [Tensor(t.verts_uvs) for t in self._tex]

    def faces_uvs_padded(self) -> Tensor:
        n = max(len(t.faces_uvs) for t in self._tex)
        out = np.full((len(self), n, 3), -1, np.int64)
        for i, t in enumerate(self._tex):  # loop over batch members
            out[i, :len(t.faces_uvs)] = t.faces_uvs
        return Tensor(out)

    def verts_uvs_padded(self) -> Tensor:
        n = max(len(t.verts_uvs) for t in self._tex)
        out = np.zeros((len(self), n, 2))
        for i, t in enumerate(self._tex):  # loop over batch members
            out[i, :len(t.verts_uvs)] = t.verts_uvs
        return Tensor(out)

    def _geofit(self, i: int) -> _gs.TexturesUV:
        return self._tex[i]

    def extend(self, N: int) -> TexturesUV:
        return self._of([t for t in self._tex for _ in range(N)])

    def _take(self, idx) -> TexturesUV:
        return self._of([self._tex[int(i)] for i in idx])

    @classmethod
    def _join(cls, textures) -> TexturesUV:
        return cls._of([x for t in textures for x in t._tex])

    def clone(self) -> TexturesUV:
        return self._of(list(self._tex))

    detach = clone

    def to(self, *args, **kwargs) -> TexturesUV:
        return self

    def __repr__(self) -> str:
        return f"TexturesUV(maps={[t.maps.shape for t in self._tex]})"


def _convert_textures(textures: list):
    """Per-mesh geofit textures (or None) to one batched texture of this module, or None."""
    if not textures or any(t is None for t in textures):
        return None
    if all(isinstance(t, _gs.TexturesUV) for t in textures):
        return TexturesUV._of(list(textures))
    if all(isinstance(t, _gs.TexturesVertex) for t in textures):
        return TexturesVertex._of([Tensor(t.verts_features) for t in textures])
    return None
