"""Fitting: objectives composed from losses by the chain rule, solvers, histories.

* :mod:`geofit.fit.history` -- :class:`Clock`, :class:`FitHistory`, :class:`FitResult`, shared by
  every fit in geofit.
* :mod:`geofit.fit.solvers` -- scipy L-BFGS-B, nlopt LD_LBFGS, SGD with momentum and Adam over a
  flat float64 vector, with budgets, statuses and non-finite guards.
"""
from __future__ import annotations

from .history import CONVERGED_STATUSES, STATUSES, Clock, FitHistory, FitResult
from .solvers import SOLVERS, SolveResult, StepInfo, adam, lbfgs_nlopt, lbfgs_scipy, minimize, sgd

__all__ = [
    "CONVERGED_STATUSES",
    "SOLVERS",
    "STATUSES",
    "Clock",
    "FitHistory",
    "FitResult",
    "SolveResult",
    "StepInfo",
    "adam",
    "lbfgs_nlopt",
    "lbfgs_scipy",
    "minimize",
    "sgd",
]
