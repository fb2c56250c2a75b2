"""geofit.nn: every layer's backward pass against central finite differences (float64), the
activations against closed forms and PyTorch's conventions, Adam against PyTorch's update rule,
the learning-rate schedules, and every validation branch."""
from __future__ import annotations

import numpy as np
import pytest

from geofit.nn import (Adam, Linear, ReLU, Sequential, Sigmoid, Softplus, concat, concat_backward,
                       count_parameters, exponential_decay, step_decay)


def fd_input_grad(layer, x, G, h=1e-6):
    """Central differences of <G, layer(x)> with respect to every entry of x."""
    out = np.zeros_like(x)
    for i in np.ndindex(x.shape):  # entries of a tiny input
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        out[i] = (np.sum(G * layer(xp)) - np.sum(G * layer(xm))) / (2 * h)
    return out


def fd_param_grads(layer, x, G, h=1e-6):
    grads = {}
    for name, p in layer.params.items():
        g = np.zeros_like(p)
        for i in np.ndindex(p.shape):  # entries of a tiny parameter
            old = p[i]
            p[i] = old + h
            fp = np.sum(G * layer(x))
            p[i] = old - h
            fm = np.sum(G * layer(x))
            p[i] = old
            g[i] = (fp - fm) / (2 * h)
        grads[name] = g
    return grads


def tiny_mlp(seed=0, act="softplus"):
    a = Softplus(beta=10.0, dtype="float64") if act == "softplus" else ReLU(dtype="float64")
    return Sequential(Linear(4, 5, seed=seed, dtype="float64"), a,
                      Linear(5, 3, seed=seed + 1, dtype="float64"), Sigmoid(dtype="float64"))


LAYERS = {
    "linear": lambda: Linear(4, 3, seed=1, dtype="float64"),
    "linear_nobias": lambda: Linear(4, 3, bias=False, seed=2, dtype="float64"),
    "softplus_beta1": lambda: Softplus(dtype="float64"),
    "softplus_beta10": lambda: Softplus(beta=10.0, dtype="float64"),
    "relu": lambda: ReLU(dtype="float64"),
    "sigmoid": lambda: Sigmoid(dtype="float64"),
    "mlp_softplus": lambda: tiny_mlp(0, "softplus"),
    "mlp_relu": lambda: tiny_mlp(3, "relu"),
}


@pytest.mark.parametrize("name", sorted(LAYERS))
def test_layer_backward_matches_finite_differences(name):
    """d<G, layer(x)>/dx and /dparams equal central differences (float64, away from kinks)."""
    layer = LAYERS[name]()
    rng = np.random.default_rng(7)
    d_in = 4
    x = rng.normal(size=(6, d_in))
    x[np.abs(x) < 0.05] += 0.1  # stay away from ReLU's kink
    y, cache = layer.forward(x)
    G = rng.normal(size=y.shape)
    gx, grads = layer.backward(cache, G)
    np.testing.assert_allclose(gx, fd_input_grad(layer, x, G), rtol=1e-6, atol=1e-8)
    fd = fd_param_grads(layer, x, G)
    assert set(grads) == set(layer.params)
    for k in layer.params:
        np.testing.assert_allclose(grads[k], fd[k], rtol=1e-6, atol=1e-8, err_msg=k)


def test_linear_is_affine_with_pytorch_layout():
    """Linear computes x W^T + b with W of shape (out, in); init bounded by 1/sqrt(in)."""
    lin = Linear(16, 3, seed=0, dtype="float64")
    W, b = lin.params["weight"], lin.params["bias"]
    assert W.shape == (3, 16) and b.shape == (3,)
    assert np.abs(W).max() <= 0.25 and np.abs(b).max() <= 0.25
    x = np.arange(32.0).reshape(2, 16)
    np.testing.assert_allclose(lin(x), x @ W.T + b, rtol=1e-14)
    assert lin.n_params == 51


def test_softplus_matches_closed_form_and_threshold():
    """Softplus = log(1 + e^{bx})/b, exactly x above bx > 20; derivative sigmoid(bx)."""
    sp = Softplus(beta=10.0, dtype="float64")
    x = np.array([[-50.0, -1.0, 0.0, 0.3, 1.9, 2.5, 100.0]])
    y, d = sp.forward(x)
    ref = np.log1p(np.exp(10 * x[:, :5])) / 10
    np.testing.assert_allclose(y[:, :5], ref, rtol=1e-14, atol=1e-300)
    assert y[0, 5] == 2.5 and y[0, 6] == 100.0  # linear branch (bx > 20)
    np.testing.assert_allclose(d[:, :5], 1 / (1 + np.exp(-10 * x[:, :5])), rtol=1e-14)
    assert np.all(d[:, 5:] == 1.0)
    y32, _ = Softplus(beta=10.0).forward(x.astype(np.float32))
    assert y32.dtype == np.float32 and np.all(np.isfinite(y32))


def test_sigmoid_and_relu_extremes_stay_finite():
    """Sigmoid of +-1000 is exactly 1 / 0 without overflow; ReLU's derivative at 0 is 0."""
    with np.errstate(over="raise"):
        y = Sigmoid(dtype="float64")(np.array([[-1000.0, 0.0, 1000.0]]))
    np.testing.assert_array_equal(y, [[0.0, 0.5, 1.0]])
    relu = ReLU(dtype="float64")
    _, mask = relu.forward(np.array([[0.0, -1.0, 2.0]]))
    gx, _ = relu.backward(mask, np.ones((1, 3)))
    np.testing.assert_array_equal(gx, [[0.0, 0.0, 1.0]])


def test_sequential_names_dtype_and_skipped_input_grad():
    """Sequential names params like a state_dict, converts dtype, and skips dx when asked."""
    net = tiny_mlp()
    assert sorted(net.params) == ["0.bias", "0.weight", "2.bias", "2.weight"]
    assert count_parameters(net) == net.n_params == 4 * 5 + 5 + 5 * 3 + 3
    net32 = net.astype(np.float32)
    assert all(v.dtype == np.float32 for v in net32.params.values())
    x = np.ones((2, 4))
    y, cache = net32.forward(x)
    assert y.dtype == np.float32
    gx, grads = net32.backward(cache, np.ones((2, 3), np.float32), need_input_grad=False)
    assert gx is None and set(grads) == set(net.params)
    np.testing.assert_allclose(y, net(x), rtol=1e-6)
    assert net.forward(x, cache=False)[1] is None


def test_concat_roundtrip():
    """concat_backward splits the gradient into the parts' shapes (the adjoint of concat)."""
    a, b = np.ones((3, 2)), np.zeros((3, 4))
    y, sizes = concat([a, b])
    assert y.shape == (3, 6) and sizes == (2, 4)
    ga, gb = concat_backward(np.arange(18.0).reshape(3, 6), sizes)
    np.testing.assert_array_equal(ga, [[0, 1], [6, 7], [12, 13]])
    assert gb.shape == (3, 4)


def test_adam_matches_pytorch_rule_and_decay():
    """Adam's iterates follow PyTorch's formulas; set_lr(reset=True) restarts the moments."""
    rng = np.random.default_rng(0)
    p0 = rng.normal(size=5)
    p = {"w": p0.copy()}
    opt = Adam(p, lr=0.01, betas=(0.8, 0.9), eps=1e-6)
    m = np.zeros(5)
    v = np.zeros(5)
    ref = p0.copy()
    for t in range(1, 6):  # steps
        g = rng.normal(size=5)
        opt.step({"w": g})
        m = 0.8 * m + 0.2 * g
        v = 0.9 * v + 0.1 * g * g
        ref -= 0.01 * (m / (1 - 0.8 ** t)) / (np.sqrt(v / (1 - 0.9 ** t)) + 1e-6)
        np.testing.assert_allclose(p["w"], ref, rtol=1e-12)
    opt.set_lr(0.001, reset=True)
    assert opt.t == 0 and np.all(opt.m["w"] == 0)
    before = p["w"].copy()
    opt.step({"w": np.ones(5)})
    np.testing.assert_allclose(before - p["w"], 0.001, rtol=1e-5)  # first step: lr * sign


def test_adam_minimises_a_quadratic_in_float32():
    """Adam on float32 arrays drives a quadratic to its minimum and keeps the dtype."""
    p = {"w": np.full(3, 5.0, np.float32)}
    opt = Adam(p, lr=0.1)
    for _ in range(500):  # steps
        opt.step({"w": 2 * (p["w"] - 1.0)})
    assert p["w"].dtype == np.float32
    np.testing.assert_allclose(p["w"], 1.0, atol=1e-2)


def test_schedules():
    """step_decay divides by 10 at 75 % and resets there; exponential_decay hits both ends."""
    s = step_decay(1e-3, 3000)
    assert s(0) == (1e-3, False) and s(2249)[0] == 1e-3
    lr, reset = s(2250)
    assert lr == pytest.approx(1e-4) and reset
    assert s(2251) == (pytest.approx(1e-4), False)
    s2 = step_decay(1.0, 10, at=(0.5, 0.8), factor=0.5, reset=False)
    assert [s2(i)[0] for i in (4, 5, 8)] == [1.0, 0.5, 0.25]
    e = exponential_decay(1e-2, 1e-4, 100)
    assert e(0)[0] == pytest.approx(1e-2) and e(100)[0] == pytest.approx(1e-4)
    assert e(50)[0] == pytest.approx(1e-3)


@pytest.mark.parametrize("make, match", [
    (lambda: Linear(0, 3), "in_features"),
    (lambda: Linear(3, 2, dtype=np.int32), "dtype"),
    (lambda: Linear(3, 2, dtype="not-a-dtype"), "dtype"),
    (lambda: Softplus(beta=0.0), "beta"),
    (lambda: Softplus(threshold=np.inf), "threshold"),
    (lambda: Sequential(), "at least one"),
    (lambda: Sequential(Linear(2, 2), Linear(2, 2, dtype="float64")), "one dtype"),
    (lambda: Linear(3, 2).forward(np.ones((4, 2))), r"\(k, 3\)"),
    (lambda: Linear(3, 2).forward(np.array([["a", "b", "c"]])), "real numbers"),
    (lambda: Softplus().forward(np.ones(3)), r"\(k, d\)"),
    (lambda: concat([]), "at least one"),
    (lambda: concat([np.ones((2, 1)), np.ones((3, 1))]), r"parts\[1\]"),
    (lambda: concat_backward(np.ones((2, 3)), (1, 1)), "grad_y"),
    (lambda: Adam({}), "non-empty"),
    (lambda: Adam({"w": [1.0]}), "float ndarray"),
    (lambda: Adam({"w": np.ones(2)}, lr=-1), "lr"),
    (lambda: Adam({"w": np.ones(2)}, betas=(1.0, 0.9)), "betas"),
    (lambda: Adam({"w": np.ones(2)}, betas=3), "betas"),
    (lambda: Adam({"w": np.ones(2)}, eps=0), "eps"),
    (lambda: Adam({"w": np.ones(2)}).step({"v": np.ones(2)}), "names"),
    (lambda: Adam({"w": np.ones(2)}).step({"w": np.ones(3)}), "shape"),
    (lambda: step_decay(1e-3, 10, factor=0), "factor"),
    (lambda: exponential_decay(1e-3, 0, 10), "lr_end"),
])
def test_validation(make, match):
    """Every invalid argument raises ValueError naming it."""
    with pytest.raises(ValueError, match=match):
        make()


def test_sequential_rejects_non_layers():
    with pytest.raises(TypeError, match=r"layers\[1\]"):
        Sequential(Linear(2, 2), "relu")
