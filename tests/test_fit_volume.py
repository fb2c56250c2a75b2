"""fit_volume: the objective's gradient, the visual hull, the methods and their failure modes.

The scenes are small procedural volumes rendered by geofit's own VolumeRenderer, so every test
runs in seconds and needs no data files.
"""
import numpy as np
import pytest

import geofit.fit._volume_problem as fv
from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
from geofit.structures import MultiViewDataset
from geofit.fit.volume import (
    FIT_VOLUME_METHODS,
    RECIPES,
    VolumeFitOptions,
    VolumeFitResult,
    fit_volume,
    visual_hull,
)
from geofit.loss import huber
from geofit.render.volume.raymarching import EmissionAbsorptionRaymarcher
from geofit.render.volume.raysampling import NDCMultinomialRaysampler
from geofit.render.volume import VolumeRenderer
from geofit.structures.volume import Volume

N_PTS = 60
SIZE = 24


def _scene(n_views=8, elev=0.0, size=SIZE, seed=0):
    """A two-coloured ellipsoid in a 16^3 grid (voxel 3/16), seen from a ring of cameras."""
    S = 16
    g = Volume(np.zeros((S, S, S)), voxel_size=3.0 / S).get_coord_grid()
    r = (g[..., 0] / 0.8) ** 2 + (g[..., 1] / 0.5) ** 2 + (g[..., 2] / 0.6) ** 2
    dens = np.where(r < 1.0, 0.6, 0.0)
    col = np.stack([np.where(g[..., 0] > 0, 0.9, 0.2), np.full(g.shape[:3], 0.5),
                    np.where(g[..., 1] > 0, 0.1, 0.8)])
    truth = Volume(dens, col, voxel_size=3.0 / S)
    azim = np.linspace(0.0, 360.0, n_views, endpoint=False) + 10.0 * seed
    R, T = look_at_view_transform(2.7, elev, azim)
    cams = FoVPerspectiveCameras(R=R, T=T)
    renderer = VolumeRenderer(NDCMultinomialRaysampler(
        image_width=size, image_height=size, n_pts_per_ray=N_PTS, min_depth=0.1, max_depth=3.0),
        EmissionAbsorptionRaymarcher())
    img, _ = renderer(cams, truth)
    return img[..., :3], (img[..., 3] > 0.5).astype(float), cams, truth, renderer


@pytest.fixture(scope="module")
def scene():
    return _scene()


def _ds(images, silhouettes, cameras) -> MultiViewDataset:
    return MultiViewDataset(images=np.clip(images, 0.0, 1.0), silhouettes=silhouettes,
                            cameras=cameras)


def _psnr_iou(result, images, sils, cams, renderer):
    img, _ = renderer(cams, result.volume)
    mse = np.mean((img[..., :3] - images) ** 2)
    pred, gt = img[..., 3] > 0.5, sils > 0.5
    return 10 * np.log10(1.0 / mse), (pred & gt).sum() / (pred | gt).sum()


# ------------------------------------------------------------------------------- loss, gradient


def test_huber_value_and_gradient():
    """The tutorial's pseudo-Huber: closed form at 0 and s, exact derivative."""
    v, g = huber(np.array([0.0, 0.1, -0.3]), 0.0, 0.1)
    np.testing.assert_allclose(v, [0.0, 0.1 * (np.sqrt(2) - 1), 0.1 * (np.sqrt(10) - 1)])
    x = np.random.default_rng(0).normal(size=20)
    y = np.random.default_rng(1).normal(size=20)
    _, g = huber(x, y, 0.3)
    h = 1e-6
    fd = (huber(x + h, y, 0.3)[0] - huber(x - h, y, 0.3)[0]) / (2 * h)
    np.testing.assert_allclose(g, fd, atol=1e-8)
    with pytest.raises(ValueError, match="scaling"):
        huber(x, y, 0.0)


def _small_level(scene, termination, smoothness, dtype=np.float64):
    """A level objective: 3 of the scene's views at 12 px, an 8^3 grid whose allowed voxels
    are a box of density 0.3; returns it and its density grid."""
    images, sils, cams, _, _ = scene
    grid = fv._Grid((8, 8, 8), 3.0 / 8, np.zeros(3))
    o, d, L = fv._rays(cams[:3], 12, 12, 30, 0.1, 3.0)
    rgb = fv._downsample(images[:3], 2).reshape(-1, 3)
    sil = fv._downsample(sils[:3], 2).reshape(-1)
    allowed = np.zeros(grid.size, bool)
    allowed[1:7, 2:6, 1:7] = True
    dens = np.where(allowed, 0.3, 0.0)
    return fv._Objective(grid, o, d, L, rgb, sil, dens, allowed, termination=termination,
                         n_pixels=3 * 144, huber_scale=0.1, dtype=dtype,
                         smoothness=smoothness), dens


@pytest.mark.parametrize("termination,smoothness", [(None, (0.0, 0.0)), (1e-2, (0.3, 0.2))])
def test_objective_gradient_finite_differences(scene, termination, smoothness):
    """The level objective's analytic gradient matches central differences (float64)."""
    p, dens = _small_level(scene, termination, smoothness)
    grid = p.grid
    rng = np.random.default_rng(2)
    x = p.pack(fv._logit(dens).reshape(-1) + rng.normal(0, 0.5, grid.n),
               rng.normal(0, 1, (3, grid.n)))
    value, grad, terms = p.evaluate(x)
    assert value == pytest.approx(sum(terms.values()))
    assert ("smoothness" in terms) == (smoothness[0] > 0)
    idx = np.concatenate([rng.choice(p.n_free_density, 8, replace=False),
                          p.n_free_density + rng.choice(3 * p.n_columns, 8, replace=False)])
    h = 1e-6
    for i in idx:
        e = np.zeros_like(x)
        e[i] = h
        fd = (p.evaluate(x + e, want_grad=False)[0] - p.evaluate(x - e, want_grad=False)[0]) / (
            2 * h)
        assert abs(grad[i] - fd) <= 1e-6 * np.abs(grad).max() + 1e-12
    # float32 arithmetic agrees to float32 precision
    p32, _ = _small_level(scene, termination, smoothness, np.float32)
    v32, g32, _ = p32.evaluate(x)
    assert abs(v32 - value) < 1e-6 * value
    assert np.abs(g32 - grad).max() < 1e-5 * np.abs(grad).max()


def test_ray_losses_reuse_the_last_evaluation(scene):
    """Each ray's loss averages to the image terms; asked at the point evaluated last, it is
    that evaluation's (no new sweep), bit for bit what a fresh computation gives."""
    def problem():
        return _small_level(scene, 1e-2, (0.3, 0.2), np.float32)[0]
    p, dens = _small_level(scene, 1e-2, (0.3, 0.2), np.float32)
    rng = np.random.default_rng(3)
    x = p.pack(fv._logit(dens).reshape(-1), rng.normal(0, 1, (3, p.grid.n)))
    x2 = x + rng.normal(0, 0.3, x.size)
    p.evaluate(x2)
    _, _, terms = p.evaluate(x)
    sweep = p._sweep
    p._sweep = lambda *a, **k: pytest.fail("ray_losses swept again at the last point")
    at_x = p.ray_losses(x.copy())
    p._sweep = sweep
    assert at_x.mean() == pytest.approx(terms["colour"] + terms["silhouette"], rel=1e-9)
    np.testing.assert_array_equal(at_x, problem().ray_losses(x))
    np.testing.assert_array_equal(p.ray_losses(x2), problem().ray_losses(x2))


def test_objective_matches_renderer(scene):
    """Without termination the skipping objective renders exactly what VolumeRenderer does."""
    images, sils, cams, truth, renderer = scene
    grid = fv._Grid((16, 16, 16), 3.0 / 16, np.zeros(3))
    o, d, L = fv._rays(cams[:2], SIZE, SIZE, N_PTS, 0.1, 3.0)
    allowed = truth.densities > 0
    p = fv._Objective(grid, o, d, L, images[:2].reshape(-1, 3), sils[:2].reshape(-1),
                    truth.densities, allowed, termination=None, n_pixels=2 * SIZE * SIZE,
                    huber_scale=0.1)
    x = p.pack(fv._logit(truth.densities).reshape(-1), fv._logit(truth.features).reshape(3, -1))
    value, _ = p.evaluate(x, want_grad=False)
    # the same model through the public renderer (logits round-trip the values)
    vol = Volume(np.where(allowed, fv._sigmoid(fv._logit(truth.densities)), 0.0),
                 fv._sigmoid(fv._logit(truth.features)), voxel_size=3.0 / 16)
    img, _ = renderer(cams[:2], vol)
    hc, _ = huber(img[..., :3], images[:2], 0.1)
    hs, _ = huber(img[..., 3], sils[:2], 0.1)
    assert value == pytest.approx(hc.mean() + hs.mean(), rel=1e-10)
    assert p.n_samples < 0.5 * len(o) * N_PTS       # empty space was skipped


# ---------------------------------------------------------------------------------- visual hull


def test_visual_hull_keeps_the_object_and_carves_outside(scene):
    """Every occupied voxel survives carving; far voxels and voxels outside a view are carved."""
    _, sils, cams, truth, _ = scene
    hull = visual_hull(sils, cams, 16, 3.0 / 16)
    occupied = truth.densities > 0
    assert hull[occupied].all()
    centres = Volume(np.zeros((16, 16, 16)), voxel_size=3.0 / 16).get_coord_grid()
    # nothing survives in the top and bottom layers (|y| = 1.41; the object's half-height is
    # 0.5 and the footprint bound adds at most ~0.7 at this coarse resolution)
    assert not hull[np.abs(centres[..., 1]) > 1.3].any()
    assert hull.sum() < 0.6 * hull.size
    # a view whose silhouette is empty carves everything, unless tolerated
    bad = sils.copy()
    bad[0] = 0.0
    assert not visual_hull(bad, cams, 16, 3.0 / 16).any()
    tolerant = visual_hull(bad, cams, 16, 3.0 / 16, tolerance=1)
    assert tolerant[occupied].all()
    assert visual_hull(sils, cams, 16, 3.0 / 16, margin=3.0).sum() > hull.sum()


def test_visual_hull_validation(scene):
    _, sils, cams, _, _ = scene
    with pytest.raises(ValueError, match="silhouettes"):
        visual_hull(sils[0], cams, 16, 0.2)
    with pytest.raises(ValueError, match="cameras"):
        visual_hull(sils, cams[:3], 16, 0.2)
    with pytest.raises(TypeError, match="cameras"):
        visual_hull(sils, "cams", 16, 0.2)
    with pytest.raises(ValueError, match="voxel_size"):
        visual_hull(sils, cams, 16, -1.0)
    with pytest.raises(ValueError, match="threshold"):
        visual_hull(sils, cams, 16, 0.2, threshold=1.0)
    with pytest.raises(ValueError, match="tolerance"):
        visual_hull(sils, cams, 16, 0.2, tolerance=-1)
    with pytest.raises(ValueError, match="volume_size"):
        visual_hull(sils, cams, 1, 0.2)


# -------------------------------------------------------------------------------------- fitting


@pytest.mark.parametrize("method", ["lbfgs", "lbfgs-nlopt", "adam"])
def test_fit_recovers_the_scene(scene, method):
    """geofit's methods fit the training views well with fewer voxels and samples than dense."""
    images, sils, cams, _, renderer = scene
    res = fit_volume(_ds(images, sils, cams), options=VolumeFitOptions(method=method,
            volume_size=16, n_pts_per_ray=N_PTS, levels=(8, 16), iterations=(40, 40),
            precision="float64"), progress=False)
    assert isinstance(res, VolumeFitResult) and res.ok
    assert res.status in ("max_iter", "converged", "stalled", "max_eval")
    assert res.volume.grid_size == (16, 16, 16)
    assert np.all(np.isfinite(res.volume.densities)) and np.all(np.isfinite(res.volume.features))
    psnr, iou = _psnr_iou(res, images, sils, cams, renderer)
    assert psnr > 20.0 and iou > 0.9, (psnr, iou)
    assert 0 < res.n_active_voxels < 16 ** 3
    assert res.samples_per_ray < N_PTS
    assert len(res.stages) == 2 and res.stages[-1]["level"] == 16
    loss = res.history.as_arrays()["loss"]
    assert loss[-1] < 0.5 * loss[0]
    assert set(res.history.terms) == {"colour", "silhouette", "smoothness"}


def test_tutorial_recipe_runs_dense(scene):
    """The tutorial recipe optimises every voxel with Adam on random view batches."""
    images, sils, cams, _, _ = scene
    seen = []
    res = fit_volume(_ds(images, sils, cams), recipe="tutorial",
            options=VolumeFitOptions(volume_size=16, n_pts_per_ray=N_PTS, batch_size=3, n_iter=12),
            seed=0, evaluator=lambda v: seen.append(v) or {"n": float(len(seen))}, eval_every=10**9,
            progress=False)
    assert res.status == "max_iter" and res.n_iterations == 12
    assert res.n_active_voxels == 16 ** 3 and res.n_params == 4 * 16 ** 3
    assert len(res.history) == 12 and len(seen) == 1
    loss = res.history.as_arrays()["loss"]
    assert np.mean(loss[-3:]) < np.mean(loss[:3])


def test_monitor_and_time_budget(scene):
    """The monitor sees finite volumes at checkpoints; a tiny budget ends with time_budget."""
    images, sils, cams, _, _ = scene
    calls = []

    def monitor(vol):
        calls.append(vol)
        assert np.all(np.isfinite(vol.densities))
        return {"mean_density": float(vol.densities.mean())}

    res = fit_volume(_ds(images, sils, cams), options=VolumeFitOptions(volume_size=16,
            n_pts_per_ray=N_PTS, levels=(8, 16), iterations=(5, 5)), evaluator=monitor,
            progress=False)
    assert len(calls) >= 2 and "mean_density" in res.history.metric_names
    quick = fit_volume(_ds(images, sils, cams), options=VolumeFitOptions(volume_size=16,
            n_pts_per_ray=N_PTS, levels=(8, 16), iterations=(500, 500)), time_budget=0.05,
            progress=False)
    assert quick.status == "time_budget"
    assert np.all(np.isfinite(quick.volume.densities))


# ------------------------------------------------------------------------------ failure modes


def test_all_black_target_is_empty_not_nan(scene):
    """Black images and empty silhouettes: nothing is carved in, the volume stays finite."""
    images, sils, cams, _, renderer = scene
    res = fit_volume(_ds(np.zeros_like(images), np.zeros_like(sils), cams),
            options=VolumeFitOptions(volume_size=16, n_pts_per_ray=N_PTS, levels=(8, 16),
            iterations=(10, 10)), progress=False)
    assert res.ok and np.all(np.isfinite(res.volume.densities))
    assert res.n_active_voxels == 0 and res.volume.densities.max() == 0.0
    img, _ = renderer(cams, res.volume)
    assert img.max() == 0.0


def test_huge_learning_rate_stays_finite(scene):
    """Adam with lr 1e6 saturates the sigmoids but never produces NaN."""
    images, sils, cams, _, _ = scene
    res = fit_volume(_ds(images, sils, cams), options=VolumeFitOptions(method="adam", lr=1e6,
            volume_size=16, n_pts_per_ray=N_PTS, levels=(8, 16), iterations=(10, 10)),
            progress=False)
    assert res.status == "diverged" and "learning rate" in res.message
    assert np.all(np.isfinite(res.volume.densities)) and np.all(np.isfinite(res.volume.features))
    assert np.all(np.isfinite(res.history.as_arrays()["loss"]))
    tut = fit_volume(_ds(images, sils, cams), recipe="tutorial", options=VolumeFitOptions(lr=1e6,
            volume_size=16, n_pts_per_ray=N_PTS, batch_size=3, n_iter=6), progress=False)
    assert tut.status == "diverged" and "saturation" in tut.message
    assert np.all(np.isfinite(tut.volume.densities))


def test_wrong_camera_and_noise_keep_a_usable_fit(scene):
    """Noisy images and one view with a wrong camera: the hull tolerates it, the fit is fine."""
    images, sils, cams, _, renderer = scene
    rng = np.random.default_rng(3)
    noisy = np.clip(images + rng.normal(0, 0.05, images.shape), 0, 1)
    R = cams.R.copy()
    T = cams.T.copy()
    R[2], T[2] = look_at_view_transform(2.7, 40.0, 123.0)[0][0], look_at_view_transform(
        2.7, 40.0, 123.0)[1][0]
    wrong = FoVPerspectiveCameras(R=R, T=T)
    res = fit_volume(_ds(noisy, sils, wrong), options=VolumeFitOptions(volume_size=16,
            n_pts_per_ray=N_PTS, levels=(8, 16), iterations=(30, 30), carve_tolerance=1),
            progress=False)
    assert res.ok
    assert res.view_losses.shape == (len(images),) and np.argmax(res.view_losses) == 2
    assert "views [2] fit much worse" in res.message
    good = np.setdiff1d(np.arange(len(images)), [2])
    psnr, iou = _psnr_iou(res, images[good], sils[good], cams[good], renderer)
    assert iou > 0.8 and psnr > 15.0, (psnr, iou)


def test_fit_validation(scene):
    """Invalid inputs and settings raise ValueError/TypeError naming the argument."""
    images, sils, cams, _, _ = scene
    with pytest.raises(TypeError, match="dataset"):
        fit_volume(images, progress=False)
    with pytest.raises(ValueError, match="dataset"):
        fit_volume(MultiViewDataset(images=None, silhouettes=sils, cameras=cams), progress=False)
    with pytest.raises(ValueError, match="recipe"):
        fit_volume(_ds(images, sils, cams), recipe="dense", progress=False)
    with pytest.raises(ValueError, match="method"):
        fit_volume(_ds(images, sils, cams), recipe="tutorial",
                options=VolumeFitOptions(method="lbfgs"), progress=False)
    with pytest.raises(ValueError, match="method"):
        fit_volume(_ds(images, sils, cams), options=VolumeFitOptions(method="sgd"),
                progress=False)
    with pytest.raises(ValueError, match="levels"):
        fit_volume(_ds(images, sils, cams), options=VolumeFitOptions(volume_size=16, levels=(16,
                8)), progress=False)
    with pytest.raises(ValueError, match="volume_size"):
        fit_volume(_ds(images, sils, cams), options=VolumeFitOptions(volume_size=1),
                progress=False)
    with pytest.raises(ValueError, match="iterations"):
        fit_volume(_ds(images, sils, cams), options=VolumeFitOptions(volume_size=16, levels=(8,
                16), iterations=(0, 1)), progress=False)
    with pytest.raises(ValueError, match="termination"):
        fit_volume(_ds(images, sils, cams), options=VolumeFitOptions(termination=2.0),
                progress=False)
    with pytest.raises(ValueError, match="precision"):
        fit_volume(_ds(images, sils, cams), options=VolumeFitOptions(precision="float16"),
                progress=False)
    with pytest.raises(ValueError, match="max_depth"):
        fit_volume(_ds(images, sils, cams), options=VolumeFitOptions(min_depth=3.0, max_depth=1.0),
                progress=False)
    with pytest.raises(ValueError, match="batch_size"):
        fit_volume(_ds(images, sils, cams), recipe="tutorial",
                options=VolumeFitOptions(batch_size=0), progress=False)
    with pytest.raises(TypeError, match="evaluator"):
        fit_volume(_ds(images, sils, cams), evaluator=3, progress=False)
    assert set(FIT_VOLUME_METHODS) == {"lbfgs", "lbfgs-nlopt", "adam"}


def test_recipes_options_callback_and_checkpoints(scene):
    """Recipes are frozen VolumeFitOptions presets; a callback(StepInfo) sees each step's level
    and terms and stops the fit; the evaluator runs every eval_every steps."""
    import dataclasses

    images, sils, cams, _, _ = scene
    opts = VolumeFitOptions(volume_size=16, n_pts_per_ray=N_PTS, levels=(8, 16),
                            iterations=(3, 3))
    assert RECIPES["tutorial"].method == "adam" and RECIPES["default"].method == "lbfgs"
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.lr = 1.0
    new = fit_volume(_ds(images, sils, cams), options=opts, progress=False)
    assert new.method == "lbfgs" and new.recipe == "default" and new.init is None
    seen = []

    def stop(info):
        seen.append((info.stage, set(info.terms)))
        return len(seen) >= 2

    res = fit_volume(_ds(images, sils, cams), options=opts, callback=stop, progress=False)
    assert res.status == "callback" and len(seen) == 2 and seen[0][0] == 0
    assert seen[0][1] == {"colour", "silhouette", "smoothness"}
    calls = []
    res = fit_volume(_ds(images, sils, cams), options=opts, progress=False, eval_every=1,
            evaluator=lambda vol: calls.append(vol.grid_size) or {"n": len(calls)})
    assert len(res.history.checkpoints) >= len(res.history) and len(calls) >= len(res.history)
    with pytest.raises(TypeError, match="options: expected a VolumeFitOptions"):
        fit_volume(_ds(images, sils, cams), options={"volume_size": 8}, progress=False)

# ------------------------------------------------------------------------------------- datasets


def test_cow_renders_and_held_out_views():
    """tutorial_views(5) follows generate_cow_renders' cameras; held-out views sit between
    them."""
    from geofit.datasets import held_out_views, training_azimuths, tutorial_views

    data = tutorial_views(5, num_views=3, image_size=24, num_held_out=0)
    assert data.held_out is None
    assert data.images.shape == (3, 24, 24, 3) and data.silhouettes.shape == (3, 24, 24)
    np.testing.assert_allclose(data.azim, [0.0, 180.0, 360.0])
    np.testing.assert_allclose(data.elev, 0.0)
    assert set(np.unique(data.silhouettes)) <= {0.0, 1.0}
    lit = data.images.max(axis=-1) > 0.0
    assert lit.any() and np.all(data.silhouettes[lit] == 1.0)   # colour only inside
    assert data.images[data.silhouettes == 0].max() == 0.0        # black background
    R, T = look_at_view_transform(2.7, 0.0, data.azim)
    np.testing.assert_allclose(data.cameras.R, R, atol=1e-12)
    np.testing.assert_allclose(data.cameras.T, T, atol=1e-12)
    sub = data.subset([0, 2])
    assert len(sub) == 2 and sub.azim.tolist() == [0.0, 360.0]
    test = held_out_views(num_views=5, elevations=(0.0, 20.0), n_azimuths=2, image_size=16)
    mids = 0.5 * (training_azimuths(5)[1:] + training_azimuths(5)[:-1])
    assert len(test) == 4 and set(test.azim.tolist()) <= set(mids.tolist())
    np.testing.assert_allclose(test.elev, [0, 0, 20, 20])
    with pytest.raises(ValueError, match="num_views"):
        tutorial_views(5, num_views=0)
    with pytest.raises(ValueError, match="n_azimuths"):
        held_out_views(num_views=5, n_azimuths=9)
    with pytest.raises(ValueError, match="background"):
        tutorial_views(5, num_views=1, image_size=8, background=(2.0, 0, 0))


def test_one_visual_hull_for_fit_volume_and_occupancy_grid(scene):
    """OccupancyGrid.from_silhouettes and fit_volume's visual_hull are one implementation
    (geofit.structures.volume.carve): the occupancy grid equals a per-voxel reference loop
    (a voxel is kept when the pixel of its centre is inside every dilated silhouette)."""
    from scipy.ndimage import binary_dilation

    import geofit.fit.volume
    from geofit.render import OccupancyGrid
    from geofit.structures import volume as sv

    assert geofit.fit.volume.visual_hull is sv.visual_hull
    _, sils, cams, _, _ = scene
    grid = OccupancyGrid.from_silhouettes(sils, cams, resolution=8, dilate_pixels=1)
    masks = np.stack([binary_dilation(s > 0.5, np.ones((3, 3), bool)) for s in sils])
    M = cams.get_full_projection_transform()
    N, H, W = sils.shape
    expected = np.ones(8 ** 3, bool)
    for k, c in enumerate(grid.centers().reshape(-1, 3)):  # voxels (reference loop)
        for v in range(N):  # views
            h = np.append(c, 1.0) @ M[v]
            col = np.rint((W - 1 - h[0] / h[3] * min(H, W)) / 2.0)
            row = np.rint((H - 1 - h[1] / h[3] * min(H, W)) / 2.0)
            if not (h[3] > 0 and 0 <= col < W and 0 <= row < H and masks[v, int(row), int(col)]):
                expected[k] = False
                break
    np.testing.assert_array_equal(grid.occupied.reshape(-1), expected)
    assert 0 < expected.sum() < expected.size


def test_grid_centres_of_some_voxels_and_row_block_views():
    """Centres of selected voxels are get_coord_grid's values; a row block of W (a small one:
    scipy's constructor would copy it) and its transpose share W's arrays, and their products
    are W[r0:r1]'s, entry for entry."""
    import scipy.sparse as sp

    g = fv._Grid((5, 6, 7), 0.3, np.array([0.1, -0.2, 0.05]))
    ref = Volume(np.zeros(g.size), voxel_size=g.voxel_size,
                 volume_translation=g.translation).get_coord_grid().reshape(-1, 3)
    flat = np.array([0, 3, 41, 77, g.n - 1])
    np.testing.assert_array_equal(g.centres(flat), ref[flat])
    np.testing.assert_array_equal(g.centres(), ref)
    W = sp.random(300, 50, density=0.1, format="csr", dtype=np.float32, random_state=1)
    B = fv._row_block(W, 40, 90)
    Bt = fv._transposed(B)
    assert B.shape == (50, 50) and Bt.shape == (50, 50)
    for M in (B, Bt):
        assert np.shares_memory(M.data, W.data) and np.shares_memory(M.indices, W.indices)
    x = np.random.default_rng(0).random(50).astype(np.float32)
    y = np.random.default_rng(1).random(50).astype(np.float32)
    np.testing.assert_array_equal(B @ x, W[40:90] @ x)
    np.testing.assert_array_equal(Bt @ y, W[40:90].T @ y)
