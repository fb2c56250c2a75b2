"""PyTorch3D's ``pytorch3d.structures``: ``Meshes``, ``Pointclouds`` and ``Volumes`` over numpy.

A :class:`Meshes` batch keeps its vertices as one packed ``(sum V, 3)`` :class:`~.tensor.Tensor`
(the tape follows ``offset_verts(deform_verts)`` back to the parameter) and one geofit
:class:`geofit.Mesh` per member for the topology (edges, adjacency, Laplacian caches are built
once and shared by every deformed copy). Losses, sampling and renders read the current positions
through geofit's own functions and record their analytic vector-Jacobian products.
"""
from __future__ import annotations

import numpy as np

from .. import structures as _gs
from ..structures.volume import Volume as _Volume
from ._common import from_padded, to_padded, missing_names, np_
from .tensor import Tensor, cat, stack
from .textures import TexturesUV, TexturesVertex, _convert_textures

__all__ = ["Meshes", "Pointclouds", "Volumes", "join_meshes_as_batch"]


def _as_tensor(x, name: str) -> Tensor:
    if isinstance(x, Tensor):
        return x
    try:
        return Tensor(np.asarray(x, dtype=np.float64))
    except (TypeError, ValueError):
        hint = ""
        mod = type(x).__module__
        if mod.startswith("open3d"):
            hint = " (an Open3D object: pass np.asarray(mesh.vertices) / np.asarray(pcd.points))"
        elif mod.startswith("trimesh"):
            hint = " (a trimesh object: pass mesh.vertices / mesh.faces)"
        raise TypeError(f"{name}: expected an array or Tensor, got {type(x)!r}{hint}") from None


def _check_array_like(x, name: str):
    mod = type(x).__module__
    if mod.startswith("open3d"):
        raise TypeError(f"{name}: got an Open3D object {type(x).__name__}; convert it with "
                        f"np.asarray(mesh.vertices) / np.asarray(mesh.triangles) (or "
                        f"geofit.Mesh.from_open3d) first")
    if mod.startswith("trimesh"):
        raise TypeError(f"{name}: got a trimesh object {type(x).__name__}; pass mesh.vertices "
                        f"and mesh.faces (numpy arrays)")


def _lists(x, name: str):
    """A list of per-member arrays/Tensors, or a padded (N, n, C) tensor split into a list."""
    _check_array_like(x, name)
    if isinstance(x, (list, tuple)):
        for v in x:
            _check_array_like(v, f"{name}[i]")
        return list(x), False
    t = _as_tensor(x, name)
    if t.ndim != 3:
        raise ValueError(f"{name}: expected a list of (n, C) arrays or a padded (N, n, C) "
                         f"tensor, got shape {t.shape}")
    return [t[i] for i in range(t.shape[0])], True


def _split_rows(t, counts: np.ndarray):
    """Packed rows ``t`` (a Tensor or None) as a list of ``counts[i]`` rows each."""
    if t is None:
        return None
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    return [t[int(a):int(a + n)] for a, n in zip(starts, counts)]


def _accessors(owner: str, name: str, packed, counts: str, docs: dict):
    """PyTorch3D's ``{name}_packed``, ``{name}_list`` and ``{name}_padded`` methods of the
    class ``owner``: ``packed(self)`` gives the packed rows (or None), ``counts`` names the
    attribute with the rows per member; ``docs[form]``: each method's docstring."""
    def as_list(self):
        return _split_rows(packed(self), getattr(self, counts))

    def padded(self):
        t = packed(self)
        return None if t is None else to_padded(t, getattr(self, counts))

    for form, f in zip(("packed", "list", "padded"), (packed, as_list, padded)):
        f.__name__, f.__doc__ = f"{name}_{form}", docs[form]
        f.__qualname__ = f"{owner}.{f.__name__}"
    return packed, as_list, padded


def _mesh_accessors(name: str, attr: str, counts: str, rows: str, what: str):
    """The accessors of :class:`Meshes` for the geofit meshes' ``(rows, 3)`` array ``attr``
    (values only: no gradient)."""
    return _accessors("Meshes", name, lambda self: Tensor(np.concatenate(
        [getattr(m, attr) for m in self._geofit()])), counts, {
        "packed": f"(sum {rows}, 3) {what} (no gradient).",
        "list": f"The {what} of each mesh, ({rows}_i, 3) each (no gradient).",
        "padded": f"(N, max {rows}, 3) {what}, zero-padded (no gradient)."})


def _cloud_accessors(name: str):
    """The accessors of :class:`Pointclouds` for its packed ``_{name}`` (None stays None)."""
    return _accessors("Pointclouds", name, lambda self: getattr(self, "_" + name), "_counts", {
        "packed": f"The {name} of all clouds, one row per point (None when not given).",
        "list": f"The {name} of each cloud, a list (None when not given).",
        "padded": f"The {name} padded to (N, max P, C) with zeros (None when not given)."})


class Meshes:
    """A batch of triangle meshes (PyTorch3D's ``Meshes``).

    Parameters
    ----------
    verts : list of (V_i, 3) float arrays / Tensors, or a padded (N, V, 3) Tensor
        Vertex positions; a Tensor that requires a gradient keeps it (the tape follows it).
    faces : list of (F_i, 3) int arrays / Tensors, or a padded (N, F, 3) tensor
        Triangles; in a padded tensor, rows of -1 are padding.
    textures : TexturesVertex or TexturesUV, optional
    verts_normals : ignored
        Accepted for signature compatibility (normals are recomputed from the positions).

    Notes
    -----
    Vertex positions are one packed ``(sum V, 3)`` Tensor; ``verts_list()``, ``verts_padded()``
    and ``get_mesh_verts_faces(i)`` are views of it recorded on the tape. Normals and areas
    (``verts_normals_packed()``, ``faces_areas_packed()``, ...) are returned as constants
    without gradient. ``device`` arguments and ``.to(device)`` are ignored.

    Examples
    --------
    >>> import numpy as np
    >>> from geofit.pytorch3d.structures import Meshes
    >>> m = Meshes(verts=[np.eye(3)], faces=[np.array([[0, 1, 2]])])
    >>> m.verts_packed().shape, m.faces_packed().shape, len(m)
    ((3, 3), (1, 3), 1)
    """

    def __init__(self, verts, faces, textures=None, *, verts_normals=None):
        vl, _ = _lists(verts, "verts")
        fl, fpadded = _lists(faces, "faces")
        if len(vl) != len(fl):
            raise ValueError(f"faces: expected {len(vl)} face arrays (one per vertex array), "
                             f"got {len(fl)}")
        vt = [_as_tensor(v, f"verts[{i}]") for i, v in enumerate(vl)]
        base = []
        for i, (v, f) in enumerate(zip(vt, fl)):  # loop over batch members
            fa = np.asarray(np_(f))
            if fpadded:
                fa = fa[~np.all(fa == -1, axis=1)]
            base.append(_gs.Mesh(v.data, fa.astype(np.int64, copy=False)))
        packed = cat(vt) if vt else Tensor(np.zeros((0, 3)))
        self._init(base, packed, textures)

    def _init(self, base, packed: Tensor, textures):
        self._base = base
        self._counts = np.array([m.n_verts for m in base], dtype=np.int64)
        self._fcounts = np.array([m.n_faces for m in base], dtype=np.int64)
        self._verts = packed
        self._gm = None
        self.textures = textures
        self.device = "cpu"

    @classmethod
    def _from_parts(cls, base, packed: Tensor, textures) -> Meshes:
        obj = cls.__new__(cls)
        obj._init(base, packed, textures)
        return obj

    @classmethod
    def _from_geofit(cls, meshes) -> Meshes:
        """From a geofit ``Mesh`` or ``Meshes`` (textures converted)."""
        ms = [meshes] if isinstance(meshes, _gs.Mesh) else list(meshes)
        packed = Tensor(np.concatenate([m.verts for m in ms]) if ms else np.zeros((0, 3)))
        return cls._from_parts(ms, packed, _convert_textures([m.textures for m in ms]))

    # ------------------------------------------------------------------ textures
    @property
    def textures(self):
        return self._textures

    @textures.setter
    def textures(self, textures):
        if textures is not None and not isinstance(textures, (TexturesVertex, TexturesUV)):
            raise TypeError(f"textures: expected TexturesVertex or TexturesUV from "
                            f"geofit.pytorch3d.renderer, got {type(textures)!r}")
        if textures is not None:
            textures._check(self._counts, self._fcounts)
        self._textures = textures

    # ------------------------------------------------------------------ sizes and indices
    def __len__(self) -> int:
        return len(self._base)

    def isempty(self) -> bool:
        return len(self._base) == 0 or int(self._counts.sum()) == 0

    def num_verts_per_mesh(self) -> Tensor:
        return Tensor(self._counts.copy())

    def num_faces_per_mesh(self) -> Tensor:
        return Tensor(self._fcounts.copy())

    def _vstarts(self) -> np.ndarray:
        return np.concatenate([[0], np.cumsum(self._counts)[:-1]]).astype(np.int64)

    def _fstarts(self) -> np.ndarray:
        return np.concatenate([[0], np.cumsum(self._fcounts)[:-1]]).astype(np.int64)

    def mesh_to_verts_packed_first_idx(self) -> Tensor:
        return Tensor(self._vstarts())

    def mesh_to_faces_packed_first_idx(self) -> Tensor:
        return Tensor(self._fstarts())

    def verts_packed_to_mesh_idx(self) -> Tensor:
        return Tensor(np.repeat(np.arange(len(self)), self._counts))

    def faces_packed_to_mesh_idx(self) -> Tensor:
        return Tensor(np.repeat(np.arange(len(self)), self._fcounts))

    # ------------------------------------------------------------------ vertices and faces
    def verts_packed(self) -> Tensor:
        """(sum V, 3) vertex positions (the tensor the tape follows)."""
        return self._verts

    def verts_list(self) -> list:
        s = self._vstarts()
        return [self._verts[int(a):int(a + n)] for a, n in zip(s, self._counts)]

    def verts_padded(self) -> Tensor:
        """(N, max V, 3), zeros as padding."""
        return to_padded(self._verts, self._counts)

    def faces_packed(self) -> Tensor:
        """(sum F, 3) int64 indices into ``verts_packed()``."""
        if not len(self):
            return Tensor(np.zeros((0, 3), np.int64))
        return Tensor(np.concatenate([m.faces + s for m, s in zip(self._base, self._vstarts())]))

    def faces_list(self) -> list:
        return [Tensor(m.faces) for m in self._base]

    def faces_padded(self) -> Tensor:
        """(N, max F, 3), rows of -1 as padding."""
        n = int(self._fcounts.max()) if len(self) else 0
        out = np.full((len(self), n, 3), -1, np.int64)
        for i, m in enumerate(self._base):  # loop over batch members
            out[i, :m.n_faces] = m.faces
        return Tensor(out)

    def edges_packed(self) -> Tensor:
        """(E, 3)... (sum E, 2) unique edges of the packed mesh, PyTorch3D's order per mesh."""
        return Tensor(np.concatenate([m.edges + s for m, s in zip(self._base, self._vstarts())])
                      if len(self) else np.zeros((0, 2), np.int64))

    def get_mesh_verts_faces(self, index: int):
        """``(verts (V, 3), faces (F, 3))`` of member ``index``."""
        if not isinstance(index, (int, np.integer)) or not -len(self) <= index < len(self):
            raise ValueError(f"index: expected an integer in [0, {len(self)}), got {index!r}")
        return self.verts_list()[index], self.faces_list()[index]

    # ------------------------------------------------------------------ geofit meshes
    def _geofit(self, i: int | None = None, *, textures: bool = False):
        """The geofit Mesh of member ``i`` (all of them as a list when None) at the current
        positions; topology caches are those of the first construction."""
        if self._gm is None or self._gm[0] is not self._verts.data:
            s = self._vstarts()
            v = self._verts.data
            self._gm = (v, [m.update_verts(v[a:a + n])
                            for m, a, n in zip(self._base, s, self._counts)])
        ms = self._gm[1]
        if textures and self._textures is not None:
            ms = [_gs.Mesh(m.verts, None, self._textures._geofit(k), _topology=m.topology)
                  for k, m in enumerate(ms)]
        return ms if i is None else ms[i]

    def _geofit_batch(self):
        ms = self._geofit()
        return ms[0] if len(ms) == 1 else _gs.Meshes(ms)

    # ------------------------------------------------------------------ derived quantities
    verts_normals_packed, verts_normals_list, verts_normals_padded = _mesh_accessors(
        "verts_normals", "verts_normals", "_counts", "V", "unit vertex normals")
    faces_normals_packed, faces_normals_list, faces_normals_padded = _mesh_accessors(
        "faces_normals", "face_normals", "_fcounts", "F", "unit face normals")

    def faces_areas_packed(self) -> Tensor:
        """(sum F,) face areas (no gradient)."""
        return Tensor(np.concatenate([m.face_areas for m in self._geofit()]))

    def get_bounding_boxes(self) -> Tensor:
        """(N, 3, 2) per-mesh min and max along x, y, z."""
        return Tensor(np.stack([m.bounding_box().T for m in self._geofit()]))

    # ------------------------------------------------------------------ new positions
    def _offsets(self, offsets) -> Tensor:
        off = offsets if isinstance(offsets, Tensor) else _as_tensor(offsets, "vert_offsets")
        n = int(self._counts.sum())
        if off.shape not in ((n, 3), (3,)):
            raise ValueError(f"vert_offsets_packed: expected shape ({n}, 3) or (3,), got "
                             f"{off.shape}")
        return off

    def offset_verts(self, vert_offsets_packed) -> Meshes:
        """A new batch with ``verts_packed() + vert_offsets_packed`` ((sum V, 3) or (3,))."""
        return self._from_parts(self._base, self._verts + self._offsets(vert_offsets_packed),
                                self._textures)

    def offset_verts_(self, vert_offsets_packed) -> Meshes:
        """In place: ``verts_packed() += vert_offsets_packed``; returns self."""
        self._verts = self._verts + self._offsets(vert_offsets_packed)
        self._gm = None
        return self

    def _scales(self, scale) -> Tensor | float:
        if isinstance(scale, Tensor) and scale.data.ndim == 1:
            if scale.shape != (len(self),):
                raise ValueError(f"scale: expected a number or shape ({len(self)},), got "
                                 f"{scale.shape}")
            return scale[np.repeat(np.arange(len(self)), self._counts)].unsqueeze(1)
        s = np_(scale, np.float64)
        if s.ndim == 1:
            if s.shape != (len(self),):
                raise ValueError(f"scale: expected a number or shape ({len(self)},), got "
                                 f"{s.shape}")
            return np.repeat(s, self._counts)[:, None]
        if s.ndim != 0 or not np.isfinite(s):
            raise ValueError(f"scale: expected a finite number or shape ({len(self)},), got "
                             f"{scale!r}")
        return scale if isinstance(scale, Tensor) else float(s)

    def scale_verts(self, scale) -> Meshes:
        """A new batch with every mesh's vertices times ``scale`` (a number or (N,))."""
        return self._from_parts(self._base, self._verts * self._scales(scale), self._textures)

    def scale_verts_(self, scale) -> Meshes:
        """In place: vertices times ``scale``; returns self."""
        self._verts = self._verts * self._scales(scale)
        self._gm = None
        return self

    def update_padded(self, new_verts_padded) -> Meshes:
        """A new batch with the positions of a padded (N, max V, 3) tensor, same faces."""
        t = _as_tensor(new_verts_padded, "new_verts_padded")
        expect = (len(self), int(self._counts.max()) if len(self) else 0, 3)
        if t.shape != expect:
            raise ValueError(f"new_verts_padded: expected shape {expect}, got {t.shape}")
        return self._from_parts(self._base, from_padded(t, self._counts), self._textures)

    def extend(self, N: int) -> Meshes:
        """Each mesh repeated ``N`` times, consecutively (m0, m0, ..., m1, m1, ...), with its
        textures."""
        if not isinstance(N, (int, np.integer)) or isinstance(N, bool) or N < 1:
            raise ValueError(f"N: expected an integer >= 1, got {N!r}")
        s = self._vstarts()
        rows = np.concatenate([np.arange(a, a + n) for a, n in zip(s, self._counts)
                               for _ in range(N)]) if len(self) else np.zeros(0, np.int64)
        base = [m for m in self._base for _ in range(N)]
        tex = self._textures.extend(N) if self._textures is not None else None
        return self._from_parts(base, self._verts[rows], tex)

    def __getitem__(self, index) -> Meshes:
        idx = np.arange(len(self))[index]
        idx = np.atleast_1d(idx)
        s = self._vstarts()
        rows = np.concatenate([np.arange(s[i], s[i] + self._counts[i]) for i in idx]) \
            if len(idx) else np.zeros(0, np.int64)
        tex = self._textures._take(idx) if self._textures is not None else None
        return self._from_parts([self._base[i] for i in idx], self._verts[rows], tex)

    # ------------------------------------------------------------------ torch conveniences
    def clone(self) -> Meshes:
        tex = self._textures.clone() if self._textures is not None else None
        return self._from_parts(self._base, self._verts.clone(), tex)

    def detach(self) -> Meshes:
        tex = self._textures.detach() if self._textures is not None else None
        return self._from_parts(self._base, self._verts.detach(), tex)

    def to(self, *args, **kwargs) -> Meshes:
        return self

    def cpu(self) -> Meshes:
        return self

    def __repr__(self) -> str:
        return (f"Meshes(n_meshes={len(self)}, verts={self._counts.tolist()}, "
                f"faces={self._fcounts.tolist()})")


def join_meshes_as_batch(meshes, include_textures: bool = True) -> Meshes:
    """One batch from a list of Meshes (PyTorch3D's ``join_meshes_as_batch``)."""
    ms = list(meshes)
    base = [b for m in ms for b in m._base]
    packed = cat([m._verts for m in ms])
    tex = None
    if include_textures and ms and all(m.textures is not None for m in ms):
        tex = type(ms[0].textures)._join([m.textures for m in ms])
    return Meshes._from_parts(base, packed, tex)


class Pointclouds:
    """A batch of point clouds with optional normals and features (PyTorch3D's ``Pointclouds``).

    Parameters
    ----------
    points : list of (P_i, 3) arrays / Tensors, or a padded (N, P, 3) tensor
    normals : list of (P_i, 3), or (N, P, 3), optional
    features : list of (P_i, C), or (N, P, C), optional
        E.g. RGB colours for the points renderer.

    Examples
    --------
    >>> import numpy as np
    >>> from geofit.pytorch3d.structures import Pointclouds
    >>> pc = Pointclouds(points=[np.zeros((4, 3))], features=[np.ones((4, 3))])
    >>> pc.points_packed().shape, pc.features_packed().shape
    ((4, 3), (4, 3))
    """

    def __init__(self, points, normals=None, features=None):
        pl, _ = _lists(points, "points")
        self._counts = np.array([len(p) for p in pl], dtype=np.int64)
        self._points = cat([_as_tensor(p, "points[i]") for p in pl]) if pl else \
            Tensor(np.zeros((0, 3)))
        if self._points.ndim != 2 or self._points.shape[1] != 3:
            raise ValueError(f"points: expected (P, 3) clouds, got packed shape "
                             f"{self._points.shape}")
        self._normals = self._extra(normals, "normals")
        self._features = self._extra(features, "features")
        self.device = "cpu"

    def _extra(self, x, name: str):
        if x is None:
            return None
        xl, _ = _lists(x, name)
        if len(xl) != len(self._counts):
            raise ValueError(f"{name}: expected {len(self._counts)} arrays, got {len(xl)}")
        t = cat([_as_tensor(v, f"{name}[i]") for v in xl])
        if t.ndim != 2 or len(t) != int(self._counts.sum()):
            raise ValueError(f"{name}: expected one row per point ({int(self._counts.sum())}), "
                             f"got packed shape {t.shape}")
        return t

    @classmethod
    def _from_parts(cls, counts, points, normals, features) -> Pointclouds:
        obj = cls.__new__(cls)
        obj._counts, obj._points, obj._normals, obj._features = counts, points, normals, features
        obj.device = "cpu"
        return obj

    def __len__(self) -> int:
        return len(self._counts)

    def isempty(self) -> bool:
        return len(self) == 0 or int(self._counts.sum()) == 0

    def num_points_per_cloud(self) -> Tensor:
        return Tensor(self._counts.copy())

    def _starts(self) -> np.ndarray:
        return np.concatenate([[0], np.cumsum(self._counts)[:-1]]).astype(np.int64)

    def cloud_to_packed_first_idx(self) -> Tensor:
        return Tensor(self._starts())

    def packed_to_cloud_idx(self) -> Tensor:
        return Tensor(np.repeat(np.arange(len(self)), self._counts))

    points_packed, points_list, points_padded = _cloud_accessors("points")
    normals_packed, normals_list, normals_padded = _cloud_accessors("normals")
    features_packed, features_list, features_padded = _cloud_accessors("features")

    def _geofit(self):
        """geofit Pointclouds (values only) for the points renderer."""
        f = self.features_list()
        clouds = [_gs.PointCloud(p.data, None if f is None else f[i].data)
                  for i, p in enumerate(self.points_list())]
        return _gs.Pointclouds(clouds)

    def _rows(self, idx):
        s = self._starts()
        return np.concatenate([np.arange(s[i], s[i] + self._counts[i]) for i in idx]) \
            if len(idx) else np.zeros(0, np.int64)

    def _take(self, idx) -> Pointclouds:
        rows = self._rows(idx)
        pick = (lambda t: None if t is None else t[rows])
        return self._from_parts(self._counts[idx], self._points[rows], pick(self._normals),
                                pick(self._features))

    def __getitem__(self, index) -> Pointclouds:
        return self._take(np.atleast_1d(np.arange(len(self))[index]))

    def extend(self, N: int) -> Pointclouds:
        """Each cloud repeated ``N`` times, consecutively."""
        if not isinstance(N, (int, np.integer)) or isinstance(N, bool) or N < 1:
            raise ValueError(f"N: expected an integer >= 1, got {N!r}")
        return self._take(np.repeat(np.arange(len(self)), N))

    def offset(self, offsets_packed) -> Pointclouds:
        """A new batch with ``points_packed() + offsets_packed``."""
        return self._from_parts(self._counts, self._points + _as_tensor(offsets_packed,
                                                                         "offsets_packed"),
                                self._normals, self._features)

    def clone(self) -> Pointclouds:
        c = (lambda t: None if t is None else t.clone())
        return self._from_parts(self._counts.copy(), self._points.clone(), c(self._normals),
                                c(self._features))

    def detach(self) -> Pointclouds:
        d = (lambda t: None if t is None else t.detach())
        return self._from_parts(self._counts, self._points.detach(), d(self._normals),
                                d(self._features))

    def to(self, *args, **kwargs) -> Pointclouds:
        return self

    def cpu(self) -> Pointclouds:
        return self

    def get_bounding_boxes(self) -> Tensor:
        """(N, 3, 2) per-cloud min and max along x, y, z."""
        return Tensor(np.stack([np.stack([p.data.min(0), p.data.max(0)], 1)
                                for p in self.points_list()]))

    def __repr__(self) -> str:
        return f"Pointclouds(n_clouds={len(self)}, points={self._counts.tolist()})"


class Volumes:
    """A batch of dense volumes (PyTorch3D's ``Volumes``), over geofit's :class:`Volume`.

    Parameters
    ----------
    densities : (N, 1, D, H, W) array / Tensor, or list of (1, D, H, W)
    features : (N, C, D, H, W) array / Tensor, or list of (C, D, H, W), optional
    voxel_size : float or (3,)
    volume_translation : (3,) float
    align_corners : bool

    Notes
    -----
    Densities and features may be tensors that require a gradient (the volume tutorial's
    ``sigmoid(log_densities)[None].expand(N, ...)``):
    :class:`geofit.pytorch3d.renderer.VolumeRenderer` records geofit's vjp to them. A batch
    that is one volume expanded N times (a zero stride) is stored once.
    """

    def __init__(self, densities, features=None, voxel_size=1.0, volume_translation=(0., 0., 0.),
                 align_corners: bool = True):
        dt = stack(densities) if isinstance(densities, list) else _as_tensor(densities,
                                                                              "densities")
        if dt.ndim != 5 or dt.shape[1] != 1:
            raise ValueError(f"densities: expected shape (N, 1, D, H, W), got {dt.shape}")
        ft = None
        if features is not None:
            ft = stack(features) if isinstance(features, list) else _as_tensor(features,
                                                                                "features")
            if ft.ndim != 5 or ft.shape[0] != dt.shape[0] or ft.shape[2:] != dt.shape[2:]:
                raise ValueError(f"features: expected shape ({dt.shape[0]}, C, "
                                 f"{', '.join(map(str, dt.shape[2:]))}), got {ft.shape}")
        d = dt.data
        f = None if ft is None else ft.data
        n = d.shape[0]
        # one volume expanded N times (zero stride) is stored, rendered and differentiated once
        self._shared = n > 1 and d.strides[0] == 0 and (f is None or f.strides[0] == 0)
        self._vols = [
            _Volume(d[i, 0], None if f is None else f[i],
                    voxel_size=np_(voxel_size, np.float64),
                    volume_translation=np_(volume_translation, np.float64),
                    align_corners=align_corners)
            for i in range(1 if self._shared else n)]  # loop over batch members
        self._densities = dt
        self._features = ft

    def __len__(self) -> int:
        return self._densities.shape[0]

    def densities(self) -> Tensor:
        return self._densities

    def features(self):
        return self._features

    def get_grid_sizes(self) -> Tensor:
        return Tensor(np.array([self._densities.shape[2:]] * len(self), np.int64))

    def get_coord_grid(self, world_coordinates: bool = True) -> Tensor:
        g = [v.get_coord_grid(world_coordinates) for v in self._vols]
        return Tensor(np.stack(g * len(self) if self._shared else g))

    def to(self, *args, **kwargs) -> Volumes:
        return self

    def cpu(self) -> Volumes:
        return self

    def __repr__(self) -> str:
        return f"Volumes(n_volumes={len(self)}, grid={self._densities.shape[2:]})"


__getattr__ = missing_names("geofit.pytorch3d.structures", {
    "join_meshes_as_scene": "build one Meshes from the concatenated vertices and offset faces, "
                            "or geofit.Meshes([...]) for geofit's own batch",
    "packed_to_list": "split the packed tensor with tensor[a:b] (Meshes.verts_list() does it)",
    "list_to_padded": "Meshes.verts_padded() / Pointclouds.points_padded()",
})
