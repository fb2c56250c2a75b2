"""NeRF: the field's backward pass and the whole pipeline from pixels to weights against central
finite differences (float64, tiny networks), the field against a per-sample reference loop and
closed forms, empty-space skipping against the full render, the fit's statuses and every
validation branch."""
from __future__ import annotations

import math

import numpy as np
import pytest
from _helpers import benchmark_module

from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
from geofit.structures import MultiViewDataset
from geofit.fit.nerf import (
    NerfConfig,
    fit_nerf,
    render_nerf,
    sample_images_at_xys,
)
from geofit.loss import huber
from geofit.metrics import psnr
from geofit.render.volume.implicit import ImplicitRenderer, NeuralRadianceField, OccupancyGrid
from geofit.render.volume.raymarching import EmissionAbsorptionRaymarcher
from geofit.render.volume import MonteCarloRaysampler, NDCMultinomialRaysampler, RayBundle


def tiny_field(activation="softplus", seed=1, **kw):
    opts = {"n_harmonic_functions": 3, "n_hidden_neurons": 6, "omega0": 1.0,
            "n_harmonic_functions_dir": 2, "n_hidden_color": 5, "activation": activation,
            "seed": seed, "dtype": np.float64, "density_bias": 0.3}
    opts.update(kw)
    return NeuralRadianceField(**opts)


def cameras(n=2, dist=2.7):
    R, T = look_at_view_transform(dist, np.linspace(0, 20, n), np.linspace(150, 210, n))
    return FoVPerspectiveCameras(R=R, T=T)


def fd_check(fun, field, grad, n=40, h=1e-6, seed=0):
    """Compare ``grad`` (flat) with central differences of ``fun()`` at ``n`` random weights."""
    x0 = field.get_flat()
    idx = np.random.default_rng(seed).choice(x0.size, size=min(n, x0.size), replace=False)
    fd = np.empty(idx.size)
    for j, i in enumerate(idx):  # checked coordinates
        e = np.zeros_like(x0)
        e[i] = h
        field.set_flat(x0 + e)
        fp = fun()
        field.set_flat(x0 - e)
        fm = fun()
        fd[j] = (fp - fm) / (2 * h)
    field.set_flat(x0)
    np.testing.assert_allclose(grad[idx], fd, rtol=1e-5, atol=1e-9)


# ------------------------------------------------------------------------------------- the field
def test_tutorial_network_size_and_names():
    """The tutorial's network: 317,188 parameters named as its state_dict, shapes PyTorch's."""
    f = NeuralRadianceField()
    assert f.n_params == 317188
    shapes = {k: v.shape for k, v in f.params.items()}
    assert shapes == {
        "mlp.0.weight": (256, 360), "mlp.0.bias": (256,),
        "mlp.2.weight": (256, 256), "mlp.2.bias": (256,),
        "density_layer.0.weight": (1, 256), "density_layer.0.bias": (1,),
        "color_layer.0.weight": (256, 616), "color_layer.0.bias": (256,),
        "color_layer.2.weight": (3, 256), "color_layer.2.bias": (3,),
    }
    assert f.params["density_layer.0.bias"][0] == np.float32(-1.5)
    assert all(v.dtype == np.float32 for v in f.params.values())


@pytest.mark.parametrize("activation", ["softplus", "relu"])
@pytest.mark.parametrize("per_ray", [True, False])
def test_field_backward_matches_finite_differences(activation, per_ray):
    """d<Gd, densities> + <Gc, colours> / d weights equals central differences (float64)."""
    f = tiny_field(activation)
    rng = np.random.default_rng(3)
    pts = rng.uniform(-1, 1, (9, 3))
    if per_ray:
        dirs, idx = rng.normal(size=(4, 3)), rng.integers(0, 4, 9)
    else:
        dirs, idx = rng.normal(size=(9, 3)), None
    scale = rng.uniform(0.5, 2.0, 9)
    Gd, Gc = rng.normal(size=(9, 1)), rng.normal(size=(9, 3))

    def fun():
        d, c, _ = f.forward(pts, dirs, idx, step_scale=scale, cache=False)
        return float(np.sum(Gd * d) + np.sum(Gc * c))

    _, _, cache = f.forward(pts, dirs, idx, step_scale=scale)
    grads = f.backward(cache, Gd, Gc)
    assert list(grads) == list(f.params)
    fd_check(fun, f, f.flatten_grads(grads), n=60)


def _reference_field(f: NeuralRadianceField, p, direction):
    """One sample, written out as the tutorial's modules compute it (a slow reference)."""
    def emb(x, e):
        th = np.outer(x, e.frequencies.astype(np.float64)).ravel()
        parts = [np.sin(th), np.cos(th)] + ([x] if e.append_input else [])
        return np.concatenate(parts)

    def sp(x, beta=10.0):
        return np.where(beta * x > 20, x, np.log1p(np.exp(beta * x)) / beta)

    P = f.params
    h = emb(p, f.embedding)
    for i in (0, 2):
        h = sp(P[f"mlp.{i}.weight"] @ h + P[f"mlp.{i}.bias"])
    raw = sp(P["density_layer.0.weight"] @ h + P["density_layer.0.bias"])
    dens = 1 - np.exp(-raw)
    dn = direction / np.linalg.norm(direction)
    x = np.concatenate([h, emb(dn, f.dir_embedding)])
    x = sp(P["color_layer.0.weight"] @ x + P["color_layer.0.bias"])
    col = 1 / (1 + np.exp(-(P["color_layer.2.weight"] @ x + P["color_layer.2.bias"])))
    return dens, col


def test_field_matches_per_sample_reference_loop():
    """Packed, per-ray-direction evaluation equals the per-sample reference (tutorial layout)."""
    f = tiny_field(append_input=True)
    rng = np.random.default_rng(5)
    pts, dirs = rng.uniform(-1, 1, (7, 3)), rng.normal(size=(3, 3))
    idx = np.array([0, 0, 1, 2, 2, 2, 1])
    d, c, _ = f.forward(pts, dirs, idx, cache=False)
    for i in range(7):  # samples of a tiny input
        rd, rc = _reference_field(f, pts[i], dirs[idx[i]])
        np.testing.assert_allclose(d[i], rd, rtol=1e-12)
        np.testing.assert_allclose(c[i], rc, rtol=1e-12)


def test_field_closed_form_with_zero_weights():
    """All weights 0: density = 1 - exp(-softplus(b)), colour = sigmoid(b2) everywhere."""
    f = tiny_field()
    f.set_flat(np.zeros(f.n_params))
    f.params["density_layer.0.bias"][0] = -1.5
    f.params["color_layer.2.bias"][:] = [0.0, 1.0, -2.0]
    d, c, _ = f.forward(np.random.default_rng(0).normal(size=(5, 3)), np.ones((5, 3)),
                        cache=False)
    np.testing.assert_allclose(d, 1 - np.exp(-np.log1p(np.exp(-15.0)) / 10), rtol=1e-12)
    np.testing.assert_allclose(c, np.tile(1 / (1 + np.exp(-np.array([0.0, 1.0, -2.0]))),
                                          (5, 1)), rtol=1e-12)


def test_flat_roundtrip_and_astype():
    f = tiny_field()
    x = np.arange(f.n_params, dtype=np.float64) / f.n_params
    f.set_flat(x)
    np.testing.assert_array_equal(f.get_flat(), x)
    g = f.astype(np.float32)
    assert g.dtype == np.float32 and g.params["mlp.0.weight"].dtype == np.float32
    np.testing.assert_allclose(g.get_flat(), x, rtol=1e-6)
    g.set_flat(np.zeros(f.n_params))
    assert f.get_flat()[1] == x[1]  # copies are independent
    assert "n_params" in repr(f)


def test_call_and_forward_batched_agree():
    """The tutorial's volumetric_function and its batched form give the same arrays."""
    f = tiny_field()
    bundle = MonteCarloRaysampler(-1, 1, -1, 1, 10, 6, 1.0, 3.0)(cameras(), seed=0)
    d1, c1 = f(bundle, cameras=None)
    d2, c2 = f.forward_batched(bundle, n_batches=3)
    assert d1.shape == (2, 10, 6, 1) and c1.shape == (2, 10, 6, 3)
    np.testing.assert_allclose(d1, d2, rtol=1e-12)
    np.testing.assert_allclose(c1, c2, rtol=1e-12)
    assert f.batched_forward == f.forward_batched


# -------------------------------------------------------------------------------------- renderer
def _skipping_renderer(sampler, use_grid: bool, z_range):
    """EA renderer of ``sampler``, with an occupancy grid (occupied: x, y in cells 1..4, z in
    ``z_range``) if ``use_grid``."""
    grid = None
    if use_grid:
        occ = np.zeros((6, 6, 6), bool)
        occ[1:5, 1:5, z_range[0]:z_range[1]] = True
        grid = OccupancyGrid(occ, [[-1.2] * 3, [1.2] * 3])
    return ImplicitRenderer(sampler, EmissionAbsorptionRaymarcher(), occupancy=grid)


@pytest.mark.parametrize("with_grid", [False, True])
def test_fit_nerf_composed_loss_matches_finite_differences(with_grid):
    """fit_nerf's training loss (Huber colour + weighted Huber silhouette + opacity regulariser
    on one fixed ray batch) has the gradient of its value, by central differences in float64."""
    f = tiny_field()
    sampler = MonteCarloRaysampler(-0.5, 0.5, -0.5, 0.5, 6, 8, 1.5, 3.5)
    ren = _skipping_renderer(sampler, with_grid, (1, 5))
    bundle = MonteCarloRaysampler(-0.5, 0.5, -0.5, 0.5, 6, 8, 1.5, 3.5)(cameras(), seed=5)
    flat = RayBundle(*(np.asarray(a).reshape(-1, a.shape[-1]) for a in bundle))
    R = flat.origins.shape[0]
    rng = np.random.default_rng(7)
    tgt_rgb, tgt_sil = rng.random((R, 3)), rng.random(R)
    sil_w = (rng.random(R) > 0.3).astype(np.float64)
    # the training step's own loss (geofit.fit._nerf_train), on a stand-in for its state
    from types import SimpleNamespace

    from geofit.fit._nerf_train import _Solver

    cfg = SimpleNamespace(huber_scale=0.1, n_pts_per_ray=8, opacity_regularization=0.05)
    state = SimpleNamespace(cfg=cfg, n_threads=1, renderer=ren, field=f, reg_on=True)

    def loss():
        return _Solver.loss_and_grads(state, flat, tgt_rgb, tgt_sil, sil_w)

    terms, grads, spr = loss()
    assert set(terms) == {"color", "silhouette", "opacity"}
    assert all(v > 0 for v in terms.values()) and spr > 0
    fd_check(lambda: sum(loss()[0].values()), f, f.flatten_grads(grads), n=60)


@pytest.mark.parametrize("use_grid", [False, True])
def test_pipeline_pixels_to_weights_matches_finite_differences(use_grid):
    """d<G, render>/d weights (sampler -> field -> EA raymarcher) equals central differences,
    with and without empty-space skipping."""
    f = tiny_field()
    ren = _skipping_renderer(MonteCarloRaysampler(-0.5, 0.5, -0.5, 0.5, 6, 9, 1.5, 3.5), use_grid,
                             (2, 4))
    img, bundle, cache = ren.render(cameras(), f, seed=4)
    if use_grid:
        assert 0 < cache.samples_per_ray < 9
    G = np.random.default_rng(1).normal(size=img.shape)
    grads = ren.backward(f, cache, G)
    fd_check(lambda: float(np.sum(G * ren.render_bundle(bundle, f))), f, f.flatten_grads(grads))


def test_extra_density_gradient_matches_finite_differences():
    """backward(..., grad_densities=c) adds d(sum_k c_k alpha_k)/d weights (a regulariser on
    the evaluated samples' opacities), checked by central differences."""
    f = tiny_field()
    ren = ImplicitRenderer(MonteCarloRaysampler(-0.5, 0.5, -0.5, 0.5, 5, 8, 1.5, 3.5),
                           EmissionAbsorptionRaymarcher())
    img, bundle, cache = ren.render(cameras(1), f, seed=2)
    rng = np.random.default_rng(3)
    G = rng.normal(size=img.shape)
    c = rng.normal(size=cache.ray_index.size)
    grads = ren.backward(f, cache, G, c)

    def fun():
        im, _, cc = ren.render(None, f, ray_bundle=bundle)
        return float(np.sum(G * im) + np.sum(c * cc.sample_densities()))

    fd_check(fun, f, f.flatten_grads(grads))
    with pytest.raises(ValueError, match="grad_densities"):
        ren.backward(f, cache, G, c[:-1])


def test_skipping_equals_zero_density_outside_the_grid():
    """Rendering with an occupancy grid equals the full render of the field with its density
    set to 0 outside the grid (the raymarcher sees zeros there)."""
    f = tiny_field(density_bias=1.0)
    occ = np.zeros((8, 8, 8), bool)
    occ[2:6, 1:7, 3:5] = True
    grid = OccupancyGrid(occ, [[-1.0] * 3, [1.0] * 3])
    sampler = NDCMultinomialRaysampler(image_width=6, image_height=5, n_pts_per_ray=20,
                                       min_depth=1.5, max_depth=3.9)
    cams = cameras()
    skip = ImplicitRenderer(sampler, EmissionAbsorptionRaymarcher(), occupancy=grid)

    def masked(bundle):
        d, c = f(bundle)
        inside = grid.contains(bundle.points())
        return d * inside[..., None], c

    full = ImplicitRenderer(sampler, EmissionAbsorptionRaymarcher())
    a, _ = skip(cams, f)
    b, _ = full(cams, masked)
    assert a.shape == (2, 5, 6, 4) and np.abs(a[..., 3]).max() > 0.1
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)  # eps of 1e-10 per skipped sample


def test_occlusion_culling_keeps_margin_behind_opaque_voxels():
    """With an opaque slab in the grid's opacity, samples more than `margin` kept samples past
    the slab's first sample are skipped; earlier ones are all kept."""
    occ = np.ones((1, 1, 40), bool)          # a row of 40 voxels along x in [0, 4]
    opacity = np.zeros((1, 1, 40), np.float32)
    opacity[0, 0, 10:] = 1.0                  # opaque from x = 1
    grid = OccupancyGrid(occ, [[0, -0.05, -0.05], [4.0, 0.05, 0.05]], opacity)
    o = np.array([[-1.0, 0.0, 0.0]])
    d = np.array([[1.0, 0.0, 0.0]])
    lengths = (np.arange(50) * 0.1 + 0.05)[None]          # samples at x = -0.95 ... 3.95
    bundle = RayBundle(o, d, lengths, np.zeros((1, 2)))
    for margin in (0, 3):
        ren = ImplicitRenderer(lambda *a, **k: None, EmissionAbsorptionRaymarcher(),
                               occupancy=grid, min_transmittance=1e-3, occlusion_margin=margin)
        pts, _, slot, _ = ren._select(bundle)
        # kept: x in (0, 1) -> 10 samples, plus the first opaque one, plus the margin
        assert pts.shape[0] == 11 + margin
        np.testing.assert_array_equal(slot, np.arange(11 + margin))
    ren = ImplicitRenderer(lambda *a, **k: None, EmissionAbsorptionRaymarcher(), occupancy=grid)
    assert ren._select(bundle)[0].shape[0] == 40   # no culling without min_transmittance


def test_visual_hull_of_a_sphere():
    """Silhouettes of a ball: the hull contains the ball and excludes points far outside it."""
    R, T = look_at_view_transform(2.7, np.tile([-60.0, 0.0, 60.0], 4),
                                  np.linspace(0, 360, 12, endpoint=False))
    cams = FoVPerspectiveCameras(R=R, T=T)
    rays = cams.pixel_rays((32, 32))
    # silhouette: ray meets the ball of radius 0.5 at the origin
    o, d = rays.origins, rays.directions
    b = np.einsum("...i,...i", o, d)
    c = np.einsum("...i,...i", o, o) - 0.25
    a = np.einsum("...i,...i", d, d)
    sil = (b * b - a * c > 0).astype(float)
    grid = OccupancyGrid.from_silhouettes(sil, cams, resolution=32, bounds=[[-1] * 3, [1] * 3],
                                          dilate_pixels=1)
    u = np.random.default_rng(0).normal(size=(500, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    assert grid.contains(0.45 * u).all()
    assert not grid.contains(0.95 * u).any()
    assert 0.05 < grid.fraction_occupied < 0.3
    assert grid.dilate(1).fraction_occupied > grid.fraction_occupied


def test_occupied_box_and_empty_grid():
    occ = np.zeros((4, 4, 4), bool)
    g = OccupancyGrid(occ, [[0, 0, 0], [4, 4, 4]])
    assert g.occupied_box() is None
    ren = ImplicitRenderer(MonteCarloRaysampler(-1, 1, -1, 1, 3, 5, 1, 3),
                           EmissionAbsorptionRaymarcher(), occupancy=g)
    img, _, cache = ren.render(cameras(1), tiny_field(), seed=0)
    np.testing.assert_array_equal(img, 0.0)
    grads = ren.backward(tiny_field(), cache, np.ones_like(img))
    assert all(np.all(v == 0) for v in grads.values())
    occ[1, 2, 3] = True
    np.testing.assert_allclose(OccupancyGrid(occ, [[0, 0, 0], [4, 4, 4]]).occupied_box(),
                               [[3, 2, 1], [4, 3, 2]])


# ------------------------------------------------------------------------------- fit utilities
def test_huber_matches_closed_form_and_finite_differences():
    x = np.array([-0.3, 0.0, 0.05, 2.0])
    v, g = huber(x, 0.0, 0.1)
    np.testing.assert_allclose(v, 0.1 * (np.sqrt(1 + (x / 0.1) ** 2) - 1), rtol=1e-14)
    h = 1e-7
    fd = (huber(x + h, 0.0, 0.1)[0] - huber(x - h, 0.0, 0.1)[0]) / (2 * h)
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-9)


def test_psnr():
    assert psnr(np.zeros(3), np.zeros(3)) == math.inf
    assert psnr(np.full(4, 0.5), np.zeros(4)) == pytest.approx(10 * math.log10(4))


def test_sample_images_at_xys_matches_bilinear_loop():
    """grid_sample(image, -xys, align_corners=True): corners hit pixel centres exactly, and
    interior points are bilinear (against a per-point loop)."""
    rng = np.random.default_rng(0)
    img = rng.uniform(size=(2, 5, 7, 3))
    xys = np.array([[[1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]]] * 2)
    out = sample_images_at_xys(img, xys)
    np.testing.assert_allclose(out[:, 0], img[:, 0, 0])      # NDC (+1, +1): top-left
    np.testing.assert_allclose(out[:, 1], img[:, -1, -1])
    np.testing.assert_allclose(out[:, 2], img[:, -1, 0])
    xy = rng.uniform(-1, 1, (2, 4, 2))
    got = sample_images_at_xys(img, xy)
    for b in range(2):  # a reference loop over a few points
        for i in range(4):
            u = (1 - xy[b, i, 0]) * 6 / 2
            v = (1 - xy[b, i, 1]) * 4 / 2
            u0, v0 = int(np.floor(u)), int(np.floor(v))
            fu, fv = u - u0, v - v0
            ref = ((1 - fu) * (1 - fv) * img[b, v0, u0] + fu * (1 - fv) * img[b, v0, min(u0 + 1, 6)]
                   + (1 - fu) * fv * img[b, min(v0 + 1, 4), u0]
                   + fu * fv * img[b, min(v0 + 1, 4), min(u0 + 1, 6)])
            np.testing.assert_allclose(got[b, i], ref, rtol=1e-12)


def test_silhouette_weights_leave_out_an_inner_band():
    """The silhouette loss weights are 0 exactly in a `margin`-pixel band inside the edge."""
    from geofit.fit._nerf_train import _silhouette_weights

    sil = np.zeros((1, 12, 12))
    sil[0, 2:10, 3:11] = 1.0
    w = _silhouette_weights(sil, 2)
    expected = np.ones((12, 12))
    expected[2:10, 3:11] = 0.0
    expected[4:8, 5:9] = 1.0
    np.testing.assert_array_equal(w[0], expected)


# ------------------------------------------------------------------------------------------ fit
@pytest.fixture(scope="module")
def toy_scene():
    """Targets rendered from a 'teacher' field restricted to a small ball (8 views, 16 px)."""
    teacher = NeuralRadianceField(2, 8, omega0=1.0, n_harmonic_functions_dir=1, n_hidden_color=8,
                                  activation="relu", seed=11, density_bias=3.0)
    occ = np.zeros((16, 16, 16), bool)
    c = (np.arange(16) + 0.5) / 16 * 2 - 1
    Z, Y, X = np.meshgrid(c, c, c, indexing="ij")
    occ[X ** 2 + Y ** 2 + Z ** 2 < 0.5 ** 2] = True
    ball = OccupancyGrid(occ, [[-1] * 3, [1] * 3])
    R, T = look_at_view_transform(2.7, np.tile([0.0, 25.0], 5), np.linspace(0, 360, 10,
                                                                             endpoint=False))
    cams = FoVPerspectiveCameras(R=R, T=T)
    imgs = render_nerf(teacher, cams, 16, n_pts_per_ray=32, occupancy=ball)
    return imgs[..., :3], (imgs[..., 3] > 0.5).astype(float), cams


def _ds(images, silhouettes, cameras) -> MultiViewDataset:
    return MultiViewDataset(images=images, silhouettes=silhouettes, cameras=cameras)


_SKELETON = benchmark_module("_skeleton_check")


def small_config(**kw):
    """The skeleton check's small NeRF (benchmarks/_skeleton_check.py), 60 steps by default."""
    return _SKELETON._small_nerf(**{"n_iter": 60, "density_grid_warmup": 20, **kw})


def test_fit_scene_preset_learns_and_reports(toy_scene):
    """The scene-sized fit lowers the loss, reports size, samples per ray, held-out PSNR and
    returns full-image renders of the held-out views."""
    imgs, sils, cams = toy_scene
    train, test = np.arange(8), np.arange(8, 10)
    res = fit_nerf(_ds(imgs[train], sils[train], cams[train]), options=small_config(),
                   evaluator=(imgs[test], sils[test], cams[test]), seed=0, progress=False)
    assert res.status == "max_iter" and res.ok, res.message
    L = np.array(res.history.loss)
    assert L[-10:].mean() < 0.5 * L[:5].mean()
    assert res.n_params == res.field.n_params and res.history.n_params[-1] == res.n_params
    assert 0 < res.samples_per_ray < 32
    assert res.images.shape == (2, 16, 16, 4) and np.isfinite(res.psnr)
    assert res.psnr == pytest.approx(psnr(np.clip(res.images[..., :3], 0, 1), imgs[test]))
    assert res.history.checkpoints and "psnr" in res.history.metric_names
    assert res.history.events and "density grid" in res.history.events[0]["message"]
    s = res.summary()
    assert s["samples_per_ray"] == res.samples_per_ray and s["config"]["activation"] == "relu"


def test_fit_with_silhouette_margin(toy_scene):
    """With a silhouette margin the fit still learns (the band carries only the RGB loss)."""
    imgs, sils, cams = toy_scene
    res = fit_nerf(_ds(imgs[:8], sils[:8], cams[:8]),
                   options=small_config(silhouette_margin=1),
                   evaluator=(imgs[8:], sils[8:], cams[8:]), seed=0, progress=False)
    L = np.array(res.history.loss)
    assert res.ok and L[-10:].mean() < 0.7 * L[:5].mean() and res.psnr > 20, res.psnr


def test_fit_tutorial_preset_runs_montecarlo_recipe(toy_scene):
    """The tutorial preset: MC rays, every sample evaluated, step decay with Adam restart."""
    imgs, sils, cams = toy_scene
    cfg = NerfConfig.tutorial(n_harmonic_functions=2, n_hidden_neurons=8, n_pts_per_ray=16,
                              n_rays_per_image=20, batch_size=2, n_iter=8, n_threads=2)
    res = fit_nerf(_ds(imgs, sils, cams), options=cfg, seed=1, progress=False)
    assert res.status == "max_iter" and res.samples_per_ray == 16
    assert res.occupancy is None and res.psnr is None and res.images is None
    assert len(res.history.loss) == 8


@pytest.mark.parametrize("lr", [5.0, 50.0])
def test_fit_huge_learning_rate_never_nan(toy_scene, lr):
    """A learning rate 250x / 2500x too large: no NaN anywhere, and status 'diverged' with a
    message saying the held-out loss got worse than the untrained network's."""
    imgs, sils, cams = toy_scene
    res = fit_nerf(_ds(imgs[:8], sils[:8], cams[:8]), options=small_config(lr=lr, n_iter=40),
                   evaluator=(imgs[8:], sils[8:], cams[8:]), seed=0, progress=False)
    assert np.all(np.isfinite(res.field.get_flat()))
    assert res.status == "diverged" and "no progress" in res.message
    assert np.all(np.isfinite(res.images)) and np.isfinite(res.psnr)
    assert not np.isnan(res.history.loss).any()


@pytest.mark.parametrize("lr, status", [(2e-2, "max_iter"), (0.2, "diverged"),
                                        (5.0, "diverged")])
def test_fit_without_held_out_flags_a_stuck_training_loss(toy_scene, lr, status):
    """Without held-out views, a training loss that does not fall (a dead network) is
    reported as 'diverged'; a healthy run is not."""
    imgs, sils, cams = toy_scene
    res = fit_nerf(_ds(imgs, sils, cams), options=small_config(lr=lr, n_iter=60), seed=0,
                   progress=False)
    assert res.status == status
    if status == "diverged":
        assert "training loss" in res.message
    assert np.all(np.isfinite(res.field.get_flat()))


def test_fit_nonfinite_gradient_returns_last_finite(toy_scene, monkeypatch):
    """A NaN gradient stops the fit with status 'nonfinite' and finite parameters."""
    imgs, sils, cams = toy_scene
    calls = {"n": 0}
    orig = ImplicitRenderer.backward

    def poisoned(self, field, cache, g, *extra):
        calls["n"] += 1
        grads = orig(self, field, cache, g, *extra)
        if calls["n"] >= 3:
            grads["mlp.0.weight"][0, 0] = np.nan
        return grads

    monkeypatch.setattr(ImplicitRenderer, "backward", poisoned)
    # one chunk per step here, so that the 3rd backward call is the 3rd step
    monkeypatch.setattr("geofit.fit._nerf_train._MIN_PARTS", 1)
    res = fit_nerf(_ds(imgs, sils, cams), options=small_config(n_iter=10), seed=0, progress=False)
    assert res.status == "nonfinite" and "NaN" in res.message
    assert np.all(np.isfinite(res.field.get_flat())) and len(res.history.loss) == 3


def test_fit_early_stopping_on_held_out_loss(toy_scene):
    """Held-out targets the field cannot approach (noise): the held-out loss stops improving
    and the fit stops early with status 'converged', returning the best checkpoint."""
    imgs, sils, cams = toy_scene
    noise = np.random.default_rng(0).uniform(size=imgs[8:].shape)
    res = fit_nerf(_ds(imgs[:8], sils[:8], cams[:8]), options=small_config(n_iter=200, early_stopping=2),
                   evaluator=(noise, 1 - sils[8:], cams[8:]), eval_every=5,
                   seed=0, progress=False)
    assert res.status == "converged" and res.n_iterations < 200
    hl = [c["held_out_loss"] for c in res.history.checkpoints]
    assert min(hl) <= hl[-1]


def test_fit_time_budget_and_callback(toy_scene):
    imgs, sils, cams = toy_scene
    res = fit_nerf(_ds(imgs, sils, cams), options=small_config(n_iter=10 ** 6), time_budget=0.5,
                   seed=0, progress=False)
    # the budget counts the fit's whole wall time (its paused checkpoints too), so the wall
    # time reaches it; FitResult.seconds (the solver's time without those pauses) need not
    assert res.status == "time_budget" and res.wall_seconds >= 0.5
    seen = []
    res = fit_nerf(_ds(imgs, sils, cams), options=small_config(n_iter=100), eval_every=4,
                   callback=lambda info: seen.append(info.iteration) or len(seen) >= 2, seed=0,
                   progress=False)
    assert res.status == "callback" and seen == [4, 8]


@pytest.mark.parametrize("kw, match", [
    ({"recipe": "nerf"}, "recipe"),
    ({"ray_sampling": "grid"}, "ray_sampling"),
    ({"occupancy": "all"}, "occupancy"),
    ({"lr_schedule": "cosine"}, "lr_schedule"),
    ({"activation": "tanh"}, "activation"),
    ({"dtype": "float16"}, "dtype"),
    ({"batch_size": 0}, "batch_size"),
    ({"n_pts_per_ray": 2.5}, "n_pts_per_ray"),
    ({"occlusion_margin": -1}, "occlusion_margin"),
    ({"lr": 0.0}, "lr"),
    ({"min_transmittance": 1.0}, "min_transmittance"),
    ({"lr_decay_at": 1.5}, "lr_decay_at"),
    ({"min_depth": 3.0, "max_depth": 1.0}, "max_depth"),
    ({"n_threads": 0}, "n_threads"),
    ({"bounds": (1, 2)}, "bounds"),
    ({"occupancy": "none"}, "ray_sampling"),
    ({"time_budget": -1.0}, "time_budget"),
    ({"eval_every": 0}, "eval_every"),
    ({"early_stopping": 2}, "evaluator"),
    ({"early_stopping": 0}, "early_stopping"),
])
def test_fit_validation(toy_scene, kw, match):
    """Invalid settings raise ValueError naming the setting (NerfConfig fields go into the
    options, the rest are fit_nerf's own keywords)."""
    imgs, sils, cams = toy_scene
    own = {k: kw.pop(k) for k in ("recipe", "time_budget", "eval_every") if k in kw}
    opts = NerfConfig.scene(**kw) if kw else None
    with pytest.raises(ValueError, match=match):
        fit_nerf(_ds(imgs, sils, cams), options=opts, evaluator=None, progress=False, **own)


def test_fit_input_validation(toy_scene):
    imgs, sils, cams = toy_scene
    with pytest.raises(TypeError, match="dataset"):
        fit_nerf(imgs, progress=False)
    with pytest.raises(ValueError, match="dataset"):
        fit_nerf(MultiViewDataset(images=None, silhouettes=sils, cameras=cams), progress=False)
    with pytest.raises(TypeError, match="options"):
        fit_nerf(_ds(imgs, sils, cams), options={"lr": 1}, progress=False)
    with pytest.raises(TypeError, match="evaluator"):
        fit_nerf(_ds(imgs, sils, cams), evaluator=(1, 2), progress=False)
    with pytest.raises(TypeError, match="unexpected keyword"):
        fit_nerf(_ds(imgs, sils, cams), n_iter=3, progress=False)


def test_fit_recipes_options_and_default_held_out(toy_scene):
    """Recipes are frozen NerfConfig presets; a dataset's held_out is the default evaluator,
    None turns it off."""
    import dataclasses

    from geofit.fit.nerf import RECIPES

    imgs, sils, cams = toy_scene
    assert RECIPES["default"] == NerfConfig.scene() and RECIPES["tutorial"] == NerfConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        RECIPES["default"].lr = 1.0
    cfg = small_config(n_iter=6)
    new = fit_nerf(_ds(imgs, sils, cams), options=cfg, seed=0, progress=False)
    assert new.method == "adam" and new.recipe == "default" and new.init is None
    ds = _ds(imgs[:8], sils[:8], cams[:8])
    ds.held_out = _ds(imgs[8:], sils[8:], cams[8:])
    assert fit_nerf(ds, options=cfg, progress=False).images.shape == (2, 16, 16, 4)
    assert fit_nerf(ds, options=cfg, evaluator=None, progress=False).images is None


@pytest.mark.parametrize("make, exc, match", [
    (lambda: tiny_field().forward(np.zeros((3, 2)), np.ones((3, 3))), ValueError, "points"),
    (lambda: tiny_field().forward(np.zeros((3, 3)), np.ones((2, 3))), ValueError, "directions"),
    (lambda: tiny_field().forward(np.zeros((3, 3)), np.zeros((3, 3))), ValueError, "non-zero"),
    (lambda: tiny_field().forward(np.zeros((2, 3)), np.ones((1, 3)), [0, 1]), ValueError,
     "ray_index"),
    (lambda: tiny_field().forward(np.zeros((2, 3)), np.ones((2, 3)), step_scale=[1.0]),
     ValueError, "step_scale"),
    (lambda: tiny_field().forward(np.zeros((2, 3)), np.ones((2, 3)), step_scale=-1.0),
     ValueError, "step_scale"),
    (lambda: tiny_field().backward(None, np.zeros((1, 1)), np.zeros((1, 3))), TypeError, "cache"),
    (lambda: tiny_field().set_params({"nope": 1}), ValueError, "unknown"),
    (lambda: tiny_field().set_params({"mlp.0.bias": np.ones(2)}), ValueError, "shape"),
    (lambda: tiny_field().set_flat(np.ones(3)), ValueError, "x"),
    (lambda: NeuralRadianceField(activation="gelu"), ValueError, "activation"),
    (lambda: NeuralRadianceField(n_hidden_neurons=0), ValueError, "n_hidden_neurons"),
    (lambda: NeuralRadianceField(n_hidden_layers=1.5), ValueError, "n_hidden_layers"),
    (lambda: tiny_field()(np.zeros(3)), TypeError, "ray_bundle"),
    (lambda: tiny_field().forward_batched(
        RayBundle(np.zeros((2, 3)), np.ones((2, 3)), np.ones((3, 4)), np.zeros((2, 2)))),
     ValueError, "ray_bundle"),
    (lambda: OccupancyGrid(np.ones((2, 2)), [[0] * 3, [1] * 3]), ValueError, "occupied"),
    (lambda: OccupancyGrid(np.ones((2, 2, 2)), [[0] * 3, [0] * 3]), ValueError, "bounds"),
    (lambda: OccupancyGrid(np.ones((2, 2, 2)), [[0] * 3, [1] * 3], np.full((2, 2, 2), 2.0)),
     ValueError, "opacity"),
    (lambda: OccupancyGrid(np.ones((2, 2, 2)), [[0] * 3, [1] * 3]).contains(np.ones(2)),
     ValueError, "points"),
    (lambda: OccupancyGrid.from_silhouettes(np.ones((2, 4, 4)), cameras(3)), ValueError,
     "cameras"),
    (lambda: ImplicitRenderer(None, EmissionAbsorptionRaymarcher()), TypeError, "raysampler"),
    (lambda: ImplicitRenderer(MonteCarloRaysampler(-1, 1, -1, 1, 2, 2, 1, 2), object()),
     TypeError, "raymarcher"),
    (lambda: ImplicitRenderer(MonteCarloRaysampler(-1, 1, -1, 1, 2, 2, 1, 2),
                              EmissionAbsorptionRaymarcher(), occupancy=np.ones(3)), TypeError,
     "occupancy"),
    (lambda: ImplicitRenderer(MonteCarloRaysampler(-1, 1, -1, 1, 2, 2, 1, 2),
                              EmissionAbsorptionRaymarcher(), min_transmittance=1.0), ValueError,
     "min_transmittance"),
    (lambda: ImplicitRenderer(MonteCarloRaysampler(-1, 1, -1, 1, 2, 2, 1, 2),
                              EmissionAbsorptionRaymarcher()).render(cameras(1), lambda b: b),
     TypeError, "field"),
    (lambda: ImplicitRenderer(MonteCarloRaysampler(-1, 1, -1, 1, 2, 2, 1, 2),
                              EmissionAbsorptionRaymarcher()).backward(tiny_field(), None, 0),
     TypeError, "cache"),
    (lambda: render_nerf("field", cameras(1)), TypeError, "field"),
    (lambda: render_nerf(tiny_field(), "cams"), TypeError, "cameras"),
    (lambda: sample_images_at_xys(np.ones((2, 3, 3, 1)), np.ones((1, 4, 2))), ValueError, "xys"),
    (lambda: psnr(np.ones(2), np.ones(3)), ValueError, "pred"),
    (lambda: huber(np.ones(2), 0.0, 0.0), ValueError, "scaling"),
])
def test_component_validation(make, exc, match):
    """Every validation branch of the field, grid, renderer and helpers names its argument."""
    with pytest.raises(exc, match=match):
        make()


# ------------------------------------------------------------------------------------------ CLI


def test_fit_same_seed_same_network_on_1_and_2_threads(toy_scene):
    """The same seed gives the same network whatever the thread count: a training step is cut
    into chunks independently of the threads, and the chunks' gradients are summed in order."""
    imgs, sils, cams = toy_scene
    fields = []
    for n_threads in (1, 2):
        res = fit_nerf(_ds(imgs[:8], sils[:8], cams[:8]), options=small_config(
            n_iter=25, n_threads=n_threads), seed=3, progress=False)
        fields.append(res.field)
    p1, p2 = (np.concatenate([np.ravel(v) for v in f.params.values()]) for f in fields)
    assert p1.size > 100
    np.testing.assert_array_equal(p1, p2)
