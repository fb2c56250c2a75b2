"""Volume structure, trilinear sampling operator, raymarchers and VolumeRenderer.

Reference numbers come from tests/data/volume.npz (PyTorch3D 0.7.9, float32; see
tests/data/README.md).
"""
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from geofit.cameras import FoVPerspectiveCameras
from geofit.render.volume.raymarching import (AbsorptionOnlyRaymarcher,
                                              EmissionAbsorptionRaymarcher, sample_deltas)
from geofit.render.volume import MonteCarloRaysampler, NDCMultinomialRaysampler, RayBundle
from geofit.render.volume import VolumeRenderer
from geofit.structures.volume import Volume, trilinear_matrix, voxel_footprint

DATA = Path(__file__).parent / "data" / "volume.npz"


@pytest.fixture(scope="module")
def ref(reference_arrays):
    return reference_arrays(DATA.name, np.float64)


def _rel(a, b):
    """Largest difference relative to the largest reference entry."""
    return np.abs(a - b).max() / np.abs(b).max()


# --------------------------------------------------------------------------------- coordinates


def test_coordinates_match_pytorch3d(ref):
    """local <-> world and the voxel-centre grid follow PyTorch3D's Volumes (float32 reference)."""
    v = Volume(np.zeros((16, 16, 16)), voxel_size=0.2)
    np.testing.assert_allclose(v.get_coord_grid()[::5, ::5, ::5], ref["vol_grid_world_sub"],
                               atol=1e-6)
    np.testing.assert_allclose(v.get_coord_grid(False)[::5, ::5, ::5], ref["vol_grid_local_sub"],
                               atol=1e-6)
    np.testing.assert_allclose(v.world_to_local(ref["vol_world_points"]),
                               ref["vol_world_to_local"], atol=1e-6)
    np.testing.assert_allclose(v.local_to_world(ref["vol_local_points"]),
                               ref["vol_local_to_world"], atol=1e-6)
    v2 = Volume(np.zeros((4, 6, 8)), voxel_size=(0.1, 0.2, 0.3),
                volume_translation=(0.5, -0.2, 0.1))
    np.testing.assert_allclose(v2.get_coord_grid(), ref["vol2_grid_world"], atol=1e-6)
    np.testing.assert_allclose(v2.world_to_local(ref["vol_world_points"]),
                               ref["vol2_world_to_local"], atol=2e-6)
    np.testing.assert_allclose(v2.local_to_world(ref["vol_local_points"]),
                               ref["vol2_local_to_world"], atol=1e-6)


def test_local_world_roundtrip_and_bounds():
    """world_to_local inverts local_to_world; the corners of the grid map to +-1."""
    v = Volume(np.zeros((3, 5, 7)), voxel_size=(0.3, 0.2, 0.1), volume_translation=(1, 2, 3))
    P = np.random.default_rng(0).normal(size=(20, 3))
    np.testing.assert_allclose(v.world_to_local(v.local_to_world(P)), P, atol=1e-12)
    g = v.get_coord_grid(False)
    np.testing.assert_allclose(g[0, 0, 0], [-1, -1, -1])
    np.testing.assert_allclose(g[-1, -1, -1], [1, 1, 1])
    box = v.bounds()
    w = v.get_coord_grid()
    np.testing.assert_allclose(box[0], w.reshape(-1, 3).min(0) - v.voxel_size)
    np.testing.assert_allclose(box[1], w.reshape(-1, 3).max(0) + v.voxel_size)


# --------------------------------------------------------------------------- trilinear operator


def _grid_sample_loop(grid, local, align_corners, mode="bilinear"):
    """torch.grid_sample (zeros padding) for one channel, point by point."""
    D, H, W = grid.shape
    out = np.zeros(len(local))
    for i, (x, y, z) in enumerate(local):  # reference loop
        if align_corners:
            px, py, pz = (x + 1) / 2 * (W - 1), (y + 1) / 2 * (H - 1), (z + 1) / 2 * (D - 1)
        else:
            px, py, pz = ((x + 1) * W - 1) / 2, ((y + 1) * H - 1) / 2, ((z + 1) * D - 1) / 2
        if mode == "nearest":
            ix, iy, iz = (int(np.rint(p)) for p in (px, py, pz))
            if 0 <= ix < W and 0 <= iy < H and 0 <= iz < D:
                out[i] = grid[iz, iy, ix]
            continue
        x0, y0, z0 = int(np.floor(px)), int(np.floor(py)), int(np.floor(pz))
        for dz in (0, 1):
            for dy in (0, 1):
                for dx in (0, 1):
                    xi, yi, zi = x0 + dx, y0 + dy, z0 + dz
                    if 0 <= xi < W and 0 <= yi < H and 0 <= zi < D:
                        w = ((px - x0) if dx else (1 - (px - x0))) * \
                            ((py - y0) if dy else (1 - (py - y0))) * \
                            ((pz - z0) if dz else (1 - (pz - z0)))
                        out[i] += w * grid[zi, yi, xi]
    return out


@pytest.mark.parametrize("align_corners", [True, False])
@pytest.mark.parametrize("mode", ["bilinear", "nearest"])
def test_trilinear_matrix_matches_loop(align_corners, mode):
    """The sparse operator equals grid_sample (zeros padding) evaluated point by point."""
    rng = np.random.default_rng(1)
    grid = rng.normal(size=(3, 4, 5))
    local = rng.uniform(-1.4, 1.4, size=(300, 3))
    local[:5] = [[-1, -1, -1], [1, 1, 1], [1.2, 0, 0], [0, -1.3, 0.5], [0.25, 0.5, -0.75]]
    M = trilinear_matrix(local, grid.shape, align_corners=align_corners, mode=mode)
    assert isinstance(M, sp.csr_matrix) and M.shape == (300, 60)
    np.testing.assert_allclose(M @ grid.ravel(), _grid_sample_loop(grid, local, align_corners,
                                                                   mode), atol=1e-12)


def test_trilinear_exact_on_linear_field_and_partition_of_unity():
    """Inside the grid, a field linear in the coordinates is reproduced and weights sum to 1."""
    v = Volume(np.zeros((5, 6, 7)), voxel_size=0.3, volume_translation=(0.1, 0.2, -0.3))
    g = v.get_coord_grid()
    field = 2.0 * g[..., 0] - 3.0 * g[..., 1] + 0.5 * g[..., 2] + 1.0
    lo, hi = g.reshape(-1, 3).min(0), g.reshape(-1, 3).max(0)
    P = np.random.default_rng(2).uniform(lo, hi, size=(200, 3))
    M = v.sampling_matrix(P)
    np.testing.assert_allclose(M @ field.ravel(), 2 * P[:, 0] - 3 * P[:, 1] + 0.5 * P[:, 2] + 1,
                               atol=1e-12)
    np.testing.assert_allclose(np.asarray(M.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    far = v.sampling_matrix(np.array([[10.0, 0, 0], [0, -10.0, 0]]))
    assert far.nnz == 0  # zero padding: nothing read far outside


def test_trilinear_columns_restriction_and_transpose_gradient():
    """Restricting columns drops the other voxels; M^T g is the gradient of <g, M x>."""
    rng = np.random.default_rng(3)
    size = (4, 4, 4)
    local = rng.uniform(-1.1, 1.1, size=(50, 3))
    M = trilinear_matrix(local, size)
    cols = np.sort(rng.choice(64, 20, replace=False))
    Mc = trilinear_matrix(local, size, columns=cols)
    np.testing.assert_allclose(Mc.toarray(), M.toarray()[:, cols], atol=0)
    x = rng.normal(size=64)
    g = rng.normal(size=50)
    grad = M.T @ g
    h = 1e-6
    fd = np.array([(g @ (M @ (x + h * e)) - g @ (M @ (x - h * e))) / (2 * h)
                   for e in np.eye(64)])
    np.testing.assert_allclose(grad, fd, atol=1e-8)


def test_volume_sample_and_footprint():
    """Volume.sample returns densities and features; voxel_footprint names the cell or -1."""
    rng = np.random.default_rng(4)
    v = Volume(rng.random((3, 3, 3)), rng.random((2, 3, 3, 3)), voxel_size=0.5)
    P = v.get_coord_grid().reshape(-1, 3)
    s = v.sample(P)
    np.testing.assert_allclose(s.densities, v.densities.ravel(), atol=1e-12)
    np.testing.assert_allclose(s.features, v.features.reshape(2, -1).T, atol=1e-12)
    cells = voxel_footprint(v.world_to_local(np.array([[0.0, 0, 0], [5.0, 0, 0]])), (3, 3, 3))
    assert cells[0] == (1 * 3 + 1) * 3 + 1  # the cell whose lowest corner is voxel (1, 1, 1)
    assert cells[1] == -1
    assert Volume(np.zeros((2, 2, 2))).sample(np.zeros((1, 3))).features is None


def test_volume_validation():
    """Every invalid argument raises ValueError naming it."""
    with pytest.raises(ValueError, match="densities"):
        Volume(np.zeros((4, 4)))
    with pytest.raises(ValueError, match="densities"):
        Volume(np.zeros((1, 4, 4)))
    with pytest.raises(ValueError, match="features"):
        Volume(np.zeros((4, 4, 4)), np.zeros((3, 4, 4, 5)))
    with pytest.raises(ValueError, match="features"):
        Volume(np.zeros((4, 4, 4)), np.zeros((0, 4, 4, 4)))
    with pytest.raises(ValueError, match="voxel_size"):
        Volume(np.zeros((4, 4, 4)), voxel_size=0.0)
    with pytest.raises(ValueError, match="voxel_size"):
        Volume(np.zeros((4, 4, 4)), voxel_size=(1.0, 2.0))
    with pytest.raises(ValueError, match="volume_translation"):
        Volume(np.zeros((4, 4, 4)), volume_translation=(0, 0))
    with pytest.raises(TypeError, match="align_corners"):
        Volume(np.zeros((4, 4, 4)), align_corners="yes")
    with pytest.raises(ValueError, match="densities"):
        Volume(np.full((4, 4, 4), np.nan))
    with pytest.raises(ValueError, match="columns"):
        trilinear_matrix(np.zeros((1, 3)), (2, 2, 2), columns=[0, 9])
    with pytest.raises(ValueError, match="columns"):
        trilinear_matrix(np.zeros((1, 3)), (2, 2, 2), columns=[3, 1])
    with pytest.raises(ValueError, match="mode"):
        trilinear_matrix(np.zeros((1, 3)), (2, 2, 2), mode="cubic")
    with pytest.raises(ValueError, match="grid_size"):
        trilinear_matrix(np.zeros((1, 3)), (2, 1, 2))
    with pytest.raises(ValueError, match="local_points"):
        trilinear_matrix(np.zeros((1, 2)), (2, 2, 2))


# ---------------------------------------------------------------------------------- raymarchers


def _ea_loop(d, f, eps=1e-10, s=1):
    """PyTorch3D's EmissionAbsorptionRaymarcher for one ray, sample by sample."""
    n = len(d)
    feats = np.zeros(f.shape[1])
    for i in range(n):  # reference loop
        T = 1.0
        for j in range(i - s + 1):
            T *= 1.0 + eps - d[j]
        feats += d[i] * T * f[i]
    return np.concatenate([feats, [1.0 - np.prod(1.0 - d)]])


def _fd(fun, x, h=1e-6):
    g = np.zeros_like(x)
    for i in np.ndindex(x.shape):  # finite differences
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        g[i] = (fun(xp) - fun(xm)) / (2 * h)
    return g


@pytest.mark.parametrize("s", [1, 2, 3])
def test_ea_matches_loop_reference(s):
    """Vectorised EA equals the per-sample formula, for several surface thicknesses."""
    rng = np.random.default_rng(5)
    d = rng.uniform(0, 1, (4, 6))
    f = rng.uniform(0, 1, (4, 6, 3))
    out = EmissionAbsorptionRaymarcher(s)(d, f)
    ref = np.stack([_ea_loop(d[r], f[r], s=s) for r in range(4)])
    np.testing.assert_allclose(out, ref, atol=1e-14)


def test_ea_closed_form_single_surface():
    """An opaque sample hides everything behind it: features are its own, opacity 1."""
    d = np.array([[0.0, 0.0, 1.0, 0.7, 0.4]])
    f = np.array([[[9, 9, 9], [9, 9, 9], [0.2, 0.5, 0.8], [1, 1, 1], [1, 1, 1]]], float)
    out = EmissionAbsorptionRaymarcher(eps=0.0)(d, f)
    np.testing.assert_allclose(out, [[0.2, 0.5, 0.8, 1.0]], atol=1e-15)
    # and the PyTorch3D (..., n, 1) density layout gives the same
    np.testing.assert_allclose(EmissionAbsorptionRaymarcher(eps=0.0)(d[..., None], f), out)


@pytest.mark.parametrize("s", [1, 2])
@pytest.mark.parametrize("physical", [False, True])
def test_ea_vjp_finite_differences(s, physical):
    """The EA vector-Jacobian product matches central differences (densities and features)."""
    rng = np.random.default_rng(6)
    m = EmissionAbsorptionRaymarcher(s, physical=physical)
    d = rng.uniform(0.05, 0.95, (2, 3, 7)) * (3.0 if physical else 1.0)
    f = rng.uniform(0, 1, (2, 3, 7, 2))
    G = rng.normal(size=(2, 3, 3))
    dl = sample_deltas(np.sort(rng.uniform(0, 2, (2, 3, 7)), axis=-1)) if physical else None
    g = m.vjp(G, d, f, dl)
    assert g.densities.shape == d.shape and g.features.shape == f.shape
    np.testing.assert_allclose(g.densities, _fd(lambda x: np.sum(m(x, f, dl) * G), d),
                               atol=1e-8)
    np.testing.assert_allclose(g.features, _fd(lambda x: np.sum(m(d, x, dl) * G), f), atol=1e-8)


@pytest.mark.filterwarnings("ignore:EmissionAbsorptionRaymarcher:UserWarning")
def test_ea_vjp_at_zero_absorption_factor():
    """With eps = 0 a density of exactly 1 zeroes 1 - d; the gradient is still exact there."""
    rng = np.random.default_rng(7)
    m = EmissionAbsorptionRaymarcher(eps=0.0)
    d = rng.uniform(0.1, 0.9, (3, 6))
    d[0, 2] = 1.0
    d[1, 0] = 1.0
    f = rng.uniform(0, 1, (3, 6, 3))
    G = rng.normal(size=(3, 4))
    g = m.vjp(G, d, f)
    assert np.all(np.isfinite(g.densities))
    # central differences straddle d = 1 (the map is polynomial in d, so this is fine)
    np.testing.assert_allclose(g.densities, _fd(lambda x: np.sum(m(x, f) * G), d, h=1e-7),
                               atol=1e-7)


def test_physical_raymarcher_is_sampling_invariant():
    """Physically based EA: a homogeneous medium gives 1 - exp(-sigma L) at any sampling."""
    m = EmissionAbsorptionRaymarcher(physical=True)
    outs = []
    for n in (10, 40, 160):
        dl = sample_deltas(np.linspace(0.0, 2.0, n + 1)[None])[:, :-1]  # n steps of 2 / n
        out = m(np.full((1, n), 0.7), np.ones((1, n, 1)), dl)
        outs.append(out[0])
    np.testing.assert_allclose([o[1] for o in outs], 1 - np.exp(-0.7 * 2.0), rtol=1e-12)
    np.testing.assert_allclose([o[0] for o in outs], 1 - np.exp(-0.7 * 2.0), rtol=1e-12)


def test_absorption_only():
    """Opacity 1 - prod(1 - d) (and the physical form) with exact gradients."""
    rng = np.random.default_rng(8)
    d = rng.uniform(0, 1, (4, 5))
    ao = AbsorptionOnlyRaymarcher()
    np.testing.assert_allclose(ao(d)[:, 0], 1 - np.prod(1 - d, axis=1))
    G = rng.normal(size=(4, 1))
    np.testing.assert_allclose(ao.vjp(G, d).densities, _fd(lambda x: np.sum(ao(x) * G), d),
                               atol=1e-9)
    ph = AbsorptionOnlyRaymarcher(physical=True)
    dl = np.full((4, 5), 0.1)
    np.testing.assert_allclose(ph(d, dl)[:, 0], 1 - np.exp(-0.1 * d.sum(1)))
    np.testing.assert_allclose(ph.vjp(G, d, dl).densities,
                               _fd(lambda x: np.sum(ph(x, dl) * G), d), atol=1e-9)


def test_sample_deltas_and_raymarcher_validation():
    """Steps from lengths (times the direction norms); invalid inputs raise."""
    np.testing.assert_allclose(sample_deltas([[0.0, 1.0, 3.0]], [[0.0, 0.0, 2.0]]),
                               [[2.0, 4.0, 4.0]])
    with pytest.raises(ValueError, match="lengths"):
        sample_deltas([1.0])
    with pytest.raises(ValueError, match="lengths"):
        sample_deltas([1.0, 0.5])
    m = EmissionAbsorptionRaymarcher()
    with pytest.raises(ValueError, match="rays_features"):
        m(np.zeros((2, 3)), np.zeros(3))
    with pytest.raises(ValueError, match="rays_densities"):
        m(np.zeros((2, 4)), np.zeros((2, 3, 1)))
    with pytest.raises(ValueError, match="deltas"):
        EmissionAbsorptionRaymarcher(physical=True)(np.zeros((2, 3)), np.zeros((2, 3, 1)))
    with pytest.raises(ValueError, match="extinction"):
        EmissionAbsorptionRaymarcher(physical=True)(-np.ones((2, 3)), np.zeros((2, 3, 1)),
                                                    np.ones((2, 3)))
    with pytest.raises(ValueError, match="grad_output"):
        m.vjp(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3, 1)))
    with pytest.raises(ValueError, match="surface_thickness"):
        EmissionAbsorptionRaymarcher(0)
    with pytest.raises(ValueError, match="eps"):
        EmissionAbsorptionRaymarcher(eps=-1.0)
    with pytest.raises(TypeError, match="physical"):
        EmissionAbsorptionRaymarcher(physical="no")
    with pytest.warns(UserWarning, match="outside the valid range"):
        m(np.full((1, 2), 1.5), np.zeros((1, 2, 1)))
    with pytest.warns(UserWarning, match="outside the valid range"):
        AbsorptionOnlyRaymarcher()(np.full((1, 2), -0.5))


# ------------------------------------------------------------------------------------- renderer


def _renderer(skip, marcher=None, n_pts=32, size=24):
    return VolumeRenderer(
        NDCMultinomialRaysampler(image_width=size, image_height=size, n_pts_per_ray=n_pts,
                                 min_depth=0.1, max_depth=3.0),
        marcher or EmissionAbsorptionRaymarcher(), skip_empty=skip, chunk_size=4000)


@pytest.mark.parametrize("skip", [True, False])
def test_renderer_matches_pytorch3d(ref, skip):
    """Images, rays and gradients agree with PyTorch3D's VolumeRenderer to float32 precision."""
    vol = Volume(ref["densities"], ref["features"], voxel_size=0.2)
    cams = FoVPerspectiveCameras(R=ref["R"], T=ref["T"])
    r = _renderer(skip)
    images, bundle = r(cams, vol)
    assert images.shape == (2, 24, 24, 4)
    assert _rel(images, ref["images"]) < 1e-5
    assert _rel(bundle.origins, ref["ray_origins"]) < 1e-5
    assert _rel(bundle.directions, ref["ray_directions"]) < 1e-5
    assert _rel(bundle.xys, ref["ray_xys"]) < 1e-5
    np.testing.assert_allclose(bundle.lengths[0, 0, 0], ref["ray_lengths_row"], rtol=1e-6)
    np.testing.assert_allclose(np.sum(images * ref["upstream_G"]), ref["inner_product"],
                               rtol=1e-5)
    g = r.vjp(ref["upstream_G"], vol, bundle)
    assert _rel(g.densities, ref["grad_densities"]) < 1e-5
    assert _rel(g.features, ref["grad_features"]) < 1e-5


@pytest.mark.parametrize("physical", [False, True])
def test_skip_empty_equals_dense_path(physical):
    """Empty-space skipping changes nothing (images and gradients) on a sparse volume."""
    rng = np.random.default_rng(9)
    dens = np.where(rng.random((8, 8, 8)) < 0.15, rng.uniform(0.2, 0.9, (8, 8, 8)), 0.0)
    dens[:, :2] = 0.0
    vol = Volume(dens, rng.random((3, 8, 8, 8)), voxel_size=0.3)
    from geofit.cameras import look_at_view_transform
    R, T = look_at_view_transform(2.5, [10.0, -30.0], [20.0, 200.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    marcher = EmissionAbsorptionRaymarcher(physical=physical)
    a, b = _renderer(True, marcher, 40, 12), _renderer(False, marcher, 40, 12)
    img_a, bundle = a(cams, vol)
    img_b = b.render_rays(vol, bundle)
    np.testing.assert_allclose(img_a, img_b, atol=1e-13)
    assert img_a[..., 3].max() > 0.2 and img_a[..., 3].min() == 0.0  # content and empty rays
    G = rng.normal(size=img_a.shape)
    ga, gb = a.vjp(G, vol, bundle), b.vjp(G, vol, bundle)
    np.testing.assert_allclose(ga.densities, gb.densities, atol=1e-12)
    np.testing.assert_allclose(ga.features, gb.features, atol=1e-12)
    ao = AbsorptionOnlyRaymarcher()
    ra, rb = _renderer(True, ao, 40, 12), _renderer(False, ao, 40, 12)
    np.testing.assert_allclose(ra.render_rays(vol, bundle), rb.render_rays(vol, bundle),
                               atol=1e-13)


def test_renderer_vjp_finite_differences():
    """VolumeRenderer.vjp matches central differences on a few voxels (both EA modes)."""
    rng = np.random.default_rng(10)
    dens = rng.uniform(0.0, 0.6, (5, 5, 5))
    feats = rng.random((3, 5, 5, 5))
    cams = FoVPerspectiveCameras(R=np.eye(3)[None] @ np.diag([-1.0, 1.0, -1.0]),
                                 T=np.array([[0.0, 0.0, 2.5]]))
    sampler = MonteCarloRaysampler(-0.6, 0.6, -0.6, 0.6, 30, 20, 1.0, 4.0)
    bundle = sampler(cams, seed=0)
    for physical in (False, True):
        r = VolumeRenderer(sampler, EmissionAbsorptionRaymarcher(physical=physical))
        vol = Volume(dens * (4.0 if physical else 1.0), feats, voxel_size=0.4)
        G = rng.normal(size=(1, 30, 4))
        g = r.vjp(G, vol, bundle)
        idx = [(2, 2, 2), (1, 2, 3), (3, 1, 2), (2, 3, 1)]
        h = 1e-6
        for i in idx:
            e = np.zeros_like(dens)
            e[i] = h
            fp = np.sum(r.render_rays(vol.update(densities=vol.densities + e), bundle) * G)
            fm = np.sum(r.render_rays(vol.update(densities=vol.densities - e), bundle) * G)
            assert abs((fp - fm) / (2 * h) - g.densities[i]) < 1e-7
            ef = np.zeros_like(feats)
            ef[(1,) + i] = h
            fp = np.sum(r.render_rays(vol.update(features=feats + ef), bundle) * G)
            fm = np.sum(r.render_rays(vol.update(features=feats - ef), bundle) * G)
            assert abs((fp - fm) / (2 * h) - g.features[(1,) + i]) < 1e-7
        assert np.abs(g.densities).max() > 1e-3


def test_renderer_validation():
    """Bad arguments raise TypeError/ValueError naming them."""
    s = NDCMultinomialRaysampler(image_width=4, image_height=4, n_pts_per_ray=4, min_depth=0.1,
                                 max_depth=3.0)
    m = EmissionAbsorptionRaymarcher()
    with pytest.raises(TypeError, match="raysampler"):
        VolumeRenderer(3, m)
    with pytest.raises(TypeError, match="raymarcher"):
        VolumeRenderer(s, "ea")
    with pytest.raises(ValueError, match="sample_mode"):
        VolumeRenderer(s, m, "cubic")
    with pytest.raises(ValueError, match="chunk_size"):
        VolumeRenderer(s, m, chunk_size=0)
    with pytest.raises(TypeError, match="skip_empty"):
        VolumeRenderer(s, m, skip_empty=1)
    r = VolumeRenderer(s, m)
    with pytest.raises(TypeError, match="cameras"):
        r("camera", Volume(np.zeros((2, 2, 2))))
    with pytest.raises(TypeError, match="volume"):
        r(FoVPerspectiveCameras(), np.zeros((2, 2, 2)))
    with pytest.raises(TypeError, match="ray_bundle"):
        r.render_rays(Volume(np.zeros((2, 2, 2))), (np.zeros((1, 3)),) * 4)
    bundle = RayBundle(np.zeros((1, 2, 3)), np.ones((1, 2, 3)), np.ones((1, 3, 4)),
                       np.zeros((1, 2, 2)))
    with pytest.raises(ValueError, match="ray_bundle"):
        r.render_rays(Volume(np.zeros((2, 2, 2))), bundle)
    vol = Volume(np.zeros((2, 2, 2)), np.zeros((3, 2, 2, 2)))
    _, b = r(FoVPerspectiveCameras(), vol)
    with pytest.raises(ValueError, match="grad_images"):
        r.vjp(np.zeros((1, 4, 4, 3)), vol, b)


def test_docstring_examples():
    """The Examples sections of the volume modules run as doctests."""
    import doctest

    import geofit.datasets as gd
    import geofit.fit.volume as gfv
    import geofit.render.volume.raymarching as grm
    import geofit.render.volume.raysampling as grs
    import geofit.render.volume.renderer as grv
    import geofit.structures.volume as gsv

    for mod in (gsv, grm, grs, grv, gfv, gd):
        result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE)
        assert result.failed == 0, mod.__name__
        assert result.attempted > 0, mod.__name__


def test_implicit_docstring_examples():
    """The Examples of the implicit renderer and the radiance field run as doctests."""
    import doctest

    import geofit.render.volume.implicit as gvi
    import geofit.render.volume.radiance_field as gvf

    for mod in (gvi, gvf):
        result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE)
        assert result.attempted > 0 and result.failed == 0, mod.__name__


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_column_scans_equal_numpy_accumulate_bit_for_bit(dtype):
    """The column-by-column scans (many rays, few samples) give numpy's accumulate's bits."""
    from geofit.render.volume import raymarching as rm

    rng = np.random.default_rng(3)
    c = rng.uniform(0.2, 1.0, (4000, 27)).astype(dtype)  # 4000 >= 32 * 27: the column loop
    assert c.shape[0] >= rm._SCAN_ROWS_PER_COLUMN * c.shape[1]
    T = rm.shifted_cumprod(c, 1)
    assert T.dtype == dtype
    np.testing.assert_array_equal(T[:, 1:], np.cumprod(c[:, :-1], axis=1))
    np.testing.assert_array_equal(T[:, 0], 1.0)
    S = rm.suffix_from(c, 1)
    np.testing.assert_array_equal(S[:, :-1], np.cumsum(c[:, :0:-1], axis=1)[:, ::-1])
    np.testing.assert_array_equal(S[:, -1], 0.0)
    U = rm.suffix_products(c)
    np.testing.assert_array_equal(U[:, :-1], np.cumprod(c[:, :0:-1], axis=1)[:, ::-1])
    q = np.stack([c, 2 * c, -c])
    np.testing.assert_array_equal(rm.sequential_sum(q), np.cumsum(q, axis=-1)[..., -1])
    # few rows: numpy's accumulate itself
    np.testing.assert_array_equal(rm.sequential_sum(c[:3]), np.cumsum(c[:3], axis=1)[:, -1])


def test_cell_indices_match_the_padded_cell_table_layout():
    """The cells of sample coordinates (axis by axis, in float64) are the flat indices of
    ``floor(clip(pix, -2, size + 1)) + 2`` in the padded (D+4, H+4, W+4) cell table, also for
    samples far outside the grid; from the rays' affine form the same cells."""
    from geofit.render.volume import skipping as sk

    size = (5, 6, 7)  # D, H, W
    rng = np.random.default_rng(4)
    A = rng.uniform(-6.0, 12.0, (50, 3))
    B = rng.uniform(-1.5, 1.5, (50, 3))
    t = np.sort(rng.uniform(0.0, 9.0, (50, 13)), axis=1)
    t[:, 0] = 0.0
    pix = A[:, None, :] + t[..., None] * B[:, None, :]
    c = (np.floor(np.clip(pix, -2.0, np.array([8.0, 7.0, 6.0]))) + 2.0).astype(np.int64)
    ref = np.ravel_multi_index((c[..., 2], c[..., 1], c[..., 0]), (9, 10, 11))
    np.testing.assert_array_equal(sk._cells_of(pix, size), ref)
    np.testing.assert_array_equal(sk._cells_affine(A, B, t, size), ref)
    assert ref.min() == 0 and ref.max() == 9 * 10 * 11 - 1  # both clipped corners are met
