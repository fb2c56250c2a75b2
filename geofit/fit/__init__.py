"""Fitting: objectives composed from losses by the chain rule, solvers, histories.

* :mod:`geofit.fit.history` -- :class:`Clock`, :class:`FitHistory`, :class:`FitResult`, shared by
  every fit in geofit.
* :mod:`geofit.fit.solvers` -- scipy L-BFGS-B, nlopt LD_LBFGS, SGD with momentum and Adam over a
  flat float64 vector, with budgets, statuses and non-finite guards.
* :mod:`geofit.fit.mesh` -- :func:`fit_mesh` (PyTorch3D's deform tutorial and faster solvers),
  the large-steps parameterisation and coarse-to-fine.
* :mod:`geofit.fit.adaptive` -- :func:`fit_mesh_adaptive`, the default of ``fit_mesh(None,
  target)``: initial mesh from the data (:mod:`geofit.fit.init`), error-driven remeshing.
* :mod:`geofit.fit.views` -- :func:`fit_mesh_to_views`: a mesh and its colours fitted to
  multi-view silhouettes and images (tutorial 4).
* :mod:`geofit.fit.volume` -- :func:`fit_volume`: a voxel grid of densities and colours fitted by
  emission-absorption raymarching (tutorial 5).
* :mod:`geofit.fit.nerf` -- :func:`fit_nerf`: a neural radiance field (tutorial 6).
"""
from __future__ import annotations

from .adaptive import ADAPTIVE_WEIGHTS, AdaptiveMeshFitResult, fit_mesh_adaptive
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
from .nerf import NerfConfig, NerfFitResult, fit_nerf
from .solvers import SOLVERS, SolveResult, StepInfo, adam, lbfgs_nlopt, lbfgs_scipy, minimize, sgd
from .views import MultiViewData, ViewsFitResult, fit_mesh_to_views
from .volume import VolumeFitResult, fit_volume

__all__ = [
    "ADAPTIVE_WEIGHTS",
    "AdaptiveMeshFitResult",
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
    "MultiViewData",
    "NerfConfig",
    "NerfFitResult",
    "SolveResult",
    "StepInfo",
    "ViewsFitResult",
    "VolumeFitResult",
    "adam",
    "fit_mesh",
    "fit_mesh_adaptive",
    "fit_mesh_to_views",
    "fit_nerf",
    "fit_volume",
    "lbfgs_nlopt",
    "lbfgs_scipy",
    "minimize",
    "sgd",
]
