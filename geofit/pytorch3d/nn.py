"""``torch.nn`` pieces the tutorials use, on the tape: ``Parameter``, ``Module``, the NeRF
tutorial's layers (``Linear``, ``Softplus``, ``Sigmoid``, ``ReLU``, ``Sequential``) and
``functional`` (``normalize``, ``grid_sample``, ``relu``, ``sigmoid``, ``softplus``).
:mod:`geofit.pytorch3d.torch` exposes them as ``torch.nn``.

The layers are geofit's :mod:`geofit.nn` layers (PyTorch's initialisation and formulas, each
with its hand-written backward), run in float64 and recorded on the tape; :class:`Module` only
collects parameters (``parameters()``), calls ``forward`` and ignores ``.to(device)``. There is
no general autodiff: a model built from these layers and the tape's arithmetic differentiates,
anything else raises.
"""
from __future__ import annotations

import numpy as np

from ..nn import layers as _layers
from . import _functional
from ._common import missing_names
from .tensor import Parameter, Tensor, default_rng

__all__ = ["Linear", "Module", "Parameter", "ReLU", "Sequential", "Sigmoid", "Softplus",
           "functional"]


class Module:
    """Base class: ``parameters()``, ``named_parameters()``, ``__call__ -> forward``, ``to``.

    Examples
    --------
    >>> import numpy as np
    >>> class Scale(Module):
    ...     def __init__(self):
    ...         super().__init__()
    ...         self.w = Parameter(np.ones(3))
    ...     def forward(self, x):
    ...         return x * self.w
    >>> m = Scale()
    >>> [tuple(p.shape) for p in m.parameters()], m(np.arange(3.0)).sum().item()
    ([(3,)], 3.0)
    """

    def __init__(self):
        self.training = True

    def _children(self):
        for name, value in vars(self).items():  # attributes in definition order
            if isinstance(value, (Parameter, Module)):
                yield name, value
            elif isinstance(value, (list, tuple)):
                for i, v in enumerate(value):
                    if isinstance(v, (Parameter, Module)):
                        yield f"{i}", v

    def named_parameters(self, prefix: str = ""):
        seen = set()
        for name, value in self._children():
            items = [(prefix + name, value)] if isinstance(value, Parameter) else \
                value.named_parameters(prefix + name + ".")
            for n, p in items:
                if id(p) not in seen:
                    seen.add(id(p))
                    yield n, p

    def parameters(self):
        return [p for _, p in self.named_parameters()]

    def register_buffer(self, name: str, tensor) -> None:
        """A constant attribute (not a parameter)."""
        setattr(self, name, _as_tensor(tensor).detach())

    def forward(self, *args, **kwargs):  # pragma: no cover - abstract
        raise NotImplementedError("Module.forward: define forward in the subclass")

    def __call__(self, *args, **kwargs):
        return self.forward(*args, **kwargs)

    def to(self, *args, **kwargs) -> Module:
        return self

    def train(self, mode: bool = True) -> Module:
        self.training = bool(mode)
        return self

    def eval(self) -> Module:
        return self.train(False)


def _as_tensor(x) -> Tensor:
    return x if isinstance(x, Tensor) else Tensor(np.asarray(x, np.float64))


def _run_layer(layer, x: Tensor, params: list) -> Tensor:
    """Apply a geofit.nn layer to the last axis of ``x``; record its backward."""
    shape = x.data.shape
    y, cache = layer.forward(x.data.reshape(-1, shape[-1]))
    names = list(layer.params)

    def vjp(g):
        gx, grads = layer.backward(cache, g.reshape(-1, g.shape[-1]))
        return (gx.reshape(shape), *(grads[k] for k in names))

    return Tensor._record(y.reshape(shape[:-1] + (y.shape[-1],)), [x, *params], vjp)


class Linear(Module):
    """``y = x W^T + b`` (``torch.nn.Linear``, PyTorch's uniform initialisation).

    Attributes
    ----------
    weight : Parameter (out_features, in_features)
    bias : Parameter (out_features,) or None
    """

    def __init__(self, in_features: int, out_features: int, bias: bool = True, device=None,
                 dtype=None):
        super().__init__()
        self._layer = _layers.Linear(in_features, out_features, bias, seed=default_rng(),
                                     dtype=np.float64)
        self.weight = Parameter(self._layer.params["weight"])
        self.bias = Parameter(self._layer.params["bias"]) if bias else None
        # the layer computes with the parameters' own arrays (optimisers update them in place)
        self._layer.params["weight"] = self.weight.data
        if bias:
            self._layer.params["bias"] = self.bias.data
        self.in_features, self.out_features = int(in_features), int(out_features)

    def forward(self, x) -> Tensor:
        params = [self.weight] + ([self.bias] if self.bias is not None else [])
        return _run_layer(self._layer, _as_tensor(x), params)


class _Activation(Module):
    _layer = None

    def forward(self, x) -> Tensor:
        return _run_layer(self._layer, _as_tensor(x), [])


class Softplus(_Activation):
    """``log(1 + exp(beta x)) / beta`` (``torch.nn.Softplus``)."""

    def __init__(self, beta: float = 1.0, threshold: float = 20.0):
        super().__init__()
        self._layer = _layers.Softplus(beta, threshold, dtype=np.float64)


class Sigmoid(_Activation):
    """``torch.nn.Sigmoid``."""

    def __init__(self):
        super().__init__()
        self._layer = _layers.Sigmoid(dtype=np.float64)


class ReLU(_Activation):
    """``torch.nn.ReLU`` (``inplace`` is accepted and ignored)."""

    def __init__(self, inplace: bool = False):
        super().__init__()
        self._layer = _layers.ReLU(dtype=np.float64)


class Sequential(Module):
    """Modules applied in order (``torch.nn.Sequential``); ``seq[i]`` is the i-th."""

    def __init__(self, *modules: Module):
        super().__init__()
        self._modules = list(modules)

    def __getitem__(self, i: int) -> Module:
        return self._modules[i]

    def __len__(self) -> int:
        return len(self._modules)

    def forward(self, x):
        for m in self._modules:  # the layers, in order
            x = m(x)
        return x


#: ``torch.nn.functional``: ``normalize``, ``grid_sample``, ``relu``, ``sigmoid``, ``softplus``.
functional = _functional


_MISSING = ("torch.nn layers other than Linear, Softplus, Sigmoid, ReLU and Sequential are not "
            "emulated (no general autodiff); geofit's NeuralRadianceField in geofit.render is "
            "the NeRF tutorial's network with its analytic backward and geofit.fit.fit_nerf its "
            "fit")
__getattr__ = missing_names("geofit.pytorch3d.nn", {
    "Conv2d": _MISSING, "ModuleList": "use Sequential or a list attribute of a Module",
    "Dropout": _MISSING, "BatchNorm1d": _MISSING, "LayerNorm": _MISSING, "Embedding": _MISSING,
})
