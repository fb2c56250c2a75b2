"""Fitting: objectives composed from losses by the chain rule, solvers, histories.

The four fits take their data first, then keyword options::

    fit_mesh(target, *, init=None, recipe="default", method=None, ...)      # tutorial 1
    fit_mesh_to_views(dataset, *, init=None, recipe="default", ...)         # tutorial 4
    fit_volume(dataset, *, recipe="default", method=None, ...)              # tutorial 5
    fit_nerf(dataset, *, recipe="default", method=None, ...)                # tutorial 6

``target`` is a :class:`~geofit.Mesh` or a ``(verts, faces)`` pair; ``dataset`` a
:class:`geofit.datasets.MultiViewDataset` (``geofit.datasets.tutorial_views(4 | 5 | 6)``
renders the tutorials'). One vocabulary across them:

=================  ========  =======================================  ==========  ============
method             fit_mesh  fit_mesh_to_views                        fit_volume  fit_nerf
=================  ========  =======================================  ==========  ============
``"lbfgs"``        default   silhouettes (default), textured (joint)  default     --
``"lbfgs-nlopt"``  yes       silhouettes                              yes         --
``"adam"``         yes       silhouettes (soft or contour loss)       yes         the only one
``"sgd"``          tutorial  tutorial (both stages)                   --          --
``"lstsq"``        --        colours (default)                        --          --
=================  ========  =======================================  ==========  ============

``"lbfgs"`` is scipy's L-BFGS-B, ``"lbfgs-nlopt"`` nlopt's LD_LBFGS. Recipes name complete
settings; every fit has ``"default"`` (geofit's) and ``"tutorial"`` (PyTorch3D's recipe,
exactly); ``fit_mesh`` adds ``"coarse-to-fine"``, ``fit_mesh_to_views`` adds ``"contour"``.
Every result is a :class:`FitResult` with ``status``, ``message``, ``seconds``,
``cpu_seconds``, ``history``, ``n_params``, ``n_iterations``, ``n_evaluations``, ``method``,
``recipe`` and ``init``. The former spellings (``fit_mesh(source, target)``,
``fit_volume(images, silhouettes, cameras)``, ``fit_nerf(images, silhouettes, cameras)``,
``"scipy-lbfgs"``, ``"nlopt-lbfgs"``, ``method="tutorial"``, ``preset=``) work for one more
release with a :class:`DeprecationWarning`.

* :mod:`geofit.fit.history` -- :class:`Clock`, :class:`FitHistory`, :class:`FitResult`, shared by
  every fit in geofit.
* :mod:`geofit.fit.solvers` -- scipy L-BFGS-B, nlopt LD_LBFGS, SGD with momentum and Adam over a
  flat float64 vector, with budgets, statuses and non-finite guards.
* :mod:`geofit.fit.mesh` -- :func:`fit_mesh` (PyTorch3D's deform tutorial and faster solvers)
  and coarse-to-fine; :mod:`geofit.fit.large_steps` -- the large-steps parameterisation.
* :mod:`geofit.fit.adaptive` -- :func:`fit_mesh_adaptive`, the default of ``fit_mesh(target)``:
  initial mesh from the data (:mod:`geofit.fit.init`), error-driven remeshing.
* :mod:`geofit.fit.views` -- :func:`fit_mesh_to_views`: a mesh and its colours fitted to
  multi-view silhouettes and images (tutorial 4).
* :mod:`geofit.fit.volume` -- :func:`fit_volume`: a voxel grid of densities and colours fitted by
  emission-absorption raymarching (tutorial 5).
* :mod:`geofit.fit.nerf` -- :func:`fit_nerf`: a neural radiance field (tutorial 6).

Private modules hold the steps of the long fits: ``_mesh_objective``, ``_views_objective``,
``_volume_problem``, ``_volume_levels``, ``_nerf_train``; ``_options`` the shared vocabulary and
checks, ``_progress`` the progress bars, ``_deprecated`` the former dataset names.
"""
from __future__ import annotations

from ._options import METHODS as METHOD_NAMES
from ._options import RECIPE_NAMES
from .history import CONVERGED_STATUSES, STATUSES, Clock, FitHistory, FitResult
from .mesh import (
    ADAPTIVE_WEIGHTS,
    FINE_WEIGHTS,
    METHODS,
    RECIPES,
    TUTORIAL_WEIGHTS,
    CoarseToFine,
    LargeSteps,
    MeshFitOptions,
    MeshFitResult,
    MeshObjective,
    Remeshing,
    fit_mesh,
)
from .nerf import NerfConfig, NerfFitResult, fit_nerf
from .solvers import SOLVERS, SolveResult, StepInfo, adam, lbfgs_nlopt, lbfgs_scipy, minimize, sgd
from .views import MultiViewData, ViewsFitResult, fit_mesh_to_views  # MultiViewData: deprecated
from .volume import VolumeFitResult, fit_volume

__all__ = [
    "ADAPTIVE_WEIGHTS",
    "CONVERGED_STATUSES",
    "FINE_WEIGHTS",
    "METHODS",
    "METHOD_NAMES",
    "RECIPES",
    "RECIPE_NAMES",
    "SOLVERS",
    "STATUSES",
    "TUTORIAL_WEIGHTS",
    "Clock",
    "CoarseToFine",
    "FitHistory",
    "FitResult",
    "LargeSteps",
    "MeshFitOptions",
    "MeshFitResult",
    "MeshObjective",
    "MultiViewData",
    "NerfConfig",
    "NerfFitResult",
    "Remeshing",
    "SolveResult",
    "StepInfo",
    "ViewsFitResult",
    "VolumeFitResult",
    "adam",
    "fit_mesh",
    "fit_mesh_to_views",
    "fit_nerf",
    "fit_volume",
    "lbfgs_nlopt",
    "lbfgs_scipy",
    "minimize",
    "sgd",
]
