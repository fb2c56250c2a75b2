"""The shared camera machinery: :class:`CamerasBase`, its result containers and the NDC grid.

Conventions (PyTorch3D's) are described in :mod:`geofit.cameras`.
"""
from __future__ import annotations

import numbers
from typing import NamedTuple

import numpy as np

from .._validate import as_array
from ._util import (
    _batch_items,
    _broadcast_batch,
    _check_bool,
    _check_rotations,
    _homogeneous_divide,
    _image_size,
    _image_sizes,
)

__all__ = ["CamerasBase", "ProjectedPoints", "Rays", "ndc_grid"]

# --------------------------------------------------------------------------------------------
# Result containers
# --------------------------------------------------------------------------------------------


class ProjectedPoints(NamedTuple):
    """NDC positions of projected points and their Jacobian with respect to world positions.

    Attributes
    ----------
    xy : (N, k, 2) float64
        NDC x, y of point ``k`` in camera ``n``.
    jacobian : (N, k, 2, 3) float64
        ``jacobian[n, k, i, a] = d xy[n, k, i] / d points[k, a]`` (world coordinate ``a``).
        A gradient ``g (N, k, 2)`` on ``xy`` carries to the points as
        ``np.einsum("nki,nkia->nka", g, jacobian)``.
    """

    xy: np.ndarray
    jacobian: np.ndarray


class Rays(NamedTuple):
    """Per-pixel rays of a batch of cameras (PyTorch3D's ``RayBundle`` without lengths).

    Attributes
    ----------
    origins : (N, H, W, 3) float64
        World-space ray origins: the camera centre for perspective cameras, the point of view
        depth 0 for orthographic cameras.
    directions : (N, H, W, 3) float64
        World-space directions with view-space z component 1 (not unit length), so
        ``origins + t * directions`` has view depth ``t``.
    xys : (N, H, W, 2) float64
        NDC x, y of each pixel centre; row 0 is the top (largest y), column 0 the left
        (largest x).
    """

    origins: np.ndarray
    directions: np.ndarray
    xys: np.ndarray

    def points(self, lengths) -> np.ndarray:
        """Points along the rays: ``origins + lengths * directions``.

        Parameters
        ----------
        lengths : (n,) or (N, H, W, n) float64
            Distances along each ray in units of ``directions`` (view depths); ``(n,)`` is
            used for every ray.

        Returns
        -------
        points : (N, H, W, n, 3) float64
            ``points[b, j, i, s]`` is sample ``s`` on the ray of pixel row ``j``, column ``i``.
        """
        lengths = as_array(lengths, "lengths")
        batch = self.origins.shape[:-1]
        if lengths.ndim == 1:
            lengths = np.broadcast_to(lengths, batch + lengths.shape)
        elif lengths.shape[:-1] != batch:
            raise ValueError(
                f"lengths: expected shape (n,) or {batch + ('n',)}, got {lengths.shape}"
            )
        return self.origins[..., None, :] + lengths[..., None] * self.directions[..., None, :]


def ndc_grid(image_size) -> np.ndarray:
    """NDC coordinates of pixel centres, as PyTorch3D's rasterizers and raysamplers place them.

    With ``S = min(H, W)``, column ``i`` sits at ``x = (W - 1 - 2 i) / S`` and row ``j`` at
    ``y = (H - 1 - 2 j) / S``; for a square image ``x = 1 - (2 i + 1) / W``. The shorter side
    spans [-1, 1] (pixel edges), the longer side [-long/short, long/short]. +X is left and +Y
    up, so column 0 has the largest x and row 0 the largest y.

    Parameters
    ----------
    image_size : (2,) int
        ``(H, W)`` in pixels.

    Returns
    -------
    xy : (H, W, 2) float64
        ``xy[j, i] = (x_i, y_j)``.

    Examples
    --------
    >>> ndc_grid((1, 4))[0, :, 0]
    array([ 3.,  1., -1., -3.])
    """
    H, W = _image_size(image_size)
    S = min(H, W)
    x = (W - 1 - 2 * np.arange(W, dtype=np.float64)) / S
    y = (H - 1 - 2 * np.arange(H, dtype=np.float64)) / S
    xy = np.empty((H, W, 2))
    xy[..., 0] = x[None, :]
    xy[..., 1] = y[:, None]
    return xy


# --------------------------------------------------------------------------------------------
# Cameras
# --------------------------------------------------------------------------------------------


class CamerasBase:
    """Shared machinery of a batch of ``N`` cameras with extrinsics ``R (N, 3, 3)``, ``T (N, 3)``.

    Subclasses define the view-to-NDC projection (``_K``) and its inverse (``_ndc_to_view``,
    ``_view_z_from_scaled``); everything else (world-to-view, full projection, screen mapping,
    unprojection, Jacobians, rays, indexing) is shared.

    Attributes
    ----------
    R : (N, 3, 3) float64, read-only
        World-to-view rotations (camera axes in the columns).
    T : (N, 3) float64, read-only
        World-to-view translations; ``X_view = X_world @ R[n] + T[n]``.
    """

    # Per-camera parameter arrays besides R and T (leading axis N), in constructor order.
    _FIELDS: tuple[str, ...] = ()

    R: np.ndarray
    T: np.ndarray

    # ---- construction -----------------------------------------------------------------

    def _prepare(self, R, T, **params: np.ndarray) -> dict:
        """Validate ``R`` and ``T`` and broadcast them with the per-camera ``params``."""
        R = np.eye(3)[None] if R is None else _batch_items(R, "R", (3, 3))
        T = np.zeros((1, 3)) if T is None else _batch_items(T, "T", (3,))
        b = _broadcast_batch(R=R, T=T, **params)
        _check_rotations(b["R"], "R")
        return b

    def _set(self, fields: dict) -> None:
        for k, v in fields.items():
            v = np.array(v, dtype=np.float64)  # a private copy, frozen below
            v.flags.writeable = False
            setattr(self, k, v)
        self._R_inv = np.linalg.inv(self.R)

    def __setattr__(self, name, value):
        """Assigning ``R``, ``T``, a per-camera parameter or a batch-wide setting (``degrees``)
        re-runs the constructor's checks."""
        if "_R_inv" in self.__dict__ and name in ("R", "T") + self._FIELDS + tuple(self._shared()):
            params = {**self._shared(), **self._fields(), name: value}
            self.__dict__.update(type(self)(**params).__dict__)
        else:
            object.__setattr__(self, name, value)

    def _shared(self) -> dict:
        """Batch-wide settings (not indexed by camera)."""
        return {}

    def _fields(self) -> dict:
        return {k: getattr(self, k) for k in ("R", "T") + self._FIELDS}

    @classmethod
    def _from_fields(cls, fields: dict, shared: dict):
        """A new batch from already-validated per-camera arrays (no checks)."""
        obj = cls.__new__(cls)
        for k, v in shared.items():
            setattr(obj, k, v)
        obj._set(fields)
        return obj

    # ---- batch ------------------------------------------------------------------------

    def __len__(self) -> int:
        return self.R.shape[0]

    def __repr__(self) -> str:
        return f"{type(self).__name__}(N={len(self)})"

    def __getitem__(self, index):
        """A batch holding the selected cameras.

        Parameters
        ----------
        index : int, slice, (m,) int array or (N,) bool array
            Cameras to keep; an int selects a batch of one camera.

        Returns
        -------
        cameras : same class
            ``len(cameras) == m``.

        Raises
        ------
        IndexError
            For indices outside ``[-N, N)``.
        ValueError
            For a boolean mask of the wrong length or a selection of no cameras.
        TypeError
            For other index types.
        """
        n = len(self)
        if isinstance(index, (numbers.Integral, np.integer)) and not isinstance(
                index, (bool, np.bool_)):
            if not -n <= index < n:
                raise IndexError(f"index: camera {index} is out of range for {n} cameras")
            idx = np.array([int(index) % n])
        elif isinstance(index, slice):
            idx = np.arange(n)[index]
        else:
            a = np.asarray(index)
            if a.size == 0:
                idx = np.zeros(0, dtype=np.int64)
            elif a.dtype == bool:
                if a.shape != (n,):
                    raise ValueError(f"index: expected a boolean mask of shape ({n},), "
                                     f"got shape {a.shape}")
                idx = np.flatnonzero(a)
            elif a.dtype.kind in "iu" and a.ndim == 1:
                if a.min() < -n or a.max() >= n:
                    raise IndexError(f"index: camera indices must lie in [-{n}, {n - 1}], got "
                                     f"range [{a.min()}, {a.max()}]")
                idx = a % n
            else:
                raise TypeError("index: expected an int, a slice, a 1-d integer array or a "
                                f"boolean mask, got {type(index).__name__} {a.dtype} {a.shape}")
        if idx.size == 0:
            raise ValueError("index: selects no cameras")
        return self._from_fields({k: v[idx] for k, v in self._fields().items()}, self._shared())

    def extend(self, n: int):
        """Repeat each camera ``n`` times: camera ``i`` becomes cameras ``i*n ... i*n + n - 1``.

        Parameters
        ----------
        n : int
            Number of copies, ``>= 1``.

        Returns
        -------
        cameras : same class
            ``len(cameras) == n * len(self)``.
        """
        if not isinstance(n, (numbers.Integral, np.integer)) or isinstance(n, (bool, np.bool_)) \
                or n < 1:
            raise ValueError(f"n: expected an integer >= 1, got {n!r}")
        fields = {k: np.repeat(v, int(n), axis=0) for k, v in self._fields().items()}
        return self._from_fields(fields, self._shared())

    # ---- projection model (subclasses) --------------------------------------------------

    def is_perspective(self) -> bool:
        """Whether the projection divides by depth."""
        raise NotImplementedError

    def _K(self) -> np.ndarray:
        """Column-vector view-to-NDC matrices ``(N, 4, 4)`` (``compute_projection_matrix``)."""
        raise NotImplementedError

    def _ndc_to_view(self, xy: np.ndarray, z: np.ndarray) -> np.ndarray:
        """View points ``(N, k, 3)`` with NDC ``xy (N, k, 2)`` at view depth ``z (N, k)``."""
        raise NotImplementedError

    def _view_z_from_scaled(self, sdepth: np.ndarray) -> np.ndarray:
        """View depth ``(N, k)`` of NDC z ``sdepth (N, k)``."""
        raise NotImplementedError

    # ---- matrices -----------------------------------------------------------------------

    def get_world_to_view_transform(self) -> np.ndarray:
        """Row-vector world-to-view matrices.

        Returns
        -------
        M : (N, 4, 4) float64
            ``[[R, 0], [T, 1]]``: ``[x, y, z, 1] @ M[n]`` is the view point, w = 1.
        """
        M = np.zeros((len(self), 4, 4))
        M[:, :3, :3] = self.R
        M[:, 3, :3] = self.T
        M[:, 3, 3] = 1.0
        return M

    def get_projection_transform(self) -> np.ndarray:
        """Row-vector view-to-NDC matrices (PyTorch3D's ``get_projection_transform()``).

        Returns
        -------
        P : (N, 4, 4) float64
            The transpose of the usual column-vector projection matrix ``K``.
        """
        return np.ascontiguousarray(self._K().transpose(0, 2, 1))

    def get_full_projection_transform(self) -> np.ndarray:
        """Row-vector world-to-NDC matrices.

        Returns
        -------
        M : (N, 4, 4) float64
            ``get_world_to_view_transform() @ get_projection_transform()``.
        """
        return self.get_world_to_view_transform() @ self.get_projection_transform()

    def get_camera_center(self) -> np.ndarray:
        """Camera centres in world coordinates.

        Returns
        -------
        C : (N, 3) float64
            ``-T[n] @ inv(R[n])``, the world point that maps to the view origin.
        """
        return -np.einsum("nj,nji->ni", self.T, self._R_inv)

    # ---- point maps ---------------------------------------------------------------------

    def _points(self, points, name: str = "points") -> np.ndarray:
        """``(k, 3)``, ``(1, k, 3)`` or ``(N, k, 3)`` as a broadcast ``(N, k, 3)`` view."""
        a = as_array(points, name)
        n = len(self)
        if a.ndim == 2 and a.shape[1] == 3:
            return np.broadcast_to(a, (n,) + a.shape)
        if a.ndim == 3 and a.shape[2] == 3 and a.shape[0] in (1, n):
            return np.broadcast_to(a, (n,) + a.shape[1:])
        raise ValueError(f"{name}: expected shape (k, 3) or ({n}, k, 3), got {a.shape}")

    def _homogeneous(self, P: np.ndarray) -> np.ndarray:
        """``[P, 1] @ M`` for the full projection ``M``: ``(N, k, 4)``."""
        M = self.get_full_projection_transform()
        return P @ M[:, :3, :] + M[:, 3:4, :]

    def transform_points_view(self, points) -> np.ndarray:
        """World points to view coordinates.

        Parameters
        ----------
        points : (k, 3) or (N, k, 3) float64
            World points, shared by all cameras or one set per camera.

        Returns
        -------
        view : (N, k, 3) float64
            ``points @ R[n] + T[n]``; ``view[..., 2]`` is the depth in front of the camera.
        """
        P = self._points(points)
        return P @ self.R + self.T[:, None, :]

    def transform_points(self, points, eps=None) -> np.ndarray:
        """World points to NDC (PyTorch3D's ``cameras.transform_points``).

        Parameters
        ----------
        points : (k, 3) or (N, k, 3) float64
            World points, shared by all cameras or one set per camera.
        eps : float, optional
            If given, the homogeneous divisor ``w`` is clamped to ``|w| >= eps`` (keeping its
            sign, 0 counting as positive), which keeps points on the camera plane finite.

        Returns
        -------
        ndc : (N, k, 3) float64
            NDC x, y (+X left, +Y up) and the *projected* z: ``zfar (z - znear) / ((zfar -
            znear) z)`` for perspective cameras, ``(z - znear) / (zfar - znear)`` (times the z
            scale) for orthographic ones, ``z`` the view depth. Points on the camera plane of a
            perspective camera give inf/nan unless ``eps`` is set.
        """
        return _homogeneous_divide(self._homogeneous(self._points(points)), eps)

    def transform_points_screen(self, points, image_size, eps=None, with_xyflip=True
                                ) -> np.ndarray:
        """World points to screen (pixel) coordinates, as PyTorch3D's ``transform_points_screen``.

        With ``s = min(H, W) / 2``: ``x_px = W/2 - s x_ndc`` and ``y_px = H/2 - s y_ndc``, so
        (0, 0) is the top-left corner of the top-left pixel and pixel ``(i, j)`` has its centre
        at ``(i + 0.5, j + 0.5)``.

        Parameters
        ----------
        points : (k, 3) or (N, k, 3) float64
            World points.
        image_size : (2,) or (N, 2) int
            ``(H, W)`` in pixels, shared or per camera.
        eps : float, optional
            As in ``transform_points``.
        with_xyflip : bool
            PyTorch3D's flag: True (default) gives x right, y down; False gives
            ``s x_ndc - W/2, s y_ndc - H/2``.

        Returns
        -------
        screen : (N, k, 3) float64
            Pixel x, pixel y, and the NDC z of ``transform_points``.
        """
        with_xyflip = _check_bool(with_xyflip, "with_xyflip")
        ndc = self.transform_points(points, eps=eps)
        sizes = _image_sizes(image_size)
        if sizes.shape[0] not in (1, len(self)):
            raise ValueError(f"image_size: expected (H, W) or ({len(self)}, 2), got shape "
                             f"{sizes.shape}")
        sizes = np.broadcast_to(sizes.astype(np.float64), (len(self), 2))
        H, W = sizes[:, 0, None], sizes[:, 1, None]
        s = np.minimum(H, W) / 2.0
        x = s * ndc[..., 0] - W / 2.0
        y = s * ndc[..., 1] - H / 2.0
        if with_xyflip:
            x, y = -x, -y
        return np.stack([x, y, ndc[..., 2]], axis=-1)

    def _unproject(self, xy: np.ndarray, z: np.ndarray, world_coordinates: bool) -> np.ndarray:
        view = self._ndc_to_view(xy, z)
        if not world_coordinates:
            return view
        return (view - self.T[:, None, :]) @ self._R_inv

    def unproject_points(self, xy_depth, world_coordinates=True, scaled_depth_input=False
                         ) -> np.ndarray:
        """NDC x, y plus depth back to world (or view) points, as PyTorch3D's ``unproject_points``.

        Parameters
        ----------
        xy_depth : (k, 3) or (N, k, 3) float64
            NDC x, y and the view depth z (or, with ``scaled_depth_input``, the NDC z of
            ``transform_points``).
        world_coordinates : bool
            Return world points (default) or view points.
        scaled_depth_input : bool
            Whether the third column is NDC z instead of view depth.

        Returns
        -------
        points : (N, k, 3) float64
            Points ``p`` with ``transform_points(p)[..., :2] == xy`` and view depth ``z``.
        """
        world_coordinates = _check_bool(world_coordinates, "world_coordinates")
        scaled_depth_input = _check_bool(scaled_depth_input, "scaled_depth_input")
        a = self._points(xy_depth, "xy_depth")
        z = a[..., 2]
        if scaled_depth_input:
            with np.errstate(divide="ignore", invalid="ignore"):
                z = self._view_z_from_scaled(z)
        return self._unproject(a[..., :2], z, world_coordinates)

    def projection_jacobian(self, points) -> ProjectedPoints:
        """NDC x, y of world points and their derivatives with respect to the world coordinates.

        With ``h = [p, 1] @ M`` (``M`` the full projection), ``xy_i = h_i / h_3`` and
        ``d xy_i / d p_a = (M[a, i] - xy_i M[a, 3]) / h_3``.

        Parameters
        ----------
        points : (k, 3) or (N, k, 3) float64
            World points.

        Returns
        -------
        ProjectedPoints
            ``xy (N, k, 2)`` and ``jacobian (N, k, 2, 3)`` with
            ``jacobian[n, k, i, a] = d xy[n, k, i] / d points[k, a]``.

        Examples
        --------
        >>> from geofit.cameras import FoVPerspectiveCameras
        >>> cam = FoVPerspectiveCameras(fov=90.0)
        >>> xy, J = cam.projection_jacobian([[0.5, 0.0, 2.0]])
        >>> xy[0, 0], J[0, 0].round(12) + 0.0
        (array([0.25, 0.  ]), array([[ 0.5  ,  0.   , -0.125],
               [ 0.   ,  0.5  ,  0.   ]]))
        """
        P = self._points(points)
        M = self.get_full_projection_transform()
        h = P @ M[:, :3, :] + M[:, 3:4, :]
        w = h[..., 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = h[..., :2] / w[..., None]
            J = (M[:, None, :3, :2].transpose(0, 1, 3, 2)
                 - xy[..., :, None] * M[:, None, None, :3, 3]) / w[..., None, None]
        return ProjectedPoints(xy, J)

    def pixel_rays(self, image_size) -> Rays:
        """One ray per pixel centre, as PyTorch3D's ``NDCMultinomialRaysampler`` (full grid).

        Each pixel's NDC centre (``ndc_grid``) is unprojected at view depths 1 and 2;
        ``directions = p2 - p1`` (view z component 1) and ``origins = p1 - directions`` (view
        depth 0: the camera centre of a perspective camera, the point on the plane z = 0 of an
        orthographic camera, whose directions are all the view +z axis).

        Parameters
        ----------
        image_size : (2,) int
            ``(H, W)`` in pixels; the rays pass through the centres of :func:`ndc_grid`.

        Returns
        -------
        Rays
            ``origins``, ``directions`` ``(N, H, W, 3)`` and ``xys (N, H, W, 2)``; the sample at
            ``origins + t * directions`` has view depth ``t`` (PyTorch3D's ray lengths).
        """
        xy = ndc_grid(image_size)
        H, W = xy.shape[:2]
        n = len(self)
        flat = np.broadcast_to(xy.reshape(1, H * W, 2), (n, H * W, 2))
        ones = np.ones((n, H * W))
        p1 = self._unproject(flat, ones, True)
        p2 = self._unproject(flat, 2.0 * ones, True)
        directions = p2 - p1
        origins = p1 - directions
        return Rays(origins.reshape(n, H, W, 3), directions.reshape(n, H, W, 3),
                    np.ascontiguousarray(np.broadcast_to(xy, (n, H, W, 2))))
