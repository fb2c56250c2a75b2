"""Adam over a dict of parameter arrays, with learning-rate decay.

:class:`Adam` updates the arrays of a network in place (in their own dtype, float32 when fitting)
with PyTorch's rule (bias-corrected moments, ``eps`` added to the corrected ``sqrt(v)``).
A schedule maps the step number to a learning rate: :func:`step_decay` is the tutorials' "divide
by 10 at 75 % of the steps" and :func:`exponential_decay` a smooth alternative. The tutorials
create a *new* optimizer at the decay (its moments restart from zero); :meth:`Adam.set_lr` with
``reset=True`` does the same.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from .._validate import check_positive

__all__ = ["Adam", "LRSchedule", "adam_step", "check_betas", "exponential_decay", "step_decay"]

#: A schedule: ``schedule(step) -> (learning rate, reset)``; ``reset`` restarts the moments.
LRSchedule = Callable[[int], "tuple[float, bool]"]


def check_betas(betas) -> tuple[float, float]:
    """Adam's ``(b1, b2)`` as two floats in [0, 1); ValueError naming ``betas`` otherwise."""
    try:
        b1, b2 = (float(b) for b in betas)
    except (TypeError, ValueError):
        raise ValueError(f"betas: expected two numbers, got {betas!r}") from None
    if not (0.0 <= b1 < 1.0 and 0.0 <= b2 < 1.0):
        raise ValueError(f"betas: expected two numbers in [0, 1), got {betas!r}")
    return b1, b2


def adam_step(g: np.ndarray, m: np.ndarray, v: np.ndarray, t: int, lr: float,
              betas: tuple[float, float], eps: float) -> np.ndarray:
    """PyTorch's Adam update at step ``t``: moves the moments in place, returns the step.

    The one implementation of the rule: :class:`Adam` subtracts the step from its arrays in
    place, :func:`geofit.fit.solvers.adam` from its parameter vector.

    Parameters
    ----------
    g : ndarray
        Gradient (the dtype of ``m`` and ``v``).
    m, v : ndarray
        First and second moments, shaped like ``g``; updated in place.
    t : int
        Step number, >= 1 (the bias corrections use it).
    lr : float
        Learning rate.
    betas : (float, float)
        Moment decay rates (checked by :func:`check_betas`).
    eps : float
        Added to the bias-corrected ``sqrt(v)``.

    Returns
    -------
    ndarray
        ``lr (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps)``; the update is ``p -= step``.

    Notes
    -----
    ``m = b1 m + (1 - b1) g``, ``v = b2 v + (1 - b2) g^2`` before the step is formed.
    """
    b1, b2 = betas
    m *= b1
    m += (1.0 - b1) * g
    v *= b2
    v += (1.0 - b2) * (g * g)
    denom = np.sqrt(v / (1.0 - b2 ** t))
    denom += eps
    return (lr / (1.0 - b1 ** t)) * m / denom


class Adam:
    """Adam (PyTorch's ``torch.optim.Adam`` without weight decay) on named arrays, in place.

    Parameters
    ----------
    params : dict str -> ndarray
        The arrays to update (float32 or float64); they are modified in place by :meth:`step`.
    lr : float
        Learning rate (> 0).
    betas : (float, float)
        Decay rates of the first and second moments, in [0, 1).
    eps : float
        Added to ``sqrt(v_hat)`` (> 0).

    Notes
    -----
    ``m = b1 m + (1 - b1) g``, ``v = b2 v + (1 - b2) g^2``,
    ``p -= lr (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps)`` (:func:`adam_step`, which
    :func:`geofit.fit.solvers.adam` uses too).

    Examples
    --------
    >>> p = {"w": np.array([1.0, -2.0])}
    >>> opt = Adam(p, lr=0.1)
    >>> opt.step({"w": np.array([1.0, -1.0])})
    >>> p["w"]  # the first Adam step moves every coordinate by lr against the gradient's sign
    array([ 0.9, -1.9])
    """

    def __init__(self, params: Mapping[str, np.ndarray], lr: float = 1e-3,
                 betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        if not isinstance(params, Mapping) or not params:
            raise ValueError("params: expected a non-empty dict of arrays")
        for k, v in params.items():
            if not isinstance(v, np.ndarray) or v.dtype.kind != "f":
                raise ValueError(f"params[{k!r}]: expected a float ndarray, got {type(v)!r}")
        self.params = params
        self.lr = check_positive(lr, "lr")
        self.betas = check_betas(betas)
        self.eps = check_positive(eps, "eps")
        self.reset()

    def reset(self) -> None:
        """Zero the moments and the step count (as a freshly created optimizer)."""
        self.t = 0
        self.m = {k: np.zeros_like(v) for k, v in self.params.items()}
        self.v = {k: np.zeros_like(v) for k, v in self.params.items()}

    def set_lr(self, lr: float, *, reset: bool = False) -> None:
        """Change the learning rate; ``reset=True`` also restarts the moments."""
        self.lr = check_positive(lr, "lr")
        if reset:
            self.reset()

    def step(self, grads: Mapping[str, np.ndarray]) -> None:
        """One update from ``grads`` (same names and shapes as ``params``)."""
        if set(grads) != set(self.params):
            raise ValueError(f"grads: expected the names {sorted(self.params)}, got "
                             f"{sorted(grads)}")
        self.t += 1
        for k, p in self.params.items():  # parameter arrays
            g = np.asarray(grads[k], dtype=p.dtype)
            if g.shape != p.shape:
                raise ValueError(f"grads[{k!r}]: expected shape {p.shape}, got {g.shape}")
            p -= adam_step(g, self.m[k], self.v[k], self.t, self.lr, self.betas, self.eps)


@dataclass(frozen=True)
class _StepDecay:
    lr: float
    at: tuple[int, ...]
    factor: float
    reset: bool

    def __call__(self, step: int) -> tuple[float, bool]:
        n = sum(step >= a for a in self.at)
        return self.lr * self.factor ** n, bool(self.reset and step in self.at)


@dataclass(frozen=True)
class _ExpDecay:
    lr: float
    lr_end: float
    n_steps: int

    def __call__(self, step: int) -> tuple[float, bool]:
        f = min(max(step / max(self.n_steps, 1), 0.0), 1.0)
        return self.lr * (self.lr_end / self.lr) ** f, False


def step_decay(lr: float, n_steps: int, *, at: float | tuple[float, ...] = 0.75,
               factor: float = 0.1, reset: bool = True) -> LRSchedule:
    """The tutorials' schedule: ``lr``, multiplied by ``factor`` at ``round(at * n_steps)``.

    Parameters
    ----------
    lr : float
        Initial learning rate.
    n_steps : int
        Number of steps of the fit.
    at : float or tuple of float
        Fractions of ``n_steps`` where the rate is multiplied by ``factor``.
    factor : float
        Multiplier (> 0).
    reset : bool
        Restart Adam's moments at each decay, as the tutorials do by creating a new optimizer.

    Examples
    --------
    >>> s = step_decay(1e-3, 100)
    >>> s(74), s(75)
    ((0.001, False), (0.0001, True))
    """
    lr = check_positive(lr, "lr")
    factor = check_positive(factor, "factor")
    fractions = (at,) if np.isscalar(at) else tuple(at)
    steps = tuple(round(float(a) * int(n_steps)) for a in fractions)
    return _StepDecay(lr, steps, factor, bool(reset))


def exponential_decay(lr: float, lr_end: float, n_steps: int) -> LRSchedule:
    """``lr * (lr_end / lr) ** (step / n_steps)``: a smooth decay from ``lr`` to ``lr_end``."""
    return _ExpDecay(check_positive(lr, "lr"), check_positive(lr_end, "lr_end"),
                     max(int(n_steps), 1))
