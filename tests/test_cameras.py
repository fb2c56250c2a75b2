"""Cameras: PyTorch3D parity, projection invariants, Jacobians, rays and OpenCV/Open3D conversions.

Reference data: ``tests/data/cameras.npz`` is an unchanged copy (``np.savez_compressed`` of all
62 arrays) of ``cameras.npz`` from the PyTorch3D parity set (pytorch3d 0.7.9 CPU, torch 2.13;
numpy seed 20250). PyTorch3D's camera math runs in float32, so every reference value is a float32
result cast to float64: it is compared with ``rtol=1e-5`` and an absolute tolerance of 1e-6 times
the value scale (``assert_f32``). Inputs are the float32-rounded values PyTorch3D received.
"""
import doctest
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

import geofit.cameras as gc
from geofit.cameras import (
    FoVOrthographicCameras,
    FoVPerspectiveCameras,
    Rays,
    camera_position_from_spherical_angles,
    cameras_from_opencv_projection,
    from_open3d,
    look_at_rotation,
    look_at_view_transform,
    ndc_grid,
    opencv_from_cameras_projection,
    to_open3d,
)

REF = np.load(Path(__file__).parent / "data" / "cameras.npz")


def assert_f32(actual, desired, scale_atol=1e-6):
    """Compare with a float32-computed reference: rtol 1e-5, atol relative to the value scale."""
    scale = max(1.0, float(np.abs(desired).max()))
    assert_allclose(actual, desired, rtol=1e-5, atol=scale_atol * scale)


def reference_camera(name):
    """The three cameras of the reference set, built with geofit's own look_at."""
    if name == "ortho":
        R, T = look_at_view_transform(20.0, 10.0, 0.0)
        return FoVOrthographicCameras(znear=0.01, R=R, T=T)
    R, T = look_at_view_transform(2.7, 10.0, -150.0)
    if name == "persp":
        return FoVPerspectiveCameras(R=R, T=T, fov=60.0, znear=1.0, zfar=100.0, aspect_ratio=1.0)
    return FoVPerspectiveCameras(R=R, T=T, fov=45.0, znear=1.0, zfar=100.0, aspect_ratio=1.5)


def random_cameras(rng, n=3):
    """A small batch of perspective cameras around the origin with varied intrinsics."""
    R, T = look_at_view_transform(rng.uniform(2, 4, n), rng.uniform(-60, 60, n),
                                  rng.uniform(-180, 180, n), at=rng.uniform(-0.2, 0.2, (n, 3)))
    return FoVPerspectiveCameras(znear=0.5, zfar=50.0, aspect_ratio=rng.uniform(0.7, 1.4, n),
                                 fov=rng.uniform(30, 80, n), R=R, T=T)


def is_rotation(R, tol=1e-12):
    return (np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max() < tol
            and np.abs(np.linalg.det(R) - 1).max() < tol)


# ---------------------------------------------------------------------------------------------
# PyTorch3D parity
# ---------------------------------------------------------------------------------------------


def test_look_at_batched_matches_pytorch3d():
    """One batched call over 51 poses, including elev = +-90, 270 and the near-pole rows."""
    R, T = look_at_view_transform(REF["lookat_dist"], REF["lookat_elev"], REF["lookat_azim"])
    assert R.shape == (51, 3, 3) and T.shape == (51, 3)
    assert_f32(R, REF["lookat_R"])
    assert_f32(T, REF["lookat_T"])


def test_look_at_scalar_calls_match_pytorch3d():
    """Separate calls with Python floats give the same R, T as the batched call."""
    for i, (d, e, a) in enumerate(zip(REF["lookat_dist"], REF["lookat_elev"], REF["lookat_azim"])):
        R, T = look_at_view_transform(float(d), float(e), float(a))
        assert_f32(R[0], REF["lookat_R_scalar_calls"][i])
        assert_f32(T[0], REF["lookat_T_scalar_calls"][i])


def test_look_at_pole_roll_matches_pytorch3d_closed_form():
    """At elev = +-90 the x axis is (cos a, 0, -sin a); at 89.99 it is (-cos a, 0, sin a)."""
    elev, azim = REF["lookat_elev"], np.radians(REF["lookat_azim"])
    R, _ = look_at_view_transform(REF["lookat_dist"], elev, REF["lookat_azim"])
    assert is_rotation(R, 1e-9)
    pole = np.abs(elev) == 90
    assert pole.sum() == 16
    x_pole = np.stack([np.cos(azim), 0 * azim, -np.sin(azim)], axis=1)
    assert_allclose(R[pole, :, 0], x_pole[pole], atol=1e-6)
    near = np.isclose(np.abs(elev), 89.99, atol=1e-4)
    assert near.sum() == 2
    assert_allclose(R[near, :, 0], -x_pole[near], atol=1e-3)
    # without the float32 pole emulation the float64 formula (cos 90 = 6e-17) collapses
    with pytest.warns(RuntimeWarning, match="rotations are singular"):
        R64 = look_at_rotation([6e-17, 1.5, 6e-17])
    assert np.abs(np.linalg.det(R64)) < 1e-6


def test_look_at_eye_matches_pytorch3d():
    """eye/at/up inputs; the third camera has up parallel to the view direction (singular R)."""
    with pytest.warns(RuntimeWarning, match="1 of 3 rotations are singular"):
        R, T = look_at_view_transform(eye=REF["lookat_eye_eye"], at=REF["lookat_eye_at"],
                                      up=REF["lookat_eye_up"])
    assert_f32(R, REF["lookat_eye_R"])
    assert_f32(T, REF["lookat_eye_T"])
    assert is_rotation(R[:2])


def test_look_at_with_at_and_radians_match_pytorch3d():
    R, T = look_at_view_transform(dist=2.0, elev=20.0, azim=30.0, at=[[0.3, -0.1, 0.2]])
    assert_f32(R, REF["lookat_at_R"])
    assert_f32(T, REF["lookat_at_T"])
    R, T = look_at_view_transform(dist=2.7, elev=0.3, azim=-1.2, degrees=False)
    assert_f32(R, REF["lookat_rad_R"])
    assert_f32(T, REF["lookat_rad_T"])


@pytest.mark.parametrize("name", ["persp", "ortho", "persp2"])
def test_camera_maps_match_pytorch3d(name):
    """R, T, NDC, view, 128x128 screen, centre and the three 4x4 matrices."""
    cam = reference_camera(name)
    P = REF["world_points"]
    assert_f32(cam.R, REF[f"{name}_R"])
    assert_f32(cam.T, REF[f"{name}_T"])
    assert_f32(cam.transform_points(P), REF[f"{name}_ndc"])
    assert_f32(cam.transform_points(P[0]), REF[f"{name}_ndc"])
    assert_f32(cam.transform_points_view(P), REF[f"{name}_view"])
    assert_f32(cam.transform_points_screen(P, (128, 128)), REF[f"{name}_screen_128x128"])
    assert_f32(cam.get_camera_center(), REF[f"{name}_center"])
    assert_f32(cam.get_full_projection_transform(), REF[f"{name}_full_proj"])
    assert_f32(cam.get_projection_transform(), REF[f"{name}_proj"])
    assert_f32(cam.get_world_to_view_transform(), REF[f"{name}_world_to_view"])


def test_non_square_screen_matches_pytorch3d():
    """For H != W the shorter side spans NDC [-1, 1]."""
    cam = reference_camera("persp2")
    assert_f32(cam.transform_points_screen(REF["world_points"], (128, 192)),
               REF["persp2_screen_128x192"])
    assert_f32(cam.transform_points_screen(REF["world_points"], [[128, 192]]),
               REF["persp2_screen_128x192"])


def test_unproject_matches_pytorch3d():
    cam = reference_camera("persp")
    out = cam.unproject_points(REF["persp_unproject_in"], world_coordinates=True)
    # PyTorch3D inverts the 4x4 world-to-NDC matrix in float32 (Transform3d.inverse), which
    # costs about 1e-6 relative; geofit inverts analytically in float64.
    assert_f32(out, REF["persp_unproject_out"], scale_atol=3e-6)
    assert_f32(out, REF["world_points"])


@pytest.mark.parametrize("key, name, hw", [("a", "persp", (3, 5)), ("b", "persp", (4, 4)),
                                           ("c", "persp2", (3, 5))])
def test_rays_match_ndc_multinomial_raysampler(key, name, hw):
    """Origins, directions, xys, lengths and points of NDCMultinomialRaysampler (full grid)."""
    rays = reference_camera(name).pixel_rays(hw)
    assert isinstance(rays, Rays)
    assert_f32(rays.origins, REF[f"rays_{key}_origins"])
    assert_f32(rays.directions, REF[f"rays_{key}_directions"])
    assert_f32(rays.xys, REF[f"rays_{key}_xys"])
    lengths = np.linspace(0.1, 3.0, 4)
    assert_f32(np.broadcast_to(lengths, REF[f"rays_{key}_lengths"].shape),
               REF[f"rays_{key}_lengths"])
    assert_f32(rays.points(lengths), REF[f"rays_{key}_points"])
    assert_f32(rays.points(REF[f"rays_{key}_lengths"]), REF[f"rays_{key}_points"])


# ---------------------------------------------------------------------------------------------
# Invariants and closed forms
# ---------------------------------------------------------------------------------------------


def test_look_at_frame_invariants():
    """R is a proper rotation, the centre is the spherical position, and `at` projects to (0, 0)."""
    rng = np.random.default_rng(0)
    n = 20
    dist, elev, azim = rng.uniform(1, 5, n), rng.uniform(-89, 89, n), rng.uniform(-180, 360, n)
    at = rng.uniform(-1, 1, (n, 3))
    R, T = look_at_view_transform(dist, elev, azim, at=at)
    assert is_rotation(R)
    C = camera_position_from_spherical_angles(dist, elev, azim) + at
    assert_allclose(np.linalg.norm(C - at, axis=1), dist, rtol=1e-14)
    cams = FoVPerspectiveCameras(R=R, T=T)
    assert_allclose(cams.get_camera_center(), C, rtol=1e-13, atol=1e-13)
    centre_view = cams.transform_points_view(cams.get_camera_center()[:, None, :])
    assert_allclose(centre_view, 0.0, atol=1e-14)
    view_at = cams.transform_points_view(at[:, None, :])
    assert_allclose(view_at[..., :2], 0.0, atol=1e-13)
    assert_allclose(view_at[..., 2], dist[:, None], rtol=1e-13)
    # the camera y axis (second column) lies in the half-plane of world up
    assert np.all(R[:, 1, 1] > 0)
    assert_allclose(look_at_rotation(C, at), R, atol=1e-15)
    # eye gives the same frame as the spherical angles
    assert_allclose(look_at_view_transform(eye=C, at=at)[0], R, atol=1e-15)


def test_azim_180_looks_at_the_front_from_minus_z():
    """azim = 180 puts the camera on -Z; world +X is then on its left (positive NDC x)."""
    R, T = look_at_view_transform(2.7, 0.0, 180.0)
    cam = FoVPerspectiveCameras(R=R, T=T)
    assert_allclose(cam.get_camera_center(), [[0.0, 0.0, -2.7]], atol=1e-14)
    # a camera on -Z looking to +Z has world +X on its left, i.e. positive NDC x
    ndc = cam.transform_points([[0.5, 0.4, 0.0]])
    assert ndc[0, 0, 0] > 0 and ndc[0, 0, 1] > 0
    # (+1, +1) is the top-left corner: such a point lands in the top-left quadrant of the screen
    px = cam.transform_points_screen([[0.5, 0.4, 0.0]], (64, 64))
    assert px[0, 0, 0] < 32 and px[0, 0, 1] < 32


@pytest.mark.parametrize("make", [
    lambda: random_cameras(np.random.default_rng(1)),
    lambda: FoVOrthographicCameras(znear=-2.0, zfar=7.0, max_y=1.5, min_y=-0.5, max_x=2.0,
                                   min_x=-1.0, scale_xyz=[[1.0, 2.0, 0.5], [0.7, 0.7, 1.0]],
                                   R=look_at_view_transform(3.0, [20.0, -40.0], [10.0, 200.0])[0],
                                   T=look_at_view_transform(3.0, [20.0, -40.0], [10.0, 200.0])[1]),
])
def test_unproject_inverts_transform(make):
    """unproject(ndc xy, view depth) and unproject(ndc xyz, scaled) return the world points."""
    cams = make()
    P = np.random.default_rng(2).uniform(-1, 1, (len(cams), 30, 3))
    ndc = cams.transform_points(P)
    view = cams.transform_points_view(P)
    xy_depth = np.concatenate([ndc[..., :2], view[..., 2:]], axis=-1)
    assert_allclose(cams.unproject_points(xy_depth), P, atol=1e-12)
    assert_allclose(cams.unproject_points(xy_depth, world_coordinates=False), view, atol=1e-12)
    assert_allclose(cams.unproject_points(ndc, scaled_depth_input=True), P, atol=1e-10)
    # the full projection matrix agrees with the composed maps
    h = np.concatenate([P, np.ones(P.shape[:-1] + (1,))], -1) @ cams.get_full_projection_transform()
    assert_allclose(h[..., :3] / h[..., 3:], ndc, atol=1e-12)


def test_projected_z_closed_forms():
    """NDC z is 0 at znear and 1 at zfar for both camera types (scale_xyz z = 1)."""
    z = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 30.0]])
    persp = FoVPerspectiveCameras(znear=2.0, zfar=30.0)
    assert_allclose(persp.transform_points(z)[0, :, 2], [0.0, 1.0], atol=1e-14)
    ortho = FoVOrthographicCameras(znear=2.0, zfar=30.0)
    assert_allclose(ortho.transform_points(z)[0, :, 2], [0.0, 1.0], atol=1e-14)
    # FoV perspective: x_ndc = x / (tan(fov/2) aspect z), y_ndc = y / (tan(fov/2) z)
    cam = FoVPerspectiveCameras(fov=90.0, aspect_ratio=2.0)
    assert_allclose(cam.transform_points([[1.0, 1.0, 4.0]])[0, 0, :2], [0.125, 0.25], rtol=1e-14)


def test_transform_points_eps_clamps_the_divisor():
    cam = FoVPerspectiveCameras()
    on_plane = [[0.5, -0.25, 0.0]]
    assert np.all(np.isinf(cam.transform_points(on_plane)[0, 0, :2]))
    assert_allclose(cam.transform_points(on_plane, eps=0.5)[0, 0, :2],
                    np.array([0.5, -0.25]) * np.sqrt(3) / 0.5, rtol=1e-14)
    behind = [[0.5, 0.0, -0.1]]
    assert_allclose(cam.transform_points(behind, eps=0.5)[0, 0, 0], -0.5 * np.sqrt(3) / 0.5,
                    rtol=1e-14)


@pytest.mark.parametrize("hw", [(4, 4), (3, 5), (6, 2)])
def test_ndc_grid_pixel_centres(hw):
    """Pixel centres are at 1 - (2i+1)/W (square) and land on screen pixel (i + 0.5, j + 0.5)."""
    H, W = hw
    xy = ndc_grid(hw)
    assert xy.shape == (H, W, 2)
    S = min(H, W)
    assert_allclose(xy[0, :, 0], (W - 1 - 2 * np.arange(W)) / S, rtol=1e-15)
    assert_allclose(xy[:, 0, 1], (H - 1 - 2 * np.arange(H)) / S, rtol=1e-15)
    if H == W:
        assert_allclose(xy[0, :, 0], 1 - (2 * np.arange(W) + 1) / W, atol=1e-15)
    # pixel edges: the shorter side spans [-1, 1], the longer [-long/short, long/short]
    short, long_ = (0, 1) if W <= H else (1, 0)
    assert_allclose(np.abs(xy[..., short]).max(), 1 - 1 / S, rtol=1e-15)
    assert_allclose(np.abs(xy[..., long_]).max(), max(H, W) / S - 1 / S, rtol=1e-15)
    cam = FoVPerspectiveCameras(R=look_at_view_transform(3.0, 20.0, 40.0)[0],
                                T=look_at_view_transform(3.0, 20.0, 40.0)[1])
    pts = cam.unproject_points(np.concatenate([xy.reshape(-1, 2), np.full((H * W, 1), 2.5)], 1))
    px = cam.transform_points_screen(pts, hw)[0]
    jj, ii = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    assert_allclose(px[:, 0], ii.ravel() + 0.5, atol=1e-12)
    assert_allclose(px[:, 1], jj.ravel() + 0.5, atol=1e-12)


def test_perspective_rays_geometry():
    """Origins are the camera centre, directions have view z = 1 and pass through the pixel."""
    cams = random_cameras(np.random.default_rng(3))
    rays = cams.pixel_rays((5, 7))
    n = len(cams)
    assert rays.origins.shape == (n, 5, 7, 3) and rays.xys.shape == (n, 5, 7, 2)
    assert_allclose(rays.origins, np.broadcast_to(cams.get_camera_center()[:, None, None],
                                                  (n, 5, 7, 3)), atol=1e-12)
    t = np.array([0.7, 2.0, 4.5])
    pts = rays.points(t)  # (n, 5, 7, 3, 3)
    flat = pts.reshape(n, -1, 3)
    view = cams.transform_points_view(flat).reshape(n, 5, 7, 3, 3)
    assert_allclose(view[..., 2], np.broadcast_to(t, (n, 5, 7, 3)), rtol=1e-12)
    ndc = cams.transform_points(flat).reshape(n, 5, 7, 3, 3)
    assert_allclose(ndc[..., :2], np.broadcast_to(rays.xys[..., None, :], ndc[..., :2].shape),
                    atol=1e-12)


def test_orthographic_rays_geometry():
    """Directions are the view +z axis; origins lie at view depth 0 and project to the pixel."""
    R, T = look_at_view_transform(5.0, [30.0, -10.0], [0.0, 120.0])
    cams = FoVOrthographicCameras(znear=0.1, max_x=2.0, min_x=-2.0, max_y=1.0, min_y=-1.0,
                                  R=R, T=T)
    rays = cams.pixel_rays((3, 4))
    assert_allclose(rays.directions, np.broadcast_to(R[:, None, None, :, 2], (2, 3, 4, 3)),
                    atol=1e-14)
    o = rays.origins.reshape(2, -1, 3)
    assert_allclose(cams.transform_points_view(o)[..., 2], 0.0, atol=1e-12)
    assert_allclose(cams.transform_points(o)[..., :2], rays.xys.reshape(2, -1, 2), atol=1e-12)


def test_batch_broadcasting_indexing_and_extend():
    R, T = look_at_view_transform(3.0, 10.0, [0.0, 90.0, 180.0])
    cams = FoVPerspectiveCameras(fov=[40.0, 50.0, 60.0], znear=0.5, R=R, T=T)
    assert len(cams) == 3 and cams.is_perspective()
    assert cams.znear.shape == (3,) and cams.fov.shape == (3,)
    with pytest.raises(ValueError):
        cams.R[0, 0, 0] = 2.0  # read-only
    P = np.random.default_rng(4).uniform(-1, 1, (6, 3))
    full = cams.transform_points(P)
    for index, expect in [(1, [1]), (-1, [2]), (slice(0, 2), [0, 1]), ([2, 0], [2, 0]),
                          (np.array([True, False, True]), [0, 2])]:
        sub = cams[index]
        assert isinstance(sub, FoVPerspectiveCameras) and len(sub) == len(expect)
        assert_allclose(sub.fov, cams.fov[expect])
        assert_allclose(sub.transform_points(P), full[expect], rtol=1e-15)
    ext = cams.extend(2)
    assert len(ext) == 6
    assert_allclose(ext.fov, [40, 40, 50, 50, 60, 60])
    assert_allclose(ext.transform_points(P), np.repeat(full, 2, axis=0), rtol=1e-15)
    ortho = FoVOrthographicCameras(scale_xyz=[[1, 1, 1], [2, 2, 2]])
    assert not ortho.is_perspective() and len(ortho) == 2
    assert ortho[1].scale_xyz.shape == (1, 3) and len(ortho.extend(3)) == 6
    # per-camera points (N, k, 3)
    per = np.random.default_rng(5).uniform(-1, 1, (3, 4, 3))
    assert_allclose(cams.transform_points(per)[1], cams[1].transform_points(per[1])[0])
    assert "N=3" in repr(cams)


# ---------------------------------------------------------------------------------------------
# Projection Jacobian
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["persp", "ortho"])
def test_projection_jacobian_central_differences(kind):
    """float64 central differences of NDC x, y with respect to each world coordinate."""
    rng = np.random.default_rng(6)
    if kind == "persp":
        cams = random_cameras(rng, 2)
    else:
        R, T = look_at_view_transform(4.0, [10.0, 50.0], [30.0, -70.0])
        cams = FoVOrthographicCameras(max_x=1.5, min_x=-0.5, scale_xyz=[[1.0, 2.0, 1.0]], R=R, T=T)
    P = rng.uniform(-0.8, 0.8, (2, 7, 3))
    xy, J = cams.projection_jacobian(P)
    assert xy.shape == (2, 7, 2) and J.shape == (2, 7, 2, 3)
    assert_allclose(xy, cams.transform_points(P)[..., :2], rtol=1e-14)
    h = 1e-6
    fd = np.empty_like(J)
    for a in range(3):
        dP = np.zeros(3)
        dP[a] = h
        fd[..., a] = (cams.transform_points(P + dP)[..., :2]
                      - cams.transform_points(P - dP)[..., :2]) / (2 * h)
    assert_allclose(J, fd, rtol=1e-6, atol=1e-8 * np.abs(J).max())


def test_projection_jacobian_against_loop_and_closed_form():
    """Vectorised Jacobian equals a per-point chain rule (R^T then d(x/z)); closed form at I."""
    cams = random_cameras(np.random.default_rng(7), 2)
    P = np.random.default_rng(8).uniform(-0.5, 0.5, (4, 3))
    _, J = cams.projection_jacobian(P)
    Kp = cams.get_projection_transform()
    for n in range(len(cams)):
        for k in range(len(P)):
            v = P[k] @ cams.R[n] + cams.T[n]
            sx, sy = Kp[n, 0, 0], Kp[n, 1, 1]
            d_ndc_d_view = np.array([[sx / v[2], 0, -sx * v[0] / v[2] ** 2],
                                     [0, sy / v[2], -sy * v[1] / v[2] ** 2]])
            assert_allclose(J[n, k], d_ndc_d_view @ cams.R[n].T, rtol=1e-12, atol=1e-14)
    # identity pose, fov 90: x_ndc = x / z, so d/dx = 1/z and d/dz = -x/z^2
    _, J = FoVPerspectiveCameras(fov=90.0).projection_jacobian([[0.5, -1.0, 2.0]])
    assert_allclose(J[0, 0], [[0.5, 0.0, -0.125], [0.0, 0.5, 0.25]], rtol=1e-14, atol=1e-16)
    # moving a point along its own ray does not move its projection
    d = np.array([0.5, -1.0, 2.0])
    assert_allclose(J[0, 0] @ d, 0.0, atol=1e-15)


# ---------------------------------------------------------------------------------------------
# OpenCV / Open3D
# ---------------------------------------------------------------------------------------------


def pinhole_pixels(R, tvec, K, P):
    """OpenCV projection: x = R X + t, pixel = (K x / x_z)[:2]; (N, k, 2)."""
    x = np.einsum("nij,kj->nki", R, P) + tvec[:, None, :]
    uvw = np.einsum("nij,nkj->nki", K, x)
    return uvw[..., :2] / uvw[..., 2:]


@pytest.mark.parametrize("hw", [(128, 128), (120, 200), (300, 180)])
def test_opencv_round_trip(hw):
    """OpenCV K, R, t project points to the same pixels; converting back restores the camera."""
    cams = random_cameras(np.random.default_rng(9), 3)
    P = np.random.default_rng(10).uniform(-0.6, 0.6, (25, 3))
    R, tvec, K = opencv_from_cameras_projection(cams, hw)
    assert R.shape == (3, 3, 3) and tvec.shape == (3, 3) and K.shape == (3, 3, 3)
    assert is_rotation(R)
    assert_allclose(K[:, 0, 2], hw[1] / 2)
    assert_allclose(K[:, 1, 2], hw[0] / 2)
    assert_allclose(pinhole_pixels(R, tvec, K, P),
                    cams.transform_points_screen(P, hw)[..., :2], rtol=1e-12)
    back = cameras_from_opencv_projection(R, tvec, K, hw, znear=0.5, zfar=50.0)
    for field in ("R", "T", "fov", "aspect_ratio", "znear", "zfar"):
        assert_allclose(getattr(back, field), getattr(cams, field), rtol=1e-12, atol=1e-14)


def test_cameras_from_opencv_with_unequal_focal_lengths():
    """fx != fy maps to aspect_ratio = fy / fx; per-camera image sizes are honoured."""
    rng = np.random.default_rng(11)
    # world-to-camera in OpenCV convention for two cameras looking at the origin
    C = rng.uniform(-3, 3, (2, 3))
    R_cv = np.swapaxes(look_at_rotation(C) * np.array([-1.0, -1.0, 1.0]), 1, 2)
    tvec = -np.einsum("nij,nj->ni", R_cv, C)
    sizes = np.array([[100, 160], [90, 90]])
    K = np.zeros((2, 3, 3))
    K[:, 0, 0], K[:, 1, 1] = [150.0, 80.0], [120.0, 95.0]
    K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = sizes[:, 1] / 2, sizes[:, 0] / 2, 1.0
    cams = cameras_from_opencv_projection(R_cv, tvec, K, sizes)
    assert_allclose(cams.aspect_ratio, [120 / 150, 95 / 80], rtol=1e-14)
    assert_allclose(cams.get_camera_center(), C, atol=1e-12)
    P = rng.uniform(-0.5, 0.5, (10, 3))
    assert_allclose(cams.transform_points_screen(P, sizes)[..., :2],
                    pinhole_pixels(R_cv, tvec, K, P), rtol=1e-12)


def test_open3d_round_trip():
    o3d = pytest.importorskip("open3d")
    cams = random_cameras(np.random.default_rng(12), 2)
    hw = (96, 160)
    params = to_open3d(cams, hw)
    assert len(params) == 2 and isinstance(params[0], o3d.camera.PinholeCameraParameters)
    assert params[1].intrinsic.width == 160 and params[1].intrinsic.height == 96
    E = np.stack([p.extrinsic for p in params])
    K = np.stack([p.intrinsic.intrinsic_matrix for p in params])
    P = np.random.default_rng(13).uniform(-0.5, 0.5, (9, 3))
    assert_allclose(pinhole_pixels(E[:, :3, :3], E[:, :3, 3], K, P),
                    cams.transform_points_screen(P, hw)[..., :2], rtol=1e-12)
    back = from_open3d(params, znear=0.5, zfar=50.0)
    for field in ("R", "T", "fov", "aspect_ratio"):
        assert_allclose(getattr(back, field), getattr(cams, field), rtol=1e-12, atol=1e-14)
    assert len(from_open3d(params[0], hw)) == 1


# ---------------------------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------------------------

_I = np.eye(3)
_P1 = np.zeros((1, 3))
_CAM = FoVPerspectiveCameras(fov=[50.0, 60.0])
_K_GOOD = np.array([[100.0, 0.0, 32.0], [0.0, 100.0, 24.0], [0.0, 0.0, 1.0]])


def _k(**entries):
    K = _K_GOOD.copy()
    for key, v in entries.items():
        K[int(key[1]), int(key[2])] = v
    return K


@pytest.mark.parametrize("call, match", [
    # cameras
    (lambda: FoVPerspectiveCameras(R=np.eye(3)[None, :2]), r"R: expected shape \(n, 3, 3\)"),
    (lambda: FoVPerspectiveCameras(T=[[0.0, 0.0]]), r"T: expected shape \(n, 3\)"),
    (lambda: FoVPerspectiveCameras(R=2 * _I), "R: expected rotation matrices"),
    (lambda: FoVPerspectiveCameras(R=np.diag([1.0, 1.0, -1.0])), "R: expected rotation"),
    (lambda: FoVPerspectiveCameras(R=np.full((3, 3), np.nan)), "R: expected finite"),
    (lambda: FoVPerspectiveCameras(T=[np.inf, 0, 0]), "T: expected finite"),
    (lambda: FoVPerspectiveCameras(fov=0.0), r"fov: expected values in \(0, 180\) degrees"),
    (lambda: FoVPerspectiveCameras(fov=180.0), r"fov: expected values in \(0, 180\)"),
    (lambda: FoVPerspectiveCameras(fov=[30.0, -5.0]), "fov: expected"),
    (lambda: FoVPerspectiveCameras(fov=3.5, degrees=False), r"fov: expected values in \(0, 3.14"),
    (lambda: FoVPerspectiveCameras(fov=np.nan), "fov: expected finite"),
    (lambda: FoVPerspectiveCameras(znear=0.0), "znear: expected > 0"),
    (lambda: FoVPerspectiveCameras(znear=5.0, zfar=5.0), "zfar: expected zfar > znear"),
    (lambda: FoVPerspectiveCameras(znear=[1.0, 2.0], zfar=1.5), "zfar: expected zfar > znear"),
    (lambda: FoVPerspectiveCameras(aspect_ratio=0.0), "aspect_ratio: expected > 0"),
    (lambda: FoVPerspectiveCameras(znear=[[1.0]]), r"znear: expected a scalar or shape \(n,\)"),
    (lambda: FoVPerspectiveCameras(fov=[]), r"fov: expected a scalar or shape \(n,\)"),
    (lambda: FoVPerspectiveCameras(znear=[1.0, 2.0], fov=[40.0, 50.0, 60.0]),
     "mismatched batch sizes.*znear has 2.*fov has 3"),
    (lambda: FoVPerspectiveCameras(R=np.tile(_I, (2, 1, 1)), T=np.zeros((3, 3))),
     "mismatched batch sizes.*R has 2, T has 3"),
    (lambda: FoVOrthographicCameras(znear=1.0, zfar=0.5), "zfar: expected zfar > znear"),
    (lambda: FoVOrthographicCameras(max_x=-1.0), "max_x: expected max_x > min_x"),
    (lambda: FoVOrthographicCameras(max_y=-2.0), "max_y: expected max_y > min_y"),
    (lambda: FoVOrthographicCameras(scale_xyz=[1.0, 0.0, 1.0]), "scale_xyz: expected positive"),
    (lambda: FoVOrthographicCameras(scale_xyz=[[1.0, 1.0]]), r"scale_xyz: expected shape \(n, 3\)"),
    # point maps
    (lambda: _CAM.transform_points([[1.0, 2.0]]),
     r"points: expected shape \(k, 3\) or \(2, k, 3\)"),
    (lambda: _CAM.transform_points(np.zeros((3, 4, 3))), r"points: expected shape"),
    (lambda: _CAM.transform_points([[np.nan, 0.0, 1.0]]), "points: expected finite"),
    (lambda: _CAM.transform_points([[0.0, 0.0, 1.0]], eps=-1.0), "eps: expected a finite number"),
    (lambda: _CAM.transform_points_view(np.zeros(3)), "points: expected shape"),
    (lambda: _CAM.transform_points_screen(_P1, (0, 8)), "image_size: expected positive"),
    (lambda: _CAM.transform_points_screen(_P1, (8,)), r"image_size: expected \(H, W\)"),
    (lambda: _CAM.transform_points_screen(_P1, (8.5, 8)), "image_size: expected integer"),
    (lambda: _CAM.transform_points_screen(_P1, [[8, 8]] * 3),
     r"image_size: expected \(H, W\) or \(2, 2\)"),
    (lambda: _CAM.unproject_points(np.zeros((4, 2))), "xy_depth: expected shape"),
    (lambda: _CAM.projection_jacobian(np.zeros((2, 2, 2))), "points: expected shape"),
    (lambda: _CAM.pixel_rays((4, -1)), "image_size: expected positive"),
    (lambda: _CAM.pixel_rays([[4, 4], [4, 4]]), r"image_size: expected \(H, W\), shape \(2,\)"),
    (lambda: ndc_grid((4, 4, 4)), r"image_size: expected \(H, W\)"),
    (lambda: _CAM.pixel_rays((2, 2)).points(np.zeros((2, 2))), r"lengths: expected shape \(n,\)"),
    (lambda: _CAM.pixel_rays((2, 2)).points([np.inf]), "lengths: expected finite"),
    # indexing
    (lambda: _CAM[np.array([True])], r"index: expected a boolean mask of shape \(2,\)"),
    (lambda: _CAM[[]], "index: selects no cameras"),
    (lambda: _CAM[2:], "index: selects no cameras"),
    (lambda: _CAM.extend(0), "n: expected an integer >= 1"),
    (lambda: _CAM.extend(1.5), "n: expected an integer >= 1"),
    # look-at
    (lambda: look_at_view_transform(dist=np.ones((2, 2))), r"dist: expected a scalar or shape"),
    (lambda: look_at_view_transform(elev=[0.0, np.nan]), "elev: expected finite"),
    (lambda: look_at_view_transform(dist=[1.0, 2.0], azim=[0.0, 1.0, 2.0]),
     "mismatched batch sizes.*dist has 2.*azim has 3"),
    (lambda: look_at_view_transform(at=[0.0, 0.0]), r"at: expected shape \(n, 3\) or \(3,\)"),
    (lambda: look_at_view_transform(up=[[0.0, 1.0, 0.0, 0.0]]), r"up: expected shape \(n, 3\)"),
    (lambda: look_at_view_transform(eye=[[1.0, 2.0]]), r"eye: expected shape \(n, 3\)"),
    (lambda: look_at_rotation([[0.0, 0.0]]), r"camera_position: expected shape \(n, 3\)"),
    (lambda: look_at_rotation(np.ones((2, 3)), at=np.zeros((3, 3))), "mismatched batch sizes"),
    (lambda: camera_position_from_spherical_angles([1.0, 2.0], [0.0, 1.0, 2.0]),
     "mismatched batch sizes"),
    # OpenCV
    (lambda: cameras_from_opencv_projection(_I * [[1], [1], [-1]], np.zeros(3), _K_GOOD,
                                            (48, 64)), "R: expected rotation matrices"),
    (lambda: cameras_from_opencv_projection(_I, np.zeros(3), _k(c11=0.0), (48, 64)),
     "camera_matrix: expected focal lengths fx, fy > 0"),
    (lambda: cameras_from_opencv_projection(_I, np.zeros(3), _k(c01=0.5), (48, 64)),
     r"camera_matrix: skew K\[0, 1\] = 0.5"),
    (lambda: cameras_from_opencv_projection(_I, np.zeros(3), _k(c21=0.1), (48, 64)),
     r"camera_matrix: expected the form"),
    (lambda: cameras_from_opencv_projection(_I, np.zeros(3), _k(c00=-100.0), (48, 64)),
     "camera_matrix: expected focal lengths fx, fy > 0"),
    (lambda: cameras_from_opencv_projection(_I, np.zeros(3), _K_GOOD[:2], (48, 64)),
     r"camera_matrix: expected shape \(n, 3, 3\)"),
    (lambda: cameras_from_opencv_projection(np.tile(_I, (2, 1, 1)), np.zeros((3, 3)), _K_GOOD,
                                            (48, 64)),
     "mismatched batch sizes.*R has 2, tvec has 3"),
    (lambda: cameras_from_opencv_projection(2 * _I, np.zeros(3), _K_GOOD, (48, 64)),
     "R: expected rotation matrices"),
    (lambda: cameras_from_opencv_projection(_I, np.zeros(3), _K_GOOD, (48, 0)),
     "image_size: expected positive"),
    (lambda: opencv_from_cameras_projection(_CAM, [[8, 8]] * 3),
     r"image_size: expected \(H, W\) or"),
])
def test_invalid_inputs_raise(call, match):
    with pytest.raises(ValueError, match=match):
        call()


@pytest.mark.parametrize("call, match", [
    (lambda: FoVPerspectiveCameras(degrees="yes"), "degrees: expected True or False"),
    (lambda: _CAM.transform_points_screen(np.zeros((1, 3)), (8, 8), with_xyflip=1),
     "with_xyflip: expected True or False"),
    (lambda: _CAM.unproject_points(np.zeros((4, 3)), world_coordinates=None),
     "world_coordinates: expected True or False"),
    (lambda: _CAM.unproject_points(np.zeros((4, 3)), scaled_depth_input="no"),
     "scaled_depth_input: expected True or False"),
    (lambda: look_at_view_transform(degrees=None), "degrees: expected True or False"),
    (lambda: opencv_from_cameras_projection(FoVOrthographicCameras(), (8, 8)),
     "cameras: expected FoVPerspectiveCameras or PerspectiveCameras, got "
     "FoVOrthographicCameras"),
])
def test_invalid_types_raise(call, match):
    with pytest.raises(TypeError, match=match):
        call()


def test_invalid_index_types_and_ranges():
    with pytest.raises(IndexError, match="index: camera 2 is out of range for 2 cameras"):
        _CAM[2]
    with pytest.raises(IndexError, match=r"index: camera indices must lie in \[-2, 1\]"):
        _CAM[[0, 5]]
    with pytest.raises(TypeError, match="index: expected an int"):
        _CAM[0.5]


def test_open3d_invalid_inputs():
    o3d = pytest.importorskip("open3d")
    with pytest.raises(ValueError, match="params_list: expected at least one"):
        from_open3d([])
    with pytest.raises(TypeError, match="params_list: expected open3d.camera.PinholeCamera"):
        from_open3d(["camera"])
    with pytest.raises(TypeError, match="cameras: expected FoVPerspectiveCameras or Persp"):
        to_open3d(FoVOrthographicCameras(), (8, 8))
    p = o3d.camera.PinholeCameraParameters()
    p.intrinsic = o3d.camera.PinholeCameraIntrinsic(64, 48, 100.0, 100.0, 30.0, 24.0)
    E = np.eye(4)
    E[3, 0] = 0.5
    p.extrinsic = E
    with pytest.raises(ValueError, match=r"params_list: expected extrinsic matrices with bottom"):
        from_open3d([p])


def test_open3d_off_centre_principal_point_round_trips():
    """An off-centre Open3D intrinsic gives PerspectiveCameras that reproduce its pixels."""
    o3d = pytest.importorskip("open3d")
    p = o3d.camera.PinholeCameraParameters()
    p.intrinsic = o3d.camera.PinholeCameraIntrinsic(64, 48, 100.0, 90.0, 30.0, 20.0)
    p.extrinsic = np.eye(4)
    cams = from_open3d([p])
    assert type(cams).__name__ == "PerspectiveCameras"
    X = np.array([[0.1, -0.2, 2.0], [0.0, 0.0, 3.0]])
    px = cams.transform_points_screen(X, (48, 64))[0, :, :2]
    expect = (X[:, :2] / X[:, 2:]) * [100.0, 90.0] + [30.0, 20.0]
    assert_allclose(px, expect, atol=1e-9)
    back = to_open3d(cams, (48, 64))[0]
    assert_allclose(back.intrinsic.intrinsic_matrix, p.intrinsic.intrinsic_matrix, atol=1e-9)


def test_degenerate_look_at_warns_and_cannot_make_a_camera():
    """dist=0 raises; eye == at gives PyTorch3D's singular R with a warning; cameras reject it."""
    with pytest.raises(ValueError, match=r"dist: expected non-zero distances, got \[0.0\]"):
        look_at_view_transform(dist=0.0)
    with pytest.raises(ValueError, match="dist: expected non-zero"):
        look_at_view_transform(dist=[2.7, 0.0], azim=[0.0, 90.0])
    with pytest.warns(RuntimeWarning, match="look-at frame undefined"):
        R, T = look_at_view_transform(eye=[[0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="R: expected rotation matrices"):
        FoVPerspectiveCameras(R=R, T=T)


def test_docstring_examples():
    """The Examples sections of every geofit.cameras module run as doctests."""
    import importlib
    import pkgutil

    attempted = 0
    for info in pkgutil.iter_modules(gc.__path__):
        mod = importlib.import_module(f"geofit.cameras.{info.name}")
        result = doctest.testmod(mod, extraglobs=vars(gc),
                                 optionflags=doctest.NORMALIZE_WHITESPACE)
        assert result.failed == 0, mod.__name__
        attempted += result.attempted
    assert attempted > 5
