"""Layers of a small multilayer perceptron with hand-written forward and backward passes.

Every layer follows one contract, so that a network is composed by the chain rule in plain sight:

* ``y, cache = layer.forward(x)`` computes the output and keeps what the backward pass needs
  (``cache=False`` skips that, for inference);
* ``grad_x, grads = layer.backward(cache, grad_y, need_input_grad=True)`` returns the gradient
  with respect to the input (``None`` when not asked for: the first layer of a network does not
  need it) and a dict of parameter gradients, named like the parameters.

Parameters live in ``layer.params`` (a dict name -> array) in the layer's ``dtype``: float32 for
speed when fitting, float64 when checking gradients by finite differences (:meth:`Layer.astype`).
The names and shapes follow PyTorch (``Linear.weight`` is ``(out_features, in_features)``), so
``Sequential`` parameter names read like a PyTorch ``state_dict`` (``"0.weight"``, ``"2.bias"``).

Layers keep no per-call state: the caches are returned, not stored, so one network can run on
several chunks of a batch at once (in threads) and the gradients are summed afterwards.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from .._validate import as_rng, check_finite, check_positive

__all__ = [
    "Layer",
    "Linear",
    "ReLU",
    "Sequential",
    "Sigmoid",
    "Softplus",
    "concat",
    "concat_backward",
    "count_parameters",
]

_DTYPES = (np.dtype(np.float32), np.dtype(np.float64))


def _check_dtype(dtype) -> np.dtype:
    try:
        dt = np.dtype(dtype)
    except TypeError:
        raise ValueError(f"dtype: expected float32 or float64, got {dtype!r}") from None
    if dt not in _DTYPES:
        raise ValueError(f"dtype: expected float32 or float64, got {dt}")
    return dt


def _check_input(x, name: str, n_features: int | None, dtype: np.dtype) -> np.ndarray:
    """Public-boundary check of a layer input ``(k, n_features)`` (cast to the layer dtype)."""
    x = np.asarray(x)
    if x.ndim != 2 or (n_features is not None and x.shape[1] != n_features):
        want = f"(k, {n_features})" if n_features is not None else "(k, d)"
        raise ValueError(f"{name}: expected shape {want}, got {tuple(x.shape)}")
    if x.dtype != dtype:
        if x.dtype.kind not in "fiub":
            raise ValueError(f"{name}: expected real numbers, got dtype {x.dtype}")
        x = x.astype(dtype)
    return x


class Layer:
    """Base class: a differentiable map ``(k, d_in) -> (k, d_out)`` applied row by row.

    Attributes
    ----------
    params : dict str -> ndarray
        The trainable parameters (empty for activations).
    dtype : numpy.dtype
        float32 or float64; inputs are cast to it.
    """

    params: dict[str, np.ndarray]
    dtype: np.dtype

    def forward(self, x: np.ndarray, *, cache: bool = True) -> tuple[np.ndarray, Any]:
        """``(y, cache)`` for an input ``x (k, d_in)``; ``cache`` is None when not kept."""
        raise NotImplementedError

    def backward(self, cache: Any, grad_y: np.ndarray, *, need_input_grad: bool = True
                 ) -> tuple[np.ndarray | None, dict[str, np.ndarray]]:
        """``(grad_x, grads)`` from the forward ``cache`` and ``grad_y (k, d_out)``."""
        raise NotImplementedError

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Inference: ``forward(x, cache=False)[0]``."""
        return self.forward(x, cache=False)[0]

    @property
    def n_params(self) -> int:
        """Number of scalar parameters."""
        return int(sum(p.size for p in self.params.values()))

    def astype(self, dtype) -> Layer:
        """A copy of the layer with parameters (and arithmetic) in ``dtype``."""
        dt = _check_dtype(dtype)
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        new.params = {k: v.astype(dt) for k, v in self.params.items()}
        new.dtype = dt
        return new


class Linear(Layer):
    """``y = x W^T + b`` (PyTorch's ``torch.nn.Linear``).

    Parameters
    ----------
    in_features, out_features : int
        Sizes of the input and output rows.
    bias : bool
        Whether to add a bias.
    seed : int or numpy.random.Generator, optional
        Initialisation as PyTorch's: weight and bias uniform in
        ``[-1/sqrt(in_features), 1/sqrt(in_features)]`` (kaiming-uniform with a = sqrt(5)).
    dtype : float32 or float64

    Attributes
    ----------
    params : dict
        ``weight (out_features, in_features)`` and ``bias (out_features,)``.

    Notes
    -----
    Backward: ``dL/dW = grad_y^T x``, ``dL/db = sum_rows grad_y``, ``dL/dx = grad_y W``.

    Examples
    --------
    >>> lin = Linear(3, 2, seed=0, dtype="float64")
    >>> y, cache = lin.forward(np.ones((4, 3)))
    >>> gx, grads = lin.backward(cache, np.ones((4, 2)))
    >>> y.shape, gx.shape, grads["weight"].shape, grads["bias"].tolist()
    ((4, 2), (4, 3), (2, 3), [4.0, 4.0])
    """

    def __init__(self, in_features: int, out_features: int, bias: bool = True, *,
                 seed=None, dtype=np.float32):
        in_features, out_features = int(in_features), int(out_features)
        if in_features < 1 or out_features < 1:
            raise ValueError(f"in_features, out_features: expected >= 1, got "
                             f"{in_features}, {out_features}")
        self.dtype = _check_dtype(dtype)
        self.in_features, self.out_features = in_features, out_features
        rng = as_rng(seed)
        bound = 1.0 / np.sqrt(in_features)
        self.params = {"weight": rng.uniform(-bound, bound, (out_features, in_features))
                       .astype(self.dtype)}
        if bias:
            self.params["bias"] = rng.uniform(-bound, bound, out_features).astype(self.dtype)

    def forward(self, x, *, cache=True):
        x = _check_input(x, "x", self.in_features, self.dtype)
        y = x @ self.params["weight"].T
        if "bias" in self.params:
            y += self.params["bias"]
        return y, (x if cache else None)

    def backward(self, cache, grad_y, *, need_input_grad=True):
        x = cache
        W = self.params["weight"]
        grad_y = np.asarray(grad_y, dtype=self.dtype)
        grads = {"weight": grad_y.T @ x}
        if "bias" in self.params:
            grads["bias"] = grad_y.sum(axis=0)
        return (grad_y @ W if need_input_grad else None), grads


class _Activation(Layer):
    """A parameter-free elementwise map whose forward cache is ``dy/dx``; backward multiplies."""

    def __init__(self, *, dtype=np.float32):
        self.dtype = _check_dtype(dtype)
        self.params = {}

    def backward(self, cache, grad_y, *, need_input_grad=True):
        if not need_input_grad:
            return None, {}
        return np.multiply(grad_y, cache, dtype=self.dtype), {}


class Softplus(_Activation):
    """``y = log(1 + exp(beta x)) / beta``, linear above ``beta x > threshold`` (PyTorch's).

    Parameters
    ----------
    beta : float
        Sharpness (> 0); the tutorial's NeRF uses 10.
    threshold : float
        Above ``beta x > threshold`` the output is ``x`` (and the derivative 1), as in PyTorch.

    Notes
    -----
    Computed stably as ``(max(beta x, 0) + log1p(exp(-|beta x|))) / beta``; the derivative is
    ``sigmoid(beta x)``, cached from the same ``exp(-|beta x|)``.
    """

    def __init__(self, beta: float = 1.0, threshold: float = 20.0, *, dtype=np.float32):
        self.beta = check_positive(beta, "beta")
        self.threshold = check_finite(threshold, "threshold")
        super().__init__(dtype=dtype)

    def forward(self, x, *, cache=True):
        x = _check_input(x, "x", None, self.dtype)
        return _softplus(x, self.beta, self.threshold, cache)


def _softplus(x: np.ndarray, beta: float, threshold: float, cache: bool):
    """Softplus and (when ``cache``) its derivative sigmoid(beta x), few temporaries."""
    bx = x * x.dtype.type(beta) if beta != 1.0 else x.copy()
    e = np.abs(bx)
    np.negative(e, out=e)
    np.exp(e, out=e)                       # e = exp(-|bx|) in (0, 1]
    y = np.log1p(e)
    big = bx > threshold
    np.maximum(bx, 0, out=bx)
    y += bx
    if beta != 1.0:
        y *= y.dtype.type(1.0 / beta)
    if big.any():
        y[big] = x[big]
    if not cache:
        return y, None
    # sigmoid(bx) = 1 / (1 + e) for bx >= 0, e / (1 + e) for bx < 0; 1 above the threshold
    d = 1.0 + e
    np.reciprocal(d, out=d)
    neg = x < 0
    d[neg] *= e[neg]
    d[big] = 1.0
    return y, d


class ReLU(_Activation):
    """``y = max(x, 0)``; the derivative at 0 is taken as 0 (PyTorch's convention)."""

    def forward(self, x, *, cache=True):
        x = _check_input(x, "x", None, self.dtype)
        y = np.maximum(x, 0)
        return y, ((y > 0) if cache else None)


class Sigmoid(_Activation):
    """``y = 1 / (1 + exp(-x))``, computed without overflow; ``dy/dx = y (1 - y)``."""

    def forward(self, x, *, cache=True):
        x = _check_input(x, "x", None, self.dtype)
        y = _sigmoid(x)
        return y, ((y * (1 - y)) if cache else None)


def _sigmoid(x: np.ndarray) -> np.ndarray:
    e = np.exp(-np.abs(x))
    y = 1.0 / (1.0 + e)
    neg = x < 0
    y[neg] *= e[neg]
    return y.astype(x.dtype, copy=False)


class Sequential(Layer):
    """Layers applied in order; parameters named ``"<index>.<name>"`` as in PyTorch.

    Parameters
    ----------
    *layers : Layer
        The layers; they must share one dtype.

    Examples
    --------
    >>> net = Sequential(Linear(3, 8, seed=0), Softplus(beta=10.0), Linear(8, 1, seed=1))
    >>> sorted(net.params), net.n_params
    (['0.bias', '0.weight', '2.bias', '2.weight'], 41)
    """

    def __init__(self, *layers: Layer):
        if not layers:
            raise ValueError("layers: expected at least one layer, got none")
        for i, layer in enumerate(layers):
            if not isinstance(layer, Layer):
                raise TypeError(f"layers[{i}]: expected a Layer, got {type(layer)!r}")
        dtypes = {layer.dtype for layer in layers}
        if len(dtypes) != 1:
            raise ValueError(f"layers: expected one dtype, got {sorted(map(str, dtypes))}")
        self.layers = list(layers)
        self.dtype = layers[0].dtype

    @property
    def params(self) -> dict[str, np.ndarray]:  # type: ignore[override]
        return {f"{i}.{k}": v for i, layer in enumerate(self.layers)
                for k, v in layer.params.items()}

    @params.setter
    def params(self, values: Mapping[str, np.ndarray]) -> None:
        for name, v in values.items():
            i, k = name.split(".", 1)
            self.layers[int(i)].params[k] = v

    def astype(self, dtype) -> Sequential:
        return Sequential(*(layer.astype(dtype) for layer in self.layers))

    def __len__(self) -> int:
        return len(self.layers)

    def __getitem__(self, i: int) -> Layer:
        return self.layers[i]

    def forward(self, x, *, cache=True):
        caches = []
        for layer in self.layers:  # layers
            x, c = layer.forward(x, cache=cache)
            caches.append(c)
        return x, (caches if cache else None)

    def backward(self, cache, grad_y, *, need_input_grad=True):
        grads: dict[str, np.ndarray] = {}
        g = grad_y
        n = len(self.layers)
        for i in range(n - 1, -1, -1):  # layers, last first
            need = need_input_grad or i > 0
            g, gl = self.layers[i].backward(cache[i], g, need_input_grad=need)
            for k, v in gl.items():
                grads[f"{i}.{k}"] = v
        return g, grads


def concat(parts: Sequence[np.ndarray]) -> tuple[np.ndarray, tuple[int, ...]]:
    """Concatenate row blocks ``(k, d_i)`` along the features: ``(y (k, sum d_i), sizes)``.

    The sizes are what :func:`concat_backward` needs to split the gradient.
    """
    if not parts:
        raise ValueError("parts: expected at least one array, got none")
    arrays = [np.asarray(p) for p in parts]
    k = arrays[0].shape[0]
    for i, a in enumerate(arrays):
        if a.ndim != 2 or a.shape[0] != k:
            raise ValueError(f"parts[{i}]: expected shape ({k}, d), got {tuple(a.shape)}")
    return np.concatenate(arrays, axis=1), tuple(a.shape[1] for a in arrays)


def concat_backward(grad_y: np.ndarray, sizes: Iterable[int]) -> list[np.ndarray]:
    """Split the gradient of a concatenation into the gradients of its parts (views)."""
    sizes = tuple(int(s) for s in sizes)
    if grad_y.ndim != 2 or grad_y.shape[1] != sum(sizes):
        raise ValueError(f"grad_y: expected shape (k, {sum(sizes)}), got {tuple(grad_y.shape)}")
    cuts = np.cumsum(sizes)[:-1]
    return np.split(grad_y, cuts, axis=1)


def count_parameters(*modules: Layer | Mapping[str, np.ndarray]) -> int:
    """Total number of scalar parameters of layers or parameter dicts."""
    total = 0
    for m in modules:
        params = m.params if isinstance(m, Layer) else m
        total += int(sum(np.asarray(p).size for p in params.values()))
    return total
