"""Solvers (scipy/nlopt L-BFGS, SGD, Adam) and the shared history/result/clock of geofit.fit."""
from __future__ import annotations

import json
import time

import numpy as np
import pytest

from geofit.fit import (
    SOLVERS,
    STATUSES,
    Clock,
    FitHistory,
    FitResult,
    adam,
    lbfgs_nlopt,
    lbfgs_scipy,
    minimize,
    sgd,
)


def rosenbrock(x):
    a, b = x
    value = (1 - a) ** 2 + 100 * (b - a * a) ** 2
    grad = np.array([-2 * (1 - a) - 400 * a * (b - a * a), 200 * (b - a * a)])
    return float(value), grad


def quadratic(x):
    return 0.5 * float(x @ x), x.copy()


class NanAfter:
    """A quadratic that returns NaN (value or gradient) from evaluation ``k`` on."""

    def __init__(self, k, where="value"):
        self.k, self.where, self.n, self.seen = k, where, 0, []

    def __call__(self, x):
        self.n += 1
        v, g = rosenbrock(x)
        if self.n >= self.k:
            if self.where == "value":
                v = float("nan")
            else:
                g = g * np.nan
        else:
            self.seen.append((v, x.copy()))
        return v, g


# ------------------------------------------------------------------------------------ convergence
@pytest.mark.parametrize("solver", [lbfgs_scipy, lbfgs_nlopt])
def test_lbfgs_solves_rosenbrock(solver):
    """Both quasi-Newton wrappers reach the Rosenbrock minimum (1, 1) and report convergence."""
    res = solver(rosenbrock, np.array([-1.2, 1.0]))
    assert res.status == "converged", res.message
    np.testing.assert_allclose(res.x, [1.0, 1.0], atol=1e-5)
    assert res.value < 1e-10
    assert res.n_evaluations >= res.n_iterations > 0
    assert res.seconds >= 0


def test_sgd_matches_pytorch_momentum_rule():
    """SGD: buf = g at step 1, then buf = m buf + g; x -= lr buf (PyTorch, dampening 0)."""
    lr, m = 0.1, 0.9
    res = sgd(quadratic, np.array([1.0, -2.0]), lr=lr, momentum=m, n_iter=3)
    x = np.array([1.0, -2.0])
    buf = None
    for _ in range(3):
        g = x.copy()
        buf = g if buf is None else m * buf + g
        x = x - lr * buf
    np.testing.assert_allclose(res.x, x, rtol=1e-15)
    assert res.status == "max_iter" and res.n_iterations == 3


def test_adam_matches_pytorch_rule():
    """Adam with bias correction and eps outside the sqrt, as torch.optim.Adam."""
    lr, b1, b2, eps = 0.05, 0.8, 0.9, 1e-8
    res = adam(rosenbrock, np.array([-1.2, 1.0]), lr=lr, betas=(b1, b2), eps=eps, n_iter=4)
    x = np.array([-1.2, 1.0])
    mom, v = np.zeros(2), np.zeros(2)
    for t in range(1, 5):
        g = rosenbrock(x)[1]
        mom = b1 * mom + (1 - b1) * g
        v = b2 * v + (1 - b2) * g * g
        x = x - lr * (mom / (1 - b1 ** t)) / (np.sqrt(v / (1 - b2 ** t)) + eps)
    np.testing.assert_allclose(res.x, x, rtol=1e-14)


@pytest.mark.parametrize("method,opts", [
    ("lbfgs", {}), ("lbfgs-nlopt", {}),
    ("sgd", {"lr": 0.1, "momentum": 0.5, "n_iter": 200}),
    ("adam", {"lr": 0.05, "n_iter": 500}),
])
def test_minimize_dispatch_reaches_minimum(method, opts):
    """Every solver named in SOLVERS minimises a convex quadratic."""
    res = minimize(quadratic, np.full(5, 3.0), method, **opts)
    assert np.abs(res.x).max() < 1e-3, (method, res.message)
    assert res.status in STATUSES


# ------------------------------------------------------------------------------------ guards
@pytest.mark.parametrize("where", ["value", "gradient"])
@pytest.mark.parametrize("method", SOLVERS)
def test_nonfinite_objective_stops_with_finite_best(method, where):
    """A NaN value or gradient stops every solver with 'nonfinite' and the best finite point."""
    fun = NanAfter(6, where)
    opts = {"sgd": {"lr": 1e-4, "n_iter": 50}, "adam": {"lr": 1e-2, "n_iter": 50}}.get(method, {})
    res = minimize(fun, np.array([-1.2, 1.0]), method, **opts)
    assert res.status == "nonfinite", res.message
    assert where in res.message
    assert np.all(np.isfinite(res.x))
    best_v, best_x = min(fun.seen, key=lambda t: t[0])
    assert res.value == best_v
    np.testing.assert_array_equal(res.x, best_x)


def test_nan_at_first_evaluation_returns_x0():
    res = lbfgs_scipy(lambda x: (float("nan"), x), np.array([1.0, 2.0]))
    assert res.status == "nonfinite"
    np.testing.assert_array_equal(res.x, [1.0, 2.0])
    assert res.value == np.inf


def test_huge_lr_sgd_stops_with_status_and_finite_x():
    """SGD with a step far too large diverges: it stops (diverged/nonfinite), x stays finite."""
    res = sgd(quadratic, np.ones(4), lr=100.0, momentum=0.9, n_iter=5000)
    assert res.status in ("diverged", "nonfinite"), res.message
    assert res.n_iterations < 5000
    assert np.all(np.isfinite(res.x))
    np.testing.assert_array_equal(res.x, np.ones(4))  # the best point was the start


def test_time_budget_stops_solvers():
    def slow(x):
        time.sleep(0.01)
        return rosenbrock(x)

    for method in ("lbfgs", "lbfgs-nlopt"):
        res = minimize(slow, np.array([-1.2, 1.0]), method, time_budget=0.05)
        assert res.status == "time_budget", res.message
        assert 0.05 <= res.seconds < 0.5
    res = sgd(slow, np.array([-1.2, 1.0]), lr=1e-4, n_iter=1000, time_budget=0.05)
    assert res.status == "time_budget" and res.n_iterations < 20


def test_max_eval_budget():
    for method in ("lbfgs", "lbfgs-nlopt"):
        res = minimize(rosenbrock, np.array([-1.2, 1.0]), method, max_eval=7)
        assert res.status == "max_eval", res.message
        assert res.n_evaluations == 7


@pytest.mark.parametrize("max_iter, memory", [(1000, 10), (6, 3), (25, 20)])
def test_lbfgs_scipy_iterates_equal_scipy_minimize(max_iter, memory):
    """lbfgs_scipy drives scipy's compiled L-BFGS-B step itself: the objective sees the same
    points, bit for bit, as under scipy.optimize.minimize, and the result is the same."""
    from scipy.optimize import minimize as sp_minimize

    rng = np.random.default_rng(3)
    D, b = rng.uniform(0.5, 3.0, 200), rng.standard_normal(200)

    def fun(x):  # a smooth non-quadratic objective
        r = x - b
        return float(0.5 * (D * r) @ r + 0.3 * np.sum(np.cos(3 * x))), D * r - 0.9 * np.sin(3 * x)

    ours, theirs = [], []
    res = lbfgs_scipy(lambda x: (ours.append(x.copy()), fun(x))[1], np.zeros(200),
                      max_iter=max_iter, memory=memory, ftol=1e-12, gtol=1e-10)
    ref = sp_minimize(lambda x: (theirs.append(x.copy()), fun(x))[1], np.zeros(200), jac=True,
                      method="L-BFGS-B", options={"maxiter": max_iter, "maxcor": memory,
                                                  "ftol": 1e-12, "gtol": 1e-10,
                                                  "maxfun": np.iinfo(np.int32).max})
    assert len(ours) == len(theirs) == res.n_evaluations > 3
    assert all(np.array_equal(a, c) for a, c in zip(ours, theirs))
    assert np.array_equal(res.x, ref.x) and res.value == ref.fun
    assert res.n_iterations == ref.nit
    assert res.status == ("max_iter" if ref.status == 1 else "converged"), ref.message


def test_max_iter_scipy():
    res = lbfgs_scipy(rosenbrock, np.array([-1.2, 1.0]), max_iter=3)
    assert res.status == "max_iter" and res.n_iterations == 3


@pytest.mark.parametrize("method", SOLVERS)
def test_callback_can_stop_and_sees_iterations(method):
    seen = []

    def cb(info):
        seen.append(info)
        return info.iteration >= 3

    opts = {"sgd": {"lr": 1e-4}, "adam": {"lr": 1e-2}}.get(method, {})
    res = minimize(rosenbrock, np.array([-1.2, 1.0]), method, callback=cb, **opts)
    assert res.status == "callback"
    assert [s.iteration for s in seen] == [1, 2, 3]
    assert all(np.isfinite(s.value) for s in seen)
    assert not seen[-1].x.flags.writeable


def test_paused_clock_time_is_excluded():
    """Time the callback spends under clock.paused() is not charged to the solver."""
    clock = Clock()

    def cb(info):
        with clock.paused():
            time.sleep(0.02)

    res = sgd(quadratic, np.ones(3), lr=0.1, n_iter=10, callback=cb, clock=clock)
    assert res.seconds < 0.05  # 10 x 20 ms were spent paused
    assert clock.elapsed() < 0.05


@pytest.mark.parametrize("method", SOLVERS)
def test_objective_exception_propagates_with_message(method):
    def bad(x):
        raise KeyError("broken objective")

    with pytest.raises(KeyError, match="broken objective"):
        minimize(bad, np.ones(2), method)


# ------------------------------------------------------------------------------------ validation
@pytest.mark.parametrize("x0,match", [
    (np.ones((2, 2)), "x0: expected shape"), (np.zeros(0), "x0: expected at least one"),
    (np.array([1.0, np.nan]), "x0: expected finite"),
])
def test_bad_x0(x0, match):
    with pytest.raises(ValueError, match=match):
        lbfgs_scipy(quadratic, x0)


# Each row: a solver, one invalid option, the error and the text naming the option.
_BAD_OPTIONS = [
    (minimize, {"method": "bfgs"}, ValueError, "method"),
    (sgd, {"lr": 0.0}, ValueError, "lr"),
    (sgd, {"momentum": 1.0}, ValueError, "momentum"),
    (sgd, {"n_iter": 0}, ValueError, "n_iter"),
    (adam, {"n_iter": None}, ValueError, "n_iter"),
    (adam, {"betas": (0.9, 1.0)}, ValueError, "betas"),
    (adam, {"betas": 0.9}, ValueError, "betas"),
    (adam, {"eps": -1.0}, ValueError, "eps"),
    (lbfgs_scipy, {"max_iter": 0}, ValueError, "max_iter"),
    (lbfgs_nlopt, {"max_eval": 1.5}, ValueError, "max_eval"),
    (lbfgs_nlopt, {"time_budget": -1}, ValueError, "time_budget"),
    (lbfgs_scipy, {"memory": 0}, ValueError, "memory"),
    (lbfgs_nlopt, {"memory": 0}, ValueError, "memory"),
    (lbfgs_scipy, {"ftol": -1}, ValueError, "ftol"),
    (lbfgs_nlopt, {"ftol_rel": np.nan}, ValueError, "ftol_rel"),
    (lbfgs_nlopt, {"xtol_rel": -1}, ValueError, "xtol_rel"),
    (lbfgs_scipy, {"gtol": -1}, ValueError, "gtol"),
    (sgd, {"divergence": 0}, ValueError, "divergence"),
    (sgd, {"clock": time.perf_counter}, TypeError, "clock"),
]


@pytest.mark.parametrize("solver, option, error, match", _BAD_OPTIONS,
                         ids=[f"{i}-{r[0].__name__}-{r[3]}" for i, r in enumerate(_BAD_OPTIONS)])
def test_bad_options(solver, option, error, match):
    """Every invalid option raises, naming the option."""
    with pytest.raises(error, match=match):
        solver(quadratic, np.ones(2), **option)


def test_bad_gradient_shape():
    with pytest.raises(ValueError, match="gradient must have shape"):
        lbfgs_scipy(lambda x: (0.0, np.zeros(3)), np.ones(2))


# ------------------------------------------------------------------------------------ history
def test_history_records_columns_and_checkpoints():
    h = FitHistory()
    h.record(0, 0.0, 3.0, {"a": 1.0, "b": 2.0}, n_params=9)
    h.record(5, 0.5, 2.0, {"a": 0.5, "b": 1.5}, {"cd": 0.1}, n_params=9, stage=1)
    h.record(9, 0.7, 1.0, {"b": 0.7, "a": 0.3}, n_params=30, stage=2)
    h.checkpoint(9, 0.7, {"cd": 0.05})
    a = h.as_arrays()
    np.testing.assert_array_equal(a["step"], [0, 5, 9])
    np.testing.assert_array_equal(a["terms"]["a"], [1.0, 0.5, 0.3])
    np.testing.assert_array_equal(a["n_params"], [9, 9, 30])
    np.testing.assert_array_equal(a["stage"], [0, 1, 2])
    np.testing.assert_array_equal(a["checkpoint_step"], [5, 9])
    np.testing.assert_array_equal(a["metrics"]["cd"], [0.1, 0.05])
    assert h.last_metrics() == {"cd": 0.05}
    assert len(h) == 3


def test_history_json_round_trip_with_nonfinite_loss():
    h = FitHistory()
    h.record(0, 0.0, 1.0, {"a": 1.0}, {"m": 2.0})
    h.record(1, 0.1, float("nan"), {"a": float("inf")})
    h.note(1, 0.1, "stage 1", n_verts=42)
    text = h.to_json()
    d = json.loads(text)
    json.dumps(d, allow_nan=False)  # strict JSON: non-finite values are strings
    assert d["loss"][1] == "nan" and d["terms"]["a"][1] == "inf"
    h2 = FitHistory.from_dict(d)
    assert np.isnan(h2.loss[1]) and h2.terms["a"][1] == np.inf
    assert h2.checkpoints == h.checkpoints and h2.events == h.events


def test_history_rejects_inconsistent_rows():
    h = FitHistory()
    h.record(3, 1.0, 1.0, {"a": 1.0}, {"m": 1.0})
    with pytest.raises(ValueError, match="step"):
        h.record(2, 1.0, 1.0, {"a": 1.0})
    with pytest.raises(ValueError, match="seconds"):
        h.record(4, 0.5, 1.0, {"a": 1.0})
    with pytest.raises(ValueError, match="terms"):
        h.record(4, 1.5, 1.0, {"b": 1.0})
    with pytest.raises(ValueError, match="metrics"):
        h.checkpoint(4, 1.5, {"other": 1.0})
    with pytest.raises(ValueError, match="loss"):
        h.record(4, 1.5, "x", {"a": 1.0})


def test_fit_result_status_and_summary():
    h = FitHistory()
    h.record(0, 0.0, 1.0, {}, {"m": 0.5})
    r = FitResult(status="converged", message="ok", history=h, n_params=6)
    assert r.converged and r.ok
    s = r.summary()
    assert s["metrics"] == {"m": 0.5} and s["final_loss"] == 1.0
    assert not FitResult(status="nonfinite").ok
    with pytest.raises(ValueError, match="status"):
        FitResult(status="fine")


def test_clock_pause_is_reentrant():
    c = Clock()
    with c.paused():
        with c.paused():
            time.sleep(0.02)
        assert c.is_paused
    assert not c.is_paused
    assert c.elapsed() < 0.015


def test_clock_cpu_time_excludes_paused_work():
    """CPU time spent busy inside clock.paused() is not charged; outside it is."""
    def burn(seconds):
        t0 = time.process_time()
        while time.process_time() - t0 < seconds:
            pass

    c = Clock()
    with c.paused():
        burn(0.05)
    assert c.cpu_elapsed() < 0.02
    burn(0.05)
    assert c.cpu_elapsed() >= 0.05


def test_adam_solver_and_nn_adam_take_the_same_steps():
    """fit.solvers.adam and geofit.nn.Adam share one update rule: identical iterates."""
    from geofit.fit.solvers import adam
    from geofit.nn import Adam

    A = np.diag([1.0, 4.0, 0.25])

    def fun(x):
        return 0.5 * float(x @ A @ x), A @ x

    x0 = np.array([1.0, -2.0, 3.0])
    iterates = []
    adam(fun, x0, lr=0.05, betas=(0.8, 0.95), eps=1e-6, n_iter=6,
         callback=lambda info: iterates.append(info.x.copy()))
    p = {"x": x0.copy()}
    opt = Adam(p, lr=0.05, betas=(0.8, 0.95), eps=1e-6)
    for want in iterates:
        opt.step({"x": fun(p["x"])[1]})
        np.testing.assert_array_equal(p["x"], want)
    assert len(iterates) == 6
