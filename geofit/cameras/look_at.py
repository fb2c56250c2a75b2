"""Look-at camera placement with PyTorch3D's formulas (including its float32 pole behaviour)."""
from __future__ import annotations

import math
import warnings

import numpy as np

from ._util import (
    _NORMALIZE_EPS,
    _POLE_COS,
    _X_AXIS_FALLBACK_ATOL,
    _batch_items,
    _batch_scalar,
    _broadcast_batch,
    _check_bool,
    _normalize,
)

__all__ = ["camera_position_from_spherical_angles", "look_at_rotation", "look_at_view_transform"]

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
