"""fit_mesh: composite objective gradients, large steps, frames, solvers, guards, coarse-to-fine."""
from __future__ import annotations

import numpy as np
import pytest

from geofit import Mesh, ico_sphere
from geofit.fit import (
    FINE_WEIGHTS,
    RECIPES,
    TUTORIAL_WEIGHTS,
    CoarseToFine,
    LargeSteps,
    MeshFitOptions,
    MeshObjective,
    fit_mesh,
)
from geofit.metrics import MeshEvaluator

ALL_TERMS = {"chamfer": 1.3, "edge": 0.7, "normal": 0.2, "laplacian": 0.4}


def bumpy_target():
    """A non-convex closed target: ico_sphere(3) with two bumps, normalised."""
    m = ico_sphere(3)
    d = m.verts
    r = 1.0 + 0.3 * np.exp(-np.sum((d - [0, 0, 1]) ** 2, 1) / 0.1) \
        - 0.2 * np.exp(-np.sum((d - [1, 0, 0]) ** 2, 1) / 0.2)
    return m.update_verts(d * r[:, None] * [1.0, 0.7, 1.2]).normalize().mesh


def perturbed_source(level=1, seed=3, scale=0.05):
    m = ico_sphere(level)
    rng = np.random.default_rng(seed)
    return m.update_verts(m.verts * 0.8 + rng.normal(scale=scale, size=m.verts.shape))


def central_fd(fun, x, idx, h):
    out = []
    for i in idx:  # a handful of coordinates
        e = np.zeros_like(x)
        e[i] = h
        out.append((fun(x + e)[0] - fun(x - e)[0]) / (2 * h))
    return np.array(out)


# ------------------------------------------------------------------------------------ gradients
@pytest.mark.parametrize("distance", ["surface", "points"])
def test_objective_gradient_matches_finite_differences(distance):
    """All four weighted terms: analytic gradient = central differences (fixed samples)."""
    src, tgt = perturbed_source(), bumpy_target()
    obj = MeshObjective(src, tgt, ALL_TERMS, distance=distance, n_samples=400, seed=1)
    x = obj.params_from_verts(src.verts)
    value, grad = obj(x)
    assert set(obj.last_terms) == {"chamfer", "edge", "normal", "laplacian"}
    expected = sum(ALL_TERMS[k] * v for k, v in obj.last_terms.items())
    np.testing.assert_allclose(value, expected, rtol=1e-12)
    idx = np.random.default_rng(0).choice(x.size, 25, replace=False)
    fd = central_fd(obj, x, idx, 1e-6)
    np.testing.assert_allclose(grad[idx], fd, rtol=2e-4, atol=1e-7 * np.abs(grad).max())


def test_surface_data_term_is_zero_on_the_target():
    """Closed form: a source identical to the target has zero exact distance and gradient."""
    tgt = bumpy_target()
    obj = MeshObjective(tgt, tgt, {"chamfer": 1.0}, n_samples=500, seed=0)
    value, grad = obj(obj.params_from_verts(tgt.verts))
    assert value < 1e-28 and np.abs(grad).max() < 1e-14


def test_surface_gradient_matches_reference_loop():
    """The sparse scatter of both exact terms equals a per-sample loop over the barycentrics."""
    from geofit.raycast import PointToMeshDistance

    src, tgt = perturbed_source(), bumpy_target()
    obj = MeshObjective(src, tgt, {"chamfer": 1.0}, n_samples=60, seed=3)
    _, grad = obj(obj.params_from_verts(src.verts))
    V, F = src.verts, src.faces
    B = obj._B.toarray()  # (n, V): the fixed source samples
    P = B @ V
    ref = np.zeros_like(V)
    closest = PointToMeshDistance(tgt).query(P)
    for i in range(len(P)):  # source samples -> target surface
        ref += np.outer(B[i], 2 * (P[i] - closest.points[i]) / len(P))
    c = PointToMeshDistance(src).query(obj._Y)
    for j in range(len(obj._Y)):  # target samples -> source surface
        for k in range(3):
            ref[F[c.face_ids[j], k]] -= 2 * c.bary[j, k] * (obj._Y[j] - c.points[j]) / len(obj._Y)
    np.testing.assert_allclose(grad.reshape(-1, 3), ref, atol=1e-14)


def test_weights_scale_terms_linearly():
    """Doubling one weight adds exactly that term's value and gradient once more."""
    src, tgt = perturbed_source(), bumpy_target()
    w2 = dict(ALL_TERMS, normal=2 * ALL_TERMS["normal"])
    a = MeshObjective(src, tgt, ALL_TERMS, n_samples=300, seed=5)
    b = MeshObjective(src, tgt, w2, n_samples=300, seed=5)
    only = MeshObjective(src, tgt, {"chamfer": 1e-300, "normal": ALL_TERMS["normal"]},
                         n_samples=300, seed=5)
    x = a.params_from_verts(src.verts)
    (va, ga), (vb, gb), (_, gn) = a(x), b(x), only(x)
    np.testing.assert_allclose(vb - va, ALL_TERMS["normal"] * a.last_terms["normal"], rtol=1e-10)
    np.testing.assert_allclose(gb - ga, gn, atol=1e-12 * np.abs(ga).max())


def test_large_steps_chain_rule():
    """dE/du = M^-1 dE/dV: the reparameterised objective matches finite differences in u."""
    src, tgt = perturbed_source(), bumpy_target()
    ls = LargeSteps(src, 5.0)
    obj = MeshObjective(src, tgt, ALL_TERMS, n_samples=400, seed=2, large_steps=ls)
    u = obj.params_from_verts(src.verts)
    np.testing.assert_allclose(obj.verts_from_params(u), src.verts, atol=1e-12)
    _, grad = obj(u)
    idx = np.random.default_rng(1).choice(u.size, 20, replace=False)
    fd = central_fd(obj, u, idx, 1e-6)
    np.testing.assert_allclose(grad[idx], fd, rtol=2e-4, atol=1e-7 * np.abs(grad).max())


def test_large_steps_matrix():
    """M = I + lambda (D - A): symmetric, rows sum to 1, and grad_params solves M g_u = g_V."""
    m = ico_sphere(2)
    ls = LargeSteps(m, 7.0)
    M = ls.matrix.toarray()
    np.testing.assert_array_equal(M, M.T)
    np.testing.assert_allclose(M.sum(1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.diag(M), 1.0 + 7.0 * m.topology.degrees)
    g = np.random.default_rng(0).normal(size=(m.n_verts, 3))
    np.testing.assert_allclose(M @ ls.grad_params(g), g, atol=1e-10)
    with pytest.raises(ValueError, match="large_steps"):
        LargeSteps(m, 0.0)
    with pytest.raises(TypeError, match="mesh"):
        LargeSteps(m.verts, 1.0)


def test_nonfinite_parameters_give_nan_value_not_exception():
    src, tgt = perturbed_source(), bumpy_target()
    obj = MeshObjective(src, tgt, ALL_TERMS, n_samples=100)
    x = obj.params_from_verts(src.verts)
    x[4] = np.nan
    value, grad = obj(x)
    assert np.isnan(value) and np.all(grad == 0)


# ------------------------------------------------------------------------------------ fits
def test_result_in_original_frame():
    """A sphere target scaled by 3 and shifted: the fitted vertices come back in that frame."""
    centre = np.array([5.0, -2.0, 1.0])
    s = ico_sphere(3)
    target = s.update_verts(3.0 * s.verts + centre)
    res = fit_mesh(target, recipe="sphere", options=MeshFitOptions(init=1, weights=FINE_WEIGHTS,
              n_samples=500, n_stages=1, n_iter=60), evaluator=None, progress=False)
    r = np.linalg.norm(res.mesh.verts - centre, axis=1)
    # 42 vertices straddle the sphere: vertices slightly outside, face centres inside
    assert np.all((r > 2.9) & (r < 3.25)), (r.min(), r.max())
    np.testing.assert_allclose(res.mesh.verts.mean(0), centre, atol=0.05)
    np.testing.assert_allclose(res.mesh.verts, res.mesh_normalized.verts * res.scale + res.center,
                               rtol=1e-12)
    np.testing.assert_allclose(res.center, centre, atol=1e-9)
    assert res.n_verts == 42 and res.n_params == 126


@pytest.mark.parametrize("method", ["lbfgs", "lbfgs-nlopt"])
def test_quasi_newton_paths_reach_small_loss(method):
    """ico_sphere(1) -> a scaled sphere: both L-BFGS wrappers get the data term near its floor."""
    s = ico_sphere(3)
    target = s.update_verts(s.verts * [1.0, 0.8, 0.6])
    res = fit_mesh(target, recipe="sphere", options=MeshFitOptions(init=1, method=method,
              weights=FINE_WEIGHTS, n_samples=500, n_stages=2, n_iter=80), evaluator=None,
              progress=False)
    assert res.status in ("converged", "max_iter", "max_eval", "stalled"), res.message
    first, last = res.history.terms["chamfer"][0], res.history.terms["chamfer"][-1]
    assert last < 2e-3 and last < 0.05 * first
    ev = MeshEvaluator(target, n_samples=5000, normalize=True)
    assert ev.evaluate(res.mesh).chamfer_l2 < 2e-3


def test_history_time_monotone_and_checkpoints():
    tgt = bumpy_target()
    ev = MeshEvaluator(tgt, n_samples=2000, normalize=True)
    res = fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1, n_samples=300, n_stages=2,
              n_iter=15), evaluator=ev, progress=False)
    a = res.history.as_arrays()
    assert np.all(np.diff(a["seconds"]) >= 0) and np.all(np.diff(a["step"]) > 0)
    assert set(a["terms"]) == {"chamfer", "edge", "normal", "laplacian"}
    assert len(a["checkpoint_step"]) == 2  # one per stage (the last stage's is the final)
    assert np.all(np.diff(a["checkpoint_seconds"]) >= 0)
    assert res.metrics is not None
    assert res.metrics.chamfer_l2 == a["metrics"]["chamfer_l2"][-1]
    assert res.n_evaluations >= a["step"][-1]
    assert len(res.stages) == 2 and res.stages[0]["weights"] == TUTORIAL_WEIGHTS
    assert res.stages[1]["weights"] == FINE_WEIGHTS
    assert res.stages[0]["large_steps"] == 10.0  # "auto" for L-BFGS
    assert res.stages[0]["n_samples"] == 300  # given


def test_sgd_is_the_tutorial_update():
    """method='sgd' = PyTorch's SGD (lr 1, momentum 0.9) on the tutorial's stochastic objective."""
    tgt = bumpy_target()
    src = ico_sphere(1)
    res = fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=src, method="sgd",
              n_samples=200, n_iter=3), evaluator=None, seed=4, progress=False)
    norm = tgt.normalize()
    obj = MeshObjective(src, norm.mesh, TUTORIAL_WEIGHTS, distance="points", n_samples=200,
                        resample="step", seed=np.random.default_rng(4))
    x = src.verts.ravel().copy()
    buf = None
    for _ in range(3):
        g = obj(x)[1]
        buf = g if buf is None else 0.9 * buf + g
        x = x - 1.0 * buf
    np.testing.assert_allclose(res.mesh_normalized.verts.ravel(), x, atol=1e-12)
    assert res.status == "max_iter" and res.n_iterations == 3
    assert res.stages[0]["large_steps"] is None and res.stages[0]["n_samples"] == 200


def test_adam_reduces_loss():
    tgt = bumpy_target()
    res = fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=2, method="adam",
              n_samples=500, n_iter=150, lr=0.01), evaluator=None, progress=False)
    c = np.asarray(res.history.terms["chamfer"])
    assert c[-20:].mean() < 0.3 * c[:5].mean()


def test_huge_lr_sgd_stops_with_status_and_finite_verts():
    tgt = bumpy_target()
    res = fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1, method="sgd", lr=100.0,
              n_samples=200, n_iter=500), evaluator=None, progress=False)
    assert res.status in ("diverged", "nonfinite"), res.message
    assert res.n_iterations < 500
    assert np.all(np.isfinite(res.mesh.verts))
    assert res.message


def test_nan_target_raises_with_message():
    m = ico_sphere(2)
    v = m.verts.copy()
    v[7, 1] = np.nan
    with pytest.raises(ValueError, match="target: the vertices contain 1 NaN"):
        fit_mesh((v, m.faces), recipe="sphere", options=MeshFitOptions(init=1), progress=False)


def test_degenerate_start_is_repaired_and_stays_finite():
    """A source with collapsed triangles is repaired first, and SGD then stays bounded."""
    src = ico_sphere(2)
    v = src.verts.copy()
    nb = src.edges[::7]
    v[nb[:, 0]] = v[nb[:, 1]]  # collapse every 7th edge: its triangles get zero area
    src = src.update_verts(v)
    n_zero = int(np.sum(src.face_areas == 0))
    assert n_zero > 10
    res = fit_mesh(bumpy_target(), recipe="sphere", options=MeshFitOptions(init=src, n_samples=300,
              n_stages=1, n_iter=30), evaluator=None, progress=False)
    assert np.all(np.isfinite(res.mesh.verts)) and res.ok
    assert f"{n_zero} zero-area triangles" in res.message
    assert res.history.events[0]["n_degenerate"] == n_zero
    sgd = fit_mesh(bumpy_target(), recipe="sphere", options=MeshFitOptions(init=src, method="sgd",
              n_samples=300, n_iter=30), evaluator=None, progress=False)
    # without the repair the 1e8 normal-consistency gradients make SGD diverge at once
    assert sgd.status == "max_iter", sgd.message
    assert sgd.history.terms["chamfer"][-1] < sgd.history.terms["chamfer"][0]


def test_time_budget_and_callback_stop():
    tgt = bumpy_target()
    res = fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1, n_samples=300,
              n_iter=10_000, n_stages=3), time_budget=0.3, evaluator=None, progress=False)
    assert res.status == "time_budget" and res.seconds < 2.0
    res = fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1, n_samples=300),
              evaluator=None, progress=False, callback=lambda info: info.iteration >= 4)
    assert res.status == "callback" and res.n_iterations == 4


def test_coarse_to_fine_subdivides_only_when_needed():
    """Loose accuracy: stays at the start level; strict: subdivides up to the max level."""
    s = ico_sphere(3)
    target = s.update_verts(s.verts * [1.0, 0.9, 0.8])
    loose = CoarseToFine(start_level=1, max_level=3, chamfer_l2=1.0, fscore=0.0)
    res = fit_mesh(target, recipe="coarse-to-fine", options=MeshFitOptions(refine=loose,
              n_samples=400, n_iter=30), evaluator=None, progress=False)
    assert res.n_verts == 42 and "accuracy reached" in res.message
    strict = CoarseToFine(start_level=1, max_level=2, chamfer_l2=0.0, fscore=1.0)
    res = fit_mesh(target, recipe="coarse-to-fine", options=MeshFitOptions(refine=strict,
              n_samples=400, n_iter=30), evaluator=None, progress=False)
    assert res.n_verts == 162 and "max level" in res.message
    assert [s["n_verts"] for s in res.stages] == [42, 162]
    assert "estimate" in res.stages[0] and res.stages[0]["estimate"]["chamfer_l2"] > 0
    capped = CoarseToFine(start_level=1, max_level=4, chamfer_l2=0.0, fscore=1.0, max_verts=200)
    res = fit_mesh(target, recipe="coarse-to-fine", options=MeshFitOptions(refine=capped,
              n_iter=10), evaluator=None, progress=False)
    assert res.n_verts == 162 and "max_verts" in res.message
    # default samples per L-BFGS stage: min(5000, max(1000, 8 V))
    assert [s["n_samples"] for s in res.stages] == [1000, 8 * 162]


def test_coarse_to_fine_stall_test_ends_a_level():
    """The stall test stops a level whose data term no longer improves, status converged."""
    from geofit.fit.mesh import _Stall

    st = _Stall(3, 0.1)
    assert [st.update(v) for v in (5.0, 4.0, 3.0, 2.9, 2.8, 2.75)] == [False] * 5 + [True]
    s = ico_sphere(3)
    target = s.update_verts(s.verts * [1.0, 0.9, 0.8])
    c2f = CoarseToFine(start_level=1, max_level=1, stall_window=3, stall_rel=0.5)
    res = fit_mesh(target, recipe="coarse-to-fine", options=MeshFitOptions(refine=c2f,
              n_samples=300, n_iter=200), evaluator=None, progress=False)
    assert res.stages[0]["status"] == "converged"
    assert "stall test" in res.stages[0]["message"]
    assert res.stages[0]["n_iterations"] < 200
    with pytest.raises(ValueError, match="stall_window"):
        CoarseToFine(stall_window=0)


def test_save_obj_round_trip(tmp_path):
    from geofit.io import load_mesh

    s = ico_sphere(2)
    target = s.update_verts(2.0 * s.verts + 1.0)
    res = fit_mesh(target, recipe="sphere", options=MeshFitOptions(init=1, n_samples=200,
              n_stages=1, n_iter=5), evaluator=None, progress=False)
    path = tmp_path / "fit.obj"
    res.save_obj(path)
    back = load_mesh(path, load_textures=False)
    np.testing.assert_array_equal(back.faces, res.mesh.faces)
    np.testing.assert_allclose(back.verts, res.mesh.verts, atol=1e-5)


def test_validation():
    tgt = ico_sphere(2)
    with pytest.raises(ValueError, match="method"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1, method="bfgs"),
            progress=False)
    with pytest.raises(ValueError, match="recipe"):
        fit_mesh(tgt, recipe="fast", progress=False)
    with pytest.raises(ValueError, match="unknown terms"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1, weights={"chamfer": 1,
            "smooth": 1}), progress=False)
    with pytest.raises(ValueError, match="edge"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1, weights={"chamfer": 1,
            "edge": -1}), progress=False)
    with pytest.raises(ValueError, match="'chamfer' needs a weight"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1, weights={"edge": 1}),
            progress=False)
    with pytest.raises(ValueError, match="refine: coarse-to-fine needs"):
        fit_mesh(tgt, recipe="coarse-to-fine", options=MeshFitOptions(method="sgd"),
            progress=False)
    with pytest.raises(TypeError, match="options.refine"):
        fit_mesh(tgt, recipe="coarse-to-fine", options=MeshFitOptions(refine="yes"),
            progress=False)
    with pytest.raises(ValueError, match="n_stages"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1, method="adam", n_stages=2),
            progress=False)
    with pytest.raises(ValueError, match="distance"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1, distance="l1"),
            progress=False)
    with pytest.raises(ValueError, match="large_steps"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1, large_steps="big"),
            progress=False)
    with pytest.raises(ValueError, match="large_steps"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1, large_steps=-1.0),
            progress=False)
    with pytest.raises(ValueError, match="n_samples"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1, n_samples=0),
            progress=False)
    with pytest.raises(ValueError, match="lr"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1, method="sgd", lr=-1),
            progress=False)
    with pytest.raises(ValueError, match="time_budget"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1), time_budget=0,
            progress=False)
    with pytest.raises(ValueError, match="eval_every"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1), eval_every=0,
            progress=False)
    with pytest.raises(ValueError, match="evaluator"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1), evaluator="fast",
            progress=False)
    with pytest.raises(TypeError, match="evaluator"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=1), evaluator=3,
            progress=False)
    with pytest.raises(TypeError, match="init"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=object()), progress=False)
    with pytest.raises(ValueError, match="init"):  # strings: "auto" or "sphere" only
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init="cube"), progress=False)
    with pytest.raises(TypeError, match="target"):
        fit_mesh(object(), recipe="sphere", options=MeshFitOptions(init=1), progress=False)
    with pytest.raises(ValueError, match="target: a point cloud"):  # only the default call
        fit_mesh(tgt.verts, recipe="sphere", options=MeshFitOptions(init=1), progress=False)
    with pytest.raises(ValueError, match="init: the surface has zero area"):
        fit_mesh(tgt, recipe="sphere", options=MeshFitOptions(init=Mesh(np.zeros((3, 3)), [[0, 1,
            2]])), progress=False)
    with pytest.raises(ValueError, match="target: expected a mesh with at least one face"):
        fit_mesh((tgt.verts, np.zeros((0, 3), np.int64)), recipe="sphere",
            options=MeshFitOptions(init=1), progress=False)
    with pytest.raises(TypeError, match="positional"):
        fit_mesh(tgt, 1, tgt, progress=False)
    with pytest.raises(TypeError, match="options: expected a MeshFitOptions"):
        fit_mesh(tgt, options={"n_iter": 3}, progress=False)
    with pytest.raises(ValueError, match="start_level"):
        CoarseToFine(start_level=-1)
    with pytest.raises(ValueError, match="max_level"):
        CoarseToFine(start_level=3, max_level=2)
    with pytest.raises(ValueError, match="fscore"):
        CoarseToFine(fscore=1.5)
    with pytest.raises(ValueError, match="max_verts"):
        CoarseToFine(max_verts=2)




def test_fit_docstring_examples():
    """The Examples sections of the fit modules run as doctests."""
    import doctest

    import geofit.fit.history as fh
    import geofit.fit.large_steps as fl
    import geofit.fit.mesh as fm
    import geofit.fit.solvers as fs

    for mod in (fh, fl, fm, fs):
        result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE)
        assert result.failed == 0, mod.__name__
        assert result.attempted > 0, mod.__name__


def test_time_budget_used_up_while_building_the_objective(monkeypatch):
    """A budget that runs out between the stage check and the solve ends with status
    "time_budget" (it once raised "time_budget: expected a finite number > 0")."""
    import time

    import geofit.fit.mesh as fm

    class Slow(fm.MeshObjective):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            time.sleep(0.3)

    monkeypatch.setattr(fm, "MeshObjective", Slow)
    res = fit_mesh(ico_sphere(2), recipe="sphere", options=MeshFitOptions(init=1), time_budget=0.1,
              evaluator=None, progress=False)
    assert res.status == "time_budget" and np.all(np.isfinite(res.mesh.verts))


def test_recipes_are_frozen_option_presets():
    """Each recipe is a MeshFitOptions preset; the user's options override only the fields
    they set; the options object is frozen."""
    import dataclasses

    from geofit.fit import Remeshing

    assert set(RECIPES) == {"default", "sphere", "coarse-to-fine", "tutorial"}
    assert all(isinstance(r, MeshFitOptions) for r in RECIPES.values())
    assert isinstance(RECIPES["default"].refine, Remeshing)
    assert isinstance(RECIPES["coarse-to-fine"].refine, CoarseToFine)
    assert RECIPES["tutorial"].method == "sgd" and RECIPES["sphere"].refine is None
    opts = MeshFitOptions(n_iter=3)
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.n_iter = 4
    res = fit_mesh(ico_sphere(2), recipe="tutorial", options=MeshFitOptions(init=1, n_iter=3,
                                                                           n_samples=100),
                   evaluator=None, progress=False)
    assert res.method == "sgd" and res.recipe == "tutorial" and res.n_iterations == 3
