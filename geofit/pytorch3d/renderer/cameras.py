"""PyTorch3D's cameras: geofit's classes (same conventions and numbers), with ``device=``."""
from __future__ import annotations

from ... import cameras as _gc
from .._common import drop_device, np_
from ..tensor import Tensor

__all__ = ["FoVOrthographicCameras", "FoVPerspectiveCameras", "OpenGLOrthographicCameras",
           "OpenGLPerspectiveCameras", "camera_position_from_spherical_angles",
           "look_at_rotation", "look_at_view_transform"]

FoVPerspectiveCameras = drop_device(_gc.FoVPerspectiveCameras)
FoVOrthographicCameras = drop_device(_gc.FoVOrthographicCameras)
#: PyTorch3D's older name of FoVPerspectiveCameras (the fit_textured_mesh tutorial uses it).
OpenGLPerspectiveCameras = FoVPerspectiveCameras
#: PyTorch3D's older name of FoVOrthographicCameras.
OpenGLOrthographicCameras = FoVOrthographicCameras


def _np_args(kwargs: dict) -> dict:
    return {k: (np_(v) if isinstance(v, (Tensor, list)) and k != "degrees" else v)
            for k, v in kwargs.items() if k != "device"}


def look_at_view_transform(dist=1.0, elev=0.0, azim=0.0, degrees: bool = True, eye=None,
                           at=((0, 0, 0),), up=((0, 1, 0),), device="cpu"):
    """``R (N, 3, 3), T (N, 3)`` of cameras looking at ``at``
    (:func:`geofit.look_at_view_transform`).

    Examples
    --------
    >>> R, T = look_at_view_transform(2.7, 0, 180)
    >>> R.shape, T.shape
    ((1, 3, 3), (1, 3))
    """
    kw = _np_args({"dist": dist, "elev": elev, "azim": azim, "eye": eye, "at": at, "up": up})
    R, T = _gc.look_at_view_transform(degrees=degrees, **kw)
    return Tensor(R), Tensor(T)


def look_at_rotation(camera_position, at=((0, 0, 0),), up=((0, 1, 0),), device="cpu") -> Tensor:
    """(N, 3, 3) rotations of cameras at ``camera_position`` looking at ``at``."""
    return Tensor(_gc.look_at_rotation(np_(camera_position), np_(at), np_(up)))


def camera_position_from_spherical_angles(distance, elevation, azimuth, degrees: bool = True,
                                          device="cpu") -> Tensor:
    """(N, 3) camera centres from distance, elevation and azimuth."""
    return Tensor(_gc.camera_position_from_spherical_angles(
        np_(distance), np_(elevation), np_(azimuth), degrees=degrees))
