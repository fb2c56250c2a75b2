"""Ray samplers: PyTorch3D's NDCMultinomialRaysampler and MonteCarloRaysampler semantics.

The reference rays are PyTorch3D 0.7.9's (float32) stored in tests/data/cameras.npz
(``rays_a/b/c_*``, see tests/data/README.md).
"""
from pathlib import Path

import numpy as np
import pytest

from geofit.cameras import FoVOrthographicCameras, FoVPerspectiveCameras, look_at_view_transform
from geofit.render.volume.raysampling import (MonteCarloRaysampler, NDCMultinomialRaysampler,
                                              RayBundle, ray_bundle_to_ray_points)

CAMERAS = Path(__file__).parent / "data" / "cameras.npz"


@pytest.fixture(scope="module")
def ref(reference_arrays):
    return reference_arrays(CAMERAS.name)


def _camera(ref, which):
    if which == "persp2":
        return FoVPerspectiveCameras(R=ref["persp2_R"], T=ref["persp2_T"], fov=45.0,
                                     aspect_ratio=1.5)
    return FoVPerspectiveCameras(R=ref["persp_R"], T=ref["persp_T"])


@pytest.mark.parametrize("tag,which", [("a", "persp"), ("b", "persp"), ("c", "persp2")])
def test_ndc_grid_rays_match_pytorch3d(ref, tag, which):
    """Origins, directions, lengths, xys and points equal PyTorch3D's (float32 precision)."""
    H, W = ref[f"rays_{tag}_xys"].shape[1:3]
    sampler = NDCMultinomialRaysampler(image_width=W, image_height=H, n_pts_per_ray=4,
                                       min_depth=0.1, max_depth=3.0)
    b = sampler(_camera(ref, which))
    for key in ("origins", "directions", "lengths", "xys"):
        got, want = getattr(b, key), ref[f"rays_{tag}_{key}"]
        assert got.shape == want.shape
        assert np.abs(got - want).max() <= 1e-6 * max(1.0, np.abs(want).max()), key
    pts = ray_bundle_to_ray_points(b)
    assert np.abs(pts - ref[f"rays_{tag}_points"]).max() < 3e-6
    np.testing.assert_allclose(b.points(), pts)


def test_directions_have_unit_view_depth():
    """Directions have view-space z = 1, so lengths are view depths; origins are the centre."""
    R, T = look_at_view_transform(2.7, [10.0, -40.0], [30.0, 150.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    b = NDCMultinomialRaysampler(image_width=6, image_height=5, n_pts_per_ray=7, min_depth=0.5,
                                 max_depth=2.0)(cams)
    dz = np.einsum("nhwi,ni->nhw", b.directions, cams.R[:, :, 2])
    np.testing.assert_allclose(dz, 1.0, atol=1e-12)
    np.testing.assert_allclose(b.origins, np.broadcast_to(cams.get_camera_center()[:, None, None],
                                                          b.origins.shape), atol=1e-12)
    view = cams.transform_points_view(b.points().reshape(2, -1, 3))
    np.testing.assert_allclose(view[..., 2].reshape(2, 5, 6, 7), b.lengths, atol=1e-12)
    # the grid is the rasterizer's pixel centres: row 0 top (largest y), column 0 largest x
    assert b.xys[0, 0, 0, 0] > b.xys[0, 0, -1, 0] and b.xys[0, 0, 0, 1] > b.xys[0, -1, 0, 1]
    unit = NDCMultinomialRaysampler(image_width=6, image_height=5, n_pts_per_ray=7,
                                    min_depth=0.5, max_depth=2.0, unit_directions=True)(cams)
    np.testing.assert_allclose(np.linalg.norm(unit.directions, axis=-1), 1.0, atol=1e-12)
    ortho = NDCMultinomialRaysampler(image_width=3, image_height=3, n_pts_per_ray=2,
                                     min_depth=0.0, max_depth=1.0)(FoVOrthographicCameras())
    np.testing.assert_allclose(ortho.directions, np.broadcast_to([0, 0, 1.0], (1, 3, 3, 3)),
                               atol=1e-12)


def test_random_rays_are_distinct_grid_pixels():
    """n_rays_per_image draws distinct pixel centres per camera, reproducibly by seed."""
    R, T = look_at_view_transform(2.7, 0.0, [0.0, 90.0, 180.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    s = NDCMultinomialRaysampler(image_width=8, image_height=6, n_pts_per_ray=5, min_depth=0.1,
                                 max_depth=3.0, n_rays_per_image=20)
    b = s(cams, seed=3)
    assert b.origins.shape == (3, 20, 1, 3) and b.lengths.shape == (3, 20, 1, 5)
    grid = s.xy_grid().reshape(-1, 2)
    full = NDCMultinomialRaysampler(image_width=8, image_height=6, n_pts_per_ray=5,
                                    min_depth=0.1, max_depth=3.0)(cams)
    for n in range(3):  # cameras
        xy = b.xys[n, :, 0]
        match = np.all(np.abs(xy[:, None, :] - grid[None]) < 1e-12, axis=-1)
        assert np.all(match.sum(axis=1) == 1)              # each is a pixel centre
        idx = np.argmax(match, axis=1)
        assert len(set(idx.tolist())) == 20                # without replacement
        np.testing.assert_allclose(b.directions[n, :, 0],
                                   full.directions[n].reshape(-1, 3)[idx], atol=1e-12)
    np.testing.assert_array_equal(s(cams, seed=3).xys, b.xys)
    assert not np.array_equal(s(cams, seed=4).xys, b.xys)


def test_mask_weights_the_choice():
    """With a mask, rays come only from its non-zero pixels (its smallest count by default)."""
    cams = FoVPerspectiveCameras()
    s = NDCMultinomialRaysampler(image_width=5, image_height=4, n_pts_per_ray=3, min_depth=0.1,
                                 max_depth=3.0)
    mask = np.zeros((1, 4, 5))
    mask[0, 1, 1:4] = 1.0
    b = s(cams, mask=mask, seed=0)
    assert b.xys.shape == (1, 3, 1, 2)
    allowed = s.xy_grid()[1, 1:4]
    got = {tuple(np.round(v, 9)) for v in b.xys[0, :, 0]}
    assert got == {tuple(np.round(v, 9)) for v in allowed}
    more = s(cams, mask=mask, n_rays_per_image=7, seed=0)   # with replacement beyond the mask
    assert more.xys.shape == (1, 7, 1, 2)


def test_stratified_samples_stay_in_their_bins():
    """Stratified lengths are jiggled within the bins around the regular depths."""
    s = NDCMultinomialRaysampler(image_width=4, image_height=4, n_pts_per_ray=10, min_depth=1.0,
                                 max_depth=2.0, stratified_sampling=True)
    b = s(FoVPerspectiveCameras(), seed=1)
    reg = np.linspace(1.0, 2.0, 10)
    mids = 0.5 * (reg[1:] + reg[:-1])
    lo = np.concatenate([[1.0], mids])
    hi = np.concatenate([mids, [2.0]])
    assert np.all(b.lengths >= lo - 1e-12) and np.all(b.lengths <= hi + 1e-12)
    assert np.all(np.diff(b.lengths, axis=-1) >= 0)
    assert not np.allclose(b.lengths, reg)


def test_monte_carlo_sampler():
    """xy uniform in the box, (B, n) layout, reproducible, directions with view z 1."""
    R, T = look_at_view_transform(2.7, 0.0, [0.0, 45.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    s = MonteCarloRaysampler(-0.5, 1.0, -1.0, 0.25, 4000, 6, 0.1, 3.0)
    b = s(cams, seed=0)
    assert b.xys.shape == (2, 4000, 2) and b.lengths.shape == (2, 4000, 6)
    assert b.xys[..., 0].min() >= -0.5 and b.xys[..., 0].max() < 1.0
    assert b.xys[..., 1].min() >= -1.0 and b.xys[..., 1].max() < 0.25
    assert abs(b.xys[..., 0].mean() - 0.25) < 0.03 and abs(b.xys[..., 1].mean() + 0.375) < 0.03
    np.testing.assert_array_equal(s(cams, seed=0).xys, b.xys)
    dz = np.einsum("nki,ni->nk", b.directions, cams.R[:, :, 2])
    np.testing.assert_allclose(dz, 1.0, atol=1e-12)
    # the rays pass through their NDC points
    ndc = cams.transform_points(b.points()[:, :, 3])
    np.testing.assert_allclose(ndc[..., :2], b.xys, atol=1e-10)


def test_raysampler_validation():
    """Invalid settings and inputs raise ValueError/TypeError naming the argument."""
    kw = {"image_width": 4, "image_height": 4, "n_pts_per_ray": 3, "min_depth": 0.1,
          "max_depth": 3.0}
    with pytest.raises(ValueError, match="image_width"):
        NDCMultinomialRaysampler(**{**kw, "image_width": 0})
    with pytest.raises(ValueError, match="n_pts_per_ray"):
        NDCMultinomialRaysampler(**{**kw, "n_pts_per_ray": 2.5})
    with pytest.raises(ValueError, match="max_depth"):
        NDCMultinomialRaysampler(**{**kw, "max_depth": 0.05})
    with pytest.raises(ValueError, match="min_depth"):
        NDCMultinomialRaysampler(**{**kw, "min_depth": float("nan")})
    with pytest.raises(ValueError, match="n_rays_per_image"):
        NDCMultinomialRaysampler(**kw, n_rays_per_image=0)
    s = NDCMultinomialRaysampler(**kw)
    with pytest.raises(TypeError, match="cameras"):
        s("camera")
    with pytest.raises(ValueError, match="mask"):
        s(FoVPerspectiveCameras(), mask=np.ones((1, 3, 4)))
    with pytest.raises(ValueError, match="mask"):
        s(FoVPerspectiveCameras(), mask=-np.ones((1, 4, 4)))
    with pytest.raises(ValueError, match="mask"):
        s(FoVPerspectiveCameras(), mask=np.zeros((1, 4, 4)))
    with pytest.raises(ValueError, match="min_x"):
        MonteCarloRaysampler("a", 1, 0, 1, 10, 3, 0.1, 1.0)
    with pytest.raises(ValueError, match="n_rays_per_image"):
        MonteCarloRaysampler(0, 1, 0, 1, 0, 3, 0.1, 1.0)
    with pytest.raises(TypeError, match="seed"):
        MonteCarloRaysampler(0, 1, 0, 1, 5, 3, 0.1, 1.0)(FoVPerspectiveCameras(), seed="x")
    with pytest.raises(TypeError, match="ray_bundle"):
        ray_bundle_to_ray_points((np.zeros(3),) * 4)
    with pytest.raises(ValueError, match="ray_bundle"):
        ray_bundle_to_ray_points(RayBundle(np.zeros((1, 3)), np.zeros((1, 3)),
                                           np.zeros((2, 4)), np.zeros((1, 2))))
