"""Solvers over a flat float64 parameter vector with ``(value, grad)`` objectives.

Four solvers share one contract:

* :func:`lbfgs_scipy` -- scipy's L-BFGS-B (unbounded), deterministic objectives;
* :func:`lbfgs_nlopt` -- nlopt's ``LD_LBFGS``, deterministic objectives;
* :func:`sgd` -- stochastic gradient descent with (heavy-ball) momentum, PyTorch's update rule;
* :func:`adam` -- Adam, PyTorch's update rule.

The objective is ``fun(x) -> (value, grad)`` with ``x`` and ``grad`` of shape (n,) float64. Every
solver:

* counts evaluations and iterations and measures its time on a :class:`~geofit.fit.history.Clock`
  (pass the fit's clock so that time spent in the callback under ``clock.paused()`` is excluded);
* honours ``max_iter``, ``max_eval`` and ``time_budget`` (seconds of this solve) and the clock's
  ``deadline`` (the fit's time budget, checked after every evaluation and, through
  :class:`~geofit.fit.history.TimeUp`, inside evaluations that call ``clock.check()``), and ends
  with a status from :data:`~geofit.fit.history.STATUSES` and a message;
* guards against non-finite objectives: when the value or the gradient is NaN or inf it stops with
  status ``"nonfinite"``; SGD and Adam also stop with ``"diverged"`` when the value exceeds
  ``divergence`` times the first one. In both cases the returned ``x`` is the finite point with
  the lowest objective seen (for the line-search solvers, the last accepted iterate; for SGD/Adam
  the best iterate, the iterates after it having been on the way to the blow-up). The returned
  ``x`` is never NaN;
* calls ``callback(info: StepInfo)`` once per iteration (nlopt, which has no iteration hook: once
  per evaluation that improves the best value); a callback returning True stops the solve with
  status ``"callback"``.

Exceptions raised by the objective or the callback propagate unchanged (with their message).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from types import SimpleNamespace
from typing import NamedTuple

import numpy as np

from .._validate import as_array, check_choice, check_positive
from ..nn.optim import adam_step, check_betas
from ._options import check_int
from .history import STATUSES, Clock, TimeUp, budget_status

__all__ = [
    "SOLVERS",
    "SolveResult",
    "StepInfo",
    "adam",
    "lbfgs_nlopt",
    "lbfgs_scipy",
    "minimize",
    "sgd",
]

Objective = Callable[[np.ndarray], "tuple[float, np.ndarray]"]

#: Solver names accepted by :func:`minimize` (the method names of :mod:`geofit.fit`).
SOLVERS = ("lbfgs", "lbfgs-nlopt", "sgd", "adam")


class StepInfo(NamedTuple):
    """What a callback sees after an iteration.

    Attributes
    ----------
    iteration : int
        Iterations completed in this solve (1 after the first).
    n_evaluations : int
        Objective evaluations so far in this solve.
    x : (n,) float64
        The current iterate (a read-only view: copy it to keep it).
    value : float
        Objective value at ``x``.
    seconds : float
        The clock's reading (solver time, paused intervals excluded).
    stage : int
        The fit's stage (level, round) of this solve (0 for a single solve).
    terms : dict or None
        The fit's unweighted loss terms at ``x``, when the fit reports them.
    metrics : dict or None
        The evaluator's metrics when this step was a checkpoint.
    """

    iteration: int
    n_evaluations: int
    x: np.ndarray
    value: float
    seconds: float
    stage: int = 0
    terms: dict | None = None
    metrics: dict | None = None


@dataclass
class SolveResult:
    """The outcome of one solve.

    Attributes
    ----------
    x : (n,) float64
        The final parameters (always finite).
    value : float
        Objective at ``x`` (inf if no finite value was ever seen; then ``x`` is ``x0``).
    status : str
        One of :data:`~geofit.fit.history.STATUSES`.
    message : str
        Why the solver stopped.
    n_iterations, n_evaluations : int
        Counts for this solve.
    seconds : float
        Solver time for this solve (paused intervals excluded).
    """

    x: np.ndarray
    value: float
    status: str
    message: str
    n_iterations: int
    n_evaluations: int
    seconds: float

    @property
    def converged(self) -> bool:
        return self.status == "converged"


class _Stop(Exception):
    """Internal: unwinds a solver with a status and a message."""

    def __init__(self, status: str, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


class _Tracker:
    """Wraps the objective: counts, checks finiteness and budgets, keeps the best finite point."""

    def __init__(self, fun, x0, *, clock, max_eval, time_budget, callback):
        self.fun = fun
        self.clock = clock
        self.t0 = clock.elapsed()
        self.max_eval = max_eval
        self.time_budget = time_budget
        self.callback = callback
        self.n_eval = 0
        self.n_iter = 0
        self.best_x = x0.copy()
        self.best_value = np.inf
        self.last_x = x0.copy()
        self.last_value = np.inf

    def seconds(self) -> float:
        return self.clock.elapsed() - self.t0

    def __call__(self, x: np.ndarray, owned: bool = False):
        """``fun(x)``, checked and counted; ``owned``: ``x`` is a fresh copy that nobody else
        changes, kept as it is (no second copy)."""
        if self.max_eval is not None and self.n_eval >= self.max_eval:
            raise _Stop("max_eval", f"stopped after {self.n_eval} evaluations (max_eval)")
        try:
            value, grad = self.fun(x)
        except TimeUp:  # the clock's deadline passed inside the evaluation
            raise _Stop("time_budget", self.time_up()) from None
        self.n_eval += 1
        value = float(value)
        grad = np.asarray(grad, dtype=np.float64)
        if grad.shape != x.shape:
            raise ValueError(f"fun: the gradient must have shape {x.shape}, got {grad.shape}")
        if not (np.isfinite(value) and np.all(np.isfinite(grad))):
            what = "value" if not np.isfinite(value) else "gradient"
            raise _Stop("nonfinite", f"the objective's {what} became non-finite at evaluation "
                                     f"{self.n_eval}; returning the best finite parameters")
        self.last_x = x if owned else np.array(x, dtype=np.float64)
        self.last_value = value
        if value < self.best_value:
            self.best_value = value
            self.best_x = self.last_x
        if (self.time_budget is not None and self.seconds() > self.time_budget) or \
                self.clock.over():
            raise _Stop("time_budget", self.time_up())
        return value, grad

    def time_up(self, budget: float | None = None) -> str:
        """The status message of a used-up time budget (``budget``: the solver's own, when the
        tracker was not given it)."""
        if self.clock.deadline is not None:
            words = self.clock.status_words(self.n_iter)
        else:
            words = budget_status(self.time_budget if self.time_budget is not None else budget,
                                  self.n_iter)
        return f"{words} ({self.seconds():.1f} s of this solve)"

    def iteration(self, x: np.ndarray, value: float) -> None:
        """Count an iteration and run the callback (raises _Stop when it asks to stop)."""
        self.n_iter += 1
        if self.callback is not None:
            xv = x.view()
            xv.flags.writeable = False
            info = StepInfo(self.n_iter, self.n_eval, xv, float(value), self.clock.elapsed())
            if self.callback(info):
                raise _Stop("callback", f"the callback asked to stop at iteration {self.n_iter}")

    def result(self, x, value, status, message) -> SolveResult:
        if x is None or not np.all(np.isfinite(x)) or not np.isfinite(value):
            x, value = self.best_x, self.best_value
        if status not in STATUSES:  # pragma: no cover - internal consistency
            raise RuntimeError(f"unknown status {status!r}")
        return SolveResult(np.array(x, dtype=np.float64), float(value), status, message,
                           self.n_iter, self.n_eval, self.seconds())


def _common(x0, counts, time_budget, clock):
    x0 = as_array(x0, "x0", (None,))
    if x0.size == 0:
        raise ValueError("x0: expected at least one parameter, got shape (0,)")
    for name, v in counts.items():
        if v is not None and (not isinstance(v, (int, np.integer)) or isinstance(v, bool)
                              or v < 1):
            raise ValueError(f"{name}: expected an integer >= 1 or None, got {v!r}")
    if time_budget is not None:
        time_budget = check_positive(time_budget, "time_budget")
    if clock is None:
        clock = Clock()
    elif not isinstance(clock, Clock):
        raise TypeError(f"clock: expected a geofit.fit.Clock, got {type(clock)!r}")
    return x0, clock, time_budget


def lbfgs_scipy(fun: Objective, x0, *, max_iter: int | None = 1000, max_eval: int | None = None,
                time_budget: float | None = None, ftol: float = 1e-10, gtol: float = 1e-9,
                memory: int = 10, max_line_search: int = 20,
                callback: Callable[[StepInfo], bool | None] | None = None,
                clock: Clock | None = None) -> SolveResult:
    """Minimise a deterministic objective with scipy's L-BFGS-B (no bounds).

    Parameters
    ----------
    fun : callable
        ``fun(x) -> (value, grad)``, ``x`` and ``grad`` (n,) float64. Must be deterministic
        (the line search compares values at nearby points).
    x0 : (n,) float64
        Starting point (finite).
    max_iter, max_eval : int or None
        Iteration and evaluation budgets (None: unlimited).
    time_budget : float or None
        Seconds of solver time (None: unlimited).
    ftol : float
        Stop when the relative decrease ``(f_k - f_{k+1}) / max(|f_k|, |f_{k+1}|, 1)`` falls
        below this (scipy's ``ftol``).
    gtol : float
        Stop when the largest gradient component falls below this (scipy's ``gtol``).
    memory : int
        Number of correction pairs kept (scipy's ``maxcor``).
    max_line_search : int
        Evaluations per line search (scipy's ``maxls``).
    callback : callable, optional
        ``callback(StepInfo) -> bool | None``, after every iteration; True stops the solve.
    clock : Clock, optional
        Clock to measure on (its paused intervals are excluded).

    Returns
    -------
    SolveResult
    """
    from scipy.optimize import minimize as sp_minimize

    x0, clock, time_budget = _common(x0, {"max_iter": max_iter, "max_eval": max_eval},
                                     time_budget, clock)
    ftol = check_positive(ftol, "ftol", strict=False)
    gtol = check_positive(gtol, "gtol", strict=False)
    memory = check_int(memory, "memory")
    tr = _Tracker(fun, x0, clock=clock, max_eval=max_eval, time_budget=time_budget,
                  callback=callback)

    def cb(intermediate_result):
        tr.iteration(intermediate_result.x, intermediate_result.fun)

    big = np.iinfo(np.int32).max
    options = {"maxiter": int(max_iter) if max_iter is not None else big,
               "maxfun": big, "ftol": ftol, "gtol": gtol, "maxcor": int(memory),
               "maxls": int(max_line_search)}
    core = _lbfgsb_core()
    try:
        if core is None:
            res = sp_minimize(tr, x0, jac=True, method="L-BFGS-B", callback=cb, options=options)
        else:
            res = _lbfgsb_loop(core, tr, x0, m=int(memory), ftol=ftol, gtol=gtol,
                               max_iter=options["maxiter"], max_line_search=int(max_line_search))
    except _Stop as stop:  # a line-search method's best point is its last accepted iterate
        return tr.result(tr.best_x, tr.best_value, stop.status, stop.message)
    msg = str(res.message)
    if res.status == 0:
        status, words = "converged", f"converged after {tr.n_iter} iterations"
    elif res.status == 1:
        status = "max_iter" if "ITERATIONS" in msg.upper() else "max_eval"
        words = f"completed {tr.n_iter} iterations"
    elif res.status == 2:
        status, words = "stalled", f"no further decrease after {tr.n_iter} iterations"
    else:  # pragma: no cover - scipy reserves other codes
        status, words = "failed", "failed"
    x, val = res.x, float(res.fun)
    if tr.best_value < val:  # the line search may end above a point it already visited
        x, val = tr.best_x, tr.best_value
    return tr.result(x, val, status, f"{words} (scipy L-BFGS-B: {msg.lower()})")


def _lbfgsb_core():
    """scipy's L-BFGS-B module (``scipy.optimize._lbfgsb_py``) when its compiled step
    ``_lbfgsb.setulb`` has the calling convention of scipy 1.15-1.17 (the C translation), else
    None (then :func:`scipy.optimize.minimize` runs the loop)."""
    import scipy  # kept local, as lbfgs_scipy's minimize: scipy.optimize loads when used
    from scipy.optimize import _lbfgsb_py

    try:
        version = tuple(int(v) for v in scipy.__version__.split(".")[:2])
    except ValueError:  # pragma: no cover - an unusual version string
        return None
    # setulb is private: used only in the versions whose calling convention we know (the C
    # translation of 1.15 to 1.17; tested against minimize here); other versions run minimize
    if not (1, 15) <= version < (1, 18) or not all(hasattr(_lbfgsb_py, name) for name in (
            "_lbfgsb", "status_messages", "task_messages")):
        return None  # pragma: no cover - another scipy: minimize runs the loop
    return _lbfgsb_py


def _lbfgsb_loop(core, tr: _Tracker, x0: np.ndarray, *, m: int, ftol: float, gtol: float,
                 max_iter: int, max_line_search: int):
    """scipy's ``_minimize_lbfgsb`` loop without bounds, driving its compiled step directly.

    The same calls of ``setulb`` with the same arguments, so the same iterates bit for bit
    (tested against :func:`scipy.optimize.minimize`), without the wrapper's copies and
    comparisons of ``x`` and ``g`` at every evaluation (``ScalarFunction``, ``MemoizeJac``,
    ``g.astype``): at 948,148 parameters, 25-30 ms of main-thread CPU per evaluation beyond
    ``setulb`` and the objective, against ~9 ms here with the tracker (measured). ``tr`` gets
    a fresh copy of ``x`` (scipy's wrapper also hands the objective a copy), is not called
    again at the point it saw last (scipy's ``ScalarFunction`` keeps that value too) and the
    callback runs at every new iterate. Returns an object with scipy's ``x``, ``fun``,
    ``status`` (0 converged, 1 iteration limit, 2 other stop) and ``message``.
    """
    n = x0.size
    x = np.array(x0, dtype=np.float64)
    f = np.array(0.0, dtype=np.float64)
    g = np.zeros(n)
    lower, upper, nbd = np.zeros(n), np.zeros(n), np.zeros(n, np.int32)  # no bounds
    wa = np.zeros(2 * m * n + 5 * n + 11 * m * m + 8 * m)
    iwa = np.zeros(3 * n, np.int32)
    task, ln_task = np.zeros(2, np.int32), np.zeros(2, np.int32)
    lsave, isave, dsave = np.zeros(4, np.int32), np.zeros(44, np.int32), np.zeros(29)
    factr = ftol / np.finfo(float).eps
    n_iter, last, g_last = 0, None, None
    while True:  # one call per evaluation or new iterate, as scipy's
        core._lbfgsb.setulb(m, x, lower, upper, nbd, f, g, factr, gtol, wa, iwa, task, lsave,
                            isave, dsave, max_line_search, ln_task)
        if task[0] == 3:  # f and g wanted at x (at the last point evaluated: kept, as scipy)
            if last is None or not np.array_equal(x, last):
                last = x.copy()
                f, g_last = tr(last, owned=True)
            np.copyto(g, g_last)  # setulb may write into g: it gets a copy, as scipy's
        elif task[0] == 1:  # a new iterate
            n_iter += 1
            tr.iteration(x, f)
            if n_iter >= max_iter:
                task[0], task[1] = 5, 504
        else:
            break
    status = 0 if task[0] == 4 else (1 if n_iter >= max_iter else 2)
    message = core.status_messages[task[0]] + ": " + core.task_messages[task[1]]
    return SimpleNamespace(x=x, fun=float(f), status=status, message=message)


_NLOPT_STATUS = {1: ("converged", "success"), 2: ("converged", "stopval reached"),
                 3: ("converged", "relative/absolute ftol reached"),
                 4: ("converged", "relative/absolute xtol reached"),
                 5: ("max_eval", "maxeval reached"), 6: ("time_budget", "maxtime reached")}


def lbfgs_nlopt(fun: Objective, x0, *, max_eval: int | None = 1000,
                time_budget: float | None = None, ftol_rel: float = 1e-10,
                xtol_rel: float = 0.0, memory: int = 10,
                callback: Callable[[StepInfo], bool | None] | None = None,
                clock: Clock | None = None) -> SolveResult:
    """Minimise a deterministic objective with nlopt's ``LD_LBFGS``.

    nlopt has no iteration hook, so an "iteration" here is an evaluation that lowers the best
    value so far; ``callback`` runs after each of them.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> (value, grad)``, ``x`` and ``grad`` (n,) float64, deterministic.
    x0 : (n,) float64
        Starting point (finite).
    max_eval : int or None
        Evaluation budget.
    time_budget : float or None
        Seconds of solver time (measured on ``clock``, so paused intervals do not count).
    ftol_rel, xtol_rel : float
        nlopt's relative tolerances on the value and on the parameters (0 disables).
    memory : int
        nlopt's vector storage (number of L-BFGS correction pairs).
    callback : callable, optional
        ``callback(StepInfo) -> bool | None``; True stops the solve.
    clock : Clock, optional
        Clock to measure on.

    Returns
    -------
    SolveResult
        nlopt's "roundoff limited" ending is reported as ``"stalled"``, its generic failure as
        ``"failed"`` (the best point found is returned in both cases).
    """
    import nlopt

    x0, clock, time_budget = _common(x0, {"max_eval": max_eval}, time_budget, clock)
    ftol_rel = check_positive(ftol_rel, "ftol_rel", strict=False)
    xtol_rel = check_positive(xtol_rel, "xtol_rel", strict=False)
    memory = check_int(memory, "memory")
    tr = _Tracker(fun, x0, clock=clock, max_eval=max_eval, time_budget=time_budget,
                  callback=callback)
    opt = nlopt.opt(nlopt.LD_LBFGS, x0.size)
    state = {"stop": None, "error": None}

    def f(x, grad):
        if state["stop"] is not None or state["error"] is not None:
            opt.force_stop()
            if grad.size:
                grad[:] = 0.0
            return float(tr.best_value) if np.isfinite(tr.best_value) else 0.0
        try:
            best_before = tr.best_value
            value, g = tr(x)
            if grad.size:
                grad[:] = g
            if value < best_before:
                tr.iteration(x, value)
            return value
        except _Stop as stop:
            state["stop"] = stop
        except Exception as exc:  # noqa: BLE001 - re-raised after nlopt returns (it drops it)
            state["error"] = exc
        opt.force_stop()
        if grad.size:
            grad[:] = 0.0
        return float(tr.best_value) if np.isfinite(tr.best_value) else 0.0

    opt.set_min_objective(f)
    opt.set_ftol_rel(ftol_rel)
    opt.set_xtol_rel(xtol_rel)
    opt.set_vector_storage(int(memory))
    try:
        opt.optimize(x0.copy())
        code = opt.last_optimize_result()
        status, why = _NLOPT_STATUS.get(code, ("failed", f"result code {code}"))
        message = f"nlopt LD_LBFGS: {why}"
    except nlopt.ForcedStop:
        status, message = "callback", "nlopt LD_LBFGS: forced stop"
    except nlopt.RoundoffLimited:
        status, message = "stalled", ("nlopt LD_LBFGS: roundoff limited (no further decrease "
                                      "possible in floating point)")
    except RuntimeError as exc:
        status, message = "failed", f"nlopt LD_LBFGS: generic failure ({exc or 'no detail'})"
    if state["error"] is not None:
        raise state["error"]
    if state["stop"] is not None:
        status, message = state["stop"].status, state["stop"].message
    return tr.result(tr.best_x, tr.best_value, status, message)


def _first_order(fun, x0, step_rule, *, n_iter, time_budget, divergence, callback, clock,
                 name):
    if n_iter is None:
        raise ValueError("n_iter: expected an integer >= 1, got None")
    x0, clock, time_budget = _common(x0, {"n_iter": n_iter}, time_budget, clock)
    divergence = check_positive(divergence, "divergence")
    tr = _Tracker(fun, x0, clock=clock, max_eval=None, time_budget=None, callback=callback)
    x = x0.copy()
    first = None
    state = step_rule.init(x)
    try:
        for _ in range(int(n_iter)):  # iterations
            value, grad = tr(x)
            if first is None:
                first = max(abs(value), np.finfo(float).tiny)
            elif value > divergence * first:
                raise _Stop("diverged", f"{name}: the objective reached {value:.3g}, more than "
                                        f"{divergence:g} times its first value {first:.3g}, at "
                                        f"step {tr.n_iter + 1}; returning the best finite "
                                        f"parameters")
            step = step_rule.step(state, grad)
            x_new = x - step
            if not np.all(np.isfinite(x_new)):
                raise _Stop("nonfinite", f"{name}: the update became non-finite at step "
                                         f"{tr.n_iter + 1}; returning the best finite parameters")
            x = x_new
            tr.iteration(x, value)
            if (time_budget is not None and tr.seconds() > time_budget) or clock.over():
                raise _Stop("time_budget", f"{name}: {tr.time_up(time_budget)}")
    except _Stop as stop:
        if stop.status in ("nonfinite", "diverged"):
            return tr.result(tr.best_x, tr.best_value, stop.status, stop.message)
        return tr.result(x, tr.last_value, stop.status, stop.message)
    return tr.result(x, tr.last_value, "max_iter", f"{name}: completed {tr.n_iter} steps")


class _SGDRule:
    def __init__(self, lr, momentum, nesterov):
        self.lr, self.momentum, self.nesterov = lr, momentum, nesterov

    def init(self, x):
        return {"buf": None}

    def step(self, state, g):
        # PyTorch's SGD (dampening 0): buf = momentum * buf + g; x -= lr * buf
        if self.momentum == 0.0:
            return self.lr * g
        buf = g.copy() if state["buf"] is None else self.momentum * state["buf"] + g
        state["buf"] = buf
        d = g + self.momentum * buf if self.nesterov else buf
        return self.lr * d


class _AdamRule:
    def __init__(self, lr, betas, eps):
        self.lr, self.betas, self.eps = lr, betas, eps

    def init(self, x):
        return {"m": np.zeros_like(x), "v": np.zeros_like(x), "t": 0}

    def step(self, state, g):
        state["t"] += 1  # the rule is geofit.nn.optim's (PyTorch's Adam)
        return adam_step(g, state["m"], state["v"], state["t"], self.lr, self.betas, self.eps)


def sgd(fun: Objective, x0, *, lr: float = 1.0, momentum: float = 0.9, nesterov: bool = False,
        n_iter: int = 2000, time_budget: float | None = None, divergence: float = 1e8,
        callback: Callable[[StepInfo], bool | None] | None = None,
        clock: Clock | None = None) -> SolveResult:
    """Stochastic gradient descent with momentum (PyTorch's ``torch.optim.SGD``, dampening 0).

    ``buf = momentum * buf + g`` (``buf = g`` at the first step), ``x -= lr * buf``.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> (value, grad)``; may be stochastic (one call per step).
    x0 : (n,) float64
        Starting point.
    lr : float
        Learning rate (> 0).
    momentum : float
        Momentum in [0, 1).
    nesterov : bool
        Nesterov momentum (PyTorch's variant).
    n_iter : int
        Number of steps.
    time_budget : float or None
        Seconds of solver time.
    divergence : float
        Stop with ``"diverged"`` when the value exceeds this multiple of the first value.
    callback : callable, optional
        ``callback(StepInfo) -> bool | None`` after each step (``info.value`` is the objective
        at the point before the step, as in a PyTorch training loop).
    clock : Clock, optional

    Returns
    -------
    SolveResult
        Status ``"max_iter"`` after ``n_iter`` steps (a stochastic method has no convergence
        test).
    """
    lr = check_positive(lr, "lr")
    momentum = float(momentum)
    if not 0.0 <= momentum < 1.0:
        raise ValueError(f"momentum: expected a number in [0, 1), got {momentum!r}")
    return _first_order(fun, x0, _SGDRule(lr, momentum, bool(nesterov)), n_iter=n_iter,
                        time_budget=time_budget, divergence=divergence, callback=callback,
                        clock=clock, name="SGD")


def adam(fun: Objective, x0, *, lr: float = 1e-3, betas: tuple[float, float] = (0.9, 0.999),
         eps: float = 1e-8, n_iter: int = 1000, time_budget: float | None = None,
         divergence: float = 1e8, callback: Callable[[StepInfo], bool | None] | None = None,
         clock: Clock | None = None) -> SolveResult:
    """Adam (PyTorch's ``torch.optim.Adam``, no weight decay).

    Parameters
    ----------
    fun : callable
        ``fun(x) -> (value, grad)``; may be stochastic.
    x0 : (n,) float64
        Starting point.
    lr : float
        Step size (> 0).
    betas : (2,) float
        Moment decay rates in [0, 1).
    eps : float
        Added to the bias-corrected ``sqrt(v)``.
    n_iter, time_budget, divergence, callback, clock
        As in :func:`sgd`.

    Returns
    -------
    SolveResult
    """
    lr = check_positive(lr, "lr")
    eps = check_positive(eps, "eps")
    return _first_order(fun, x0, _AdamRule(lr, check_betas(betas), eps), n_iter=n_iter,
                        time_budget=time_budget, divergence=divergence, callback=callback,
                        clock=clock, name="Adam")


def minimize(fun: Objective, x0, method: str = "lbfgs", **options) -> SolveResult:
    """Dispatch to one of :data:`SOLVERS` by name.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> (value, grad)``.
    x0 : (n,) float64
        Starting point.
    method : str
        ``"lbfgs"`` (scipy), ``"lbfgs-nlopt"``, ``"sgd"`` or ``"adam"``.
    **options
        Keyword options of the chosen solver.

    Examples
    --------
    >>> import numpy as np
    >>> res = minimize(lambda x: (float(x @ x), 2 * x), np.ones(3))
    >>> res.status, bool(np.allclose(res.x, 0))
    ('converged', True)
    """
    check_choice(method, "method", SOLVERS)
    solver = {"lbfgs": lbfgs_scipy, "lbfgs-nlopt": lbfgs_nlopt, "sgd": sgd, "adam": adam}[method]
    return solver(fun, x0, **options)
