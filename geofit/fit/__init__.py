"""Fitting: objectives composed from losses by the chain rule, solvers, histories.

The four fits share one skeleton, in the spirit of ``scipy.optimize.minimize``: the data first,
a named recipe, one frozen options object, and the same monitoring keywords::

    fit_mesh(target, *, recipe="default", options=MeshFitOptions(...), time_budget=None,
             seed=0, evaluator="default", eval_every=None, callback=None, progress=True)
    fit_mesh_to_views(dataset, *, recipe="default", options=ViewsFitOptions(...), ...)
    fit_volume(dataset, *, recipe="default", options=VolumeFitOptions(...), ...)
    fit_nerf(dataset, *, recipe="default", options=NerfConfig(...), ...)

``target`` is a :class:`~geofit.Mesh`, a ``(verts, faces)`` pair or a point cloud;
``dataset`` a :class:`geofit.datasets.MultiViewDataset` (``geofit.datasets.tutorial_views(4 |
5 | 6)`` renders the tutorials'). Each fit's ``RECIPES`` maps a name to a preset of its options
object; the fields of ``options`` that are set (not None) override the preset. Every fit has
``"default"`` (geofit's best, what the call with the data alone runs) and ``"tutorial"``
(PyTorch3D's recipe, exactly); ``fit_mesh`` adds ``"sphere"`` and ``"coarse-to-fine"``,
``fit_mesh_to_views`` adds ``"sphere-lbfgs"`` and ``"contour"``.

Monitoring, the same everywhere: ``evaluator`` (metrics at checkpoints, the clock paused),
``eval_every`` (steps between checkpoints), ``callback(StepInfo) -> bool | None`` (True stops the
fit with status ``"callback"``), ``progress`` (a tqdm bar). ``time_budget`` is wall-clock
seconds for the whole fit, everything the fit does on its own included (set-up, visual hulls,
its default metrics and held-out renders, final stages); not counted: the time spent in the
evaluator and callback you pass (:class:`Clock`: ``deadline``, ``until`` for a stage's share,
``check`` inside long stages). No fit has a time budget unless you give one: the defaults stop
on their own iteration and convergence tests, so the same call gives the same result on any
load. ``seed`` is the randomness.

Inside, every fit has the same stages: the data are checked and normalised once at the door
(``as_target`` / ``_as_dataset``), the recipe and options become a plan (``plan`` / ``_Plan``),
an objective (``MeshObjective``, ``_Objective``) is handed to a solver (``_Solver``, or the
solvers of :mod:`geofit.fit.solvers`), which returns the result. Every result is a
:class:`FitResult` with ``status``, ``message``, ``seconds``, ``cpu_seconds``, ``history``,
``n_params``, ``n_iterations``, ``n_evaluations``, ``method``, ``recipe`` and ``init``, and
``wall_seconds`` / ``total_cpu_seconds`` of the whole call.

=================  ========  =======================================  ==========  ============
method             fit_mesh  fit_mesh_to_views                        fit_volume  fit_nerf
=================  ========  =======================================  ==========  ============
``"lbfgs"``        default   silhouettes (default), textured (joint)  default     --
``"lbfgs-nlopt"``  yes       silhouettes                              yes         --
``"adam"``         yes       silhouettes (soft or contour loss)       yes         the only one
``"sgd"``          tutorial  tutorial (both stages)                   --          --
``"lstsq"``        --        colours (default)                        --          --
=================  ========  =======================================  ==========  ============

* :mod:`geofit.fit.history` -- :class:`Clock`, :class:`FitHistory`, :class:`FitResult`.
* :mod:`geofit.fit.solvers` -- scipy L-BFGS-B, nlopt LD_LBFGS, SGD with momentum and Adam over a
  flat float64 vector, with budgets, statuses and non-finite guards; :class:`StepInfo`.
* :mod:`geofit.fit.mesh` -- :func:`fit_mesh` (tutorial 1); its plan, options and result in
  ``_mesh_plan``; the remeshing solver of the default recipe in :mod:`geofit.fit.adaptive`;
  :mod:`geofit.fit.large_steps` -- the large-steps parameterisation.
* :mod:`geofit.fit.views` -- :func:`fit_mesh_to_views` (tutorial 4), and
  :func:`render_mesh_at_views`, the one "render this mesh at these views" helper.
* :mod:`geofit.fit.volume` -- :func:`fit_volume` (tutorial 5).
* :mod:`geofit.fit.nerf` -- :func:`fit_nerf` (tutorial 6).

Private modules hold the steps of the long fits: ``_mesh_plan``, ``_mesh_objective``, ``_cloud``,
``_views_objective``, ``_views_eval``, ``_views_init``, ``_volume_problem``, ``_volume_levels``,
``_nerf_render``, ``_nerf_train``; ``_options`` the shared vocabulary and checks, ``_progress``
the progress bars.
"""
from __future__ import annotations

from ._options import METHODS as METHOD_NAMES
from ._options import RECIPE_NAMES
from ._scan_report import DataReport
from .history import CONVERGED_STATUSES, STATUSES, Clock, FitHistory, FitResult, TimeUp
from .mesh import *  # noqa: F403 - fit_mesh, its options, recipes and results: its __all__
from .nerf import NerfConfig, NerfFitResult, fit_nerf
from .solvers import SOLVERS, SolveResult, StepInfo, adam, lbfgs_nlopt, lbfgs_scipy, minimize, sgd
from .views import ViewsFitOptions, ViewsFitResult, fit_mesh_to_views, render_mesh_at_views
from .volume import VolumeFitOptions, VolumeFitResult, fit_volume

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
    "DataReport",
    "FitHistory",
    "FitResult",
    "LargeSteps",
    "MeshFitOptions",
    "MeshFitResult",
    "MeshObjective",
    "NerfConfig",
    "NerfFitResult",
    "Remeshing",
    "SolveResult",
    "StepInfo",
    "TimeUp",
    "ViewsFitOptions",
    "ViewsFitResult",
    "VolumeFitOptions",
    "VolumeFitResult",
    "adam",
    "fit_mesh",
    "fit_mesh_to_views",
    "fit_nerf",
    "fit_volume",
    "lbfgs_nlopt",
    "lbfgs_scipy",
    "minimize",
    "render_mesh_at_views",
    "sgd",
]
