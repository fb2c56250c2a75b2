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
rays with ``NDCMultinomialRaysampler``'s conventions, :class:`PerspectiveCameras` (focal length
and principal point, for calibrated captures), and conversions to and from OpenCV's, Open3D's,
OpenGL's (NeRF/Blender camera-to-world) and COLMAP's pinhole cameras.

Modules: :mod:`~geofit.cameras.base` (``CamerasBase``, rays, the NDC grid),
:mod:`~geofit.cameras.perspective` (the camera models), :mod:`~geofit.cameras.look_at`,
:mod:`~geofit.cameras.conversions`.
"""
from . import base, conversions, look_at, perspective
from .base import CamerasBase, ProjectedPoints, Rays, ndc_grid
from .conversions import (cameras_from_colmap, cameras_from_opencv_projection,
                          cameras_from_opengl, colmap_from_cameras, from_open3d,
                          matrix_to_quaternion, opencv_from_cameras_projection,
                          opengl_from_cameras, quaternion_to_matrix, to_open3d)
from .look_at import camera_position_from_spherical_angles, look_at_rotation, look_at_view_transform
from .perspective import FoVOrthographicCameras, FoVPerspectiveCameras, PerspectiveCameras

# Each module lists its public names once, in its own __all__.
__all__ = sorted(base.__all__ + conversions.__all__ + look_at.__all__ + perspective.__all__)
