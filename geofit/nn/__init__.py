"""A small numpy neural-network toolkit with hand-written backward passes.

* :mod:`geofit.nn.layers` -- :class:`Linear`, :class:`Softplus`, :class:`ReLU`, :class:`Sigmoid`,
  :class:`Sequential`, :func:`concat` / :func:`concat_backward`: ``forward(x) -> (y, cache)``
  and ``backward(cache, grad_y) -> (grad_x, grads)``, float32 for speed or float64 for
  finite-difference checks.
* :mod:`geofit.nn.optim` -- :class:`Adam` on named arrays, :func:`step_decay` (the tutorials'
  divide-by-10 at 75 %) and :func:`exponential_decay`.
"""
from __future__ import annotations

from . import layers, optim
from .layers import *  # noqa: F403 - the public names are the submodules' __all__
from .optim import *  # noqa: F403

__all__ = sorted([*layers.__all__, *optim.__all__])
