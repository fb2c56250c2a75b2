"""Fitting: objectives composed from losses by the chain rule, solvers, histories.

* :mod:`geofit.fit.history` -- :class:`Clock`, :class:`FitHistory`, :class:`FitResult`, shared by
  every fit in geofit.
* :mod:`geofit.fit.solvers` -- scipy L-BFGS-B, nlopt LD_LBFGS, SGD with momentum and Adam over a
  flat float64 vector, with budgets, statuses and non-finite guards.
* :mod:`geofit.fit.mesh` -- :func:`fit_mesh` (PyTorch3D's deform tutorial and faster solvers),
  the large-steps parameterisation and coarse-to-fine.
"""
from __future__ import annotations

from .history import CONVERGED_STATUSES, STATUSES, Clock, FitHistory, FitResult
from .mesh import (
    FINE_WEIGHTS,
    METHODS,
    RECIPES,
    TUTORIAL_WEIGHTS,
    CoarseToFine,
    LargeSteps,
    MeshFitResult,
    MeshObjective,
    fit_mesh,
)
from .solvers import SOLVERS, SolveResult, StepInfo, adam, lbfgs_nlopt, lbfgs_scipy, minimize, sgd

__all__ = [
    "CONVERGED_STATUSES",
    "FINE_WEIGHTS",
    "METHODS",
    "RECIPES",
    "SOLVERS",
    "STATUSES",
    "TUTORIAL_WEIGHTS",
    "Clock",
    "CoarseToFine",
    "FitHistory",
    "FitResult",
    "LargeSteps",
    "MeshFitResult",
    "MeshObjective",
    "SolveResult",
    "StepInfo",
    "adam",
    "fit_mesh",
    "lbfgs_nlopt",
    "lbfgs_scipy",
    "minimize",
    "sgd",
]
