"""Camera conversions: OpenCV, OpenGL (NeRF/Blender camera-to-world) and COLMAP round trips.

Reference projections are written out here from each convention's own definition (column
vectors, pixel (0, 0) at the top-left image corner), independently of geofit's conversion code.
"""
from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from geofit.cameras import (
    FoVPerspectiveCameras,
    PerspectiveCameras,
    cameras_from_colmap,
    cameras_from_opencv_projection,
    cameras_from_opengl,
    colmap_from_cameras,
    look_at_view_transform,
    matrix_to_quaternion,
    opencv_from_cameras_projection,
    opengl_from_cameras,
    quaternion_to_matrix,
)

HW = (48, 80)  # non-square: H < W


def _random_rotations(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _colmap_qvec2rotmat(q):
    """COLMAP's own ``qvec2rotmat`` (scripts/python/read_write_model.py), one quaternion."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * y * y - 2 * z * z, 2 * x * y - 2 * w * z, 2 * z * x + 2 * w * y],
        [2 * x * y + 2 * w * z, 1 - 2 * x * x - 2 * z * z, 2 * y * z - 2 * w * x],
        [2 * z * x - 2 * w * y, 2 * y * z + 2 * w * x, 1 - 2 * x * x - 2 * y * y]])


def _pinhole_pixels(R, t, K, X):
    """OpenCV/COLMAP pixels of world points ``X (k, 3)`` for one camera (column vectors)."""
    x = X @ R.T + t
    return (x[:, :2] / x[:, 2:]) * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]


def _scene(rng, n=4, k=20):
    """``n`` cameras looking at the origin from distance ~4 and ``k`` points near the origin."""
    R, T = look_at_view_transform(dist=rng.uniform(3.5, 4.5, n), elev=rng.uniform(-40, 40, n),
                                  azim=rng.uniform(0, 360, n), up=((0.1, 1.0, 0.05),))
    return R, T, rng.uniform(-0.7, 0.7, size=(k, 3))


def test_opencv_round_trip_off_centre_non_square():
    """Off-centre principal points and fx != fy: geofit's pixels equal OpenCV's to 1e-6 px,
    and opencv_from_cameras_projection gives back R, t, K."""
    rng = np.random.default_rng(0)
    Rg, Tg, X = _scene(rng)
    cams0 = FoVPerspectiveCameras(R=Rg, T=Tg)
    R_cv, t_cv, _ = opencv_from_cameras_projection(cams0, HW)
    K = np.tile(np.eye(3), (4, 1, 1))
    K[:, 0, 0] = [90.0, 110.0, 70.0, 120.0]
    K[:, 1, 1] = [95.0, 100.0, 75.0, 118.0]
    K[:, 0, 2] = [35.0, 44.5, 40.0, 52.25]   # W/2 = 40
    K[:, 1, 2] = [20.0, 26.0, 24.0, 30.5]    # H/2 = 24
    cams = cameras_from_opencv_projection(R_cv, t_cv, K, HW, znear=0.1)
    assert isinstance(cams, PerspectiveCameras)
    px = cams.transform_points_screen(X, HW)[..., :2]
    for n in range(4):
        assert_allclose(px[n], _pinhole_pixels(R_cv[n], t_cv[n], K[n], X), atol=1e-6, rtol=0)
    R2, t2, K2 = opencv_from_cameras_projection(cams, HW)
    assert_allclose(R2, R_cv, atol=1e-12)
    assert_allclose(t2, t_cv, atol=1e-12)
    assert_allclose(K2, K, atol=1e-9)


def test_opencv_centred_principal_point_gives_fov_cameras():
    """A centred principal point keeps FoVPerspectiveCameras (usable by every renderer)."""
    K = np.array([[100.0, 0.0, 40.0], [0.0, 100.0, 24.0], [0.0, 0.0, 1.0]])
    cams = cameras_from_opencv_projection(np.eye(3), [0.0, 0.0, 3.0], K, HW)
    assert isinstance(cams, FoVPerspectiveCameras)
    X = np.array([[0.3, -0.2, 0.5]])
    assert_allclose(cams.transform_points_screen(X, HW)[0, :, :2],
                    _pinhole_pixels(np.eye(3), np.array([0.0, 0.0, 3.0]), K, X), atol=1e-9)


def test_perspective_cameras_match_equivalent_fov_cameras():
    """PerspectiveCameras with FoV's focal length and a zero principal point are the same
    projection, NDC z included; pixel rays and unprojection invert transform_points."""
    R, T = look_at_view_transform(2.7, 10.0, [30.0, 200.0])
    fov = FoVPerspectiveCameras(fov=50.0, aspect_ratio=1.2, R=R, T=T)
    t = np.tan(np.radians(25.0))
    persp = PerspectiveCameras(focal_length=[[1 / (t * 1.2), 1 / t]], R=R, T=T)
    assert_allclose(persp.get_full_projection_transform(), fov.get_full_projection_transform(),
                    atol=1e-12)
    off = PerspectiveCameras(focal_length=[1.5, 2.0], principal_point=[[0.2, -0.1]], R=R, T=T)
    rays = off.pixel_rays(HW)
    pts = rays.origins + 2.5 * rays.directions                    # (N, H, W, 3)
    px = np.stack([off[n].transform_points_screen(pts[n].reshape(-1, 3), HW)[0, :, :2]
                   for n in range(2)]).reshape(2, *HW, 2)
    jj, ii = np.meshgrid(np.arange(HW[0]), np.arange(HW[1]), indexing="ij")
    assert_allclose(px[..., 0], np.broadcast_to(ii + 0.5, px.shape[:-1]), atol=1e-9)
    assert_allclose(px[..., 1], np.broadcast_to(jj + 0.5, px.shape[:-1]), atol=1e-9)


def test_renderer_accepts_perspective_cameras():
    """The mesh rasterizer gives the same depth image for FoV cameras and their
    PerspectiveCameras equivalent (an exact re-parametrisation)."""
    from geofit.render import MeshRasterizer, RasterizationSettings
    from geofit.shapes import ico_sphere

    R, T = look_at_view_transform(3.0, 15.0, 40.0)
    fov = FoVPerspectiveCameras(fov=45.0, R=R, T=T)
    Rc, tc, K = opencv_from_cameras_projection(fov, (24, 32))
    persp = PerspectiveCameras(focal_length=np.full((1, 2), 1 / np.tan(np.radians(22.5))),
                               R=R, T=T)
    settings = RasterizationSettings(image_size=(24, 32))
    a = MeshRasterizer(cameras=fov, raster_settings=settings)(ico_sphere(2))
    b = MeshRasterizer(cameras=persp, raster_settings=settings)(ico_sphere(2))
    assert (a.pix_to_face >= 0).sum() > 50
    np.testing.assert_array_equal(a.pix_to_face, b.pix_to_face)
    assert_allclose(a.zbuf, b.zbuf, atol=1e-9)


def test_opengl_round_trip_and_axes():
    """OpenGL camera-to-world: the camera looks down -z, x is right and y up in the image;
    converting geofit -> OpenGL -> geofit keeps pixels to 1e-6 px (non-square, off-centre)."""
    rng = np.random.default_rng(1)
    Rg, Tg, X = _scene(rng)
    cams = PerspectiveCameras(focal_length=[[1.8, 1.6]], principal_point=[[0.1, -0.05]],
                              R=Rg, T=Tg, znear=0.1)
    c2w, K = opengl_from_cameras(cams, HW)
    assert_allclose(c2w[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (4, 1)))
    assert_allclose(c2w[:, :3, 3], cams.get_camera_center(), atol=1e-12)
    # a point 2 units down the camera's -z axis lands on the principal point; +x goes right
    # (pixel x grows), +y goes up (pixel y shrinks)
    local = np.array([[0.0, 0.0, -2.0, 1.0], [0.3, 0.0, -2.0, 1.0], [0.0, 0.3, -2.0, 1.0]])
    for n in range(4):
        world = (local @ c2w[n].T)[:, :3]
        px = cams[n].transform_points_screen(world, HW)[0, :, :2]
        assert_allclose(px[0], K[n, :2, 2], atol=1e-9)
        assert px[1, 0] > px[0, 0] + 5 and abs(px[1, 1] - px[0, 1]) < 1e-9
        assert px[2, 1] < px[0, 1] - 5 and abs(px[2, 0] - px[0, 0]) < 1e-9
    back = cameras_from_opengl(c2w, K, HW, znear=0.1)
    assert_allclose(back.transform_points_screen(X, HW), cams.transform_points_screen(X, HW),
                    atol=1e-6, rtol=0)
    assert_allclose(back.R, cams.R, atol=1e-12)
    assert_allclose(back.T, cams.T, atol=1e-12)


def test_colmap_reprojection_and_round_trip():
    """COLMAP quaternion + t + PINHOLE reproject test points as COLMAP's own formulas do, to
    1e-6 px; colmap_from_cameras gives the pose and intrinsics back (qw >= 0)."""
    rng = np.random.default_rng(2)
    q = _random_rotations(rng, 5)
    q[q[:, 0] < 0] *= -1
    R = np.stack([_colmap_qvec2rotmat(v) for v in q])
    X = rng.uniform(-0.5, 0.5, size=(30, 3))
    t = np.array([0.0, 0.0, 4.0]) - np.einsum("nij,j->ni", R, np.zeros(3))
    t = t + rng.uniform(-0.3, 0.3, size=(5, 3))
    K = np.array([[60.0, 0.0, 37.3], [0.0, 64.0, 25.9], [0.0, 0.0, 1.0]])
    cams = cameras_from_colmap(q, t, K, HW, znear=0.5)
    px = cams.transform_points_screen(X, HW)[..., :2]
    for n in range(5):
        assert_allclose(px[n], _pinhole_pixels(R[n], t[n], K, X), atol=1e-6, rtol=0)
    q2, t2, K2 = colmap_from_cameras(cams, HW)
    assert_allclose(q2, q, atol=1e-12)
    assert_allclose(t2, t, atol=1e-12)
    assert_allclose(K2, np.broadcast_to(K, (5, 3, 3)), atol=1e-9)


def test_quaternion_matrix_round_trip():
    """quaternion_to_matrix agrees with COLMAP's qvec2rotmat; matrix_to_quaternion inverts it
    with w >= 0 (q and -q are the same rotation)."""
    rng = np.random.default_rng(3)
    q = _random_rotations(rng, 50)
    R = quaternion_to_matrix(q)
    assert_allclose(R, np.stack([_colmap_qvec2rotmat(v) for v in q]), atol=1e-12)
    q2 = matrix_to_quaternion(R)
    assert np.all(q2[:, 0] >= 0)
    assert_allclose(q2, q * np.sign(q[:, :1]), atol=1e-12)


_C2W_BAD = np.eye(4)
_C2W_BAD[:3, :3] *= 2.0
_C2W_ROW = np.eye(4)
_C2W_ROW[3, 2] = 1.0
_KC = np.array([[50.0, 0.0, 16.0], [0.0, 50.0, 16.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("call, match", [
    (lambda: cameras_from_opengl(_C2W_BAD, _KC, (32, 32)),
     "camera_to_world: expected rotation matrices"),
    (lambda: cameras_from_opengl(_C2W_ROW, _KC, (32, 32)),
     r"camera_to_world: expected a bottom row \(0, 0, 0, 1\)"),
    (lambda: cameras_from_opengl(np.eye(3), _KC, (32, 32)),
     r"camera_to_world: expected shape \(n, 3, 4\)"),
    (lambda: quaternion_to_matrix([1.0, 0.5, 0.0, 0.0]),
     "quaternions: expected unit quaternions"),
    (lambda: matrix_to_quaternion(np.diag([1.0, 1.0, -1.0])),
     "matrix: expected rotation matrices"),
    (lambda: cameras_from_colmap([1.0, 0.0, 0.0], [0.0, 0.0, 1.0], _KC, (32, 32)),
     r"quaternions: expected shape \(n, 4\)"),
    (lambda: PerspectiveCameras(focal_length=[[1.0, -1.0]]),
     "focal_length: expected positive focal lengths"),
    (lambda: PerspectiveCameras(principal_point=[0.0, 0.0, 0.0]),
     r"principal_point: expected shape \(n, 2\)"),
    (lambda: PerspectiveCameras(znear=0.0), "znear: expected > 0"),
])
def test_invalid_conversion_inputs_raise(call, match):
    with pytest.raises(ValueError, match=match):
        call()
