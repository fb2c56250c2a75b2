"""A small numpy neural-network toolkit with hand-written backward passes.

* :mod:`geofit.nn.layers` -- :class:`Linear`, :class:`Softplus`, :class:`ReLU`, :class:`Sigmoid`,
  :class:`Sequential`, :func:`concat` / :func:`concat_backward`: ``forward(x) -> (y, cache)``
  and ``backward(cache, grad_y) -> (grad_x, grads)``, float32 for speed or float64 for
  finite-difference checks.
* :mod:`geofit.nn.optim` -- :class:`Adam` on named arrays, :func:`step_decay` (the tutorials'
  divide-by-10 at 75 %) and :func:`exponential_decay`.
"""
from __future__ import annotations

from .layers import (
    Layer,
    Linear,
    ReLU,
    Sequential,
    Sigmoid,
    Softplus,
    concat,
    concat_backward,
    count_parameters,
)
from .optim import Adam, LRSchedule, exponential_decay, step_decay

__all__ = [
    "Adam",
    "LRSchedule",
    "Layer",
    "Linear",
    "ReLU",
    "Sequential",
    "Sigmoid",
    "Softplus",
    "concat",
    "concat_backward",
    "count_parameters",
    "exponential_decay",
    "step_decay",
]
