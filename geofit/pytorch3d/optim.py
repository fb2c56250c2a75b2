"""``torch.optim.SGD`` and ``torch.optim.Adam`` for :class:`~.tensor.Tensor` parameters.

``optimizer.zero_grad()`` clears the ``.grad`` of every parameter, ``loss.backward()`` fills
them, ``optimizer.step()`` updates the parameters' values in place with PyTorch's update rules.
Adam is geofit's :class:`geofit.nn.optim.Adam` (PyTorch's rule) over the parameter arrays.
"""
from __future__ import annotations

import numpy as np

from .._validate import check_positive
from ..nn import optim as _nn_optim
from .tensor import Tensor

__all__ = ["SGD", "Adam", "Optimizer"]


class Optimizer:
    """Base: ``param_groups`` (a list with one dict holding ``params`` and ``lr``),
    ``zero_grad()`` and ``step()``."""

    def __init__(self, params, defaults: dict):
        params = list(params)
        if params and isinstance(params[0], dict):
            raise ValueError("params: parameter groups (dicts) are not supported; pass a list "
                             "of tensors")
        if not params:
            raise ValueError("params: expected a non-empty list of tensors")
        for i, p in enumerate(params):
            if not isinstance(p, Tensor) or not p.requires_grad or not p.is_leaf:
                raise TypeError(f"params[{i}]: expected a leaf Tensor with requires_grad=True "
                                f"(Parameter(array) or full(..., requires_grad=True)), got "
                                f"{type(p)!r}")
        self.param_groups = [dict(defaults, params=params)]
        self.state: dict = {}

    @property
    def params(self) -> list:
        return self.param_groups[0]["params"]

    def zero_grad(self, set_to_none: bool = True) -> None:
        """Clear the gradients (None, or zeros with ``set_to_none=False``)."""
        for p in self.params:
            p.grad = None if set_to_none or p.grad is None else Tensor(np.zeros_like(p.data))


class SGD(Optimizer):
    """Stochastic gradient descent with momentum (``torch.optim.SGD``).

    Parameters
    ----------
    params : list of Tensor
    lr : float
    momentum, dampening, weight_decay : float
    nesterov : bool

    Notes
    -----
    PyTorch's rule: ``g += weight_decay p``; ``b = g`` on the first step, then
    ``b = momentum b + (1 - dampening) g``; ``g = g + momentum b`` (Nesterov) or ``b``;
    ``p -= lr g``.
    """

    def __init__(self, params, lr: float = 1e-3, momentum: float = 0.0, dampening: float = 0.0,
                 weight_decay: float = 0.0, nesterov: bool = False):
        check_positive(lr, "lr")
        if momentum < 0 or weight_decay < 0:
            raise ValueError(f"momentum, weight_decay: expected >= 0, got {momentum!r}, "
                             f"{weight_decay!r}")
        if nesterov and (momentum <= 0 or dampening != 0):
            raise ValueError("nesterov: needs momentum > 0 and dampening 0")
        super().__init__(params, {"lr": float(lr), "momentum": float(momentum),
                                  "dampening": float(dampening),
                                  "weight_decay": float(weight_decay), "nesterov": nesterov})

    def step(self) -> None:
        group = self.param_groups[0]
        lr, mu, damp = group["lr"], group["momentum"], group["dampening"]
        wd, nesterov = group["weight_decay"], group["nesterov"]
        for p in group["params"]:  # loop over parameter tensors
            if p.grad is None:
                continue
            g = p.grad.data
            if wd:
                g = g + wd * p.data
            if mu:
                buf = self.state.get(id(p))
                buf = g.copy() if buf is None else mu * buf + (1.0 - damp) * g
                self.state[id(p)] = buf
                g = g + mu * buf if nesterov else buf
            p.data -= lr * g


class Adam(Optimizer):
    """Adam (``torch.optim.Adam`` without weight decay), via :class:`geofit.nn.optim.Adam`.

    Parameters
    ----------
    params : list of Tensor
    lr : float
    betas : (float, float)
    eps : float

    Notes
    -----
    Changing ``optimizer.param_groups[0]["lr"]`` between steps changes the step size (the
    tutorials' learning-rate decay).
    """

    def __init__(self, params, lr: float = 1e-3, betas=(0.9, 0.999), eps: float = 1e-8,
                 weight_decay: float = 0.0):
        if weight_decay:
            raise ValueError("weight_decay: not supported by geofit's Adam; add an L2 term to "
                             "the loss instead")
        super().__init__(params, {"lr": float(lr), "betas": tuple(betas), "eps": float(eps)})
        self._adam = _nn_optim.Adam({str(i): p.data for i, p in enumerate(self.params)},
                                    lr=lr, betas=betas, eps=eps)

    def step(self) -> None:
        group = self.param_groups[0]
        self._adam.set_lr(group["lr"])
        arrays = self._adam.params
        for i, p in enumerate(group["params"]):  # the parameter arrays may have been replaced
            arrays[str(i)] = p.data
        self._adam.step({str(i): (p.grad.data if p.grad is not None else np.zeros_like(p.data))
                         for i, p in enumerate(group["params"])})
