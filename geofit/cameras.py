"""Cameras with PyTorch3D's conventions, in numpy float64.

World to view uses **row vectors**: ``X_view = X_world @ R + T`` with ``R (N, 3, 3)`` whose
*columns* are the camera axes and ``T (N, 3)``. View space has +X left, +Y up and +Z into the
scene (right-handed). NDC (normalised device coordinates) has (+1, +1) at the **top-left** corner
of the image; for a non-square image the shorter side spans [-1, 1] and the longer side
[-long/short, +long/short]. Screen space is in pixels with (0, 0) at the top-left corner of the
top-left pixel, x to the right and y down.

Every 4x4 matrix returned here is a row-vector matrix, as PyTorch3D's ``Transform3d.get_matrix()``:
a homogeneous row ``[x, y, z, 1] @ M[n] = [X, Y, Z, W]`` maps to ``[X, Y, Z] / W``.

The camera classes mirror ``pytorch3d.renderer.FoVPerspectiveCameras`` and
``FoVOrthographicCameras`` (batched over ``N`` cameras, every parameter broadcast from 1 to ``N``),
add the projection Jacobian needed to carry image-space gradients back to world points, per-pixel
rays with ``NDCMultinomialRaysampler``'s conventions, and conversions to and from OpenCV's and
Open3D's pinhole cameras.
"""
from __future__ import annotations

import math
import numbers
import warnings
from typing import NamedTuple

import numpy as np

from ._validate import as_array, check_positive, shape_str

__all__ = [
    "CamerasBase",
    "FoVOrthographicCameras",
    "FoVPerspectiveCameras",
    "ProjectedPoints",
    "Rays",
    "camera_position_from_spherical_angles",
    "cameras_from_opencv_projection",
    "from_open3d",
    "look_at_rotation",
    "look_at_view_transform",
    "ndc_grid",
    "opencv_from_cameras_projection",
    "to_open3d",
]

# torch.nn.functional.normalize(eps=1e-5) and the isclose(x, 0, atol=5e-3) fallback of
# pytorch3d.renderer.cameras.look_at_rotation.
_NORMALIZE_EPS = 1e-5
_X_AXIS_FALLBACK_ATOL = 5e-3
# |cos(elev)| below this counts as a pole: elev is +-90 degrees to within float32 resolution.
_POLE_COS = 1e-7
# Largest max|R R^T - I| accepted for a camera rotation.
_ROTATION_TOL = 1e-4


# --------------------------------------------------------------------------------------------
# Input helpers (public entry points validate with these, then trust their arrays)
# --------------------------------------------------------------------------------------------


def _batch_scalar(x, name: str) -> np.ndarray:
    """A scalar or ``(n,)`` array as a finite ``(n,)`` float64 array with ``n >= 1``."""
    a = as_array(x, name)
    if a.ndim == 0:
        a = a.reshape(1)
    if a.ndim != 1 or a.shape[0] == 0:
        raise ValueError(f"{name}: expected a scalar or shape (n,) with n >= 1, got {a.shape}")
    return a


def _batch_items(x, name: str, item: tuple) -> np.ndarray:
    """An ``item``-shaped or ``(n, *item)`` array as a finite ``(n, *item)`` float64 array."""
    a = as_array(x, name)
    if a.shape == item:
        a = a[None]
    if a.ndim != len(item) + 1 or a.shape[1:] != item or a.shape[0] == 0:
        raise ValueError(
            f"{name}: expected shape {shape_str((None,) + item)} or {shape_str(item)}, "
            f"got {a.shape}"
        )
    return a


def _broadcast_batch(**arrays: np.ndarray) -> dict:
    """Broadcast the leading (batch) axis of every array to the common size ``N``.

    Each array must have batch size 1 or ``N``, as in PyTorch3D's
    ``convert_to_tensors_and_broadcast``.
    """
    sizes = {k: v.shape[0] for k, v in arrays.items()}
    n = max(sizes.values())
    if any(s not in (1, n) for s in sizes.values()):
        listing = ", ".join(f"{k} has {s}" for k, s in sizes.items())
        raise ValueError(
            f"mismatched batch sizes: every argument needs 1 or N = {n} entries, got {listing}"
        )
    return {k: np.ascontiguousarray(np.broadcast_to(v, (n,) + v.shape[1:])) for k, v in
            arrays.items()}


def _image_size(image_size, name: str = "image_size") -> tuple[int, int]:
    """One ``(H, W)`` pair of positive integers."""
    a = as_array(image_size, name, dtype=np.int64)
    if a.shape == (1, 2):
        a = a[0]
    if a.shape != (2,):
        raise ValueError(f"{name}: expected (H, W), shape (2,), got shape {a.shape}")
    if np.any(a < 1):
        raise ValueError(f"{name}: expected positive (H, W), got {tuple(int(v) for v in a)}")
    return int(a[0]), int(a[1])


def _image_sizes(image_size, name: str = "image_size") -> np.ndarray:
    """``(H, W)`` or ``(n, 2)`` positive integers as an ``(n, 2)`` int64 array."""
    a = as_array(image_size, name, dtype=np.int64)
    if a.shape == (2,):
        a = a[None]
    if a.ndim != 2 or a.shape[1] != 2 or a.shape[0] == 0:
        raise ValueError(f"{name}: expected (H, W), shape (2,) or (n, 2), got shape {a.shape}")
    if np.any(a < 1):
        raise ValueError(f"{name}: expected positive (H, W) sizes, got minimum {int(a.min())}")
    return a


def _check_rotations(R: np.ndarray, name: str) -> None:
    """Raise unless every ``R[n]`` is orthonormal with determinant +1 (to ``_ROTATION_TOL``)."""
    err = np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = np.flatnonzero((err > _ROTATION_TOL) | (np.abs(det - 1.0) > _ROTATION_TOL))
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"{name}: expected rotation matrices (orthonormal, det +1); {bad.size} of {len(R)} "
            f"are not, e.g. R[{i}] has max|R R^T - I| = {err[i]:.3g} and det {det[i]:.6g}"
        )


def _check_bool(value, name: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name}: expected True or False, got {value!r}")
    return bool(value)


def _normalize(v: np.ndarray) -> np.ndarray:
    """``torch.nn.functional.normalize(v, dim=-1, eps=1e-5)``: ``v / max(|v|, eps)``."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(norm, _NORMALIZE_EPS)


def _homogeneous_divide(h: np.ndarray, eps) -> np.ndarray:
    """``h[..., :3] / h[..., 3:]``, the divisor clamped to ``|w| >= eps`` (sign kept) if given."""
    w = h[..., 3:]
    if eps is not None:
        eps = check_positive(eps, "eps", strict=False)
        sign = np.sign(w) + (w == 0.0)
        w = sign * np.maximum(np.abs(w), eps)
    with np.errstate(divide="ignore", invalid="ignore"):
        return h[..., :3] / w


# --------------------------------------------------------------------------------------------
# Look-at
# --------------------------------------------------------------------------------------------


def _cos_elevation(elev: np.ndarray, degrees: bool) -> np.ndarray:
    """``cos(elev)`` in float64, except at the poles where PyTorch3D's float32 value is used.

    PyTorch3D evaluates ``cos(float32(pi/180) * float32(elev))`` in float32. At elev = +-90 (and
    270, ...) the float32 angle misses the pole and the cosine is a tiny number whose *sign*
    decides the roll of the look-at frame (see ``look_at_view_transform``). float64 gives a
    different tiny number (6e-17 at 90 degrees) for which the frame collapses.
    """
    rad = elev * (math.pi / 180.0) if degrees else elev
    c = np.cos(rad)
    pole = np.abs(c) < _POLE_COS
    if np.any(pole):
        e32 = elev[pole].astype(np.float32)
        if degrees:
            e32 = e32 * np.float32(math.pi / 180.0)
        c[pole] = np.cos(e32).astype(np.float64)
    return c


def _spherical_position(dist, elev, azim, degrees: bool) -> np.ndarray:
    if degrees:
        sin_e = np.sin(elev * (math.pi / 180.0))
        azim = azim * (math.pi / 180.0)
    else:
        sin_e = np.sin(elev)
    cos_e = _cos_elevation(elev, degrees)
    return dist[:, None] * np.stack(
        [cos_e * np.sin(azim), sin_e, cos_e * np.cos(azim)], axis=1
    )


def camera_position_from_spherical_angles(distance=1.0, elevation=0.0, azimuth=0.0,
                                          degrees=True) -> np.ndarray:
    """Camera centre at ``distance`` from the origin, given elevation and azimuth.

    ``C = distance * (cos(elev) sin(azim), sin(elev), cos(elev) cos(azim))``: azim = 0 puts the
    camera on +Z, elev = 90 on +Y.

    Parameters
    ----------
    distance, elevation, azimuth : float or (N,) float64
        Broadcast against each other (each of size 1 or N).
    degrees : bool
        Whether the angles are in degrees (default) or radians.

    Returns
    -------
    C : (N, 3) float64
        Camera positions in world units.

    Notes
    -----
    At an exact pole (``|cos(elev)| < 1e-7``) ``cos(elev)`` is PyTorch3D's float32 value (e.g.
    -4.37e-8 at elev = +-90 degrees), see ``look_at_view_transform``.

    Examples
    --------
    >>> camera_position_from_spherical_angles(2.0, 0.0, 90.0).round(12) + 0.0
    array([[2., 0., 0.]])
    """
    degrees = _check_bool(degrees, "degrees")
    b = _broadcast_batch(distance=_batch_scalar(distance, "distance"),
                         elevation=_batch_scalar(elevation, "elevation"),
                         azimuth=_batch_scalar(azimuth, "azimuth"))
    return _spherical_position(b["distance"], b["elevation"], b["azimuth"], degrees)


def _look_at_rotation(C: np.ndarray, at: np.ndarray, up: np.ndarray) -> np.ndarray:
    """PyTorch3D's look-at formula on broadcast ``(N, 3)`` arrays; warns if degenerate."""
    z = _normalize(at - C)
    x = _normalize(np.cross(up, z))
    y = _normalize(np.cross(z, x))
    close = np.all(np.abs(x) <= _X_AXIS_FALLBACK_ATOL, axis=1, keepdims=True)
    if np.any(close):
        x = np.where(close, _normalize(np.cross(y, z)), x)
    R = np.stack([x, y, z], axis=2)  # the camera axes are the columns
    det = np.linalg.det(R)
    bad = np.flatnonzero(det < 0.5)
    if bad.size:
        i = int(bad[0])
        warnings.warn(
            "look-at frame undefined where the viewing direction at - camera_position is zero "
            f"or parallel to up: {bad.size} of {len(R)} rotations are singular (as in "
            f"PyTorch3D), e.g. camera {i} with camera_position {C[i].tolist()}, "
            f"at {at[i].tolist()}, up {up[i].tolist()}",
            RuntimeWarning, stacklevel=3,
        )
    return R


def look_at_rotation(camera_position, at=((0, 0, 0),), up=((0, 1, 0),)) -> np.ndarray:
    """Rotation of a camera at ``camera_position`` looking at ``at`` with ``up`` roughly up.

    PyTorch3D's formula: ``z = normalize(at - C)``, ``x = normalize(up x z)``,
    ``y = normalize(z x x)``, with ``normalize(v) = v / max(|v|, 1e-5)``; where every entry of
    ``x`` is within 5e-3 of zero, ``x`` is replaced by ``normalize(y x z)``. ``R = [x | y | z]``
    (the axes are the columns), so ``X_view = X_world @ R + T``.

    Parameters
    ----------
    camera_position : (N, 3) or (3,) float64
        Camera centres in world coordinates.
    at : (N, 3) or (3,) float64
        Points the cameras look at.
    up : (N, 3) or (3,) float64
        World "up" directions (the camera y axis is the part of ``up`` orthogonal to the view
        direction); need not be unit or orthogonal to the view direction.

    Returns
    -------
    R : (N, 3, 3) float64
        World-to-view rotations, ``N`` the broadcast batch size.

    Raises
    ------
    ValueError
        On bad shapes, non-finite values or mismatched batch sizes.

    Warns
    -----
    RuntimeWarning
        Where ``at - camera_position`` is zero or parallel to ``up``: the frame is undefined
        and, as in PyTorch3D, the returned matrix is singular (e.g. ``[0 | 0 | z]`` for
        ``up x z = 0``); cameras built from it raise ValueError.

    Examples
    --------
    >>> look_at_rotation([0.0, 0.0, 3.0])[0].round(12) + 0.0
    array([[-1.,  0.,  0.],
           [ 0.,  1.,  0.],
           [ 0.,  0., -1.]])
    """
    b = _broadcast_batch(camera_position=_batch_items(camera_position, "camera_position", (3,)),
                         at=_batch_items(at, "at", (3,)), up=_batch_items(up, "up", (3,)))
    return _look_at_rotation(b["camera_position"], b["at"], b["up"])


def look_at_view_transform(dist=1.0, elev=0.0, azim=0.0, degrees=True, eye=None,
                           at=((0, 0, 0),), up=((0, 1, 0),)) -> tuple[np.ndarray, np.ndarray]:
    """World-to-view ``R, T`` of cameras looking at ``at`` (PyTorch3D's ``look_at_view_transform``).

    The camera sits at ``C = at + dist * (cos(elev) sin(azim), sin(elev), cos(elev) cos(azim))``
    (or at ``eye`` when given), ``R = look_at_rotation(C, at, up)`` and ``T = -R^T C``, so the
    camera centre maps to the view origin. azim = 0 puts the camera on +Z looking towards -Z;
    PyTorch3D's tutorials use azim = 180 to face the cow, which looks towards -Z.

    Parameters
    ----------
    dist : float or (N,) float64
        Distance of the camera from ``at``.
    elev : float or (N,) float64
        Elevation: angle between the ``at``-to-camera vector and the xz plane.
    azim : float or (N,) float64
        Azimuth: angle of that vector's projection on the xz plane, from +Z towards +X.
    degrees : bool
        Whether ``elev`` and ``azim`` are in degrees (default) or radians.
    eye : (N, 3) or (3,) float64, optional
        Camera positions in world coordinates; when given, ``dist``, ``elev`` and ``azim`` are
        ignored.
    at : (N, 3) or (3,) float64
        Points looked at.
    up : (N, 3) or (3,) float64
        World up directions (the y axis of each camera lies in the plane of ``up`` and the view
        direction).

    Returns
    -------
    R : (N, 3, 3) float64
        Rotations, camera axes in the columns.
    T : (N, 3) float64
        Translations; ``X_view = X_world @ R[n] + T[n]``.

    Raises
    ------
    ValueError
        On bad shapes, non-finite values, mismatched batch sizes or ``dist == 0``.

    Warns
    -----
    RuntimeWarning
        For a degenerate frame (``eye == at``, or ``up`` parallel to the view direction away
        from the special-cased poles), where ``R`` is singular as in PyTorch3D.

    Notes
    -----
    **The pole quirk.** PyTorch3D computes in float32, where ``cos(deg2rad(90))`` is
    ``-4.37e-8``: a camera at elev = +-90 sits just *beyond* the pole. ``up x z`` then has norm
    4.4e-8, the 1e-5 normalisation eps shrinks ``x`` to length 4.4e-3 < 5e-3, the fallback
    ``x = normalize(y x z)`` fires, and the result is a proper rotation with x axis
    ``(cos azim, 0, -sin azim)``, rolled by 180 degrees relative to elev = 89.99 (x axis
    ``(-cos azim, 0, sin azim)``). In float64 ``cos`` is 6e-17 and the same formula collapses
    to a singular matrix. To match PyTorch3D, wherever ``|cos(elev)| < 1e-7`` this function
    uses the float32 value of ``cos(elev)`` (the sign is what matters: negative at +-90 degrees,
    positive at 270); everything else is evaluated in float64. With ``eye`` there is no such
    special case: ``up`` exactly parallel to the view direction gives PyTorch3D's singular
    ``R = [0 | 0 | z]`` and a RuntimeWarning.

    Examples
    --------
    >>> R, T = look_at_view_transform(dist=2.7, elev=0.0, azim=180.0)
    >>> R.shape, T.shape
    ((1, 3, 3), (1, 3))
    >>> T.round(12) + 0.0
    array([[0. , 0. , 2.7]])
    """
    degrees = _check_bool(degrees, "degrees")
    at = _batch_items(at, "at", (3,))
    up = _batch_items(up, "up", (3,))
    if eye is not None:
        b = _broadcast_batch(eye=_batch_items(eye, "eye", (3,)), at=at, up=up)
        C = b["eye"]
    else:
        b = _broadcast_batch(dist=_batch_scalar(dist, "dist"), elev=_batch_scalar(elev, "elev"),
                             azim=_batch_scalar(azim, "azim"), at=at, up=up)
        if np.any(b["dist"] == 0):  # the camera would sit on the point it looks at
            raise ValueError(f"dist: expected non-zero distances, got {b['dist'].tolist()[:8]}")
        C = _spherical_position(b["dist"], b["elev"], b["azim"], degrees) + b["at"]
    R = _look_at_rotation(C, b["at"], b["up"])
    T = -np.einsum("nji,nj->ni", R, C)
    return R, T


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
            ``(H, W)`` in pixels.

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


class FoVPerspectiveCameras(CamerasBase):
    """A batch of OpenGL-style perspective cameras given by field of view (PyTorch3D's class).

    The column-vector projection matrix is, with ``t = tan(fov / 2)``::

        K = [[1 / (t * aspect_ratio), 0,     0,                      0                        ],
             [0,                      1 / t, 0,                      0                        ],
             [0,                      0,     zfar / (zfar - znear),  -zfar znear / (zfar - znear)],
             [0,                      0,     1,                      0                        ]]

    so NDC x = x / (t aspect z), y = y / (t z) and NDC z runs from 0 at znear to 1 at zfar.
    ``aspect_ratio`` is the *pixel* aspect ratio (keep 1.0 and set a non-square image size
    instead); note that it divides x, not y (PyTorch3D's docstring has it the other way round).

    Parameters
    ----------
    znear : float or (N,) float64
        Near plane distance, > 0.
    zfar : float or (N,) float64
        Far plane distance, > znear.
    aspect_ratio : float or (N,) float64
        Pixel aspect ratio, > 0.
    fov : float or (N,) float64
        Vertical field of view, in (0, 180) degrees or (0, pi) radians.
    degrees : bool
        Whether ``fov`` is in degrees (default); shared by the batch.
    R : (N, 3, 3) or (3, 3) float64, optional
        World-to-view rotations (default identity); must be rotations.
    T : (N, 3) or (3,) float64, optional
        World-to-view translations (default zeros).

    All per-camera arguments broadcast to the largest batch size ``N`` (each has 1 or N
    entries); they are stored as read-only ``(N,)`` arrays of the same names.

    Examples
    --------
    >>> R, T = look_at_view_transform(2.7, 0.0, [0.0, 90.0])
    >>> cams = FoVPerspectiveCameras(fov=60.0, R=R, T=T)
    >>> len(cams), cams.transform_points([[0.0, 0.0, 0.0]]).shape
    (2, (2, 1, 3))
    """

    _FIELDS = ("znear", "zfar", "aspect_ratio", "fov")

    def __init__(self, znear=1.0, zfar=100.0, aspect_ratio=1.0, fov=60.0, degrees=True,
                 R=None, T=None):
        self.degrees = _check_bool(degrees, "degrees")
        b = self._prepare(R, T, znear=_batch_scalar(znear, "znear"),
                          zfar=_batch_scalar(zfar, "zfar"),
                          aspect_ratio=_batch_scalar(aspect_ratio, "aspect_ratio"),
                          fov=_batch_scalar(fov, "fov"))
        if np.any(b["znear"] <= 0):
            raise ValueError(f"znear: expected > 0 for a perspective camera, got minimum "
                             f"{b['znear'].min():g}")
        if np.any(b["zfar"] <= b["znear"]):
            raise ValueError("zfar: expected zfar > znear for every camera, got "
                             f"{int(np.sum(b['zfar'] <= b['znear']))} cameras with zfar <= znear")
        if np.any(b["aspect_ratio"] <= 0):
            raise ValueError(f"aspect_ratio: expected > 0, got minimum {b['aspect_ratio'].min():g}")
        limit = 180.0 if self.degrees else math.pi
        unit = "degrees" if self.degrees else "radians"
        if np.any((b["fov"] <= 0) | (b["fov"] >= limit)):
            raise ValueError(f"fov: expected values in (0, {limit:g}) {unit}, got range "
                             f"[{b['fov'].min():g}, {b['fov'].max():g}]")
        self._set(b)

    def _shared(self) -> dict:
        return {"degrees": self.degrees}

    def is_perspective(self) -> bool:
        return True

    def _K(self) -> np.ndarray:
        fov = self.fov * (math.pi / 180.0) if self.degrees else self.fov
        znear, zfar = self.znear, self.zfar
        max_y = np.tan(fov / 2.0) * znear
        min_y = -max_y
        max_x = max_y * self.aspect_ratio
        min_x = -max_x
        K = np.zeros((len(self), 4, 4))
        K[:, 0, 0] = 2.0 * znear / (max_x - min_x)
        K[:, 1, 1] = 2.0 * znear / (max_y - min_y)
        K[:, 0, 2] = (max_x + min_x) / (max_x - min_x)
        K[:, 1, 2] = (max_y + min_y) / (max_y - min_y)
        K[:, 3, 2] = 1.0
        K[:, 2, 2] = zfar / (zfar - znear)
        K[:, 2, 3] = -(zfar * znear) / (zfar - znear)
        return K

    def _ndc_to_view(self, xy, z):
        K = self._K()
        x = (xy[..., 0] - K[:, None, 0, 2]) * z / K[:, None, 0, 0]
        y = (xy[..., 1] - K[:, None, 1, 2]) * z / K[:, None, 1, 1]
        return np.stack([x, y, np.broadcast_to(z, x.shape)], axis=-1)

    def _view_z_from_scaled(self, sdepth):
        # sdepth = K22 + K23 / z
        K = self._K()
        return K[:, None, 2, 3] / (sdepth - K[:, None, 2, 2])


class FoVOrthographicCameras(CamerasBase):
    """A batch of OpenGL-style orthographic cameras (PyTorch3D's class).

    NDC ``x = 2 sx x / (max_x - min_x) - (max_x + min_x) / (max_x - min_x)`` (likewise y), and
    ``z_ndc = sz z / (zfar - znear) - znear / (zfar - znear)`` maps [znear, zfar] to [0, 1]
    when ``sz = 1``, with ``(sx, sy, sz) = scale_xyz``.

    Parameters
    ----------
    znear : float or (N,) float64
        Near plane depth.
    zfar : float or (N,) float64
        Far plane depth, > znear.
    max_y, min_y : float or (N,) float64
        View-space y range mapped to NDC [-1, 1] (top is ``max_y``), ``max_y > min_y``.
    max_x, min_x : float or (N,) float64
        View-space x range mapped to NDC [-1, 1] (``max_x`` on the left), ``max_x > min_x``.
    scale_xyz : (N, 3) or (3,) float64
        Positive per-axis scale factors.
    R : (N, 3, 3) or (3, 3) float64, optional
        World-to-view rotations (default identity); must be rotations.
    T : (N, 3) or (3,) float64, optional
        World-to-view translations (default zeros).

    All per-camera arguments broadcast to the largest batch size ``N``.

    Examples
    --------
    >>> cam = FoVOrthographicCameras(znear=0.0, zfar=10.0, max_x=2.0, min_x=-2.0)
    >>> cam.transform_points([[1.0, 0.5, 5.0]])
    array([[[0.5, 0.5, 0.5]]])
    """

    _FIELDS = ("znear", "zfar", "max_y", "min_y", "max_x", "min_x", "scale_xyz")

    def __init__(self, znear=1.0, zfar=100.0, max_y=1.0, min_y=-1.0, max_x=1.0, min_x=-1.0,
                 scale_xyz=((1.0, 1.0, 1.0),), R=None, T=None):
        b = self._prepare(R, T, znear=_batch_scalar(znear, "znear"),
                          zfar=_batch_scalar(zfar, "zfar"), max_y=_batch_scalar(max_y, "max_y"),
                          min_y=_batch_scalar(min_y, "min_y"), max_x=_batch_scalar(max_x, "max_x"),
                          min_x=_batch_scalar(min_x, "min_x"),
                          scale_xyz=_batch_items(scale_xyz, "scale_xyz", (3,)))
        if np.any(b["zfar"] <= b["znear"]):
            raise ValueError("zfar: expected zfar > znear for every camera, got "
                             f"{int(np.sum(b['zfar'] <= b['znear']))} cameras with zfar <= znear")
        if np.any(b["max_x"] <= b["min_x"]):
            raise ValueError("max_x: expected max_x > min_x for every camera")
        if np.any(b["max_y"] <= b["min_y"]):
            raise ValueError("max_y: expected max_y > min_y for every camera")
        if np.any(b["scale_xyz"] <= 0):
            raise ValueError(f"scale_xyz: expected positive scales, got minimum "
                             f"{b['scale_xyz'].min():g}")
        self._set(b)

    def is_perspective(self) -> bool:
        return False

    def _K(self) -> np.ndarray:
        max_x, min_x, max_y, min_y = self.max_x, self.min_x, self.max_y, self.min_y
        znear, zfar, s = self.znear, self.zfar, self.scale_xyz
        K = np.zeros((len(self), 4, 4))
        K[:, 0, 0] = (2.0 / (max_x - min_x)) * s[:, 0]
        K[:, 1, 1] = (2.0 / (max_y - min_y)) * s[:, 1]
        K[:, 0, 3] = -(max_x + min_x) / (max_x - min_x)
        K[:, 1, 3] = -(max_y + min_y) / (max_y - min_y)
        K[:, 3, 3] = 1.0
        K[:, 2, 2] = (1.0 / (zfar - znear)) * s[:, 2]
        K[:, 2, 3] = -znear / (zfar - znear)
        return K

    def _ndc_to_view(self, xy, z):
        K = self._K()
        x = (xy[..., 0] - K[:, None, 0, 3]) / K[:, None, 0, 0]
        y = (xy[..., 1] - K[:, None, 1, 3]) / K[:, None, 1, 1]
        return np.stack([x, y, np.broadcast_to(z, x.shape)], axis=-1)

    def _view_z_from_scaled(self, sdepth):
        K = self._K()
        return (sdepth - K[:, None, 2, 3]) / K[:, None, 2, 2]


# --------------------------------------------------------------------------------------------
# OpenCV / Open3D
# --------------------------------------------------------------------------------------------

# PyTorch3D view (x left, y up, z forward) -> OpenCV camera (x right, y down, z forward).
_CV_FLIP = np.array([-1.0, -1.0, 1.0])


def cameras_from_opencv_projection(R, tvec, camera_matrix, image_size, *, znear=1.0,
                                   zfar=100.0) -> FoVPerspectiveCameras:
    """FoVPerspectiveCameras equivalent to OpenCV pinhole cameras.

    The FoV analogue of PyTorch3D's ``cameras_from_opencv_projection`` (which builds
    ``PerspectiveCameras``). OpenCV maps a world point ``X`` to ``x = R X + tvec`` and pixel
    ``K x / x_z``. With ``S = min(H, W)`` the camera gets ``fov = 2 atan(S / (2 fy))`` degrees
    and ``aspect_ratio = fy / fx``; ``R_p3d = R^T`` with its first two columns negated and
    ``T_p3d = tvec`` with its first two entries negated (the view flip diag(-1, -1, 1)).

    Parameters
    ----------
    R : (N, 3, 3) or (3, 3) float64
        OpenCV world-to-camera rotations (column vectors).
    tvec : (N, 3) or (3,) float64
        OpenCV translations.
    camera_matrix : (N, 3, 3) or (3, 3) float64
        Intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``.
    image_size : (2,) or (N, 2) int
        ``(H, W)`` in pixels.
    znear, zfar : float or (N,) float64
        Clipping planes of the returned cameras (OpenCV has none).

    Returns
    -------
    FoVPerspectiveCameras
        ``N`` cameras whose ``transform_points_screen`` reproduces OpenCV's pixels.

    Raises
    ------
    ValueError
        If a camera cannot be represented by FoVPerspectiveCameras: principal point not at the
        image centre ``(W/2, H/2)`` (to 1e-6 W or H), non-zero skew, a bottom row other than
        (0, 0, 1), non-positive focal lengths; or on bad shapes.

    Notes
    -----
    As in PyTorch3D, the image centre is ``(W/2, H/2)`` in pixel units whose (0, 0) is the
    corner of the top-left pixel; OpenCV's own convention puts (0, 0) at that pixel's *centre*,
    so a calibration with ``cx = (W - 1) / 2`` is half a pixel off-centre here and is rejected.
    """
    b = _broadcast_batch(R=_batch_items(R, "R", (3, 3)), tvec=_batch_items(tvec, "tvec", (3,)),
                         camera_matrix=_batch_items(camera_matrix, "camera_matrix", (3, 3)),
                         image_size=_image_sizes(image_size).astype(np.float64))
    K = b["camera_matrix"]
    H, W = b["image_size"][:, 0], b["image_size"][:, 1]
    if np.any(K[:, 1, 0] != 0) or np.any(K[:, 2] != np.array([0.0, 0.0, 1.0])):
        raise ValueError("camera_matrix: expected the form [[fx, 0, cx], [0, fy, cy], "
                         "[0, 0, 1]]; entries K[1, 0] and K[2, :] other than 0, 0, 0, 1 "
                         "are not supported")
    if np.any(K[:, 0, 1] != 0):
        raise ValueError(f"camera_matrix: skew K[0, 1] = {K[np.flatnonzero(K[:, 0, 1])[0], 0, 1]:g}"
                         " is not supported by FoVPerspectiveCameras")
    fx, fy, cx, cy = K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]
    if np.any(fx <= 0) or np.any(fy <= 0):
        raise ValueError("camera_matrix: expected focal lengths fx, fy > 0, got minimum "
                         f"{min(fx.min(), fy.min()):g}")
    off = (np.abs(cx - W / 2) > 1e-6 * W) | (np.abs(cy - H / 2) > 1e-6 * H)
    if np.any(off):
        i = int(np.flatnonzero(off)[0])
        raise ValueError(
            f"camera_matrix: off-centre principal points are not supported by "
            f"FoVPerspectiveCameras: camera {i} has (cx, cy) = ({cx[i]:g}, {cy[i]:g}), "
            f"expected the image centre (W/2, H/2) = ({W[i] / 2:g}, {H[i] / 2:g})"
        )
    S = np.minimum(H, W)
    fov = np.degrees(2.0 * np.arctan(S / (2.0 * fy)))
    R_p3d = b["R"].transpose(0, 2, 1) * _CV_FLIP[None, None, :]
    T_p3d = b["tvec"] * _CV_FLIP[None, :]
    return FoVPerspectiveCameras(znear=znear, zfar=zfar, aspect_ratio=fy / fx, fov=fov,
                                 degrees=True, R=R_p3d, T=T_p3d)


def opencv_from_cameras_projection(cameras, image_size
                                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenCV ``(R, tvec, camera_matrix)`` of perspective cameras (PyTorch3D's function).

    ``fx = s K00``, ``fy = s K11`` with ``s = min(H, W) / 2``, principal point
    ``(W/2 - s K02, H/2 - s K12)`` (the image centre for FoV cameras),
    ``R = (R_p3d with columns 0, 1 negated)^T`` and ``tvec = T_p3d`` with entries 0, 1 negated.

    Parameters
    ----------
    cameras : FoVPerspectiveCameras
        ``N`` cameras.
    image_size : (2,) or (N, 2) int
        ``(H, W)`` in pixels.

    Returns
    -------
    R : (N, 3, 3) float64
        OpenCV world-to-camera rotations: ``x_cam = R[n] @ X + tvec[n]``.
    tvec : (N, 3) float64
        OpenCV translations.
    camera_matrix : (N, 3, 3) float64
        ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``; pixel = ``(K x_cam / x_cam_z)[:2]``.

    Raises
    ------
    TypeError
        For cameras that are not ``FoVPerspectiveCameras`` (an orthographic camera has no
        pinhole equivalent).
    ValueError
        For a bad ``image_size``.
    """
    if not isinstance(cameras, FoVPerspectiveCameras):
        raise TypeError("cameras: expected FoVPerspectiveCameras, got "
                         f"{type(cameras).__name__}; only perspective cameras have an OpenCV "
                         "pinhole equivalent")
    sizes = _image_sizes(image_size)
    n = len(cameras)
    if sizes.shape[0] not in (1, n):
        raise ValueError(f"image_size: expected (H, W) or ({n}, 2), got shape {sizes.shape}")
    sizes = np.broadcast_to(sizes.astype(np.float64), (n, 2))
    H, W = sizes[:, 0], sizes[:, 1]
    s = np.minimum(H, W) / 2.0
    Kp = cameras._K()
    camera_matrix = np.zeros((n, 3, 3))
    camera_matrix[:, 0, 0] = s * Kp[:, 0, 0]
    camera_matrix[:, 1, 1] = s * Kp[:, 1, 1]
    camera_matrix[:, 0, 2] = W / 2.0 - s * Kp[:, 0, 2]
    camera_matrix[:, 1, 2] = H / 2.0 - s * Kp[:, 1, 2]
    camera_matrix[:, 2, 2] = 1.0
    R = np.ascontiguousarray((cameras.R * _CV_FLIP[None, None, :]).transpose(0, 2, 1))
    tvec = cameras.T * _CV_FLIP[None, :]
    return R, tvec, camera_matrix


def to_open3d(cameras, image_size) -> list:
    """Open3D pinhole parameters (OpenCV convention) of perspective cameras.

    Parameters
    ----------
    cameras : FoVPerspectiveCameras
        ``N`` cameras.
    image_size : (2,) or (N, 2) int
        ``(H, W)`` in pixels.

    Returns
    -------
    params : list of open3d.camera.PinholeCameraParameters
        ``N`` entries; ``intrinsic`` holds width W, height H and the matrix of
        ``opencv_from_cameras_projection``, ``extrinsic`` the 4x4 world-to-camera matrix
        ``[[R, tvec], [0, 0, 0, 1]]`` (column vectors, x right, y down, z forward).

    Raises
    ------
    TypeError, ValueError
        As ``opencv_from_cameras_projection``.
    """
    import open3d as o3d

    R, tvec, K = opencv_from_cameras_projection(cameras, image_size)
    sizes = np.broadcast_to(_image_sizes(image_size), (len(cameras), 2))
    out = []
    for n in range(len(cameras)):  # one Open3D object per camera
        params = o3d.camera.PinholeCameraParameters()
        params.intrinsic = o3d.camera.PinholeCameraIntrinsic(
            int(sizes[n, 1]), int(sizes[n, 0]), K[n, 0, 0], K[n, 1, 1], K[n, 0, 2], K[n, 1, 2])
        E = np.eye(4)
        E[:3, :3] = R[n]
        E[:3, 3] = tvec[n]
        params.extrinsic = E
        out.append(params)
    return out


def from_open3d(params_list, image_size=None, *, znear=1.0, zfar=100.0
                ) -> FoVPerspectiveCameras:
    """FoVPerspectiveCameras from Open3D pinhole parameters.

    Parameters
    ----------
    params_list : sequence of open3d.camera.PinholeCameraParameters
        ``N`` cameras (a single object is accepted too).
    image_size : (2,) or (N, 2) int, optional
        ``(H, W)``; by default each intrinsic's ``(height, width)``.
    znear, zfar : float or (N,) float64
        Clipping planes of the returned cameras.

    Returns
    -------
    FoVPerspectiveCameras
        ``N`` cameras, via ``cameras_from_opencv_projection``.

    Raises
    ------
    ValueError
        On an empty list, an extrinsic whose bottom row is not (0, 0, 0, 1), or intrinsics that
        ``cameras_from_opencv_projection`` rejects.
    TypeError
        If an entry is not a ``PinholeCameraParameters``.
    """
    import open3d as o3d

    if isinstance(params_list, o3d.camera.PinholeCameraParameters):
        params_list = [params_list]
    params_list = list(params_list)
    if not params_list:
        raise ValueError("params_list: expected at least one PinholeCameraParameters, got none")
    for p in params_list:
        if not isinstance(p, o3d.camera.PinholeCameraParameters):
            raise TypeError("params_list: expected open3d.camera.PinholeCameraParameters, got "
                            f"{type(p).__name__}")
    E = np.stack([np.asarray(p.extrinsic, dtype=np.float64) for p in params_list])
    K = np.stack([np.asarray(p.intrinsic.intrinsic_matrix, dtype=np.float64)
                  for p in params_list])
    if image_size is None:
        image_size = [(p.intrinsic.height, p.intrinsic.width) for p in params_list]
    if np.any(E[:, 3] != np.array([0.0, 0.0, 0.0, 1.0])):
        raise ValueError("params_list: expected extrinsic matrices with bottom row (0, 0, 0, 1)")
    return cameras_from_opencv_projection(E[:, :3, :3], E[:, :3, 3], K, image_size,
                                          znear=znear, zfar=zfar)
