"""PyTorch3D's ``pytorch3d.transforms``: the SO(3) exponential and logarithm maps.

``so3_exp_map`` is Rodrigues' formula written with the tape's operations (so a gradient flows
to ``log_rot``); ``so3_log_map`` is its inverse (values only). Other rotation conversions come
from :class:`scipy.spatial.transform.Rotation`; camera transforms from geofit's cameras.
"""
from __future__ import annotations

import numpy as np

from ._common import missing_names, np_
from .tensor import Tensor, stack

__all__ = ["hat", "so3_exp_map", "so3_exponential_map", "so3_log_map"]


def _rotvecs(x, name: str) -> Tensor:
    t = x if isinstance(x, Tensor) else Tensor(np.asarray(x, np.float64))
    if t.ndim != 2 or t.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (N, 3), got {tuple(t.shape)}")
    return t


def hat(v) -> Tensor:
    """(N, 3, 3) skew-symmetric matrices ``K`` with ``K x = v x x`` (PyTorch3D's ``hat``)."""
    v = _rotvecs(v, "v")
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    o = x * 0.0
    return stack([stack([o, -z, y], 1), stack([z, o, -x], 1), stack([-y, x, o], 1)], 1)


def so3_exp_map(log_rot, eps: float = 0.0001) -> Tensor:
    """(N, 3, 3) rotation matrices of axis-angle vectors (PyTorch3D's ``so3_exp_map``).

    Parameters
    ----------
    log_rot : (N, 3) Tensor or array
        Rotation axis times angle (radians).
    eps : float
        As PyTorch3D: the squared angle is clamped to at least ``eps`` in the two factors
        ``sin(t) / t`` and ``(1 - cos t) / t^2``, so rotations by less than ``sqrt(eps)``
        (0.01 rad) are PyTorch3D's approximation, not the exact exponential.

    Returns
    -------
    (N, 3, 3) Tensor
        ``I + sin(t)/t K + (1 - cos t)/t^2 K^2`` with ``K = hat(log_rot)``, in PyTorch3D's
        convention (points rotate as row vectors: ``X R``); recorded on the tape.

    Examples
    --------
    >>> R = so3_exp_map([[0.0, np.pi / 2, 0.0]])
    >>> np.round(R.numpy()[0], 6) + 0.0
    array([[ 0.,  0.,  1.],
           [ 0.,  1.,  0.],
           [-1.,  0.,  0.]])
    """
    v = _rotvecs(log_rot, "log_rot")
    nrms = (v * v).sum(1)
    theta = nrms.clamp(eps).sqrt()
    fac1 = theta.sin() / theta
    fac2 = (1.0 - theta.cos()) / (theta * theta)
    K = hat(v)
    # K^2 = v v^T - |v|^2 I (no matrix product needed on the tape)
    K2 = v[:, :, None] * v[:, None, :] - nrms[:, None, None] * np.eye(3)
    return fac1[:, None, None] * K + fac2[:, None, None] * K2 + np.eye(3)


#: PyTorch3D's older name of :func:`so3_exp_map` (the volume tutorial imports it).
so3_exponential_map = so3_exp_map


def so3_log_map(R, eps: float = 0.0001, cos_bound: float = 1e-4) -> Tensor:
    """(N, 3) axis-angle vectors of rotation matrices (PyTorch3D's ``so3_log_map``).

    Parameters
    ----------
    R : (N, 3, 3) Tensor or array
        Rotation matrices (PyTorch3D's convention, as :func:`so3_exp_map` returns).
    eps : float
        Lower bound of ``|sin t|`` in the division (PyTorch3D's ``eps``).
    cos_bound : float
        ``cos t`` is clamped to ``[-1 + cos_bound, 1 - cos_bound]`` before ``arccos``.

    Returns
    -------
    (N, 3) Tensor
        Values only: no gradient is recorded (a tensor that requires one raises).
    """
    if isinstance(R, Tensor) and R.requires_grad:
        raise TypeError("so3_log_map: the tape records no gradient here; pass R.detach()")
    M = np_(R, np.float64)
    if M.ndim != 3 or M.shape[1:] != (3, 3):
        raise ValueError(f"R: expected shape (N, 3, 3), got {M.shape}")
    c = np.clip((np.trace(M, axis1=1, axis2=2) - 1.0) / 2.0, -1.0 + cos_bound, 1.0 - cos_bound)
    t = np.arccos(c)
    s = np.sin(t)
    s = np.where(np.abs(s) < eps, np.where(s < 0, -eps, eps), s)
    skew = 0.5 * (M - np.swapaxes(M, 1, 2)) * (t / s)[:, None, None]
    # PyTorch3D's hat_inv of the skew part
    return Tensor(np.stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]], axis=1))


_ROT = ("scipy.spatial.transform.Rotation converts between rotation matrices, quaternions "
        "(as_quat / from_quat, scalar-last), axis-angle and Euler angles")
__getattr__ = missing_names("geofit.pytorch3d.transforms", {
    "quaternion_to_matrix": _ROT, "matrix_to_quaternion": _ROT, "axis_angle_to_matrix": _ROT,
    "matrix_to_axis_angle": _ROT, "euler_angles_to_matrix": _ROT,
    "matrix_to_euler_angles": _ROT, "random_rotations": _ROT, "random_rotation": _ROT,
    "so3_relative_angle": _ROT, "se3_exp_map": _ROT, "se3_log_map": _ROT,
    "Transform3d": "geofit's cameras apply their world-to-view and projection transforms "
                   "(get_world_to_view_transform, transform_points) as 4x4 numpy matrices",
    "Rotate": _ROT, "Translate": "add the translation to the points (numpy)",
    "Scale": "multiply the points (numpy)", "RotateAxisAngle": _ROT,
})
