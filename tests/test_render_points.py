"""Point rasterization and compositing: PyTorch3D parity, a naive loop reference, edge cases."""
import heapq
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from geofit import PointCloud, Pointclouds
from geofit.cameras import FoVOrthographicCameras, FoVPerspectiveCameras, look_at_view_transform
from geofit.render.points import rasterizer as points_mod
from geofit.render.points.compositing import (
    AlphaCompositor,
    NormWeightedCompositor,
    add_background_color,
)
from geofit.render.points import (
    PointFragments,
    PointsRasterizationSettings,
    PointsRasterizer,
    PointsRenderer,
    rasterize_points,
)

DATA = Path(__file__).parent / "data"
CROP = 32


# ------------------------------------------------------------------ naive references

def _naive_rasterize(xy, z, radius, image, n_images, H, W, K):
    """PyTorch3D's RasterizePointsNaiveCpu as a loop: a bounded max-heap on (z, index) per pixel."""
    S = min(H, W)
    idx = np.full((n_images, H, W, K), -1)
    zbuf = np.full((n_images, H, W, K), -1.0)
    dists = np.full((n_images, H, W, K), -1.0)
    for n in range(n_images):
        for j in range(H):
            yf = (H - 1 - 2 * j) / S
            for i in range(W):
                xf = (W - 1 - 2 * i) / S
                heap = []
                for p in range(len(z)):
                    if image[p] != n or z[p] < 0:
                        continue
                    d2 = (xf - xy[p, 0]) ** 2 + (yf - xy[p, 1]) ** 2
                    if d2 < radius[p] ** 2:
                        heapq.heappush(heap, (-z[p], -p, d2))
                        if len(heap) > K:
                            heapq.heappop(heap)
                hits = sorted((-a, -b, c) for a, b, c in heap)
                for k, (zz, p, d2) in enumerate(hits):
                    idx[n, j, i, k], zbuf[n, j, i, k], dists[n, j, i, k] = p, zz, d2
    return idx, zbuf, dists


def _naive_composite(idx, w, feats, alpha: bool):
    out = np.zeros(idx.shape[:3] + (feats.shape[1],))
    for pix in np.ndindex(idx.shape[:3]):
        T, acc, tot = 1.0, np.zeros(feats.shape[1]), 0.0
        for k in range(idx.shape[3]):
            p = idx[pix + (k,)]
            if p < 0:
                continue
            a = w[pix + (k,)]
            acc += (a * T if alpha else a) * feats[p]
            T *= 1 - a
            tot += a
        out[pix] = acc if alpha else acc / max(tot, 1e-4)
    return out


def _random_cloud(rng, n, spread=1.0, depth=(1.0, 3.0)):
    xy = rng.uniform(-spread, spread, (n, 2))
    z = rng.uniform(*depth, n)
    return np.column_stack([xy, z])


# ------------------------------------------------------------------ PyTorch3D parity

@pytest.fixture(scope="module")
def ref():
    return dict(np.load(DATA / "render_points.npz"))


def _ref_camera(ref, cam):
    if cam == "ortho":
        return FoVOrthographicCameras(R=ref["ortho_R"], T=ref["ortho_T"], znear=0.01)
    return FoVPerspectiveCameras(R=ref["persp_R"], T=ref["persp_T"])


CASES = [(cam, rk, r) for cam in ("ortho", "persp") for rk, r in (("r010", 0.01), ("r003", 0.003))]


@pytest.mark.parametrize("cam,rk,radius", CASES)
def test_fragments_match_pytorch3d(ref, cam, rk, radius):
    """idx, zbuf and dists equal PyTorch3D's on a 32x32 crop (idx exactly, values to float32)."""
    cloud = PointCloud(ref["points"], ref["colours"])
    settings = PointsRasterizationSettings(image_size=128, radius=radius, points_per_pixel=10)
    f = PointsRasterizer(_ref_camera(ref, cam), settings)(cloud)
    r0, c0 = ref[f"{cam}_crop"]
    sl = (0, slice(r0, r0 + CROP), slice(c0, c0 + CROP))
    kept = ref["kept"]
    idx = np.where(f.idx[sl] >= 0, kept[np.maximum(f.idx[sl], 0)], -1)
    p = f"{cam}_{rk}_"
    assert np.mean(idx == ref[p + "idx"]) >= 0.99
    same = (idx == ref[p + "idx"]) & (idx >= 0)
    n_ref = np.sum(ref[p + "idx"] >= 0)
    assert n_ref > 200 and same.sum() >= 0.99 * n_ref
    assert_allclose(f.zbuf[sl][same], ref[p + "zbuf"][same], rtol=1e-6)
    assert_allclose(f.dists[sl][same], ref[p + "dists"][same], atol=2e-8)
    assert_array_equal(f.zbuf[sl][idx < 0], -1.0)


@pytest.mark.parametrize("cam,rk,radius", CASES)
@pytest.mark.parametrize("name,compositor", [
    ("alpha", AlphaCompositor()),
    ("alpha_blue", AlphaCompositor(background_color=(0, 0, 1))),
    ("normw_red", NormWeightedCompositor(background_color=(1, 0, 0))),
])
def test_images_match_pytorch3d(ref, cam, rk, radius, name, compositor):
    """Rendered images differ from PyTorch3D's by far less than 1/255 on average."""
    cloud = PointCloud(ref["points"], ref["colours"])
    settings = PointsRasterizationSettings(image_size=128, radius=radius, points_per_pixel=10)
    renderer = PointsRenderer(PointsRasterizer(_ref_camera(ref, cam), settings), compositor)
    img = renderer(cloud)
    assert img.shape == (1, 128, 128, 3)
    r0, c0 = ref[f"{cam}_crop"]
    crop = img[0, r0:r0 + CROP, c0:c0 + CROP]
    err = np.abs(crop - ref[f"{cam}_{rk}_{name}"])
    assert err.mean() < 1e-4
    assert err.max() < 0.01


# ------------------------------------------------------------------ naive loop reference

@pytest.mark.parametrize("threads", [1, 2, 3])
@pytest.mark.parametrize("H,W", [(9, 9), (7, 12), (11, 6)])
def test_rasterize_points_matches_naive_loop(H, W, threads, monkeypatch):
    """The vectorised core equals the heap-per-pixel loop, also for non-square images and when
    the rows are split into bands for threads."""
    monkeypatch.setattr(points_mod, "get_num_threads", lambda: threads)
    monkeypatch.setattr(points_mod, "_THREAD_MIN_POINTS", 0)
    rng = np.random.default_rng(1)
    n = 60
    xy = rng.uniform(-1.3, 1.3, (n, 2))
    z = rng.uniform(-0.5, 2.0, n)
    z[5:10] = z[4]                     # equal depths: lower index first
    xy[5:10] = xy[4]                   # ... at the same place
    radius = rng.uniform(0.0, 0.5, n)
    image = rng.integers(0, 2, n)
    image.sort()
    for K in (1, 3, 8):
        got = rasterize_points(xy, z, radius, image, 2, (H, W), K)
        want = _naive_rasterize(xy, z, radius, image, 2, H, W, K)
        assert_array_equal(got[0], want[0])
        assert_allclose(got[1], want[1], rtol=0, atol=0)
        assert_allclose(got[2], want[2], rtol=1e-12, atol=1e-15)


def test_chunked_candidates_match_single_pass(monkeypatch):
    """Processing candidates in many front-to-back chunks gives the same fragments as one pass."""
    rng = np.random.default_rng(2)
    n = 400
    xy = rng.uniform(-1, 1, (n, 2))
    z = rng.uniform(0, 1, n)
    z[::7] = 0.5
    radius = np.full(n, 0.3)
    image = np.zeros(n, dtype=np.int64)
    one = rasterize_points(xy, z, radius, image, 1, (16, 16), 6)
    monkeypatch.setattr(points_mod, "_CHUNK_CANDIDATES", 50)
    many = rasterize_points(xy, z, radius, image, 1, (16, 16), 6)
    for a, b in zip(one, many):
        assert_array_equal(a, b)
    monkeypatch.setattr(points_mod, "_THREAD_MIN_POINTS", 0)   # two row bands, in threads
    threaded = rasterize_points(xy, z, radius, image, 1, (16, 16), 6)
    for a, b in zip(one, threaded):
        assert_array_equal(a, b)


def test_rasterizer_batches_match_naive_loop():
    """N clouds with N cameras, one cloud with N cameras and N clouds with one camera."""
    rng = np.random.default_rng(3)
    clouds = Pointclouds([PointCloud(_random_cloud(rng, 30)), PointCloud(_random_cloud(rng, 20))])
    R, T = look_at_view_transform(2.5, [0.0, 30.0], [0.0, 40.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    s = PointsRasterizationSettings(image_size=(8, 10), radius=0.2, points_per_pixel=4)
    f = PointsRasterizer(cams, s)(clouds)
    assert f.idx.shape == (2, 8, 10, 4)
    packed = clouds.points_packed()
    for n, (lo, hi) in enumerate([(0, 30), (30, 50)]):
        ndc = cams[n].transform_points(packed[lo:hi])[0]
        view = cams[n].transform_points_view(packed[lo:hi])[0]
        want = _naive_rasterize(ndc[:, :2], view[:, 2], np.full(hi - lo, 0.2),
                                np.zeros(hi - lo, int), 1, 8, 10, 4)
        assert_array_equal(f.idx[n], np.where(want[0][0] >= 0, want[0][0] + lo, -1))
        assert_allclose(f.zbuf[n], want[1][0], atol=1e-12)
        assert_allclose(f.dists[n], want[2][0], atol=1e-12)
    # one cloud, two cameras: each image indexes the same cloud
    f1 = PointsRasterizer(cams, s)(clouds[0])
    assert_array_equal(f1.idx[0], f.idx[0])
    single = PointsRasterizer(cams[1], s)(clouds[0])
    assert_array_equal(f1.idx[1], single.idx[0])
    # two clouds, one camera
    f2 = PointsRasterizer(cams[0], s)(clouds)
    assert_array_equal(f2.idx[0], f.idx[0])
    second = PointsRasterizer(cams[0], s)(clouds[1])
    assert_array_equal(f2.idx[1], np.where(second.idx[0] >= 0, second.idx[0] + 30, -1))


def test_fragment_invariants():
    """Hits lie strictly inside the disc, depths ascend along K, -1 slots are trailing."""
    rng = np.random.default_rng(4)
    cloud = PointCloud(_random_cloud(rng, 3000, 0.8, (0.5, 2.0)))
    s = PointsRasterizationSettings(image_size=(24, 32), radius=0.08, points_per_pixel=5,
                                    dtype=np.float64)
    f = PointsRasterizer(FoVOrthographicCameras(), s)(cloud)
    v = f.idx >= 0
    assert v.any() and (~v).any()
    assert np.all(f.dists[v] < 0.08 ** 2) and np.all(f.dists[v] >= 0)
    assert np.all(np.diff(np.where(v, f.zbuf, 1e9), axis=-1) >= 0)
    assert np.all(v[..., 1:] <= v[..., :-1])                    # no hole before a hit
    assert_array_equal(f.zbuf[v], cloud.points[f.idx[v], 2])   # ortho at identity: z = depth
    assert_array_equal(f.radius[v], 0.08)
    assert_array_equal(f.depth, f.zbuf[..., 0])
    assert_array_equal(f.mask, f.idx[..., 0] >= 0)


# ------------------------------------------------------------------ compositors

def test_compositors_match_naive_loop():
    """Alpha (front to back) and normalised weighted sums equal the per-pixel loops."""
    rng = np.random.default_rng(5)
    idx = rng.integers(0, 7, (2, 3, 4, 5))
    counts = rng.integers(0, 6, (2, 3, 4))
    idx[np.arange(5) >= counts[..., None]] = -1
    w = rng.uniform(0, 1, idx.shape)
    w[0, 0, 0, :] = 1e-6                                       # below the 1e-4 clamp
    feats = rng.uniform(0, 1, (7, 4))
    assert_allclose(AlphaCompositor()(idx, w, feats), _naive_composite(idx, w, feats, True),
                    rtol=1e-13, atol=1e-15)
    assert_allclose(NormWeightedCompositor()(idx, w, feats),
                    _naive_composite(idx, w, feats, False), rtol=1e-13, atol=1e-15)


def test_background_replaces_only_uncovered_pixels():
    """The background colour fills idx[..., 0] < 0; covered pixels keep their leftover transmittance."""
    idx = np.array([[[[0, -1]], [[-1, -1]]]])              # (1, 2, 1, 2)
    w = np.array([[[[0.5, 0.0]], [[0.0, 0.0]]]])
    feats = np.array([[1.0, 0.0, 0.0]])
    img = AlphaCompositor(background_color=(0, 0, 1))(idx, w, feats)
    assert_allclose(img[0, 0, 0], [0.5, 0, 0])             # not blended with blue
    assert_allclose(img[0, 1, 0], [0, 0, 1])
    assert_allclose(AlphaCompositor()(idx, w, feats)[0, 1, 0], [0, 0, 0])
    # scalar backgrounds fill every channel; C - 1 channels get alpha 1 appended
    rgba = np.array([[0.2, 0.4, 0.6, 0.8]])
    out = NormWeightedCompositor(background_color=(0, 1, 0))(idx, w, rgba)
    assert_allclose(out[0, 1, 0], [0, 1, 0, 1])
    assert_allclose(out[0, 0, 0], rgba[0])
    assert_allclose(AlphaCompositor(background_color=0.25)(idx, w, feats)[0, 1, 0], [0.25] * 3)
    # a per-call override
    assert_allclose(AlphaCompositor()(idx, w, feats, background_color=(1, 1, 1))[0, 1, 0], [1] * 3)
    assert_allclose(AlphaCompositor((1, 1, 1))(idx, w, feats, background_color=None)[0, 1, 0], 0)


def test_renderer_weights_are_pytorch3d_weights():
    """PointsRenderer feeds 1 - d^2/r^2 to the compositor: a point at a pixel centre is opaque."""
    # 1x1 image, ortho, point exactly at the centre (x = y = 0) in front of a second point
    cloud = PointCloud([[0.0, 0.0, 1.0], [0.3, 0.0, 2.0]], [[1.0, 0, 0], [0, 1.0, 0]])
    s = PointsRasterizationSettings(image_size=1, radius=0.6, points_per_pixel=2)
    r = PointsRenderer(PointsRasterizer(FoVOrthographicCameras(), s), AlphaCompositor())
    out = r.render(cloud)
    assert_array_equal(out.fragments.idx[0, 0, 0], [0, 1])
    assert_allclose(out.fragments.weights()[0, 0, 0], [1.0, 1 - 0.09 / 0.36])
    assert_allclose(out.images[0, 0, 0], [1, 0, 0])        # alpha 1 hides the green point
    assert_allclose(out.depth[0], [[1.0]])
    nw = PointsRenderer(PointsRasterizer(FoVOrthographicCameras(), s), NormWeightedCompositor())
    assert_allclose(nw(cloud)[0, 0, 0], [1, 0.75, 0] / np.float64(1.75))


# ------------------------------------------------------------------ beyond PyTorch3D

def test_world_radius_shrinks_with_depth():
    """radius_units='world': r_ndc = r K00 / z (perspective), r K00 (orthographic)."""
    cloud = PointCloud([[0.0, 0.0, 1.0], [0.5, 0.0, 4.0]])
    cam = FoVPerspectiveCameras(fov=90.0)                  # K00 = 1
    s = PointsRasterizationSettings(image_size=64, radius=0.2, points_per_pixel=2,
                                    radius_units="world")
    f = PointsRasterizer(cam, s)(cloud)
    near, far = f.idx[0] == 0, f.idx[0] == 1
    assert_allclose(f.radius[0][near], 0.2)
    assert_allclose(f.radius[0][far], 0.05)
    # covered pixel counts follow the disc areas pi (r S / 2)^2 (to a pixel-sampling error)
    assert abs(near.sum() - np.pi * (0.2 * 32) ** 2) < 0.1 * np.pi * (0.2 * 32) ** 2
    assert abs(far.sum() - np.pi * (0.05 * 32) ** 2) < 3 * np.pi * 0.05 * 32 * 2
    ortho = FoVOrthographicCameras(scale_xyz=(2.0, 2.0, 1.0))
    fo = PointsRasterizer(ortho, s)(cloud)
    assert_allclose(fo.radius[fo.idx >= 0], 0.4)


def test_per_point_radius():
    """A (P,) radius gives each point its own disc; the weights use each point's radius."""
    cloud = PointCloud([[0.5, 0.0, 1.0], [-0.5, 0.0, 1.0]], [[1.0], [2.0]])
    s = PointsRasterizationSettings(image_size=32, radius=np.array([0.1, 0.3]), points_per_pixel=1)
    f = PointsRasterizer(FoVOrthographicCameras(), s)(cloud)
    area0, area1 = np.sum(f.idx == 0), np.sum(f.idx == 1)
    assert area1 > 6 * area0 > 0
    assert_allclose(f.radius[f.idx == 1], 0.3)
    assert np.all((f.weights()[f.idx >= 0] > 0) & (f.weights()[f.idx >= 0] <= 1))


# ------------------------------------------------------------------ edge cases

def _renderer(cam=None, radius=0.1, bg=(0.0, 0.0, 1.0)):
    s = PointsRasterizationSettings(image_size=16, radius=radius, points_per_pixel=4)
    return PointsRenderer(PointsRasterizer(cam or FoVOrthographicCameras(), s),
                          AlphaCompositor(background_color=bg))


def test_empty_cloud_zero_radius_and_points_behind_give_background():
    """No point reaches a pixel: all idx -1, the image is the background, nothing is NaN."""
    rng = np.random.default_rng(6)
    P = _random_cloud(rng, 200, 0.5)
    feats = rng.uniform(0, 1, (200, 3))
    cases = [
        (_renderer(), PointCloud(np.zeros((0, 3)), np.zeros((0, 3)))),
        (_renderer(radius=0.0), PointCloud(P, feats)),
        (_renderer(), PointCloud(P * [1, 1, -1], feats)),
        (_renderer(FoVPerspectiveCameras()), PointCloud(P * [1, 1, -1], feats)),
        (_renderer(FoVPerspectiveCameras()), PointCloud(P * [1, 1, 0], feats)),  # on the camera plane
    ]
    for r, cloud in cases:
        out = r.render(cloud)
        assert np.all(out.fragments.idx == -1)
        assert np.all(np.isfinite(out.images))
        assert_array_equal(out.images, np.broadcast_to([0.0, 0.0, 1.0], out.images.shape))
        assert_array_equal(out.depth, -1.0)
    # without a background the empty image is 0
    assert_array_equal(_renderer(bg=None)(PointCloud(P * [1, 1, -1], feats)), 0.0)


def test_points_at_depth_zero_are_kept_by_orthographic_cameras():
    """PyTorch3D skips only z < 0: an orthographic camera keeps a point at z == 0."""
    f = PointsRasterizer(FoVOrthographicCameras(znear=-1.0),
                         PointsRasterizationSettings(4, 0.6, 1))(PointCloud([[0.0, 0.0, 0.0]]))
    assert np.sum(f.idx >= 0) == 4


def test_huge_coordinates_give_no_warning_or_nan():
    """Points near the float64 limit overflow in the projection: they are dropped quietly."""
    P = np.array([[1e308, 1e308, 1e308], [-1e308, 1e308, 1e308], [0.0, 0.0, 2.0]])
    cloud = PointCloud(P, np.eye(3))
    for cam in (FoVPerspectiveCameras(R=look_at_view_transform(2.7, 30, 40)[0]),
                FoVOrthographicCameras()):
        out = _renderer(cam).render(cloud)
        assert np.all(np.isfinite(out.images))
        assert set(np.unique(out.fragments.idx)) <= {-1, 2}


def test_nan_points_raise():
    with pytest.raises(ValueError, match="points: expected finite values"):
        PointCloud([[0.0, np.nan, 1.0]], [[1.0, 0, 0]])


# ------------------------------------------------------------------ validation

@pytest.mark.parametrize("kwargs,match", [
    ({"image_size": 0}, "image_size"),
    ({"image_size": (4, 0)}, r"image_size\[1\]"),
    ({"image_size": (4,)}, "image_size"),
    ({"image_size": 2.5}, "image_size"),
    ({"points_per_pixel": 0}, "points_per_pixel"),
    ({"radius": -0.1}, "radius"),
    ({"radius": np.nan}, "radius"),
    ({"radius": "big"}, "radius"),
    ({"radius": np.array([0.1, -1.0])}, "radius"),
    ({"radius": np.ones((2, 2))}, "radius"),
    ({"radius_units": "pixels"}, "radius_units"),
])
def test_settings_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        PointsRasterizationSettings(**kwargs)


@pytest.mark.parametrize("kwargs", [{"points_per_pixel": True}, {"points_per_pixel": 2.0},
                                    {"image_size": (4, 4.5)}])
def test_settings_type_errors(kwargs):
    with pytest.raises(TypeError, match="points_per_pixel|image_size"):
        PointsRasterizationSettings(**kwargs)


def test_rasterize_points_validation():
    xy, z, r, img = np.zeros((3, 2)), np.ones(3), np.full(3, 0.1), np.zeros(3, dtype=int)
    cases = [
        ((np.zeros((3, 3)), z, r, img, 1, (4, 4), 2), "xy"),
        ((xy, np.ones(2), r, img, 1, (4, 4), 2), "z"),
        ((xy, z, np.array([0.1, np.nan, 0.1]), img, 1, (4, 4), 2), "radius"),
        ((xy, z, -r, img, 1, (4, 4), 2), "radius"),
        ((xy, z, r, img + 1, 1, (4, 4), 2), "image_index"),
        ((xy, z, r, img - 1, 1, (4, 4), 2), "image_index"),
        ((xy, z, r, img, 0, (4, 4), 2), "n_images"),
        ((xy, z, r, img, 1, (4, 0), 2), "image_size"),
        ((xy, z, r, img, 1, (4, 4), 0), "K"),
    ]
    for args, match in cases:
        with pytest.raises(ValueError, match=match):
            rasterize_points(*args)


def test_rasterizer_validation():
    cloud = PointCloud(np.ones((3, 3)), np.ones((3, 3)))
    cams2 = FoVOrthographicCameras(R=np.stack([np.eye(3)] * 2))
    cams3 = FoVOrthographicCameras(R=np.stack([np.eye(3)] * 3))
    with pytest.raises(ValueError, match="cameras: none given"):
        PointsRasterizer()(cloud)
    with pytest.raises(TypeError, match="cameras"):
        PointsRasterizer(cameras="camera")
    with pytest.raises(TypeError, match="cameras"):
        PointsRasterizer()(cloud, cameras=np.eye(3))
    with pytest.raises(TypeError, match="raster_settings"):
        PointsRasterizer(cams2, raster_settings={"radius": 0.1})
    with pytest.raises(TypeError, match="raster_settings"):
        PointsRasterizer(cams2)(cloud, raster_settings=0.1)
    with pytest.raises(TypeError, match="point_clouds"):
        PointsRasterizer(cams2)(np.ones((3, 3)))
    with pytest.raises(ValueError, match="at least one cloud"):
        PointsRasterizer(cams2)(Pointclouds([]))
    with pytest.raises(ValueError, match="expected 1 or 2 cameras"):
        PointsRasterizer(cams3)(Pointclouds([cloud, cloud]))
    with pytest.raises(ValueError, match=r"radius: expected a scalar or shape \(3,\)"):
        s = PointsRasterizationSettings(radius=np.ones(4))
        PointsRasterizer(cams2, s)(cloud)


def test_renderer_and_compositor_validation():
    cams = FoVOrthographicCameras()
    rast = PointsRasterizer(cams)
    with pytest.raises(TypeError, match="rasterizer"):
        PointsRenderer(cams, AlphaCompositor())
    with pytest.raises(TypeError, match="compositor"):
        PointsRenderer(rast, "alpha")
    with pytest.raises(ValueError, match="no features"):
        PointsRenderer(rast, AlphaCompositor())(PointCloud(np.ones((2, 3))))
    idx = np.zeros((1, 2, 2, 1), dtype=np.int64)
    w = np.ones((1, 2, 2, 1))
    feats = np.ones((1, 3))
    with pytest.raises(ValueError, match="background_color: expected 3 or 2 channels"):
        AlphaCompositor(background_color=(0, 0, 0, 0, 1))(idx - 1, w, feats)
    with pytest.raises(ValueError, match="background_color"):
        AlphaCompositor(background_color=np.ones((2, 3)))
    with pytest.raises(ValueError, match="background_color"):
        AlphaCompositor(background_color=())
    with pytest.raises(ValueError, match="background_color"):
        add_background_color(np.zeros((1, 2, 2, 3)), idx, (1.0, np.nan, 0.0))
    with pytest.raises(ValueError, match="idx: expected shape"):
        AlphaCompositor()(idx[0], w[0], feats)
    with pytest.raises(ValueError, match="weights"):
        AlphaCompositor()(idx, w[..., :0], feats)
    with pytest.raises(ValueError, match="idx: point indices must be < 1"):
        NormWeightedCompositor()(idx + 1, w, feats)
    with pytest.raises(ValueError, match="idx: expected -1"):
        NormWeightedCompositor()(idx - 2, w, feats)
    with pytest.raises(ValueError, match="features"):
        NormWeightedCompositor()(idx, w, np.ones((1, 2, 3)))


def test_fragments_are_a_dataclass_with_documented_fields():
    f = PointsRasterizer(FoVOrthographicCameras(), PointsRasterizationSettings(4, 0.5, 2))(
        PointCloud([[0.0, 0.0, 1.0]]))
    assert isinstance(f, PointFragments)
    for a in (f.idx, f.zbuf, f.dists, f.radius):
        assert a.shape == (1, 4, 4, 2)
    assert f.idx.dtype == np.int64
    assert f.zbuf.dtype == f.dists.dtype == f.radius.dtype == np.float32   # as PyTorch3D


def test_float32_fragments_and_images_by_default_float64_on_request():
    """Fragments and images are float32 by default; dtype=np.float64 gives float64 arrays with
    the same hits, and the float32 values are the float64 ones rounded."""
    rng = np.random.default_rng(5)
    cloud = PointCloud(_random_cloud(rng, 2000, 0.8, (0.5, 2.0)), rng.random((2000, 3)))
    ren = PointsRenderer(PointsRasterizer(FoVOrthographicCameras()), AlphaCompositor())
    out = {dt: ren.render(cloud, raster_settings=PointsRasterizationSettings(
        image_size=(24, 32), radius=0.08, points_per_pixel=5, dtype=dt))
        for dt in (np.float32, np.float64)}
    f32, f64 = out[np.float32].fragments, out[np.float64].fragments
    assert out[np.float32].images.dtype == np.float32
    assert out[np.float64].images.dtype == np.float64
    assert_array_equal(f32.idx, f64.idx)
    assert_array_equal(f32.zbuf, f64.zbuf.astype(np.float32))
    assert_array_equal(f32.dists, f64.dists.astype(np.float32))
    assert_allclose(out[np.float32].images, out[np.float64].images, rtol=0, atol=1e-6)
    assert f32.zbuf.nbytes * 2 == f64.zbuf.nbytes


@pytest.mark.parametrize("dtype", ["float16", np.int64, None, "nope"])
def test_points_settings_dtype_validation(dtype):
    with pytest.raises(ValueError, match="dtype: expected numpy.float32 or numpy.float64"):
        PointsRasterizationSettings(dtype=dtype)


def test_docstring_examples():
    """The Examples sections of the points and compositing modules run as doctests."""
    import doctest

    from geofit.render.points import compositing

    for mod in (points_mod, compositing):
        result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE)
        assert result.attempted >= 2 and result.failed == 0


# ------------------------------------------------------------------ command line

def test_cli_renders_an_npz_cloud(tmp_path, capsys):
    """`geofit render-points CLOUD.npz` writes the renderer's image and the depth image."""
    from PIL import Image

    from geofit.cli import main

    rng = np.random.default_rng(7)
    verts = rng.uniform(-0.8, 0.8, (3000, 3))
    rgb = rng.uniform(0, 1, (3000, 3))
    np.savez(tmp_path / "cloud.npz", verts=verts, rgb=rgb)
    out = tmp_path / "out"
    code = main(["render-points", str(tmp_path / "cloud.npz"), "--out", str(out),
                 "--image-size", "48", "--radius", "0.05", "--background", "0", "0", "1"])
    assert code == 0
    assert "3000 points" in capsys.readouterr().out
    img = np.asarray(Image.open(out / "render_points.png"))
    depth = np.asarray(Image.open(out / "render_points_depth.png"))
    assert img.shape == (48, 48, 3) and depth.shape == (48, 48)
    # the same render through the API (tutorial camera: ortho, look_at(20, 10, 0), znear 0.01)
    R, T = look_at_view_transform(20.0, 10.0, 0.0)
    renderer = PointsRenderer(
        PointsRasterizer(FoVOrthographicCameras(R=R, T=T, znear=0.01),
                         PointsRasterizationSettings(48, 0.05, 10)),
        AlphaCompositor(background_color=(0, 0, 1)))
    want = renderer.render(PointCloud(verts, rgb))
    assert np.max(np.abs(img / 255.0 - want.images[0])) <= 0.5 / 255 + 1e-9
    assert_array_equal(depth == 0, want.depth[0] < 0)


def test_cli_renders_a_ply_cloud(tmp_path, capsys):
    """A .ply cloud (read through Open3D) renders like the same points given directly."""
    from PIL import Image

    from geofit.cli import main
    from geofit.io import save_pointcloud

    rng = np.random.default_rng(8)
    cloud = PointCloud(rng.uniform(-0.8, 0.8, (500, 3)), rng.integers(0, 256, (500, 3)) / 255)
    save_pointcloud(tmp_path / "cloud.ply", cloud)
    code = main(["render-points", str(tmp_path / "cloud.ply"), "--out", str(tmp_path / "o"),
                 "--image-size", "32", "--radius", "0.1", "--compositor", "norm"])
    assert code == 0
    assert "500 points" in capsys.readouterr().out
    img = np.asarray(Image.open(tmp_path / "o" / "render_points.png")) / 255.0
    R, T = look_at_view_transform(20.0, 10.0, 0.0)
    want = PointsRenderer(
        PointsRasterizer(FoVOrthographicCameras(R=R, T=T, znear=0.01),
                         PointsRasterizationSettings(32, 0.1, 10)),
        NormWeightedCompositor())(cloud)[0]
    assert np.max(np.abs(img - want)) <= 0.5 / 255 + 1e-9


def test_cli_default_cloud_without_data(tmp_path, monkeypatch, capsys):
    """Without tutorial data the default cloud samples the procedural textured mesh."""
    from geofit.cli import main

    monkeypatch.setenv("GEOFIT_DATA", str(tmp_path / "nodata"))
    monkeypatch.setenv("GEOFIT_SHIPPED_DATA", "0")  # not the cow installed with geofit
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    code = main(["render-points", "--out", str(tmp_path / "o"), "--image-size", "32",
                 "--n-points", "2000", "--camera", "persp"])
    assert code == 0
    text = capsys.readouterr().out
    assert "procedural_textured (2000 points" in text
    assert (tmp_path / "o" / "render_points.png").is_file()


def test_cli_finds_the_bridge_cloud_in_the_data_folder(tmp_path, monkeypatch, capsys):
    """Without CLOUD, PittsburghBridge/pointcloud.npz in $GEOFIT_DATA is rendered if present."""
    from geofit.cli import main

    (tmp_path / "data" / "PittsburghBridge").mkdir(parents=True)
    rng = np.random.default_rng(9)
    np.savez(tmp_path / "data" / "PittsburghBridge" / "pointcloud.npz",
             verts=rng.uniform(-1, 1, (123, 3)), rgb=rng.uniform(0, 1, (123, 3)))
    monkeypatch.setenv("GEOFIT_DATA", str(tmp_path / "data"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert main(["render-points", "--out", str(tmp_path / "o"), "--image-size", "16"]) == 0
    text = capsys.readouterr().out
    assert "pointcloud.npz (123 points" in text and "azim 0" in text


def test_cli_errors(tmp_path, capsys):
    """A missing file or a cloud without colours is a clear error with exit code 1."""
    from geofit.cli import main

    assert main(["render-points", str(tmp_path / "missing.npz"), "--out", str(tmp_path)]) == 1
    assert "not found" in capsys.readouterr().err
    np.savez(tmp_path / "plain.npz", verts=np.zeros((4, 3)))
    assert main(["render-points", str(tmp_path / "plain.npz"), "--out", str(tmp_path)]) == 1
    assert "no colours" in capsys.readouterr().err
