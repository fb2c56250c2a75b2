"""Point clouds on disk: ``.npz`` (PyTorch3D's PittsburghBridge layout) and ``.ply`` (Open3D)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._validate import as_array
from ..structures.pointcloud import PointCloud, as_pointcloud

__all__ = ["load_pointcloud", "save_pointcloud"]

_POINT_KEYS = ("verts", "points")
_COLOUR_KEYS = ("rgb", "colors", "colours", "features")


def _colours_to_float(c: np.ndarray, path: Path, key: str) -> np.ndarray:
    if c.dtype.kind in "iu":
        if c.size and (c.min() < 0 or c.max() > 255):
            raise ValueError(f"{path}: integer colours {key!r} must lie in [0, 255], got range "
                             f"[{c.min()}, {c.max()}]")
        return c.astype(np.float64) / 255.0
    return c


def load_pointcloud(path: str | os.PathLike) -> PointCloud:
    """Read a point cloud with optional colours and normals.

    Parameters
    ----------
    path : str or os.PathLike
        ``.npz``: the points under ``verts`` (PyTorch3D's PittsburghBridge file) or ``points``;
        colours, optional, under ``rgb``, ``colors``, ``colours`` or ``features``; normals,
        optional, under ``normals``.
        ``.ply``: read with ``open3d.io.read_point_cloud`` (points, colours and normals).

    Returns
    -------
    PointCloud
        ``points (k, 3) float64``; ``features (k, C) float64`` from the colours, or None;
        ``normals (k, 3) float64`` or None.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        For an unsupported extension, missing point key, wrong shapes, non-finite values, a
        colour count different from the point count, or a file without points.

    Notes
    -----
    Colour rule for ``.npz``: integer arrays (such as uint8) are 8-bit values and are divided
    by 255 (values outside [0, 255] are an error); float arrays are used as they are, assumed to
    be in [0, 1] already (the PittsburghBridge ``rgb`` array is read by the PyTorch3D tutorial
    as a float tensor and used directly as features). Open3D stores PLY colours as floats in
    [0, 1].
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".ply"):
        raise ValueError(f"path: expected a .npz or .ply file, got {path.name!r}")
    if not path.is_file():
        raise FileNotFoundError(f"point cloud file not found: {path}")
    if suffix == ".npz":
        with np.load(path, allow_pickle=False) as z:
            keys = set(z.files)
            pk = next((k for k in _POINT_KEYS if k in keys), None)
            if pk is None:
                raise ValueError(f"{path}: expected the points under one of {_POINT_KEYS}, "
                                 f"found keys {sorted(keys)}")
            pts = np.asarray(z[pk])
            ck = next((k for k in _COLOUR_KEYS if k in keys), None)
            col = None if ck is None else _colours_to_float(np.asarray(z[ck]), path, ck)
            nrm = np.asarray(z["normals"]) if "normals" in keys else None
    else:
        import open3d as o3d

        pc = o3d.io.read_point_cloud(str(path), format="ply")
        pts = np.asarray(pc.points, dtype=np.float64)
        col = np.asarray(pc.colors, dtype=np.float64) if pc.has_colors() else None
        nrm = np.asarray(pc.normals, dtype=np.float64) if pc.has_normals() else None
        pk, ck = "points", "colors"
    pts = as_array(pts, f"{path}: {pk}", (None, 3))
    if len(pts) == 0:
        extra = " (or Open3D could not parse it)" if suffix == ".ply" else ""
        raise ValueError(f"{path}: the file holds no points{extra}")
    if col is not None:
        if col.ndim == 1:
            col = col[:, None]
        col = as_array(col, f"{path}: {ck}", (len(pts), None))
    if nrm is not None:
        nrm = as_array(nrm, f"{path}: normals", (len(pts), 3))
    return PointCloud(pts, col, nrm)


def save_pointcloud(path: str | os.PathLike, cloud: PointCloud) -> None:
    """Write a point cloud as ``.npz`` or ``.ply``.

    Parameters
    ----------
    path : str or os.PathLike
        ``.npz``: keys ``verts`` (k, 3) float64, ``rgb`` (k, C) float64 when the cloud has
        features, ``normals`` (k, 3) when it has normals (the PittsburghBridge layout); exact.
        ``.ply``: binary PLY through Open3D; positions and normals are written as doubles,
        colours as 8-bit values (so they come back quantised to multiples of 1/255); only the
        first three feature channels are written, and the features must then lie in [0, 1].
    cloud : PointCloud
        The cloud.

    Raises
    ------
    TypeError
        If ``cloud`` is not a PointCloud.
    ValueError
        For an unsupported extension, or features that a PLY cannot hold (fewer than three
        channels, values outside [0, 1]).
    """
    path = Path(path)
    cloud = as_pointcloud(cloud, "cloud")  # a geofit, trimesh or Open3D point cloud
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".ply"):
        raise ValueError(f"path: expected a .npz or .ply file, got {path.name!r}")
    if suffix == ".npz":
        arrays = {"verts": cloud.points}
        if cloud.features is not None:
            arrays["rgb"] = cloud.features
        if cloud.normals is not None:
            arrays["normals"] = cloud.normals
        with open(path, "wb") as fh:  # an open handle keeps numpy from appending ".npz"
            np.savez_compressed(fh, **arrays)
        return
    import open3d as o3d

    f = cloud.features
    if f is not None:
        if f.shape[1] < 3:
            raise ValueError(f"cloud.features: a PLY needs 3 colour channels, got {f.shape[1]}")
        if f.size and (f[:, :3].min() < 0 or f[:, :3].max() > 1):
            raise ValueError("cloud.features: PLY colours must lie in [0, 1], got range "
                             f"[{f[:, :3].min():.6g}, {f[:, :3].max():.6g}]")
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(cloud.points)))
    if f is not None:
        pc.colors = o3d.utility.Vector3dVector(np.array(f[:, :3]))
    if cloud.normals is not None:
        pc.normals = o3d.utility.Vector3dVector(np.array(cloud.normals))
    if not o3d.io.write_point_cloud(str(path), pc, write_ascii=False):
        raise OSError(f"Open3D could not write {path}")
