"""Tests for geofit.fit.views (fit a mesh and its colours to multi-view images) and the
``geofit fit-views`` command line.

Objects are small procedural meshes (an ellipsoid with smooth vertex colours) rendered at
24-32 px, so every fit runs in seconds.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from geofit import FoVPerspectiveCameras, Mesh, TexturesVertex, ico_sphere, look_at_view_transform
from geofit.structures import MultiViewDataset, TexturesUV
from geofit.datasets import tutorial_views
from geofit.fit._views_objective import (_lstsq_colors, _Objective, _silhouette_residual,
                                             regularizers, silhouette_pinning)
from geofit.loss import mesh_laplacian_smoothing
from geofit.ops import uniform_laplacian
from geofit.fit.large_steps import IdentityParameterization, LargeSteps
from geofit.fit.views import (
    SILHOUETTE_METHODS,
    ViewsEvaluator,
    ViewsFitOptions,
    fit_mesh_to_views,
    render_mesh_at_views,
)
from geofit.metrics import psnr, silhouette_iou
from geofit.render.soft import SoftRasterizationSettings


def _object(level=3):
    """An ellipsoid (semi-axes 0.9, 0.6, 0.5) with smooth vertex colours."""
    m = ico_sphere(level)
    V = m.verts * np.array([0.9, 0.6, 0.5])
    c = 0.5 + 0.4 * np.stack([np.sin(3 * V[:, 0]), np.cos(4 * V[:, 1]), V[:, 2]], 1)
    return Mesh(V, m.faces, TexturesVertex(np.clip(c, 0, 1)))


#: A short silhouette stage alone (no RGB stage, vertex colours: no UV atlas), for the tests of
#: options that act in the silhouette stage and compare its vertices (0.5 CPU s a fit where
#: the default's RGB stage and texture made it 2.5 CPU s, measured warm).
_SILHOUETTE_STAGE_ONLY = dict(init="sphere", silhouette_iters=4, levels=((0, 1),),
                              remesh_rounds=0, textured_method="none", rgb_iters=0,
                              texture="vertex")


@pytest.fixture(scope="module")
def data() -> MultiViewDataset:
    return tutorial_views(4, mesh=_object(), num_views=6, image_size=24, num_held_out=3)


# ------------------------------------------------------------------------------------------
# dataset and metrics
# ------------------------------------------------------------------------------------------


def test_dataset_follows_the_tutorial(data):
    """20-view recipe geometry: elev linspace(0, 360), azim linspace(-180, 180), distance 2.7;
    soft silhouettes in [0, 1] with a soft rim, binary held-out masks, white background."""
    tr, ho = data, data.held_out
    assert tr.silhouettes.shape == (6, 24, 24) and tr.images.shape == (6, 24, 24, 3)
    np.testing.assert_allclose(data.elev, np.linspace(0, 360, 6))
    np.testing.assert_allclose(data.azim, np.linspace(-180, 180, 6))
    R, _ = look_at_view_transform(2.7, np.linspace(0, 360, 6), np.linspace(-180, 180, 6))
    np.testing.assert_allclose(tr.cameras.R, R, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(tr.cameras.get_camera_center(), axis=1), 2.7)
    s = tr.silhouettes
    assert s.min() >= 0 and s.max() <= 1 and np.any((s > 0.01) & (s < 0.99))
    assert set(np.unique(ho.silhouettes)) <= {0.0, 1.0}
    bg = tr.silhouettes < 1e-6
    np.testing.assert_allclose(tr.images[bg], 1.0)
    # held-out directions differ from every training direction
    ct, ch = tr.cameras.get_camera_center(), ho.cameras.get_camera_center()
    d = np.linalg.norm(ct[:, None] - ch[None], axis=2)
    assert d.min() > 0.05
    np.testing.assert_allclose(data.lights.location, [[0.0, 0.0, -3.0]])


def test_iou_and_psnr_closed_forms():
    a = np.zeros((2, 4, 4))
    b = np.zeros((2, 4, 4))
    a[0, :2] = 1.0      # 8 pixels
    b[0, :1] = 1.0      # 4 of them
    np.testing.assert_allclose(silhouette_iou(a, b), [0.5, 1.0])   # empty view: 1
    x = np.full((3, 3), 0.5)
    assert psnr(x, x + 0.1) == pytest.approx(20.0)                  # 10 log10(1 / 0.01)
    assert psnr(x, x) == math.inf
    with pytest.raises(ValueError, match="pred, target"):
        silhouette_iou(a, b[:1])
    with pytest.raises(ValueError, match="pred, target"):
        psnr(x, x[:2])


def test_evaluator_scores_the_truth_perfectly(data):
    """The true mesh gets IoU 1, chamfer 0, F-score 1 and a PSNR limited only by the vertex
    colours' interpolation (here the truth *is* vertex-coloured: identical images)."""
    ev = ViewsEvaluator(data.held_out, data.mesh, n_samples=2000)
    m = ev(data.mesh, data.mesh.textures.verts_features)
    assert m["iou"] == 1.0
    assert m["chamfer_l2"] < 1e-12 and m["fscore@0.01"] == 1.0
    assert m["psnr"] > 60.0
    worse = ev(ico_sphere(2), np.full((162, 3), 0.5))
    assert worse["iou"] < 0.9 and worse["chamfer_l2"] > 1e-3 and worse["psnr"] < m["psnr"]


# ------------------------------------------------------------------------------------------
# objective pieces
# ------------------------------------------------------------------------------------------


def test_large_steps_parameterisation_is_consistent():
    """to_verts(to_params(V)) == V and grad_params is the adjoint of to_verts
    (<g, J u> = <J^T g, u>), on flat parameter vectors as the fits use them."""
    m = ico_sphere(2)
    for p in (LargeSteps(m, 10.0), IdentityParameterization(m)):
        np.testing.assert_allclose(p.to_verts(p.to_params(m.verts).ravel()), m.verts,
                                   atol=1e-12)
        rng = np.random.default_rng(0)
        u, g = rng.normal(size=3 * m.n_verts), rng.normal(size=(m.n_verts, 3))
        assert np.sum(g * p.to_verts(u)) == pytest.approx(np.sum(p.grad_params(g).ravel() * u),
                                                          rel=1e-12)


@pytest.mark.parametrize("textured,large", [(False, None), (True, None), (False, 5.0)])
def test_objective_gradient_matches_finite_differences(data, textured, large):
    """The composed objective (data terms, edge / normal / Laplacian / normal-variation terms,
    parameterisation): a central difference along a random direction matches <grad, u>."""
    m = ico_sphere(2)
    m = m.update_verts(m.verts * 0.7)
    param = LargeSteps(m, large) if large else IdentityParameterization(m)
    weights = {"silhouette": 1.0, "rgb": 1.0, "edge": 1.0, "normal": 0.01, "laplacian": 1.0,
               "normal_variation": 0.05}
    st = SoftRasterizationSettings.tutorial(24, perspective_correct=False if textured else None,
                                            dtype=np.float64)  # exact to float64
    obj = _Objective(m, data, weights, textured=textured, param=param, settings=st)
    x = param.to_params(m.verts).ravel()
    if textured:
        x = np.concatenate([x, np.random.default_rng(1).uniform(0.2, 0.8, 3 * m.n_verts)])
    f, g = obj(x)
    assert np.all(np.isfinite(g)) and f > 0
    u = np.random.default_rng(2).normal(size=x.shape)
    h = 1e-7
    fd = (obj(x + h * u)[0] - obj(x - h * u)[0]) / (2 * h)
    assert fd == pytest.approx(float(g @ u), rel=1e-4)
    regs = {"edge", "normal", "laplacian", "normal_variation"}
    assert set(obj.last["terms"]) == regs | ({"silhouette", "rgb"} if textured else
                                             {"silhouette"})


@pytest.mark.parametrize("large", [None, 5.0])
def test_log_transmittance_silhouette_gradient_matches_finite_differences(data, large):
    """options.silhouette_log_eps: the silhouette residual in log-transmittance
    (-log(1 - S + e)); a central difference along a random direction matches <grad, u>."""
    m = ico_sphere(2)
    m = m.update_verts(m.verts * 0.7)
    param = LargeSteps(m, large) if large else IdentityParameterization(m)
    st = SoftRasterizationSettings.tutorial(24, dtype=np.float64)
    obj = _Objective(m, data, {"silhouette": 1.0, "edge": 1.0, "laplacian": 1.0}, textured=False,
                     param=param, settings=st, log_eps=0.02)
    x = param.to_params(m.verts).ravel()
    f, g = obj(x)
    assert np.all(np.isfinite(g)) and f > 0
    plain = _Objective(m, data, {"silhouette": 1.0, "edge": 1.0, "laplacian": 1.0},
                       textured=False, param=param, settings=st)
    assert f > plain(x)[0]  # the log branch is exercised (the sphere covers background)
    u = np.random.default_rng(2).normal(size=x.shape)
    h = 1e-7
    fd = (obj(x + h * u)[0] - obj(x - h * u)[0]) / (2 * h)
    assert fd == pytest.approx(float(g @ u), rel=1e-4)


def test_log_transmittance_residual_keeps_the_truth_and_weighs_covered_pixels():
    """r = 0 where S = T (a mesh rendering the targets stays a minimum); on background pixels
    (T < e) the mesh over-covers, the chain rule's factor (1 - S) dr/dS is (1 - S) / (1 - S + e)
    instead of 1 - S; under-covered pixels and T >= e keep r = S - T."""
    S = np.array([0.0, 0.3, 0.95, 0.999])
    r, dr = _silhouette_residual(S, S, 0.02)
    np.testing.assert_allclose(r, 0.0, atol=1e-15)
    r0, dr0 = _silhouette_residual(S, np.zeros(4), 0.0)
    np.testing.assert_allclose(r0, S)
    assert dr0 == 1.0
    e = 0.02
    r1, dr1 = _silhouette_residual(S, np.zeros(4), e)
    np.testing.assert_allclose(r1, np.log((1 + e) / (1 - S + e)), rtol=1e-12)
    assert (1 - S[2]) * dr1[2] == pytest.approx(0.05 / 0.07, rel=1e-12)   # 0.05 plain
    # the target above e, or the mesh under-covering: the plain residual
    T = np.array([0.5, 0.5, 0.5, 0.5])
    r2, dr2 = _silhouette_residual(S, T, e)
    np.testing.assert_allclose(r2, S - T)
    np.testing.assert_allclose(dr2, 1.0)
    r3, dr3 = _silhouette_residual(np.array([0.005]), np.array([0.01]), e)
    np.testing.assert_allclose(r3, [-0.005])
    # C1 at S = T: the residual's two branches both vanish there
    lo, _ = _silhouette_residual(np.array([0.01 - 1e-9]), np.array([0.01]), e)
    hi, _ = _silhouette_residual(np.array([0.01 + 1e-9]), np.array([0.01]), e)
    assert abs(lo[0]) < 2e-9 and abs(hi[0]) < 2e-9


@pytest.mark.parametrize("textured", [False, True])
def test_objective_batches_on_threads_are_bit_identical(data, textured):
    """Whole view batches on each of 2 threads (6 views in 2 batches of 3) give exactly the
    value and gradient of the batches one after the other on 1 thread."""
    from geofit import set_num_threads

    m = ico_sphere(2)
    m = m.update_verts(m.verts * 0.7)
    weights = {"silhouette": 1.0, "rgb": 1.0, "edge": 1.0, "laplacian": 1.0}
    st = SoftRasterizationSettings.tutorial(24)
    obj = _Objective(m, data, weights, textured=textured, param=IdentityParameterization(m),
                     settings=st, max_views=3)
    x = m.verts.ravel()
    if textured:
        x = np.concatenate([x, np.random.default_rng(1).uniform(0.2, 0.8, 3 * m.n_verts)])
    out = {}
    try:
        for n in (1, 2):  # threads
            set_num_threads(n)
            out[n] = obj(x)
    finally:
        set_num_threads(None)
    assert out[1][0] == out[2][0]
    np.testing.assert_array_equal(out[1][1], out[2][1])


def test_lstsq_colours_recover_known_vertex_colours():
    """With the true geometry the hard render is affine in the colours: one sparse solve
    recovers the colours of every vertex the views see well."""
    obj = _object(2)
    ds = tutorial_views(4, mesh=obj, num_views=8, image_size=48, num_held_out=1)
    c = _lstsq_colors(Mesh(obj.verts, obj.faces), ds, 1e-6)
    truth = obj.textures.verts_features
    err = np.abs(c - truth).max(1)
    assert np.median(err) < 0.02
    ev = ViewsEvaluator(ds)
    assert ev(Mesh(obj.verts, obj.faces), c)["psnr"] > 35.0


# ------------------------------------------------------------------------------------------
# fits
# ------------------------------------------------------------------------------------------


def _iou(data, mesh):
    return ViewsEvaluator(data.held_out)(mesh)["iou"]


@pytest.mark.parametrize("method,kw", [
    ("sgd", {"silhouette_iters": 60}),
    ("lbfgs", {"silhouette_iters": 25}),
    ("lbfgs-nlopt", {"silhouette_iters": 40}),
    ("lbfgs", {"silhouette_iters": 30, "large_steps": 5.0, "levels": [(0, 2), (1, 1)],
               "remesh_rounds": 0}),
    ("adam", {"silhouette_iters": 60, "large_steps": 5.0, "adam_lr": 0.01,
              "silhouette_loss": "contour"}),
])
def test_silhouette_methods_improve_the_fit(data, method, kw):
    """Every silhouette method ends with a status from STATUSES, a lower loss, and a better
    held-out IoU than the starting sphere."""
    init = ico_sphere(2)
    res = fit_mesh_to_views(data, options=ViewsFitOptions(
        init=init, silhouette_method=method, textured_method="none", **kw))
    h = res.history
    assert res.ok and res.status in ("converged", "max_iter", "max_eval", "stalled")
    assert len(h) > 3 and h.loss[-1] < h.loss[0]
    assert np.all(np.isfinite(h.loss))
    assert _iou(data, res.mesh) > _iou(data, init.update_verts(init.verts)) + 0.05
    assert res.stages[0]["method"] == method and res.colors is None
    if kw.get("levels"):
        assert res.mesh.n_verts == ico_sphere(3).n_verts
        assert len([e for e in h.events if "level" in e["message"]]) == 2


def test_textured_fit_is_finite_at_every_step(data):
    """The tutorial's textured recipe (SGD on positions and colours, perspective-correct
    barycentrics, as the tutorial had before it switched them off for the NaN) and the joint
    L-BFGS: every step's value, gradient and parameters are finite."""
    seen = []

    def check(rec):
        seen.append(rec.stage)
        assert math.isfinite(rec.value)
        assert np.all(np.isfinite(rec.x))
        assert all(math.isfinite(v) for v in rec.terms.values())

    for method, init in (("sgd", "sphere"), ("lbfgs", "silhouette")):
        res = fit_mesh_to_views(data, options=ViewsFitOptions(init=ico_sphere(2),
                silhouette_method="sgd", silhouette_iters=15, textured_method=method,
                textured_init=init, textured_iters=15), callback=check, progress=False)
        assert res.ok, res.message
        assert np.all(np.isfinite(res.history.loss))
        assert np.all(np.isfinite(res.mesh.verts)) and np.all(np.isfinite(res.colors))
        assert res.colors.shape == (res.mesh.n_verts, 3)
    assert 100 in seen and 0 in seen


def test_textured_stage_improves_psnr(data):
    """Least-squares colours beat uniform grey on held-out views; the joint L-BFGS (positions
    and colours) then lowers its training loss without losing held-out PSNR."""
    ev = ViewsEvaluator(data.held_out)
    res = fit_mesh_to_views(data, recipe="sphere-lbfgs",
            options=ViewsFitOptions(init=ico_sphere(2), silhouette_iters=25,
            textured_method="lbfgs", textured_iters=10), progress=False)
    sil = res.silhouette_mesh
    grey = ev(sil, np.full((sil.n_verts, 3), 0.5))["psnr"]
    lsq = fit_mesh_to_views(data, options=ViewsFitOptions(init=sil, silhouette_method="none",
            textured_method="lstsq"), progress=False)
    assert lsq.stages[0]["name"] == "textured" and lsq.n_iterations == 0
    p_lsq = ev(lsq.mesh, lsq.colors)["psnr"]
    assert p_lsq > grey + 0.5
    tex = res.history.as_arrays()
    rows = tex["stage"] == 100
    assert rows.sum() >= 2 and tex["loss"][rows][-1] < tex["loss"][rows][0]
    assert ev(res.mesh, res.colors)["psnr"] > p_lsq - 0.2
    assert [s["name"] for s in res.stages] == ["silhouette", "textured"]
    assert isinstance(res.mesh.textures, TexturesVertex)


def test_evaluate_and_callback_hooks(data):
    """Checkpoints carry the evaluator's metrics with the clock paused; a callback returning
    True stops the stage with status 'callback'."""
    ev = ViewsEvaluator(data.held_out)
    res = fit_mesh_to_views(data, options=ViewsFitOptions(init=ico_sphere(2),
            silhouette_method="lbfgs", silhouette_iters=10, textured_method="none"),
            evaluator=lambda m, c: ev(m, c), eval_every=1, progress=False)
    assert len(res.history.checkpoints) == len(res.history)
    assert res.history.metric_names == ("iou",)
    res = fit_mesh_to_views(data, options=ViewsFitOptions(init=ico_sphere(2),
            silhouette_method="sgd", silhouette_iters=50, textured_method="none"),
            callback=lambda info: info.iteration >= 5, progress=False)
    assert res.status == "callback" and len(res.history) == 5


# ------------------------------------------------------------------------------------------
# stability
# ------------------------------------------------------------------------------------------


def _perturbed(data, kind, rng):
    tr = data
    if kind == "few_views":
        return tr[np.arange(0, 6, 2)]
    if kind == "noisy":
        noisy = np.clip(tr.silhouettes + rng.normal(0, 0.2, tr.silhouettes.shape), 0, 1)
        return MultiViewDataset(images=tr.images, silhouettes=noisy, cameras=tr.cameras,
                                lights=tr.lights)
    if kind == "hole":
        s = tr.silhouettes.copy()
        s[:, 10:14, 10:14] = 0.0
        return MultiViewDataset(images=tr.images, silhouettes=s, cameras=tr.cameras,
                                lights=tr.lights)
    if kind == "camera_1deg":
        R, T = look_at_view_transform(2.7, data.elev + 1.0, data.azim + 1.0)
        return MultiViewDataset(images=tr.images, silhouettes=tr.silhouettes,
                                cameras=FoVPerspectiveCameras(R=R, T=T), lights=tr.lights)
    return tr


@pytest.mark.parametrize("kind", ["few_views", "noisy", "hole", "camera_1deg", "small",
                                  "off_centre"])
def test_stability_cases_end_with_a_clear_status(data, kind):
    """Every perturbation: a status from STATUSES, finite results, no worse than the start."""
    rng = np.random.default_rng(0)
    views = _perturbed(data, kind, rng)
    init = ico_sphere(2)
    if kind == "small":
        init = init.update_verts(init.verts * 0.2)
    if kind == "off_centre":
        init = init.update_verts(init.verts * 0.6 + [0.3, 0.2, 0.0])
    for method in ("lbfgs", "sgd"):
        res = fit_mesh_to_views(views, options=ViewsFitOptions(init=init, silhouette_method=method,
                silhouette_iters=20, textured_method="lstsq"), progress=False)
        assert res.status in ("converged", "max_iter", "max_eval", "stalled", "time_budget")
        assert np.all(np.isfinite(res.mesh.verts)) and np.all(np.isfinite(res.colors))
        assert _iou(data, res.mesh) >= _iou(data, init) - 1e-9


# ------------------------------------------------------------------------------------------
# validation and CLI
# ------------------------------------------------------------------------------------------


def test_validation(data):
    tr = data
    with pytest.raises(TypeError, match="dataset"):
        fit_mesh_to_views(tr.silhouettes, progress=False)
    with pytest.raises(ValueError, match="recipe"):
        fit_mesh_to_views(tr, recipe="fast", progress=False)
    with pytest.raises(ValueError, match="silhouette_loss"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(silhouette_loss="hard"), progress=False)
    with pytest.raises(ValueError, match="silhouette_loss"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(silhouette_loss="contour",
                silhouette_method="lbfgs"), progress=False)
    with pytest.raises(ValueError, match="silhouette_method"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(silhouette_method="adamw"), progress=False)
    with pytest.raises(ValueError, match="textured_method"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(textured_method="adam"), progress=False)
    with pytest.raises(ValueError, match="textured_init"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(textured_init="cube"), progress=False)
    with pytest.raises(ValueError, match="dataset"):
        fit_mesh_to_views(MultiViewDataset(images=None,
                silhouettes=tr.silhouettes,
                                           cameras=tr.cameras),
                options=ViewsFitOptions(textured_method="lstsq"), progress=False)
    with pytest.raises(ValueError, match="silhouette_weights"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(silhouette_weights={"chamfer": 1.0}),
                progress=False)
    with pytest.raises(ValueError, match="textured_weights"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(textured_weights={"rgb": -1.0}),
                progress=False)
    with pytest.raises(TypeError, match="silhouette_weights"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(silhouette_weights=[1.0]), progress=False)
    with pytest.raises(ValueError, match="silhouette_iters"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(silhouette_iters=0), progress=False)
    with pytest.raises(ValueError, match="views_per_step"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(views_per_step=7), progress=False)
    with pytest.raises(ValueError, match="large_steps"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(large_steps=-1.0), progress=False)
    with pytest.raises(ValueError, match="silhouette_log_eps"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(silhouette_log_eps=-0.1), progress=False)
    with pytest.raises(ValueError, match="silhouette_log_eps"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(silhouette_log_eps=float("nan")),
                          progress=False)
    with pytest.raises(ValueError, match="levels"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(levels=[(0,)]), progress=False)
    with pytest.raises(ValueError, match="levels"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(levels=[(-1, 1)]), progress=False)
    with pytest.raises(ValueError, match="levels"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(levels=[(0, 5)]), progress=False)
    with pytest.raises(TypeError, match="init"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(init=np.zeros((3, 3))), progress=False)
    with pytest.raises(ValueError, match="nothing to fit"):
        fit_mesh_to_views(tr, options=ViewsFitOptions(silhouette_method="none",
                textured_method="none"), progress=False)
    with pytest.raises(ValueError, match="factor"):
        tr.downsample(5)
    with pytest.raises(TypeError, match="mesh"):
        tutorial_views(4, mesh=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="textured"):
        tutorial_views(4, mesh=ico_sphere(1))
    with pytest.raises(ValueError, match="num_views"):
        tutorial_views(4, mesh=_object(1), num_views=0)
    with pytest.raises(ValueError, match="dist"):
        tutorial_views(4, mesh=_object(1), dist=0.0)
    with pytest.raises(TypeError, match="heldout"):
        ViewsEvaluator(tr.silhouettes)
    assert SILHOUETTE_METHODS == ("lbfgs", "lbfgs-nlopt", "sgd", "adam")


def test_recipes_are_option_presets_and_options_override(data):
    """A recipe is a frozen ViewsFitOptions preset; the user's options override the fields
    they set and agree with the same settings spelled out on another recipe."""
    import dataclasses

    from geofit.fit.views import RECIPES

    assert all(isinstance(r, ViewsFitOptions) for r in RECIPES.values())
    with pytest.raises(dataclasses.FrozenInstanceError):
        RECIPES["default"].silhouette_iters = 3
    common = {"init": ico_sphere(1), "silhouette_iters": 3, "textured_iters": 2}
    tut = fit_mesh_to_views(data, recipe="tutorial", options=ViewsFitOptions(**common),
                            progress=False)
    same = fit_mesh_to_views(data, recipe="sphere-lbfgs", options=ViewsFitOptions(
        silhouette_method="sgd", textured_method="sgd", textured_init="sphere", **common),
        progress=False)
    assert tut.method == "sgd+sgd" and tut.recipe == "tutorial" and tut.init == "user"
    np.testing.assert_array_equal(tut.colors, same.colors)
    kw = dict(common, textured_method="none", large_steps=5.0)
    a = fit_mesh_to_views(data, recipe="contour", options=ViewsFitOptions(**kw),
                          progress=False)
    b = fit_mesh_to_views(data, recipe="sphere-lbfgs", options=ViewsFitOptions(
        silhouette_method="adam", silhouette_loss="contour", **kw), progress=False)
    assert a.method == "adam+none"
    np.testing.assert_array_equal(a.mesh.verts, b.mesh.verts)
    with pytest.raises(TypeError, match="options: expected a ViewsFitOptions"):
        fit_mesh_to_views(data, options={"silhouette_iters": 3}, progress=False)


def test_textured_mesh_and_render_helper_match_the_evaluator(data):
    """With texture="vertex", ViewsFitResult.textured_mesh carries the clipped colours;
    render_mesh_at_views (and result.render) draw it as the ViewsEvaluator scores it (the same PSNR), with the dataset's
    lights; without colours the mesh is grey."""
    h = data.held_out
    res = fit_mesh_to_views(data, options=ViewsFitOptions(init=ico_sphere(2),
                                                          silhouette_iters=3, texture="vertex"),
                            progress=False)
    tm = res.textured_mesh
    np.testing.assert_array_equal(tm.textures.verts_features, np.clip(res.colors, 0.0, 1.0))
    imgs = res.render(h)
    assert imgs.shape == (len(h), *h.image_size, 3)
    assert psnr(imgs, h.images) == pytest.approx(ViewsEvaluator(h)(res.mesh, res.colors)["psnr"],
                                                 rel=1e-12)
    np.testing.assert_array_equal(render_mesh_at_views(res.mesh, h, res.colors, n_views=2),
                                  imgs[:2])
    sil = fit_mesh_to_views(data, options=ViewsFitOptions(init=ico_sphere(1), silhouette_iters=2,
                                                          textured_method="none"),
                            progress=False)
    np.testing.assert_array_equal(sil.textured_mesh.textures.verts_features, 0.7)
    with pytest.raises(TypeError, match="views"):
        render_mesh_at_views(res.mesh, h.images)


def test_one_time_budget_bounds_both_stages(data):
    """One wall-clock time_budget bounds the whole fit (silhouettes and the textured SGD)."""
    res = fit_mesh_to_views(data, recipe="tutorial", options=ViewsFitOptions(
        init=ico_sphere(2), silhouette_iters=10 ** 6, textured_iters=10 ** 6),
        time_budget=1.0, progress=False)
    assert [s["status"] for s in res.stages] == ["time_budget", "time_budget"]
    assert res.seconds < 3.0 and res.cpu_seconds > 0


def test_default_result_carries_a_uv_texture(data):
    """The default's mesh carries a TexturesUV solved on the final geometry (a last
    "texture" stage); texture="vertex" keeps the vertex colours; the geometry and the vertex
    colours are the same either way; the held-out evaluator and the render helper score the
    texture alike."""
    from geofit.structures import TexturesUV

    kw = dict(init=ico_sphere(2), silhouette_iters=3)
    h = data.held_out
    # an evaluator that ignores the colours (as notebook 04's): the checkpoints keep one set of
    # metric names (the last is the vertex colours'; the texture is scored on the result)
    uv = fit_mesh_to_views(data, options=ViewsFitOptions(**kw), progress=False,
                           evaluator=lambda mesh, colors: ViewsEvaluator(h)(mesh))
    assert uv.history.checkpoints and "psnr" not in uv.history.metric_names
    vx = fit_mesh_to_views(data, options=ViewsFitOptions(texture="vertex", **kw),
                           progress=False)
    assert isinstance(uv.mesh.textures, TexturesUV) and uv.textured_mesh is uv.mesh
    assert isinstance(vx.mesh.textures, TexturesVertex)
    assert [s["name"] for s in uv.stages] == ["silhouette", "rgb", "textured", "texture"]
    assert [s["name"] for s in vx.stages] == ["silhouette", "rgb", "textured"]
    np.testing.assert_array_equal(uv.mesh.verts, vx.mesh.verts)
    np.testing.assert_array_equal(uv.colors, vx.colors)
    assert uv.n_params == vx.n_params + uv.mesh.textures.maps.size
    imgs = uv.render(h)
    np.testing.assert_array_equal(imgs, render_mesh_at_views(uv.mesh, h))
    assert ViewsEvaluator(h)(uv.mesh)["psnr"] == pytest.approx(psnr(imgs, h.images), rel=1e-12)
    assert not np.array_equal(imgs, vx.render(h))


@pytest.mark.parametrize("lit", [True, False])
def test_uv_texture_uses_the_datasets_lights_or_unlit_colour(data, lit):
    """On the true surface the UV texture reproduces the training views (> 33 dB) rendered as
    the fit sees the dataset: with its lights, or unlit (AmbientLights) when it has none,
    the texture then holding what the camera saw (shading baked in)."""
    import dataclasses

    train = data if lit else dataclasses.replace(data, lights=None)
    truth = Mesh(data.mesh.verts, data.mesh.faces)
    res = fit_mesh_to_views(train, options=ViewsFitOptions(init=truth, silhouette_method="none"),
                            progress=False)
    assert psnr(res.render(train), train.images) > 33.0
    if not lit:  # what the camera saw (shading baked in): lit again, it no longer matches
        assert psnr(res.render(data), data.images) < psnr(res.render(train), train.images) - 3


def test_uv_texture_skipped_when_predicted_past_the_budget(data, monkeypatch):
    """With a time budget the UV texture is not started when its predicted time (a multiple
    of the colours' stage) does not fit in what is left (a budget ends the fit near it on a
    loaded machine); without a budget it always runs."""
    from geofit.fit import views

    truth = Mesh(data.mesh.verts, data.mesh.faces)
    opts = ViewsFitOptions(init=truth, silhouette_method="none")
    monkeypatch.setattr(views, "_TEXTURE_PER_COLOURS", 1e9)
    res = fit_mesh_to_views(data, options=opts, time_budget=600.0, progress=False)
    st = res.stages[-1]
    assert st["name"] == "texture" and st["status"] == "time_budget"
    assert "needs about" in st["message"] and "vertex colours kept" in st["message"]
    assert isinstance(res.mesh.textures, TexturesVertex)
    res = fit_mesh_to_views(data, options=opts, progress=False)
    assert res.stages[-1]["status"] == "converged"
    assert isinstance(res.mesh.textures, TexturesUV)


def test_uv_texture_respects_the_time_budget(data):
    """A budget spent before the texture stage solves no texture and says so: the colour
    stage is not run when nothing is left of the budget for it, else the texture stage keeps
    the vertex colours (which of the two depends on where the 1 ms ran out)."""
    res = fit_mesh_to_views(data, options=ViewsFitOptions(init=ico_sphere(2)),
                            time_budget=1e-3, progress=False)
    st = res.stages[-1]
    assert st["status"] == "time_budget" and res.status == "time_budget"
    assert not isinstance(res.mesh.textures, TexturesUV)
    if st["name"] == "texture":
        assert "vertex colours kept" in st["message"]
        assert isinstance(res.mesh.textures, TexturesVertex)
    else:
        assert st["name"] == "textured" and "no time left" in st["message"]


def test_texture_options_are_validated(data):
    for opts, match in ((ViewsFitOptions(texture="atlas"), "options.texture"),
                        (ViewsFitOptions(texel_px=0.0), "options.texel_px")):
        with pytest.raises(ValueError, match=match):
            fit_mesh_to_views(data, options=opts, progress=False)


def test_final_large_steps_is_the_last_levels_lambda(data):
    """``final_large_steps`` sets lambda of the last coarse-to-fine level only: with one level
    it is that level's lambda (bit-identical to ``large_steps`` set alike, different from the
    other lambda); a negative value is refused."""
    o = dict(_SILHOUETTE_STAGE_ONLY)

    def verts(**kw):
        return fit_mesh_to_views(data, options=ViewsFitOptions(**o, **kw),
                                 progress=False).mesh.verts

    a = verts(large_steps=10.0, final_large_steps=3.0)
    np.testing.assert_array_equal(a, verts(large_steps=3.0, final_large_steps=3.0))
    assert np.abs(a - verts(large_steps=10.0, final_large_steps=10.0)).max() > 1e-6
    # two levels: the first keeps large_steps
    o["levels"] = ((0, 2), (0, 1))
    b = verts(large_steps=10.0, final_large_steps=3.0)
    assert np.abs(b - verts(large_steps=3.0, final_large_steps=3.0)).max() > 1e-6
    with pytest.raises(ValueError, match="options.final_large_steps"):
        fit_mesh_to_views(data, options=ViewsFitOptions(final_large_steps=-1.0), progress=False)


def test_final_regularization_scales_the_last_levels_regularisers(data):
    """``final_regularization`` multiplies the edge / normal / Laplacian / normal-variation
    weights of the last coarse-to-fine level only: with one level, factor 0.5 is bit-identical
    to those weights halved (the silhouette weight kept); with two levels the first keeps its
    weights; a negative factor is refused."""
    w = {"silhouette": 1.0, "edge": 0.3, "normal": 0.01, "laplacian": 0.3,
         "normal_variation": 0.02}
    half = {k: (v if k == "silhouette" else 0.5 * v) for k, v in w.items()}
    o = dict(_SILHOUETTE_STAGE_ONLY)

    def verts(**kw):
        return fit_mesh_to_views(data, options=ViewsFitOptions(**o, **kw),
                                 progress=False).mesh.verts

    a = verts(silhouette_weights=w, final_regularization=0.5)
    np.testing.assert_array_equal(a, verts(silhouette_weights=half, final_regularization=1.0))
    assert np.abs(a - verts(silhouette_weights=w, final_regularization=1.0)).max() > 1e-6
    # two levels: the first keeps the weights as given
    o["levels"] = ((0, 2), (0, 1))
    b = verts(silhouette_weights=w, final_regularization=0.5)
    assert np.abs(b - verts(silhouette_weights=half, final_regularization=1.0)).max() > 1e-6
    with pytest.raises(ValueError, match="options.final_regularization"):
        fit_mesh_to_views(data, options=ViewsFitOptions(final_regularization=-1.0),
                          progress=False)


def test_rgb_stage_gets_what_the_silhouette_stage_leaves(data):
    """With a time budget the silhouette stage may spend the geometry's whole part: a
    silhouette stage without an iteration limit ends by the budget and the RGB stage is not
    run (and says so); one that ends early leaves the rest to the RGB stage, which runs and
    ends by the budget without letting the clock's TimeUp escape; the colours and texture
    come after it either way."""
    def fit(sil_iters, budget):
        return fit_mesh_to_views(data, options=ViewsFitOptions(
            init=ico_sphere(2), silhouette_iters=sil_iters, rgb_iters=10 ** 4),
            time_budget=budget, progress=False)

    res = fit(10 ** 6, 3.0)
    assert [s["name"] for s in res.stages][:3] == ["silhouette", "rgb", "textured"]
    sil, rgb = res.stages[0], res.stages[1]
    assert sil["status"] == "time_budget"
    assert rgb["status"] == "time_budget" and rgb["seconds"] == 0.0
    assert "not run" in rgb["message"]
    res = fit(2, 6.0)
    assert [s["name"] for s in res.stages][:3] == ["silhouette", "rgb", "textured"]
    sil, rgb = res.stages[0], res.stages[1]
    assert sil["status"] != "time_budget"
    assert rgb["status"] == "time_budget" and rgb["seconds"] > 0
    assert res.status == "time_budget" and np.all(np.isfinite(res.mesh.verts))


def test_default_rgb_stage_needs_a_silhouette_stage_and_images(data):
    """The default recipe's RGB stage refines the silhouette stage's result: it is left out
    for silhouettes alone (no RGB images) and after ``silhouette_method="none"``; asked for
    explicitly without images it is refused."""
    sil_only = MultiViewDataset(images=None, silhouettes=data.silhouettes, cameras=data.cameras)
    o = dict(init=ico_sphere(2), silhouette_iters=2, textured_method="none")
    res = fit_mesh_to_views(sil_only, options=ViewsFitOptions(**o), progress=False)
    assert [s["name"] for s in res.stages] == ["silhouette"]
    given = fit_mesh_to_views(data, options=ViewsFitOptions(init=ico_sphere(2),
                              silhouette_method="none"), progress=False)
    assert [s["name"] for s in given.stages][:1] == ["textured"]
    with pytest.raises(ValueError, match="rgb_iters"):
        fit_mesh_to_views(sil_only, options=ViewsFitOptions(rgb_iters=2, **o), progress=False)


def _check_anchored_objective_fd(data, large, seed, pinned):
    """The silhouette objective with an anchored (``pinned``: per-vertex mixed, random pins)
    Laplacian on a shrunk ico-sphere whose anchor has bumps: asserts a central difference
    along a random direction matches <grad, u> (float64); returns the mesh, anchor, pins."""
    m = ico_sphere(2)
    rng = np.random.default_rng(seed)
    m = m.update_verts(m.verts * 0.7)
    anchor = m.verts + 0.02 * rng.normal(size=m.verts.shape)  # a rest shape with bumps
    pin = rng.uniform(size=m.n_verts) if pinned else None
    param = LargeSteps(m, large) if large else IdentityParameterization(m)
    weights = {"silhouette": 1.0, "edge": 0.3, "normal": 0.01, "laplacian": 1.0}
    st = SoftRasterizationSettings.tutorial(24, dtype=np.float64)
    obj = _Objective(m, data, weights, textured=False, param=param, settings=st, anchor=anchor,
                     pin=pin)
    x = param.to_params(m.verts).ravel()
    f, g = obj(x)
    u = rng.normal(size=x.shape)
    h = 1e-7
    fd = (obj(x + h * u)[0] - obj(x - h * u)[0]) / (2 * h)
    assert fd == pytest.approx(float(g @ u), rel=1e-4)
    return m, anchor, pin


@pytest.mark.parametrize("large", [None, 5.0])
def test_anchored_laplacian_gradient_matches_finite_differences(data, large):
    """With ``anchor`` the objective's Laplacian term acts on ``V - anchor``: a central
    difference along a random direction matches <grad, u> (float64), the term is 0 at the
    anchor and equal to the plain term of the displacement mesh elsewhere."""
    m, anchor, _ = _check_anchored_objective_fd(data, large, 3, pinned=False)
    terms, _ = regularizers(m, {"laplacian": 1.0}, anchor)
    lap, _ = mesh_laplacian_smoothing(m.update_verts(m.verts - anchor), "uniform")
    assert terms["laplacian"] == pytest.approx(lap, rel=1e-12) and lap > 0
    # at the anchor the term and its (zero) subgradient vanish; a rigid move costs nothing
    t0, g0 = regularizers(m, {"laplacian": 1.0}, m.verts)
    assert t0["laplacian"] == 0.0 and not np.any(g0)
    t1, _ = regularizers(m.update_verts(m.verts + [0.1, -0.2, 0.3]), {"laplacian": 1.0},
                         m.verts)
    assert t1["laplacian"] == pytest.approx(0.0, abs=1e-12)
    assert regularizers(m, {"laplacian": 1.0})[0]["laplacian"] > 0.01  # the sphere's curvature


def test_laplacian_anchor_changes_the_fit_only_where_asked(data):
    """``laplacian_anchor``: "none" is the plain Laplacian (the result bit-identical to the
    option left out), "round" and "last" move the fit differently from it (with one level
    and one round "last" and "final" are "round"; with two levels of one round each "final"
    is "last", which differs from "round"); an unknown form is refused."""
    o = dict(_SILHOUETTE_STAGE_ONLY)

    def verts(**kw):
        return fit_mesh_to_views(data, options=ViewsFitOptions(**o, **kw),
                                 progress=False).mesh.verts

    base = verts()
    np.testing.assert_array_equal(base, verts(laplacian_anchor="none"))
    r = verts(laplacian_anchor="round")
    assert np.abs(r - base).max() > 1e-6
    np.testing.assert_array_equal(r, verts(laplacian_anchor="last"))
    np.testing.assert_array_equal(r, verts(laplacian_anchor="final"))
    o["levels"] = ((0, 2), (0, 1))
    last = verts(laplacian_anchor="last")
    assert np.abs(last - verts(laplacian_anchor="round")).max() > 1e-6
    np.testing.assert_array_equal(last, verts(laplacian_anchor="final"))
    with pytest.raises(ValueError, match="options.laplacian_anchor"):
        fit_mesh_to_views(data, options=ViewsFitOptions(laplacian_anchor="vertices"),
                          progress=False)


@pytest.mark.parametrize("large", [None, 5.0])
def test_pinned_laplacian_gradient_matches_finite_differences(data, large):
    """With ``anchor`` and ``pin`` the Laplacian term is the per-vertex mix
    ``pin_i |(L (V - A))_i| + (1 - pin_i) |(L V)_i|``: a central difference along a random
    direction matches <grad, u> (float64); pin 1 everywhere is the anchored term, pin 0 the
    plain one (values and gradients)."""
    m, anchor, pin = _check_anchored_objective_fd(data, large, 4, pinned=True)
    w = {"laplacian": 1.0}
    for p, ref in ((np.ones(m.n_verts), regularizers(m, w, anchor)),
                   (np.zeros(m.n_verts), regularizers(m, w))):
        t, gp = regularizers(m, w, anchor, p)
        assert t["laplacian"] == pytest.approx(ref[0]["laplacian"], rel=1e-12)
        np.testing.assert_allclose(gp, ref[1], rtol=1e-10, atol=1e-15)
    L = uniform_laplacian(m)  # the mix, from its definition
    na = np.linalg.norm(L @ (m.verts - anchor), axis=1)
    n0 = np.linalg.norm(L @ m.verts, axis=1)
    mixed = regularizers(m, w, anchor, pin)[0]["laplacian"]
    assert mixed == pytest.approx(np.mean(pin * na + (1 - pin) * n0), rel=1e-12)


def test_silhouette_pinning_is_the_silhouettes_share_of_the_forces(data):
    """``silhouette_pinning`` (spread 0) is ``2 |g_s| / (|g_s| + |g_L|)`` clipped to [0, 1]
    from the silhouette term's and the plain Laplacian's vertex gradients; the spread only
    raises it, toward the neighbours' mean; a mesh well inside the silhouettes (whose
    outline the silhouette term pulls outward everywhere) is pinned more than its centre."""
    m = ico_sphere(2)
    m = m.update_verts(m.verts * 0.5)
    weights = {"silhouette": 1.0, "laplacian": 0.3}
    st = SoftRasterizationSettings.tutorial(24, dtype=np.float64)
    obj = _Objective(m, data, weights, textured=False, param=IdentityParameterization(m),
                     settings=st)
    p0 = silhouette_pinning(obj, m, spread=0)
    sil = _Objective(m, data, {"silhouette": 1.0}, textured=False,
                     param=IdentityParameterization(m), settings=st)
    gs = np.linalg.norm(sil(m.verts.ravel())[1].reshape(-1, 3), axis=1)
    gl = np.linalg.norm(regularizers(m, {"laplacian": 0.3})[1], axis=1)
    np.testing.assert_allclose(p0, np.clip(2 * gs / (gs + gl), 0, 1), rtol=1e-12)
    assert p0.shape == (m.n_verts,) and 0 < p0.min() and p0.max() <= 1.0
    p1 = silhouette_pinning(obj, m)
    assert np.all(p1 >= p0) and np.any(p1 > p0) and p1.max() <= 1.0


def test_laplacian_pin_changes_the_anchored_fit_and_is_validated(data):
    """``laplacian_pin="force"`` changes the anchored fit (the mix is not the anchored term);
    an unknown mix, or a mix without an anchored Laplacian, is refused naming the option."""
    o = dict(init="sphere", silhouette_iters=4, levels=((0, 1),), remesh_rounds=0,
             textured_method="none", laplacian_anchor="round")

    def verts(**kw):
        return fit_mesh_to_views(data, options=ViewsFitOptions(**{**o, **kw}),
                                 progress=False).mesh.verts

    anchored = verts()
    np.testing.assert_array_equal(anchored, verts(laplacian_pin="none"))
    pinned = verts(laplacian_pin="force")
    assert np.all(np.isfinite(pinned)) and np.abs(pinned - anchored).max() > 1e-6
    with pytest.raises(ValueError, match="options.laplacian_pin"):
        fit_mesh_to_views(data, options=ViewsFitOptions(laplacian_pin="rims"), progress=False)
    with pytest.raises(ValueError, match="options.laplacian_pin.*laplacian_anchor"):
        fit_mesh_to_views(data, options=ViewsFitOptions(laplacian_pin="force"), progress=False)
