"""Camera models: PyTorch3D's field-of-view perspective and orthographic cameras, and
:class:`PerspectiveCameras` (focal length and principal point, for calibrated captures)."""
from __future__ import annotations

import math

import numpy as np

from ._util import _batch_items, _batch_scalar, _check_bool
from .base import CamerasBase

__all__ = ["FoVOrthographicCameras", "FoVPerspectiveCameras", "PerspectiveCameras"]


def _check_depth_range(b: dict, perspective: bool = True) -> None:
    if perspective and np.any(b["znear"] <= 0):
        raise ValueError(f"znear: expected > 0 for a perspective camera, got minimum "
                         f"{b['znear'].min():g}")
    if np.any(b["zfar"] <= b["znear"]):
        raise ValueError("zfar: expected zfar > znear for every camera, got "
                         f"{int(np.sum(b['zfar'] <= b['znear']))} cameras with zfar <= znear")


class _PinholeCameras(CamerasBase):
    """Perspective cameras whose projection is ``x_ndc = K00 x / z + K02``, ``y_ndc = K11 y / z
    + K12`` and NDC z ``K22 + K23 / z`` (0 at znear, 1 at zfar)."""

    def is_perspective(self) -> bool:
        return True

    def _K_depth(self, K: np.ndarray) -> np.ndarray:
        znear, zfar = self.znear, self.zfar
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


class FoVPerspectiveCameras(_PinholeCameras):
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
    R, T : (N, 3, 3) or (3, 3), and (N, 3) or (3,) float64, optional
        World-to-view rotations (default identity; must be rotations) and translations
        (default zeros), as :class:`CamerasBase` keeps them.

    Notes
    -----
    All per-camera arguments broadcast to the largest batch size ``N`` (each has 1 or N
    entries); they are stored as read-only ``(N,)`` arrays of the same names.

    Examples
    --------
    >>> from geofit.cameras import look_at_view_transform
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
        _check_depth_range(b)
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

    def _K(self) -> np.ndarray:
        fov = self.fov * (math.pi / 180.0) if self.degrees else self.fov
        znear = self.znear
        max_y = np.tan(fov / 2.0) * znear
        min_y = -max_y
        max_x = max_y * self.aspect_ratio
        min_x = -max_x
        K = np.zeros((len(self), 4, 4))
        K[:, 0, 0] = 2.0 * znear / (max_x - min_x)
        K[:, 1, 1] = 2.0 * znear / (max_y - min_y)
        K[:, 0, 2] = (max_x + min_x) / (max_x - min_x)
        K[:, 1, 2] = (max_y + min_y) / (max_y - min_y)
        return self._K_depth(K)


class PerspectiveCameras(_PinholeCameras):
    """A batch of pinhole cameras given by focal length and principal point in NDC units.

    PyTorch3D's ``PerspectiveCameras`` with ``in_ndc=True``: ``x_ndc = fx x / z + px`` and
    ``y_ndc = fy y / z + py`` (view coordinates, +X left, +Y up), so an off-centre principal
    point and unequal focal lengths are represented exactly. NDC units are those of
    ``transform_points_screen``: ``s = min(H, W) / 2`` pixels per unit, the principal point at
    pixel ``(W/2 - s px, H/2 - s py)`` and focal lengths ``s fx``, ``s fy`` pixels (see
    :func:`cameras_from_opencv_projection`). Unlike PyTorch3D's class it has clipping planes:
    NDC z runs from 0 at ``znear`` to 1 at ``zfar`` as for :class:`FoVPerspectiveCameras`
    (PyTorch3D's gives ``1 / z``), and the renderers use them the same way.

    Parameters
    ----------
    focal_length : float, (N,) or (N, 2) float64
        ``(fx, fy)`` in NDC units, > 0; a scalar (or one value per camera) sets both.
    principal_point : (N, 2) or (2,) float64
        ``(px, py)`` in NDC units (0, 0 is the image centre).
    znear : float or (N,) float64
        Near plane distance, > 0.
    zfar : float or (N,) float64
        Far plane distance, > znear.
    R, T : (N, 3, 3) or (3, 3), and (N, 3) or (3,) float64, optional
        World-to-view rotations (default identity; must be rotations) and translations
        (default zeros), as :class:`CamerasBase` keeps them.

    Notes
    -----
    All per-camera arguments broadcast to the largest batch size ``N``; they are stored as
    read-only arrays ``focal_length (N, 2)``, ``principal_point (N, 2)``, ``znear``, ``zfar``.

    Examples
    --------
    >>> cam = PerspectiveCameras(focal_length=2.0, principal_point=(0.25, 0.0))
    >>> cam.transform_points([[0.5, 0.5, 2.0]])[0, 0, :2]
    array([0.75, 0.5 ])
    """

    _FIELDS = ("focal_length", "principal_point", "znear", "zfar")

    def __init__(self, focal_length=1.0, principal_point=((0.0, 0.0),), znear=1.0, zfar=100.0,
                 R=None, T=None):
        if np.ndim(focal_length) <= 1:
            f = _batch_scalar(focal_length, "focal_length")
            f = np.stack([f, f], axis=1)
        else:
            f = _batch_items(focal_length, "focal_length", (2,))
        b = self._prepare(R, T, focal_length=f,
                          principal_point=_batch_items(principal_point, "principal_point", (2,)),
                          znear=_batch_scalar(znear, "znear"), zfar=_batch_scalar(zfar, "zfar"))
        _check_depth_range(b)
        if np.any(b["focal_length"] <= 0):
            raise ValueError("focal_length: expected positive focal lengths, got minimum "
                             f"{b['focal_length'].min():g}")
        self._set(b)

    def _K(self) -> np.ndarray:
        K = np.zeros((len(self), 4, 4))
        K[:, 0, 0] = self.focal_length[:, 0]
        K[:, 1, 1] = self.focal_length[:, 1]
        K[:, 0, 2] = self.principal_point[:, 0]
        K[:, 1, 2] = self.principal_point[:, 1]
        return self._K_depth(K)


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
    R, T : (N, 3, 3) or (3, 3), and (N, 3) or (3,) float64, optional
        World-to-view rotations (default identity; must be rotations) and translations
        (default zeros), as :class:`CamerasBase` keeps them.

    Notes
    -----
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
        _check_depth_range(b, perspective=False)
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
