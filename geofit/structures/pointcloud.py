"""Point clouds: a single ``PointCloud`` and a batch ``Pointclouds`` with packed views."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .._foreign import (foreign_kind, from_uint8, geofit_record, require_kind, stash_matches,
                        to_uint8)
from .._validate import as_array, as_points, as_rng
from ._batch import Batch, as_batch, first_index, packed_to_item, padded

__all__ = ["PointCloud", "Pointclouds", "as_pointcloud", "as_pointclouds"]


class PointCloud:
    """Points with optional per-point features (colours) and normals.

    Parameters
    ----------
    points : (k, 3) float64
        Positions.
    features : (k, C) float64, optional
        Per-point features, typically RGB in [0, 1].
    normals : (k, 3) float64, optional
        Per-point normals.
    """

    def __init__(self, points, features=None, normals=None):
        self.points = as_points(points, "points")
        k = len(self.points)
        self.features = None
        if features is not None:
            f = np.asarray(features)
            if f.ndim == 1:
                f = f[:, None]
            self.features = as_array(f, "features", (k, None))
        self.normals = None if normals is None else as_array(normals, "normals", (k, 3))
        for a in (self.points, self.features, self.normals):
            if a is not None:
                a.setflags(write=False)

    def __len__(self) -> int:
        return len(self.points)

    @property
    def n_points(self) -> int:
        return len(self.points)

    def isempty(self) -> bool:
        return len(self.points) == 0

    def __repr__(self) -> str:
        f = "" if self.features is None else f", features={self.features.shape[1]}"
        n = "" if self.normals is None else ", normals"
        return f"PointCloud(n_points={len(self)}{f}{n})"

    def bounding_box(self) -> np.ndarray:
        """(2, 3) float64 min and max corner; zeros when empty."""
        if len(self.points) == 0:
            return np.zeros((2, 3))
        return np.stack([self.points.min(0), self.points.max(0)])

    def update_points(self, points) -> "PointCloud":
        """A new cloud with new positions and the same features and normals."""
        return PointCloud(points, self.features, self.normals)

    def subsample(self, n: int, *, seed=None) -> "PointCloud":
        """A random subset of ``min(n, len)`` points without replacement (reproducible with ``seed``)."""
        rng = as_rng(seed)
        k = len(self)
        idx = np.sort(rng.choice(k, size=min(int(n), k), replace=False))
        return PointCloud(self.points[idx],
                          None if self.features is None else self.features[idx],
                          None if self.normals is None else self.normals[idx])

    def extend(self, n: int) -> "Pointclouds":
        """A batch holding this cloud ``n`` times."""
        return Pointclouds([self]).extend(n)

    # ------------------------------------------------------------------ trimesh and Open3D
    @classmethod
    def from_trimesh(cls, cloud) -> "PointCloud":
        """A PointCloud from a ``trimesh.PointCloud``.

        Parameters
        ----------
        cloud : trimesh.PointCloud
            The points; colours (8-bit RGBA) become ``features`` ``colour / 255`` (RGB, or RGBA
            when some alpha is below 255).

        Returns
        -------
        PointCloud
            A cloud written by :meth:`to_trimesh` comes back exactly (float features and
            normals are kept in ``cloud.metadata["geofit"]``, and used while they still agree
            with the trimesh object).
        """
        require_kind(cloud, "trimesh.PointCloud", "cloud")
        points = np.asarray(cloud.vertices, dtype=np.float64)
        info = geofit_record(cloud)
        stash = info.get("features")
        stash = None if stash is None else np.asarray(stash)
        if stash is not None and (stash.ndim != 2 or len(stash) != len(points)):
            stash = None
        features = None
        colors = np.asarray(cloud.colors)
        if len(points) and len(colors) == len(points):
            c = None if stash is None else stash.shape[1]
            if c in (3, 4) and stash_matches(stash, colors[:, :c]):
                features = stash
            else:
                features = from_uint8(colors)
        elif stash is not None and stash.shape[1] not in (3, 4):
            features = stash  # features that are not colours (trimesh has no place for them)
        normals = info.get("normals")
        normals = None if normals is None or np.shape(normals) != points.shape else normals
        return cls(points, features, normals)

    @classmethod
    def from_open3d(cls, cloud) -> "PointCloud":
        """A PointCloud from an ``open3d.geometry.PointCloud`` (points, colours, normals).

        Parameters
        ----------
        cloud : open3d.geometry.PointCloud
            Its ``colors`` (float64 RGB) become ``features``, its ``normals`` ``normals``.
        """
        require_kind(cloud, "open3d.PointCloud", "cloud")
        points = np.asarray(cloud.points, dtype=np.float64)
        features = np.asarray(cloud.colors, dtype=np.float64) if cloud.has_colors() else None
        normals = np.asarray(cloud.normals, dtype=np.float64) if cloud.has_normals() else None
        return cls(points, features, normals)

    def to_trimesh(self):
        """A ``trimesh.PointCloud`` with 8-bit colours (features with 3 or 4 channels).

        The unquantised features and the normals (trimesh has no place for either) are kept
        in ``metadata["geofit"]``, so :meth:`from_trimesh` gives this cloud back exactly.
        """
        import trimesh  # kept local: trimesh, loaded only when used (start-up)

        colors = None
        info: dict = {}
        f = self.features
        if f is not None:
            info["features"] = np.array(f)
            if f.shape[1] in (3, 4):
                colors = to_uint8(f)
        if self.normals is not None:
            info["normals"] = np.array(self.normals)
        return trimesh.PointCloud(np.array(self.points), colors=colors, metadata={"geofit": info})

    def to_open3d(self):
        """An ``open3d.geometry.PointCloud`` with colours (the first three feature channels,
        clipped to [0, 1]) and normals."""
        import open3d as o3d  # kept local: start-up

        # Open3D's Vector3dVector rejects read-only arrays: pass copies.
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(self.points)))
        if self.features is not None and self.features.shape[1] >= 3:
            pc.colors = o3d.utility.Vector3dVector(
                np.ascontiguousarray(np.clip(self.features[:, :3], 0, 1)))
        if self.normals is not None:
            pc.normals = o3d.utility.Vector3dVector(np.array(self.normals))
        return pc


class Pointclouds(Batch):
    """A batch of point clouds of different sizes with packed and padded views.

    Parameters
    ----------
    clouds : sequence of PointCloud
        The clouds; all or none must carry features (with the same channel count).
    """

    def __init__(self, clouds: Sequence[PointCloud]):
        clouds = list(clouds)
        for i, c in enumerate(clouds):
            if not isinstance(c, PointCloud):
                raise TypeError(f"clouds[{i}]: expected a PointCloud, got {type(c)!r}")
        has_f = {c.features is not None for c in clouds}
        if len(has_f) > 1:
            raise ValueError("clouds: either every cloud has features or none does")
        if clouds and clouds[0].features is not None:
            chans = {c.features.shape[1] for c in clouds}
            if len(chans) > 1:
                raise ValueError(f"clouds: feature channel counts differ: {sorted(chans)}")
        self._items = clouds

    @classmethod
    def from_lists(cls, points: Sequence, features: Sequence | None = None) -> "Pointclouds":
        """Build from lists of (k_i, 3) points and optional (k_i, C) features."""
        feats = list(features) if features is not None else [None] * len(points)
        if len(feats) != len(points):
            raise ValueError(f"features: expected {len(points)} arrays, got {len(feats)}")
        return cls([PointCloud(p, f) for p, f in zip(points, feats)])

    def __repr__(self) -> str:
        return f"Pointclouds(n={len(self)}, points={self.num_points_per_cloud().tolist()})"

    def num_points_per_cloud(self) -> np.ndarray:
        """(N,) int64."""
        return np.array([len(c) for c in self._items], dtype=np.int64)

    def cloud_to_packed_first_idx(self) -> np.ndarray:
        """(N,) int64 index of each cloud's first point in the packed array."""
        return first_index(self.num_points_per_cloud())

    def packed_to_cloud_idx(self) -> np.ndarray:
        """(sum k_i,) int64 cloud index of every packed point."""
        return packed_to_item(self.num_points_per_cloud())

    def points_list(self) -> list[np.ndarray]:
        return [c.points for c in self._items]

    def features_list(self) -> list:
        return [c.features for c in self._items]

    def points_packed(self) -> np.ndarray:
        """(sum k_i, 3) float64."""
        if not self._items:
            return np.zeros((0, 3))
        return np.concatenate(self.points_list(), axis=0)

    def features_packed(self) -> np.ndarray | None:
        """(sum k_i, C) float64, or None when the clouds have no features."""
        if not self._items or self._items[0].features is None:
            return None
        return np.concatenate(self.features_list(), axis=0)

    def points_padded(self, pad_value: float = 0.0) -> np.ndarray:
        """(N, max k_i, 3) float64 padded with ``pad_value``."""
        return padded(self.points_list(), self.num_points_per_cloud(), pad_value)


def as_pointcloud(cloud, name: str = "cloud") -> PointCloud:
    """The one place where point clouds from other libraries become geofit PointClouds.

    Parameters
    ----------
    cloud : PointCloud, trimesh.PointCloud or open3d.geometry.PointCloud
        A geofit PointCloud is returned as it is; the others are converted by
        :meth:`PointCloud.from_trimesh` / :meth:`PointCloud.from_open3d`.
    name : str
        As in :func:`geofit.structures.as_mesh`.

    Raises
    ------
    TypeError
        For anything else, as :func:`geofit.structures.as_mesh` does.
    """
    if isinstance(cloud, PointCloud):
        return cloud

    kind = foreign_kind(cloud)
    if kind == "trimesh.PointCloud":
        return PointCloud.from_trimesh(cloud)
    if kind == "open3d.PointCloud":
        return PointCloud.from_open3d(cloud)
    if kind == "open3d.t.PointCloud":
        return PointCloud.from_open3d(cloud.to_legacy())
    raise TypeError(f"{name}: expected a geofit PointCloud, trimesh.PointCloud or "
                    f"open3d.geometry.PointCloud (legacy or tensor API), got {type(cloud)!r}")


def as_pointclouds(clouds, name: str = "point_clouds") -> Pointclouds:
    """A Pointclouds batch from a batch, one cloud or a list of clouds (of the types
    :func:`as_pointcloud` takes)."""
    return as_batch(clouds, Pointclouds, as_pointcloud, name, "a PointCloud or Pointclouds (or a "
                    "trimesh.PointCloud or open3d.geometry.PointCloud)")
