"""Conversions between geofit's cameras and OpenCV, Open3D, OpenGL (NeRF/Blender) and COLMAP."""
from __future__ import annotations

import numpy as np

from ._util import _batch_items, _broadcast_batch, _image_sizes
from .perspective import FoVPerspectiveCameras

__all__ = ["cameras_from_opencv_projection", "from_open3d", "opencv_from_cameras_projection",
           "to_open3d"]

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
