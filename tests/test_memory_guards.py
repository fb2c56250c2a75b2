"""Memory guards: a call whose buffers would exceed the memory limit is refused from its settings,
with a ValueError naming the setting, the estimate and the limit, before anything large is
allocated (each test's traced peak stays far below 1 GB)."""
from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from geofit import PointCloud, ico_sphere
from geofit._memory import check_allocation, memory_limit, parse_bytes
from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
from geofit.structures import MultiViewDataset
from geofit.fit import VolumeFitOptions, fit_volume
from geofit.fit.nerf import NerfConfig, fit_nerf, render_nerf
from geofit.render import (
    MeshRasterizer,
    PointsRasterizationSettings,
    PointsRasterizer,
    RasterizationSettings,
    SoftPhongRenderer,
    SoftRasterizationSettings,
    SoftSilhouetteRenderer,
)
from geofit.render.volume import (
    EmissionAbsorptionRaymarcher,
    NDCMultinomialRaysampler,
    VolumeRenderer,
)

GB = 2**30


def refused(fn, *args, **kwargs) -> tuple[ValueError, int]:
    """Call ``fn``, expecting a ValueError; return it and the traced peak bytes of the call."""
    tracemalloc.start()
    try:
        with pytest.raises(ValueError) as info:
            fn(*args, **kwargs)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return info.value, peak


def cameras(n: int = 1) -> FoVPerspectiveCameras:
    R, T = look_at_view_transform(2.7, 10.0, np.linspace(0, 90, n))
    return FoVPerspectiveCameras(R=R, T=T)


# --------------------------------------------------------------------------- the helper
def test_parse_bytes_and_limit_precedence(monkeypatch):
    """Suffixes are powers of 1024; the argument beats the environment, which beats the default
    (half of MemAvailable)."""
    assert parse_bytes("4G") == parse_bytes("4GiB") == parse_bytes("4 gb") == 4 * GB
    assert parse_bytes("1.5K") == 1536 and parse_bytes(1000) == 1000
    for bad in ("", "G", "-1G", "abc", "inf", 0, -5, True, None, float("nan")):
        with pytest.raises(ValueError, match="memory_limit: expected a positive byte count"):
            parse_bytes(bad)
    monkeypatch.delenv("GEOFIT_MEMORY_LIMIT", raising=False)
    with open("/proc/meminfo") as fh:
        avail = next(int(line.split()[1]) * 1024 for line in fh
                     if line.startswith("MemAvailable:"))
    assert abs(memory_limit() - avail / 2) < 0.1 * avail  # available memory moves a little
    monkeypatch.setenv("GEOFIT_MEMORY_LIMIT", "3M")
    assert memory_limit() == 3 * 2**20
    assert memory_limit("5K") == 5120
    monkeypatch.setenv("GEOFIT_MEMORY_LIMIT", "lots")
    with pytest.raises(ValueError, match="GEOFIT_MEMORY_LIMIT: expected a positive byte count"):
        memory_limit()


def test_check_allocation_message_names_setting_estimate_and_limit():
    assert check_allocation(10, "image_size", limit=100) == 100
    with pytest.raises(ValueError, match=r"^image_size: the buffers would need about 2 GiB, over "
                                         r"the memory limit of 1 GiB"):
        check_allocation(2 * GB, "image_size", "the buffers", limit="1G")
    with pytest.raises(ValueError, match="over the memory limit"):
        check_allocation(float("inf"), "x", limit="1G")


# --------------------------------------------------------------------------- guards
def test_mesh_rasterizer_huge_image_size_refused():
    """image_size=100000 (1e10 pixels): refused naming image_size; a 64 px render still works."""
    mesh = ico_sphere(1)
    err, peak = refused(MeshRasterizer(cameras(), RasterizationSettings(image_size=100000)), mesh)
    assert str(err).startswith("image_size: rasterizing 1 view(s) at (100000, 100000)")
    assert "memory limit" in str(err) and peak < GB
    assert MeshRasterizer(cameras(), RasterizationSettings(image_size=64))(mesh).pix_to_face.shape \
        == (1, 64, 64, 1)


def test_mesh_rasterizer_respects_env_limit(monkeypatch):
    """With GEOFIT_MEMORY_LIMIT=1M an ordinary 256 px render (about 8 MB) is refused."""
    monkeypatch.setenv("GEOFIT_MEMORY_LIMIT", "1M")
    with pytest.raises(ValueError, match=r"image_size: .* over the memory limit of 1 MiB"):
        MeshRasterizer(cameras(), RasterizationSettings(image_size=256))(ico_sphere(1))


def test_soft_renderer_huge_image_size_refused():
    """The soft rasterizer at image_size=100000 (1e10 pixels x K=50): refused naming
    image_size before any per-view buffer; a 16 px silhouette still renders."""
    mesh = ico_sphere(1)
    err, peak = refused(SoftRasterizationSettings.tutorial, 100000)  # at construction (28.6)
    assert str(err).startswith("image_size and faces_per_pixel: soft fragments of 1 view(s) at "
                               "(100000, 100000) with K=50") and peak < GB
    settings = SoftRasterizationSettings.tutorial(1000)  # fits one view, not 40 views
    err, peak = refused(SoftPhongRenderer(cameras(40), raster_settings=settings), mesh,
                        np.ones((mesh.n_verts, 3)))
    assert str(err).startswith("image_size and faces_per_pixel: soft fragments of 40 view(s)")
    assert peak < GB
    small = SoftSilhouetteRenderer(cameras(), SoftRasterizationSettings.tutorial(16))(mesh)
    assert small.images.shape[:3] == (1, 16, 16)


def test_points_rasterizer_huge_points_per_pixel_refused():
    """points_per_pixel=10000 at 1024 px (1e10 slots): refused naming points_per_pixel."""
    cloud = PointCloud(np.random.default_rng(0).normal(size=(100, 3)) * 0.3)
    settings = PointsRasterizationSettings(image_size=1024, radius=0.01, points_per_pixel=10000)
    err, peak = refused(PointsRasterizer(cameras(), settings), cloud)
    assert str(err).startswith("points_per_pixel and image_size: the (1, 1024, 1024, K=10000)")
    assert peak < GB
    small = PointsRasterizationSettings(image_size=16, radius=0.05, points_per_pixel=4)
    assert PointsRasterizer(cameras(), small)(cloud).idx.shape == (1, 16, 16, 4)


def test_fit_volume_huge_volume_size_refused():
    """volume_size=2000 (8e9 voxels): refused naming volume_size before any grid exists."""
    imgs, sils = np.zeros((2, 8, 8, 3)), np.zeros((2, 8, 8))
    data = MultiViewDataset(images=imgs, silhouettes=sils, cameras=cameras(2))
    err, peak = refused(fit_volume, data, options=VolumeFitOptions(volume_size=2000),
                        progress=False)
    assert "volume_size: a 2000^3 grid" in str(err) and peak < GB


def test_volume_raysampler_huge_n_pts_per_ray_refused():
    """A ray bundle of 64 x 64 rays with 1e7 samples each: refused naming n_pts_per_ray."""
    sampler = NDCMultinomialRaysampler(image_width=64, image_height=64, n_pts_per_ray=10**7,
                                       min_depth=0.1, max_depth=3.0)
    err, peak = refused(sampler, cameras())
    assert str(err).startswith("n_pts_per_ray and image size: a bundle of 1 x 4096 rays")
    assert peak < GB
    with pytest.raises(ValueError, match=r"^chunk_size: one chunk of samples would need"):
        VolumeRenderer(sampler, EmissionAbsorptionRaymarcher(), chunk_size=10**12)


def test_fit_nerf_huge_batch_refused():
    """n_rays_per_image=1e8 (a huge batch of rays per step): refused naming the batch settings,
    before the hull, the network's first step or any ray exists."""
    imgs, sils = np.zeros((2, 8, 8, 3)), np.zeros((2, 8, 8))
    data = MultiViewDataset(images=imgs, silhouettes=sils, cameras=cameras(2))
    err, peak = refused(fit_nerf, data, recipe="tutorial", options=NerfConfig.tutorial(
        n_rays_per_image=10**8, n_iter=1), progress=False)
    assert str(err).startswith("batch_size, n_rays_per_image and n_pts_per_ray: one training "
                               "step's samples") and peak < GB
    err, _ = refused(fit_nerf, data, recipe="tutorial", options=NerfConfig.tutorial(
        n_pts_per_ray=10**8, n_iter=1), progress=False)
    assert "n_pts_per_ray" in str(err)


def test_render_nerf_huge_chunk_refused():
    """chunk_rays=1e6 rays of 1000 samples through the tutorial network: refused naming
    chunk_rays before the ray bundle is built."""
    field = NerfConfig.tutorial().network(seed=0)
    err, peak = refused(render_nerf, field, cameras(), 1024, n_pts_per_ray=1000,
                        chunk_rays=10**6)
    assert str(err).startswith("chunk_rays and n_pts_per_ray: the network activations")
    assert peak < GB


def test_docstring_examples():
    """The Examples of geofit._memory run as doctests."""
    import doctest

    import geofit._memory

    result = doctest.testmod(geofit._memory)
    assert result.attempted >= 3 and result.failed == 0
