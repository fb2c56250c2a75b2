"""Conversions between geofit's cameras and OpenCV, Open3D, OpenGL (NeRF/Blender) and COLMAP.

Every external convention here is a pinhole camera with column vectors and pixel intrinsics
``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``:

========== ============================== ======================= =============================
convention camera axes                    pose given as           rotation given as
========== ============================== ======================= =============================
geofit     x left, y up, z forward        world-to-view (rows)    ``R`` (camera axes = columns)
OpenCV     x right, y down, z forward     world-to-camera         3x3 matrix ``R``, ``tvec``
COLMAP     x right, y down, z forward     world-to-camera         quaternion ``qw qx qy qz``
OpenGL     x right, y up, z backward      camera-to-world 4x4     (NeRF's ``transform_matrix``)
========== ============================== ======================= =============================

Pixel coordinates follow geofit's (and COLMAP's, nerfstudio's, PyTorch3D's) convention: (0, 0)
is the top-left corner of the top-left pixel, so pixel ``(i, j)`` has its centre at
``(i + 0.5, j + 0.5)`` and a centred principal point is ``(W/2, H/2)``. (OpenCV's own
calibration puts (0, 0) at the centre of the top-left pixel: add 0.5 to its ``cx``, ``cy``.)
"""
from __future__ import annotations

import numpy as np

from .._validate import as_array
from ._util import _ROTATION_TOL, _batch_items, _broadcast_batch, _check_rotations, _image_sizes
from .perspective import FoVPerspectiveCameras, PerspectiveCameras, _PinholeCameras

__all__ = [
    "cameras_from_colmap",
    "cameras_from_opencv_projection",
    "cameras_from_opengl",
    "colmap_from_cameras",
    "from_open3d",
    "matrix_to_quaternion",
    "opencv_from_cameras_projection",
    "opengl_from_cameras",
    "quaternion_to_matrix",
    "to_open3d",
]

# PyTorch3D view (x left, y up, z forward) -> OpenCV camera (x right, y down, z forward).
_CV_FLIP = np.array([-1.0, -1.0, 1.0])
# OpenCV camera (x right, y down, z forward) <-> OpenGL camera (x right, y up, z backward).
_GL_FLIP = np.array([1.0, -1.0, -1.0])
# A principal point within this fraction of W (or H) of the centre counts as centred.
_CENTRE_RTOL = 1e-6


# Parameter descriptions shared by the docstrings below: a line ``%(name)s`` stands for
# ``_DOC[name]`` (as scipy's ``doccer``), so each convention is described once.
_DOC = {
    "cameras_parameters": """Parameters
    ----------
    cameras : FoVPerspectiveCameras or PerspectiveCameras
        ``N`` cameras.
    image_size : (2,) or (N, 2) int
        ``(H, W)`` in pixels.""",
    "image_size": """image_size : (2,) or (N, 2) int
        ``(H, W)`` in pixels.""",
    "clip": """znear, zfar : float or (N,) float64
        Clipping planes of the returned cameras.""",
    "returns_cameras": """Returns
    -------
    FoVPerspectiveCameras or PerspectiveCameras
        As :func:`cameras_from_opencv_projection`.""",
    "as_opencv_errors": """Raises
    ------
    TypeError, ValueError
        As :func:`opencv_from_cameras_projection`.""",
}


def _filldoc(func):
    """Expand the ``%(name)s`` lines of ``func``'s docstring from ``_DOC``."""
    for key, text in _DOC.items():
        func.__doc__ = func.__doc__.replace(f"%({key})s", text)
    return func


def _intrinsics(K: np.ndarray, name: str = "camera_matrix"):
    """``fx, fy, cx, cy`` of ``(N, 3, 3)`` pinhole matrices, validated."""
    if np.any(K[:, 1, 0] != 0) or np.any(K[:, 2] != np.array([0.0, 0.0, 1.0])):
        raise ValueError(f"{name}: expected the form [[fx, 0, cx], [0, fy, cy], "
                         "[0, 0, 1]]; entries K[1, 0] and K[2, :] other than 0, 0, 0, 1 "
                         "are not supported")
    if np.any(K[:, 0, 1] != 0):
        raise ValueError(f"{name}: skew K[0, 1] = {K[np.flatnonzero(K[:, 0, 1])[0], 0, 1]:g}"
                         " is not supported")
    fx, fy, cx, cy = K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]
    if np.any(fx <= 0) or np.any(fy <= 0):
        raise ValueError(f"{name}: expected focal lengths fx, fy > 0, got minimum "
                         f"{min(fx.min(), fy.min()):g}")
    return fx, fy, cx, cy


@_filldoc
def cameras_from_opencv_projection(R, tvec, camera_matrix, image_size, *, znear=1.0,
                                   zfar=100.0):
    """geofit cameras equivalent to OpenCV pinhole cameras (PyTorch3D's function).

    OpenCV maps a world point ``X`` to ``x = R X + tvec`` and pixel ``(K x / x_z)[:2]``. The
    view flip diag(-1, -1, 1) gives ``R_p3d = R^T`` with its first two columns negated and
    ``T_p3d = tvec`` with its first two entries negated. With ``s = min(H, W) / 2``:

    * if every principal point is the image centre ``(W/2, H/2)`` (to 1e-6 W, 1e-6 H), the
      result is a :class:`FoVPerspectiveCameras` with ``fov = 2 atan(s / fy)`` degrees and
      ``aspect_ratio = fy / fx`` (the cameras that every geofit renderer accepts);
    * otherwise a :class:`PerspectiveCameras` with ``focal_length = (fx, fy) / s`` and
      ``principal_point = ((W/2 - cx) / s, (H/2 - cy) / s)``, as PyTorch3D's function does.

    Parameters
    ----------
    R : (N, 3, 3) or (3, 3) float64
        OpenCV world-to-camera rotations (column vectors).
    tvec : (N, 3) or (3,) float64
        OpenCV translations.
    camera_matrix : (N, 3, 3) or (3, 3) float64
        Intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels, (0, 0) at the corner of
        the top-left pixel (see the module notes).
    %(image_size)s
    znear, zfar : float or (N,) float64
        Clipping planes of the returned cameras (OpenCV has none).

    Returns
    -------
    FoVPerspectiveCameras or PerspectiveCameras
        ``N`` cameras whose ``transform_points_screen`` reproduces OpenCV's pixels.

    Raises
    ------
    ValueError
        For non-zero skew, a bottom row other than (0, 0, 1), non-positive focal lengths,
        ``R`` that are not rotations, or bad shapes.

    Examples
    --------
    >>> K = [[100.0, 0.0, 40.0], [0.0, 100.0, 30.0], [0.0, 0.0, 1.0]]
    >>> cams = cameras_from_opencv_projection(np.eye(3), [0.0, 0.0, 5.0], K, (60, 80))
    >>> type(cams).__name__, cams.transform_points_screen([[1.0, 0.5, 0.0]], (60, 80))[0, 0, :2]
    ('FoVPerspectiveCameras', array([60., 40.]))
    """
    b = _broadcast_batch(R=_batch_items(R, "R", (3, 3)), tvec=_batch_items(tvec, "tvec", (3,)),
                         camera_matrix=_batch_items(camera_matrix, "camera_matrix", (3, 3)),
                         image_size=_image_sizes(image_size).astype(np.float64))
    fx, fy, cx, cy = _intrinsics(b["camera_matrix"])
    H, W = b["image_size"][:, 0], b["image_size"][:, 1]
    _check_rotations(b["R"], "R")
    R_p3d = b["R"].transpose(0, 2, 1) * _CV_FLIP[None, None, :]
    T_p3d = b["tvec"] * _CV_FLIP[None, :]
    s = np.minimum(H, W) / 2.0
    centred = (np.abs(cx - W / 2) <= _CENTRE_RTOL * W) & (np.abs(cy - H / 2) <= _CENTRE_RTOL * H)
    if np.all(centred):
        fov = np.degrees(2.0 * np.arctan(s / fy))
        return FoVPerspectiveCameras(znear=znear, zfar=zfar, aspect_ratio=fy / fx, fov=fov,
                                     degrees=True, R=R_p3d, T=T_p3d)
    return PerspectiveCameras(focal_length=np.stack([fx, fy], axis=1) / s[:, None],
                              principal_point=np.stack([W / 2 - cx, H / 2 - cy], axis=1)
                              / s[:, None], znear=znear, zfar=zfar, R=R_p3d, T=T_p3d)


def _pinhole(cameras, image_size, name: str = "cameras") -> np.ndarray:
    """Check ``cameras`` are pinhole cameras; ``image_size`` as an ``(N, 2)`` float array."""
    if not isinstance(cameras, _PinholeCameras):
        raise TypeError(f"{name}: expected FoVPerspectiveCameras or PerspectiveCameras, got "
                        f"{type(cameras).__name__}; only perspective cameras have an OpenCV "
                        "pinhole equivalent")
    sizes = _image_sizes(image_size)
    n = len(cameras)
    if sizes.shape[0] not in (1, n):
        raise ValueError(f"image_size: expected (H, W) or ({n}, 2), got shape {sizes.shape}")
    return np.broadcast_to(sizes.astype(np.float64), (n, 2))


@_filldoc
def opencv_from_cameras_projection(cameras, image_size
                                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenCV ``(R, tvec, camera_matrix)`` of perspective cameras (PyTorch3D's function).

    ``fx = s K00``, ``fy = s K11`` with ``s = min(H, W) / 2``, principal point
    ``(W/2 - s K02, H/2 - s K12)`` (the image centre for FoV cameras, ``K`` the view-to-NDC
    matrix), ``R = (R_p3d with columns 0, 1 negated)^T`` and ``tvec = T_p3d`` with entries 0, 1
    negated. The inverse of :func:`cameras_from_opencv_projection`.

    %(cameras_parameters)s

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
        For cameras that are not perspective (an orthographic camera has no pinhole
        equivalent).
    ValueError
        For a bad ``image_size``.
    """
    sizes = _pinhole(cameras, image_size)
    n = len(cameras)
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


# --------------------------------------------------------------------------------------------
# OpenGL / NeRF-Blender camera-to-world
# --------------------------------------------------------------------------------------------


@_filldoc
def cameras_from_opengl(camera_to_world, camera_matrix, image_size, *, znear=1.0, zfar=100.0):
    """geofit cameras from OpenGL camera-to-world poses (NeRF/Blender ``transform_matrix``).

    An OpenGL camera has x right, y up and looks down -z; ``camera_to_world @ [x, 1]`` maps a
    camera point to the world (column vectors), its last column is the camera centre. The pose is
    turned into OpenCV's world-to-camera ``R = (C_R diag(1, -1, -1))^T``, ``tvec = -R c`` and
    passed with the intrinsics to :func:`cameras_from_opencv_projection`.

    Parameters
    ----------
    camera_to_world : (N, 4, 4), (N, 3, 4), (4, 4) or (3, 4) float64
        Camera-to-world matrices; the top-left 3x3 block must be a rotation (no scale) and a
        4x4's bottom row (0, 0, 0, 1).
    camera_matrix : (N, 3, 3) or (3, 3) float64
        Pixel intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` with y *down* from the
        top-left image corner (NeRF's ``fl_x, fl_y, cx, cy``).
    %(image_size)s
    %(clip)s

    %(returns_cameras)s

    Raises
    ------
    ValueError
        For a rotation block that is not a rotation (``camera_to_world`` named, with the first
        offending index), a bad bottom row, or what :func:`cameras_from_opencv_projection`
        rejects.

    Examples
    --------
    >>> c2w = np.eye(4); c2w[2, 3] = 3.0  # at +3 on z, looking towards the origin
    >>> K = [[50.0, 0.0, 32.0], [0.0, 50.0, 32.0], [0.0, 0.0, 1.0]]
    >>> cams = cameras_from_opengl(c2w, K, (64, 64))
    >>> cams.get_camera_center() + 0.0, cams.transform_points_screen([[0.0, 0.0, 0.0]], (64, 64))
    (array([[0., 0., 3.]]), array([[[32.        , 32.        ,  0.67340067]]]))
    """
    M = _camera_to_world(camera_to_world, "camera_to_world")
    R_cv = (M[:, :3, :3] * _GL_FLIP[None, None, :]).transpose(0, 2, 1)
    tvec = -np.einsum("nij,nj->ni", R_cv, M[:, :3, 3])
    return cameras_from_opencv_projection(R_cv, tvec, camera_matrix, image_size, znear=znear,
                                          zfar=zfar)


def _camera_to_world(camera_to_world, name: str) -> np.ndarray:
    """``(N, 4, 4)`` or ``(N, 3, 4)`` poses as validated ``(N, 3, 4)`` (rotation block checked)."""
    a = as_array(camera_to_world, name)
    item = (4, 4) if a.shape[-2:] == (4, 4) else (3, 4)
    M = _batch_items(a, name, item)
    if item == (4, 4):
        bad = np.flatnonzero(np.any(np.abs(M[:, 3] - [0.0, 0.0, 0.0, 1.0]) > _ROTATION_TOL,
                                    axis=1))
        if bad.size:
            raise ValueError(f"{name}: expected a bottom row (0, 0, 0, 1), got "
                             f"{M[bad[0], 3].tolist()} at index {int(bad[0])}")
    _check_rotations(M[:, :3, :3], name)
    return M[:, :3, :]


@_filldoc
def opengl_from_cameras(cameras, image_size) -> tuple[np.ndarray, np.ndarray]:
    """OpenGL camera-to-world poses and pixel intrinsics of perspective cameras.

    The inverse of :func:`cameras_from_opengl` (via :func:`opencv_from_cameras_projection`).

    %(cameras_parameters)s

    Returns
    -------
    camera_to_world : (N, 4, 4) float64
        OpenGL camera-to-world matrices (x right, y up, looking down -z), bottom row
        (0, 0, 0, 1); the last column holds the camera centres.
    camera_matrix : (N, 3, 3) float64
        Pixel intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (y down).

    %(as_opencv_errors)s
    """
    R, tvec, K = opencv_from_cameras_projection(cameras, image_size)
    M = np.zeros((len(cameras), 4, 4))
    M[:, :3, :3] = R.transpose(0, 2, 1) * _GL_FLIP[None, None, :]
    M[:, :3, 3] = -np.einsum("nji,nj->ni", R, tvec)
    M[:, 3, 3] = 1.0
    return M, K


# --------------------------------------------------------------------------------------------
# COLMAP (quaternions)
# --------------------------------------------------------------------------------------------


def quaternion_to_matrix(quaternions) -> np.ndarray:
    """Rotation matrices of unit quaternions, real part first (PyTorch3D's function).

    Parameters
    ----------
    quaternions : (N, 4) or (4,) float64
        ``(w, x, y, z)``; the norm must be 1 to within 1e-3 (they are normalised).

    Returns
    -------
    R : (N, 3, 3) float64
        Rotations acting on column vectors (``R @ v``).

    Raises
    ------
    ValueError
        For non-finite entries, a bad shape or a norm off 1 by more than 1e-3 (naming the first
        index).

    Examples
    --------
    >>> quaternion_to_matrix([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]).round(12) + 0.0
    array([[[ 0., -1.,  0.],
            [ 1.,  0.,  0.],
            [ 0.,  0.,  1.]]])
    """
    from scipy.spatial.transform import Rotation  # kept local: start-up

    q = _batch_items(quaternions, "quaternions", (4,))
    norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > 1e-3)
    if bad.size:
        raise ValueError(f"quaternions: expected unit quaternions (w, x, y, z), got norm "
                         f"{norm[bad[0]]:.6g} at index {int(bad[0])}")
    return Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()


def matrix_to_quaternion(matrix) -> np.ndarray:
    """Unit quaternions ``(w, x, y, z)`` with ``w >= 0`` of rotation matrices.

    Parameters
    ----------
    matrix : (N, 3, 3) or (3, 3) float64
        Rotations (column-vector convention); must be orthonormal with determinant +1.

    Returns
    -------
    quaternions : (N, 4) float64
        Real part first, ``quaternion_to_matrix(q) == matrix``.

    Raises
    ------
    ValueError
        If a matrix is not a rotation.
    """
    from scipy.spatial.transform import Rotation  # kept local: start-up

    R = _batch_items(matrix, "matrix", (3, 3))
    _check_rotations(R, "matrix")
    q = Rotation.from_matrix(R).as_quat()[:, [3, 0, 1, 2]]
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


@_filldoc
def cameras_from_colmap(qvec, tvec, camera_matrix, image_size, *, znear=1.0, zfar=100.0):
    """geofit cameras from COLMAP poses (``images.txt``) and pinhole intrinsics (``cameras.txt``).

    COLMAP's camera frame is OpenCV's (x right, y down, z forward); an image's pose is the
    world-to-camera rotation as a quaternion ``QW QX QY QZ`` and translation ``TX TY TZ``.

    Parameters
    ----------
    qvec : (N, 4) or (4,) float64
        ``(qw, qx, qy, qz)`` world-to-camera quaternions.
    tvec : (N, 3) or (3,) float64
        World-to-camera translations.
    camera_matrix : (N, 3, 3) or (3, 3) float64
        Pixel intrinsics (``PINHOLE fx fy cx cy``, or ``SIMPLE_PINHOLE f cx cy`` with fx = fy).
    image_size : (2,) or (N, 2) int
        ``(H, W)``: COLMAP's ``HEIGHT``, ``WIDTH``.
    %(clip)s

    %(returns_cameras)s
    """
    return cameras_from_opencv_projection(quaternion_to_matrix(qvec), tvec, camera_matrix,
                                          image_size, znear=znear, zfar=zfar)


@_filldoc
def colmap_from_cameras(cameras, image_size) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """COLMAP ``(qvec, tvec, camera_matrix)`` of perspective cameras.

    %(cameras_parameters)s

    Returns
    -------
    qvec : (N, 4) float64
        World-to-camera quaternions ``(qw, qx, qy, qz)``, ``qw >= 0``.
    tvec : (N, 3) float64
        World-to-camera translations.
    camera_matrix : (N, 3, 3) float64
        Pixel intrinsics (``PINHOLE fx fy cx cy``).

    %(as_opencv_errors)s
    """
    R, tvec, K = opencv_from_cameras_projection(cameras, image_size)
    return matrix_to_quaternion(R), tvec, K


# --------------------------------------------------------------------------------------------
# Open3D
# --------------------------------------------------------------------------------------------


@_filldoc
def to_open3d(cameras, image_size) -> list:
    """Open3D pinhole parameters (OpenCV convention) of perspective cameras.

    %(cameras_parameters)s

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
    import open3d as o3d  # kept local: start-up

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


@_filldoc
def from_open3d(params_list, image_size=None, *, znear=1.0, zfar=100.0
                ):
    """geofit cameras from Open3D pinhole parameters.

    Parameters
    ----------
    params_list : sequence of open3d.camera.PinholeCameraParameters
        ``N`` cameras (a single object is accepted too).
    image_size : (2,) or (N, 2) int, optional
        ``(H, W)``; by default each intrinsic's ``(height, width)``.
    %(clip)s

    Returns
    -------
    FoVPerspectiveCameras or PerspectiveCameras
        ``N`` cameras, via ``cameras_from_opencv_projection``.

    Raises
    ------
    ValueError
        On an empty list, an extrinsic whose bottom row is not (0, 0, 0, 1), or intrinsics that
        ``cameras_from_opencv_projection`` rejects.
    TypeError
        If an entry is not a ``PinholeCameraParameters``.
    """
    import open3d as o3d  # kept local: start-up

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
