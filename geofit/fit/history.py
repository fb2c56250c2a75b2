"""What every fit in geofit records and returns: a clock, a history, a result.

* :class:`Clock` measures the solver's wall time and can be paused, so that work done for the
  observer (accuracy metrics at checkpoints, progress bars, plotting) is not charged to the solver;
  it also holds the fit's time budget (``deadline``), which counts everything the fit does on its
  own, and which every long stage checks (:meth:`Clock.check`, :meth:`Clock.remaining`).
* :class:`FitHistory` keeps one row per recorded step (step, seconds, loss, each loss term,
  number of parameters, stage) and, at checkpoints, the accuracy metrics.
* :class:`FitResult` is the common result of a fit: its status (from :data:`STATUSES`), the
  message that explains it, the history, and the size of the problem. Workflow-specific results
  (the fitted mesh, texture, volume, network) subclass it.
"""
from __future__ import annotations

import json
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._json import json_safe as _json_safe
from .._atomic import write_text

__all__ = ["CONVERGED_STATUSES", "STATUSES", "Clock", "FitHistory", "FitResult", "TimeUp",
           "budget_status"]

#: Every status a solver or a fit can end with, and what it means.
STATUSES: dict[str, str] = {
    "converged": "a convergence test was met (relative decrease, gradient norm or step size)",
    "max_iter": "stopped: the iteration budget was used up",
    "max_eval": "stopped: the evaluation budget was used up",
    "time_budget": "stopped: the time budget was used up",
    "stalled": "stopped: the line search could not decrease the objective any more",
    "callback": "stopped: the callback asked to stop",
    "nonfinite": "stopped: the objective or its gradient became NaN or inf; "
                 "the last finite parameters are returned",
    "diverged": "stopped: the objective grew beyond the divergence threshold; "
                "the best finite parameters are returned",
    "failed": "the solver failed; the message says why",
}

#: Statuses counted as a successful solve.
CONVERGED_STATUSES = frozenset({"converged"})


class TimeUp(Exception):
    """Raised by :meth:`Clock.check` inside a long evaluation or stage once the clock has passed
    its ``deadline`` (the fit's time budget); the solvers turn it into status ``"time_budget"``,
    and a fit's own stages (a visual hull, a colour solve, held-out renders) into their
    fallbacks."""


class Clock:
    """The clock of one fit: the solver's time, the time budget's time and the wall time.

    Three readings, all in seconds since the clock was made:

    * :meth:`wall` -- everything;
    * :meth:`elapsed` -- the solver's time: every :meth:`paused` interval excluded (metric
      checkpoints, progress bars, the caller's callback), the figure of curves and of
      ``FitResult.seconds``;
    * :meth:`budget_elapsed` -- what the time budget counts: the wall time minus only the
      intervals paused with ``caller=True`` (time spent in the caller's own code, the
      ``evaluator`` and ``callback`` a user hands in, which a fit cannot bound). The fit's own
      work (its set-up, its default evaluation, held-out renders, final metrics) counts.

    ``deadline`` (seconds of :meth:`budget_elapsed`, None: none) is the fit's time budget. Long
    stages call :meth:`check` between their chunks (views, passes, batches), so that a budget
    is kept within a chunk's time, not only between solver steps; :meth:`remaining` is what a
    stage may still spend.

    Examples
    --------
    >>> clock = Clock(deadline=60.0)
    >>> with clock.paused():
    ...     pass  # metric evaluation: not solver time, but counted by the budget
    >>> with clock.paused(caller=True):
    ...     pass  # the user's callback: counted by neither
    >>> clock.elapsed() <= clock.budget_elapsed() <= clock.wall()
    True
    >>> 0.0 < clock.remaining() <= 60.0
    True
    """

    def __init__(self, deadline: float | None = None) -> None:
        self._start = time.perf_counter()
        self._cpu_start = time.process_time()
        self._paused_total = 0.0
        self._cpu_paused_total = 0.0
        self._paused_at: float | None = None
        self._cpu_paused_at: float | None = None
        self._caller_total = 0.0
        self._caller_at: float | None = None
        self.deadline: float | None = deadline
        self.budget: float | None = deadline  # the fit's whole budget (deadline: a stage's)

    def wall(self) -> float:
        """Wall-clock seconds since construction, nothing excluded."""
        return time.perf_counter() - self._start

    def budget_elapsed(self) -> float:
        """Seconds counted by the time budget: :meth:`wall` minus the intervals paused with
        ``caller=True``."""
        now = self._caller_at if self._caller_at is not None else time.perf_counter()
        return now - self._start - self._caller_total

    def remaining(self) -> float:
        """Seconds of the budget left (``inf`` without a deadline; negative once past it)."""
        if self.deadline is None:
            return float("inf")
        return self.deadline - self.budget_elapsed()

    def over(self) -> bool:
        """True once the budget's time has passed the ``deadline``."""
        return self.deadline is not None and self.budget_elapsed() > self.deadline

    def check(self) -> None:
        """Raise :class:`TimeUp` when the clock has passed its ``deadline`` (not while the
        caller's code runs: a pause with ``caller=True``)."""
        if self._caller_at is None and self.over():
            raise TimeUp(self.status_words())

    def status_words(self, steps: int | None = None) -> str:
        """``"reached the time budget of 30 s[ after N steps]"``, or, inside :meth:`until`,
        ``"reached the end of this stage's share (27 s) of the time budget of 30 s"``."""
        after = "" if steps is None else f" after {steps} steps"
        if self.deadline is not None and self.budget is not None and \
                self.deadline < self.budget:
            return (f"reached the end of this stage's share ({self.deadline:.3g} s) of the "
                    f"time budget of {self.budget:g} s{after}")
        if steps is None:
            return f"reached the time budget of {self.deadline:g} s"
        return budget_status(self.deadline, steps)

    @contextmanager
    def until(self, seconds: float | None) -> Iterator[None]:
        """Context manager: a stage's own deadline (budget seconds), when earlier than the
        fit's, for the stage's solves and checks; the fit's deadline is back afterwards.
        A stage that must leave time to the stages after it runs inside
        ``clock.until(clock.deadline - reserve)``."""
        saved = self.deadline
        if seconds is not None and (saved is None or seconds < saved):
            self.deadline = float(seconds)
        try:
            yield
        finally:
            self.deadline = saved

    def elapsed(self) -> float:
        """Solver seconds: wall-clock seconds since construction, minus the paused intervals."""
        now = self._paused_at if self._paused_at is not None else time.perf_counter()
        return now - self._start - self._paused_total

    def cpu_elapsed(self) -> float:
        """CPU seconds of this process (all its threads) since construction, minus the paused
        intervals: less sensitive than :meth:`elapsed` to other processes sharing the cores."""
        now = self._cpu_paused_at if self._cpu_paused_at is not None else time.process_time()
        return now - self._cpu_start - self._cpu_paused_total

    def cpu_total(self) -> float:
        """CPU seconds of this process since construction, nothing excluded (beside
        :meth:`wall`)."""
        return time.process_time() - self._cpu_start

    @property
    def is_paused(self) -> bool:
        return self._paused_at is not None

    @contextmanager
    def paused(self, caller: bool = False) -> Iterator[None]:
        """Context manager: time spent inside is excluded from :meth:`elapsed` (re-entrant);
        with ``caller=True`` (the caller's evaluator or callback) from :meth:`budget_elapsed`
        too."""
        outer = self._paused_at is None
        if outer:
            self._paused_at = time.perf_counter()
            self._cpu_paused_at = time.process_time()
        mine = caller and self._caller_at is None
        if mine:
            self._caller_at = time.perf_counter()
        try:
            yield
        finally:
            if mine:
                self._caller_total += time.perf_counter() - self._caller_at
                self._caller_at = None
            if outer:
                self._paused_total += time.perf_counter() - self._paused_at
                self._cpu_paused_total += time.process_time() - self._cpu_paused_at
                self._paused_at = self._cpu_paused_at = None


def budget_status(deadline: float, steps: int, what: str = "steps") -> str:
    """The words of a used-up time budget: ``"reached the time budget of 30 s after 412
    steps"``."""
    return f"reached the time budget of {deadline:g} s after {steps} {what}"


def _as_float(value, name: str) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {value!r}") from None


class FitHistory:
    """The trace of a fit: one row per recorded step, metrics at checkpoints.

    Rows hold the step number (objective evaluations or iterations, as the fit documents), the
    solver's seconds (see :class:`Clock`), the total loss, each weighted loss term, the number of
    free parameters and the stage (coarse-to-fine level or sample redraw). The set of term names
    is fixed by the first row, and the set of metric names by the first checkpoint, so the
    columns of :meth:`as_arrays` are complete (no placeholder values).

    Examples
    --------
    >>> h = FitHistory()
    >>> h.record(0, 0.0, 2.0, {"chamfer": 1.5, "edge": 0.5}, n_params=6)
    >>> h.record(1, 0.1, 1.0, {"chamfer": 0.8, "edge": 0.2}, {"chamfer_l2": 0.3}, n_params=6)
    >>> h.as_arrays()["terms"]["chamfer"]
    array([1.5, 0.8])
    >>> h.as_arrays()["metrics"]["chamfer_l2"]
    array([0.3])
    """

    def __init__(self) -> None:
        self.steps: list[int] = []
        self.seconds: list[float] = []
        self.loss: list[float] = []
        self.terms: dict[str, list[float]] = {}
        self.n_params: list[int] = []
        self.stage: list[int] = []
        self.checkpoints: list[dict[str, Any]] = []
        self.events: list[dict[str, Any]] = []
        self._metric_names: tuple[str, ...] | None = None

    def __len__(self) -> int:
        return len(self.steps)

    def __repr__(self) -> str:
        last = f", last loss={self.loss[-1]:.4g} at {self.seconds[-1]:.3g} s" if self.loss else ""
        return (f"FitHistory({len(self)} rows, {len(self.checkpoints)} checkpoints, "
                f"terms={list(self.terms)}{last})")

    def record(self, step: int, seconds: float, loss: float,
               terms: Mapping[str, float] | None = None,
               metrics: Mapping[str, float] | None = None, *,
               n_params: int = 0, stage: int = 0) -> None:
        """Append one row, and a checkpoint when ``metrics`` is given.

        Parameters
        ----------
        step : int
            Step number (non-decreasing).
        seconds : float
            Solver time at this step (non-decreasing).
        loss : float
            Total objective value (may be inf/NaN when the solver reports a non-finite step;
            such rows are kept so the failure is visible).
        terms : mapping str -> float, optional
            Weighted loss terms; the names must match those of the first row.
        metrics : mapping str -> float, optional
            Accuracy metrics at this step (a checkpoint); names must match the first checkpoint.
        n_params : int
            Number of free parameters at this step.
        stage : int
            Stage index (coarse-to-fine level, sample redraw).

        Raises
        ------
        ValueError
            If step or seconds decrease, or the term or metric names change.
        """
        step = int(step)
        seconds = _as_float(seconds, "seconds")
        if self.steps and step < self.steps[-1]:
            raise ValueError(f"step: expected >= {self.steps[-1]} (non-decreasing), got {step}")
        if self.seconds and seconds < self.seconds[-1]:
            raise ValueError(
                f"seconds: expected >= {self.seconds[-1]} (non-decreasing), got {seconds}")
        terms = dict(terms or {})
        if not self.steps:
            self.terms = {k: [] for k in terms}
        elif set(terms) != set(self.terms):
            raise ValueError(f"terms: expected the names {sorted(self.terms)}, got {sorted(terms)}")
        self.steps.append(step)
        self.seconds.append(seconds)
        self.loss.append(_as_float(loss, "loss"))
        for k, v in terms.items():
            self.terms[k].append(_as_float(v, f"terms[{k!r}]"))
        self.n_params.append(int(n_params))
        self.stage.append(int(stage))
        if metrics is not None:
            self.checkpoint(step, seconds, metrics)

    def checkpoint(self, step: int, seconds: float, metrics: Mapping[str, float]) -> None:
        """Record accuracy metrics at ``step`` (see :meth:`record`)."""
        metrics = {k: _as_float(v, f"metrics[{k!r}]") for k, v in dict(metrics).items()}
        if self._metric_names is None:
            self._metric_names = tuple(metrics)
        elif set(metrics) != set(self._metric_names):
            raise ValueError(f"metrics: expected the names {sorted(self._metric_names)}, "
                             f"got {sorted(metrics)}")
        if self.checkpoints and seconds < self.checkpoints[-1]["seconds"]:
            raise ValueError("seconds: checkpoints must not go back in time")
        self.checkpoints.append({"step": int(step), "seconds": float(seconds), **metrics})

    def note(self, step: int, seconds: float, message: str, **info) -> None:
        """Record an event (stage change, subdivision, sample redraw) with a message."""
        self.events.append({"step": int(step), "seconds": float(seconds),
                            "message": str(message), **info})

    @property
    def metric_names(self) -> tuple[str, ...]:
        return self._metric_names or ()

    def last_metrics(self) -> dict[str, float] | None:
        """The metrics of the last checkpoint, or None."""
        if not self.checkpoints:
            return None
        c = self.checkpoints[-1]
        return {k: c[k] for k in self.metric_names}

    def as_arrays(self) -> dict[str, Any]:
        """Columns as numpy arrays.

        Returns
        -------
        dict
            ``step`` (n,) int64, ``seconds`` (n,) float64, ``loss`` (n,) float64,
            ``n_params`` (n,) int64, ``stage`` (n,) int64, ``terms`` {name: (n,) float64},
            ``checkpoint_step`` (c,) int64, ``checkpoint_seconds`` (c,) float64 and
            ``metrics`` {name: (c,) float64}.
        """
        return {
            "step": np.asarray(self.steps, dtype=np.int64),
            "seconds": np.asarray(self.seconds, dtype=np.float64),
            "loss": np.asarray(self.loss, dtype=np.float64),
            "n_params": np.asarray(self.n_params, dtype=np.int64),
            "stage": np.asarray(self.stage, dtype=np.int64),
            "terms": {k: np.asarray(v, dtype=np.float64) for k, v in self.terms.items()},
            "checkpoint_step": np.asarray([c["step"] for c in self.checkpoints], dtype=np.int64),
            "checkpoint_seconds": np.asarray([c["seconds"] for c in self.checkpoints],
                                             dtype=np.float64),
            "metrics": {k: np.asarray([c[k] for c in self.checkpoints], dtype=np.float64)
                        for k in self.metric_names},
        }

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (non-finite floats become the strings "nan", "inf", "-inf")."""
        return _json_safe({
            "step": self.steps, "seconds": self.seconds, "loss": self.loss,
            "n_params": self.n_params, "stage": self.stage, "terms": self.terms,
            "checkpoints": self.checkpoints, "events": self.events,
        })

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> FitHistory:
        """Rebuild a history written by :meth:`to_dict`."""
        h = cls()
        terms = d.get("terms", {})
        for i, step in enumerate(d["step"]):
            h.record(step, float(d["seconds"][i]), float(d["loss"][i]),
                     {k: float(v[i]) for k, v in terms.items()},
                     n_params=d["n_params"][i], stage=d["stage"][i])
        for c in d.get("checkpoints", []):
            h.checkpoint(c["step"], c["seconds"],
                         {k: float(v) for k, v in c.items() if k not in ("step", "seconds")})
        h.events = [dict(e) for e in d.get("events", [])]
        return h

    def to_json(self, path=None, **kwargs) -> str:
        """The history as JSON text; also written to ``path`` when given."""
        text = json.dumps(self.to_dict(), **kwargs)
        if path is not None:
            write_text(path, text)
        return text


@dataclass(kw_only=True)
class FitResult:
    """The common result of every geofit fit.

    Attributes
    ----------
    status : str
        One of :data:`STATUSES` (``"converged"``, ``"max_iter"``, ``"time_budget"``, ...).
    message : str
        A human-readable explanation of the status (solver message, stopping reason).
    history : FitHistory
        The trace of the fit.
    n_params : int
        Number of free parameters at the end.
    seconds : float
        Solver wall time (observer work such as metric checkpoints excluded).
    cpu_seconds : float
        Solver CPU time of the process over the same intervals (all threads).
    wall_seconds : float
        Wall time of the whole call, everything included (what a time budget bounds, plus the
        time spent in the caller's evaluator and callback).
    total_cpu_seconds : float
        CPU time of the process over the whole call (beside ``wall_seconds``; above it when
        both cores work, below it when other processes share them).
    n_iterations : int
        Iterations (or SGD/Adam steps) over all stages.
    n_evaluations : int
        Objective evaluations over all stages.
    method : str
        The method (solver) used, in the vocabulary of :mod:`geofit.fit` (``"lbfgs"``,
        ``"lbfgs-nlopt"``, ``"adam"``, ``"sgd"``; ``fit_mesh_to_views``: silhouette and textured
        methods joined by ``"+"``).
    recipe : str
        The recipe the settings started from (``"default"``, ``"tutorial"``, ...).
    init : object
        The starting model the fit used (the initial mesh; the initial network; None when the
        fit builds its own start, as ``fit_volume`` does from the visual hull).
    """

    status: str
    message: str = ""
    history: FitHistory = field(default_factory=FitHistory)
    n_params: int = 0
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    wall_seconds: float = 0.0
    total_cpu_seconds: float = 0.0
    n_iterations: int = 0
    n_evaluations: int = 0
    method: str = ""
    recipe: str = ""
    init: Any = None

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status: expected one of {tuple(STATUSES)}, got {self.status!r}")

    @property
    def converged(self) -> bool:
        """True when the status is ``"converged"``."""
        return self.status in CONVERGED_STATUSES

    @property
    def ok(self) -> bool:
        """True unless the fit failed or produced a non-finite/diverged objective."""
        return self.status not in ("failed", "nonfinite", "diverged")

    def summary(self) -> dict[str, Any]:
        """Status, message, sizes, time and the last metrics, JSON-ready."""
        return _json_safe({
            "status": self.status, "message": self.message, "method": self.method,
            "recipe": self.recipe, "n_params": self.n_params,
            "seconds": self.seconds, "cpu_seconds": self.cpu_seconds,
            "wall_seconds": self.wall_seconds, "total_cpu_seconds": self.total_cpu_seconds,
            "n_iterations": self.n_iterations,
            "n_evaluations": self.n_evaluations,
            "final_loss": self.history.loss[-1] if self.history.loss else None,
            "metrics": self.history.last_metrics(),
        })

    def to_dict(self) -> dict[str, Any]:
        """:meth:`summary` plus the full history."""
        d = self.summary()
        d["history"] = self.history.to_dict()
        return d
