"""Deform a source mesh into a target surface (PyTorch3D's deform tutorial, and faster ways).

The objective is a weighted sum of a data term and three regularisers of the source vertices
``V`` (all in the target's normalised frame, see :meth:`geofit.Mesh.normalize`)::

    E(V) = w_chamfer * D(V) + w_edge * edge(V) + w_normal * normal(V) + w_laplacian * lap(V)

* ``edge``, ``normal``, ``lap``: :func:`geofit.loss.mesh_edge_loss`,
  :func:`~geofit.loss.mesh_normal_consistency`, :func:`~geofit.loss.mesh_laplacian_smoothing`
  (uniform), PyTorch3D's definitions.
* ``D`` with ``distance="points"``: PyTorch3D's ``chamfer_distance`` between ``n`` samples of the
  source, ``P = B V`` (``B`` the sparse sampling matrix of
  :func:`geofit.ops.sample_points_with_jacobian`), and ``n`` samples ``Y`` of the target.
  ``dD/dV = B^T dD/dP``.
* ``D`` with ``distance="surface"``: exact point-to-surface distances both ways, with no
  sample-to-sample bias: ``mean_i d(P_i, target)^2`` (:class:`geofit.loss.PointToSurface`) plus
  ``mean_j |Y_j - C_j|^2``, where ``C_j = Bc_j V`` is the closest point of the *source* surface
  to target sample ``Y_j`` (:class:`geofit.raycast.PointToMeshDistance`, rebuilt per evaluation,
  ``Bc`` the sparse matrix of the closest faces' barycentrics). By the envelope theorem
  ``d/dV mean_j |Y_j - C_j|^2 = -Bc^T 2 (Y - C) / m`` (which face is closest is piecewise
  constant and carries no gradient).

Sampling. The tutorial (``method="sgd"``/``"adam"``) redraws both sample sets at every step, as
PyTorch3D does, so the objective is stochastic. The quasi-Newton solvers need a deterministic
function, so their samples (the source barycentrics ``B`` and the target samples ``Y``) are
drawn once per *stage* and redrawn between stages.

Large steps (Nicolet et al. 2021, "Large Steps in Inverse Rendering of Geometry", ACM TOG 40(6)):
optimise ``u = (I + lambda L) V`` with ``L = D - A`` the combinatorial graph Laplacian. Then
``V = M^-1 u`` with ``M = I + lambda L`` (symmetric positive definite, factorised once per
topology with ``scipy.sparse.linalg.splu``) and ``dE/du = M^-1 dE/dV``. Gradient steps in ``u``
are smooth (Sobolev) steps in ``V``, so large deformations keep a well-shaped mesh.

Coarse-to-fine (:class:`CoarseToFine`): start from a coarse ico-sphere, fit, estimate the
accuracy on fresh samples, and subdivide (midpoint, :func:`geofit.subdivide`) only while the
estimate misses the requested accuracy, so the result has no more vertices than needed.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._memory import check_count
from .._validate import as_array, as_faces, as_rng, check_choice, check_coordinates, check_positive
from ..structures import Mesh, as_mesh
from ._mesh_objective import TERMS, MeshObjective, mesh_weights
from ._options import Recipes, check_int, method_name, recipe_name, warn_deprecated
from ._progress import progress_bar
from .history import Clock, FitHistory, FitResult
from .large_steps import LargeSteps
from .solvers import SolveResult, StepInfo, adam, lbfgs_nlopt, lbfgs_scipy, sgd

__all__ = [
    "FINE_WEIGHTS",
    "METHODS",
    "RECIPES",
    "TUTORIAL_WEIGHTS",
    "CoarseToFine",
    "LargeSteps",
    "MeshFitResult",
    "MeshObjective",
    "fit_mesh",
]

#: Methods (solvers) :func:`fit_mesh` accepts.
METHODS = ("lbfgs", "lbfgs-nlopt", "sgd", "adam")

#: The tutorial's weights (chamfer 1, edge 1, normal consistency 0.01, Laplacian 0.1).
TUTORIAL_WEIGHTS = {"chamfer": 1.0, "edge": 1.0, "normal": 0.01, "laplacian": 0.1}

#: Lighter regularisation for the later, fine stages of the quasi-Newton fits: with exact
#: point-to-surface distances there is no sampling noise for the regularisers to smooth out.
FINE_WEIGHTS = {"chamfer": 1.0, "edge": 0.03, "normal": 0.003, "laplacian": 0.01}

#: Recipes of :func:`fit_mesh` (``fit_mesh(target, recipe=name)``; every entry is also a dict
#: of keyword options).
RECIPES: dict[str, dict] = Recipes({
    # L-BFGS, deterministic stages, exact point-to-surface distances, large steps (lambda 10)
    "default": {"method": "lbfgs"},
    # the tutorial exactly: SGD lr 1.0 momentum 0.9, 2000 steps, 5000 fresh samples a side
    "tutorial": {"method": "sgd"},
    # ico 2 -> 3 -> 4, subdividing only while the accuracy asks for it
    "coarse-to-fine": {"method": "lbfgs", "large_steps": 10.0, "coarse_to_fine": True},
}, {
    "adam": {"method": "adam", "lr": 0.01},
    "scipy-lbfgs": {"method": "lbfgs", "large_steps": None},
    "nlopt-lbfgs": {"method": "lbfgs-nlopt", "large_steps": None},
    "large-steps": {"method": "lbfgs", "large_steps": 10.0},
}, fit="fit_mesh")

_STOCHASTIC = ("sgd", "adam")


# ------------------------------------------------------------------------------------ inputs
def _as_mesh(m, name: str) -> Mesh:
    """A Mesh from a Mesh or a (verts, faces) pair, with a message naming ``name``."""
    if isinstance(m, (tuple, list)) and len(m) == 2:
        verts = as_array(m[0], f"{name} verts", (None, 3), finite=False)
        bad = int(np.count_nonzero(~np.isfinite(verts)))
        if bad:
            raise ValueError(f"{name}: the vertices contain {bad} NaN or inf coordinates; "
                             "fix or drop them before fitting")
        mesh = Mesh(verts, as_faces(m[1], f"{name} faces", len(verts)))
    else:
        mesh = as_mesh(m, name)  # a geofit, trimesh or Open3D mesh
    if mesh.n_faces == 0:
        raise ValueError(f"{name}: expected a mesh with at least one face, got 0 faces")
    check_coordinates(mesh.verts, name)  # beyond 1e38: areas overflow (not "zero area")
    if not float(mesh.face_areas.sum()) > 0:
        raise ValueError(f"{name}: the surface has zero area (every triangle is collapsed)")
    return mesh


def _repair_degenerate(mesh: Mesh, max_rounds: int = 10) -> tuple[Mesh, int, int]:
    """Move the vertices of zero-area triangles to their neighbours' centroid.

    A collapsed triangle has no normal, and PyTorch3D's normal-consistency term (cosine with
    norms clamped at 1e-8) then has gradients of order 1e8 there, which throw any solver off.
    Each round replaces the vertices of the faces whose area is below ``1e-12`` of the mean
    face area by the centroid of their edge neighbours (a uniform Laplacian step restricted to
    them). Returns the mesh, the number of degenerate faces found and the number of vertices
    moved.
    """
    areas = mesh.face_areas
    tol = 1e-12 * float(areas.mean())
    bad = areas <= tol
    n_bad = int(bad.sum())
    if n_bad == 0:
        return mesh, 0, 0
    F = mesh.faces
    repeated = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])
    bad &= ~repeated  # no vertex move gives such a face an area
    A = mesh.topology.adjacency
    deg = np.maximum(np.asarray(A.sum(axis=1)).ravel(), 1.0)
    V = mesh.verts.copy()
    moved = np.zeros(mesh.n_verts, dtype=bool)
    for _ in range(max_rounds):  # repair rounds
        idx = np.unique(mesh.faces[bad])
        moved[idx] = True
        V[idx] = (A @ V)[idx] / deg[idx, None]
        mesh = mesh.update_verts(V.copy())  # the mesh freezes the array it is given
        bad = (mesh.face_areas <= tol) & ~repeated  # a repeated index stays degenerate
        if not bad.any():
            break
    return mesh, n_bad, int(moved.sum())


# ------------------------------------------------------------------------------------ config
@dataclass
class CoarseToFine:
    """Coarse-to-fine schedule: start coarse, subdivide only while the accuracy asks for it.

    Attributes
    ----------
    start_level : int
        Ico-sphere level of the starting source when ``fit_mesh(None, ...)`` (2: 162 vertices).
    max_level : int
        Stop subdividing at this ico level (4: 2562 vertices); for a given source mesh, the number
        of subdivisions is ``max_level - start_level``.
    chamfer_l2 : float
        Accept a level when its estimated chamfer-L2 (normalised frame, fresh samples, exact
        distances) is at most this ...
    fscore : float
        ... and its estimated F-score at ``tau`` at least this.
    tau : float
        F-score threshold (normalised frame).
    max_verts : int or None
        Never subdivide past this many vertices.
    coarse_weights : dict or None
        Weights for the first (coarsest) level, where the mesh travels far from the sphere and
        needs strong regularisation; later levels use the fit's ``weights``. Default: the
        tutorial's weights.
    stall_window, stall_rel : int or None, float
        Stall test ending a level early: stop when the lowest data term of the last
        ``stall_window`` iterations is not ``stall_rel`` (relative) below the lowest before them.
        A coarse mesh reaches its best accuracy long before L-BFGS stops polishing the
        regularisers (default 10 iterations, 1%; None disables it).

    Notes
    -----
    The default accuracy (chamfer-L2 <= 3e-5, F@0.01 >= 0.97) is stricter than what PyTorch3D's
    tutorial reaches on the dolphin with 2562 vertices (6.1e-5 and 0.953 measured with
    :mod:`geofit.metrics`), leaving room for the estimate's sampling error.
    """

    start_level: int = 2
    max_level: int = 4
    chamfer_l2: float = 3e-5
    fscore: float = 0.97
    tau: float = 0.01
    max_verts: int | None = None
    coarse_weights: dict | None = field(default_factory=lambda: dict(TUTORIAL_WEIGHTS))
    stall_window: int | None = 10
    stall_rel: float = 0.01

    def __post_init__(self) -> None:
        self.start_level = check_int(self.start_level, "start_level", 0)
        self.max_level = check_int(self.max_level, "max_level", self.start_level)
        self.chamfer_l2 = check_positive(self.chamfer_l2, "chamfer_l2", strict=False)
        self.fscore = float(self.fscore)
        if not 0.0 <= self.fscore <= 1.0:
            raise ValueError(f"fscore: expected a number in [0, 1], got {self.fscore!r}")
        self.tau = check_positive(self.tau, "tau")
        if self.max_verts is not None:
            self.max_verts = check_int(self.max_verts, "max_verts", 4)
        if self.coarse_weights is not None:
            self.coarse_weights = mesh_weights(self.coarse_weights, "coarse_weights")
        if self.stall_window is not None:
            self.stall_window = check_int(self.stall_window, "stall_window")
        self.stall_rel = check_positive(self.stall_rel, "stall_rel", strict=False)


class _Stall:
    """The coarse-to-fine stall test on the data term (see :class:`CoarseToFine`)."""

    def __init__(self, window: int, rel: float):
        self.window, self.rel = window, rel
        self.values: list[float] = []

    def update(self, value: float) -> bool:
        self.values.append(value)
        if len(self.values) <= self.window:
            return False
        before = min(self.values[:-self.window])
        return min(self.values[-self.window:]) > (1.0 - self.rel) * before


# ------------------------------------------------------------------------------------ result
@dataclass(kw_only=True)
class MeshFitResult(FitResult):
    """Result of :func:`fit_mesh` (a :class:`~geofit.fit.FitResult`).

    Attributes
    ----------
    mesh : Mesh
        The fitted mesh in the target's **original** frame (normalisation undone).
    mesh_normalized : Mesh
        The same in the normalised frame the fit worked in.
    center : (3,) float64
        Normalisation centre: ``mesh.verts = mesh_normalized.verts * scale + center``.
    scale : float
        Normalisation scale.
    metrics : MeshMetrics or None
        Final accuracy (the evaluator's, see :func:`fit_mesh`), None without an evaluator.
    stages : list of dict
        One entry per solve: level, vertices, solver status and message, evaluations, seconds,
        and (coarse-to-fine) the accuracy estimate that decided whether to subdivide.
    """

    mesh: Mesh
    mesh_normalized: Mesh
    center: np.ndarray
    scale: float
    metrics: Any = None
    stages: list = field(default_factory=list)

    @property
    def n_verts(self) -> int:
        """Number of vertices of the fitted mesh."""
        return self.mesh.n_verts

    def save_obj(self, path) -> None:
        """Write the fitted mesh (original frame) as Wavefront OBJ (:func:`geofit.io.save_obj`)."""
        from ..io import save_obj

        save_obj(path, self.mesh)

    def summary(self) -> dict[str, Any]:
        d = super().summary()
        d.update(method=self.method, n_verts=self.n_verts, n_faces=self.mesh.n_faces,
                 stages=self.stages)
        if self.metrics is not None:
            d["metrics"] = self.metrics.as_dict()
        return d


# ------------------------------------------------------------------------------------ fit
_FAILED = ("nonfinite", "diverged", "failed")


_UNSET = object()


def fit_mesh(target, *args, init=None, recipe: str = "default", method: str | None = None,
             weights: Mapping[str, float] | Sequence[Mapping[str, float]] | None = None,
             distance: str | None = None, n_samples: int | None = None,
             n_iter: int | None = None,
             n_stages: int | None = None, lr: float | None = None, momentum: float = 0.9,
             large_steps: float | str | None = "auto",
             coarse_to_fine: CoarseToFine | bool | None = None,
             time_budget: float | None = None, seed=0, evaluator: Any = "default",
             checkpoint_every: int | None = None, progress: bool = True,
             callback: Callable[[StepInfo], bool | None] | None = None,
             solver_options: Mapping[str, Any] | None = None,
             source=_UNSET) -> MeshFitResult:
    """Deform a sphere (or ``init``) into ``target`` (PyTorch3D's deform tutorial, and faster
    solvers).

    Parameters
    ----------
    target : Mesh, (verts, faces) or point cloud
        Target surface, any frame: the fit normalises it (centre on the vertex mean, divide by
        the largest absolute coordinate) and returns the result in the original frame. A point
        cloud ((k, 3) float64 array, geofit ``PointCloud``/one-cloud ``Pointclouds``, trimesh or
        Open3D point cloud) is fitted by the default call: a first mesh from the points
        (Poisson reconstruction, trimmed, decimated), then the adaptive fit to the points.
    init : Mesh, (verts, faces), int, "auto", "sphere" or None
        Starting mesh, an ico-sphere level, or None / ``"auto"``: with no other option (the
        default recipe), :func:`geofit.fit.adaptive.fit_mesh_adaptive`, geofit's best fit for any
        shape (initial mesh from the target's own topology, error-driven remeshing; its result
        also reports ``init`` and ``topology``); otherwise, and with ``"sphere"``,
        ``ico_sphere(4)`` (the tutorial's), or ``ico_sphere(coarse_to_fine.start_level)`` with
        coarse-to-fine. It is placed as given
        in the target's *normalised* frame (the unit ico-sphere, as in the tutorial).
    recipe : {"default", "tutorial", "coarse-to-fine"}
        Named settings (:data:`RECIPES`) that the other options override: ``"default"`` is
        L-BFGS with large steps, ``"tutorial"`` the tutorial's SGD, ``"coarse-to-fine"``
        L-BFGS from ``ico_sphere(2)`` subdividing while the accuracy asks for it.
    method : {"lbfgs", "lbfgs-nlopt", "sgd", "adam"}, optional
        Solver (default: the recipe's). ``"lbfgs"`` is scipy's L-BFGS-B, ``"lbfgs-nlopt"``
        nlopt's LD_LBFGS. ``"sgd"`` reproduces the tutorial exactly by default (5000 fresh
        samples a side per step, point-to-point chamfer, weights 1 / 1 / 0.01 / 0.1, lr 1.0,
        momentum 0.9, 2000 steps). ``"adam"`` uses the same stochastic objective. The L-BFGS
        solvers use deterministic stages (fixed samples, redrawn between stages).
    weights : dict or sequence of dict, optional
        Term weights (``"chamfer"``, ``"edge"``, ``"normal"``, ``"laplacian"``). A sequence gives
        the weights of stage 0, 1, ... (the last one repeats). Default: the tutorial's for
        SGD/Adam; for L-BFGS the tutorial's in the first stage, then :data:`FINE_WEIGHTS`. With
        coarse-to-fine, the coarsest level uses ``coarse_to_fine.coarse_weights`` (when set)
        and every finer level the last entry (default :data:`FINE_WEIGHTS`).
    distance : {"surface", "points"}, optional
        Data term. Default ``"points"`` for SGD/Adam (the tutorial), ``"surface"`` for L-BFGS.
    n_samples : int, optional
        Samples per surface per step (SGD/Adam, default 5000 as the tutorial) or per stage
        (L-BFGS, default ``min(5000, max(1000, 8 V))`` for a source of ``V`` vertices: 1296 on
        ``ico_sphere(2)``, 5000 from ``ico_sphere(3)`` on).
    n_iter : int, optional
        Steps (SGD/Adam, default 2000) or maximum iterations per stage (L-BFGS, default 100).
    n_stages : int, optional
        L-BFGS stages, i.e. sample redraws (default 3; with coarse-to-fine, per level, default 1:
        every level draws new samples anyway).
    lr : float, optional
        Step size for SGD (default 1.0) or Adam (default 0.01).
    momentum : float
        SGD momentum.
    large_steps : float, "auto" or None
        ``lambda`` of the large-steps parameterisation; None optimises the vertices directly.
        ``"auto"`` (default): 10 for the L-BFGS methods (in vertex space they stall in folded
        local minima on the dolphin, see ``benchmarks/fit_mesh.py``), None for SGD/Adam (the
        tutorial).
    coarse_to_fine : CoarseToFine or bool, optional
        Coarse-to-fine schedule (True: the defaults of :class:`CoarseToFine`). Needs a
        deterministic method (L-BFGS).
    time_budget : float, optional
        Seconds of solver time for the whole fit.
    seed : int or numpy.random.Generator
        Sampling randomness (results are reproducible for a given seed).
    evaluator : MeshEvaluator, "default" or None
        Accuracy at checkpoints. ``"default"``: ``MeshEvaluator(target, n_samples=20000,
        taus=0.01, normalize=True)``; it is given the mesh in the original frame. Its time is
        excluded from the solver's clock.
    checkpoint_every : int, optional
        Evaluations between checkpoints (default: 200 steps for SGD/Adam; the end of each
        stage for L-BFGS). The final mesh is always evaluated.
    progress : bool
        Show a tqdm progress bar (on stderr).
    callback : callable, optional
        ``callback(StepInfo) -> bool | None`` after each iteration (``info.x`` holds the
        solver's parameters); True stops the fit with status ``"callback"``.
    solver_options : dict, optional
        Extra keyword options for the solver (e.g. ``{"ftol": 1e-12}``, ``{"betas": ...}``).

    Returns
    -------
    MeshFitResult
        ``mesh`` in the original frame, ``n_verts``, ``history`` (seconds, loss, each unweighted
        term, metric checkpoints), ``status`` / ``message``, ``metrics``, ``stages``.

    Raises
    ------
    ValueError
        For invalid options or meshes (a target with NaN or inf coordinates, no faces or zero
        area), or coarse-to-fine with SGD/Adam.
    TypeError
        If ``source`` or ``target`` is not a mesh.

    Notes
    -----
    A source with zero-area (collapsed) triangles is repaired first: their vertices are moved to
    the centroid of their neighbours (the message and ``history.events`` say how many), because
    the normal-consistency gradient is of order 1e8 at a collapsed triangle.

    Solver time is measured on a :class:`~geofit.fit.Clock` paused during metric checkpoints
    and progress-bar updates. The non-finite guard of :mod:`geofit.fit.solvers` makes every
    method end with finite vertices: a blow-up stops it with status ``"nonfinite"`` or
    ``"diverged"`` and the best finite vertices.

    Examples
    --------
    >>> from geofit import ico_sphere
    >>> target = ico_sphere(3).scale_verts(2.0)
    >>> res = fit_mesh(target, init=1, n_samples=500, n_stages=1, evaluator=None,
    ...                progress=False)
    >>> res.status in ("converged", "max_iter"), res.n_verts, bool(res.mesh.verts.max() > 1.5)
    (True, 42, True)
    """
    target, init = _init_argument(target, args, init, source)
    # the default call: the adaptive fit (initial mesh and topology from the data, remeshing)
    if isinstance(init, str):
        check_choice(init, "init", ("auto", "sphere"))
    if (init is None or init == "auto") and recipe == "default" and method is None \
            and weights is None and distance is None and n_samples is None and n_iter is None \
            and n_stages is None and large_steps == "auto" and coarse_to_fine in (None, False) \
            and callback is None and checkpoint_every is None and not solver_options:
        from .adaptive import fit_mesh_adaptive

        return fit_mesh_adaptive(target, seed=seed, evaluator=evaluator,
                                 **({} if time_budget is None else {"time_budget": time_budget}))
    from ._cloud import is_cloud

    if is_cloud(target):
        raise ValueError("target: a point cloud is fitted by the default call (fit_mesh(P), "
                         "optionally with time_budget, seed, evaluator) or by "
                         "geofit.fit.fit_mesh_adaptive; the other options need a target mesh")
    if isinstance(init, str):  # "sphere": the tutorial's start
        init = None
    plan = _MeshPlan.validate(
        target, init, recipe=recipe, method=method, weights=weights, distance=distance,
        n_samples=n_samples, n_iter=n_iter, n_stages=n_stages, lr=lr, momentum=momentum,
        large_steps=large_steps, coarse_to_fine=coarse_to_fine, time_budget=time_budget,
        evaluator=evaluator, checkpoint_every=checkpoint_every,
        solver_options=solver_options)
    run = _Run(plan, seed=seed, callback=callback, progress=progress)
    mesh, status, message = _fit_levels(plan, run)
    return _mesh_result(plan, run, mesh, status, message)


@dataclass
class _MeshPlan:
    """The validated options of one :func:`fit_mesh` call (defaults resolved)."""

    method: str
    recipe: str
    target: Mesh
    init: Mesh
    n_degenerate: int
    n_moved: int
    c2f: CoarseToFine | None
    distance: str
    n_samples: int | None
    n_iter: int
    n_stages: int
    weights: list
    lr: float
    momentum: float
    time_budget: float | None
    lam: float | None
    checkpoint_every: int | None
    evaluator: Any
    opts: dict

    @property
    def stochastic(self) -> bool:
        return self.method in _STOCHASTIC

    @classmethod
    def validate(cls, target, init, *, recipe, method, weights, distance, n_samples, n_iter,
                 n_stages, lr, momentum, large_steps, coarse_to_fine, time_budget, evaluator,
                 checkpoint_every, solver_options) -> _MeshPlan:
        """Check every option once and fill in the recipe's and the method's defaults."""
        from ..metrics import MeshEvaluator

        recipe = recipe_name(recipe, RECIPES, fit="fit_mesh")
        settings = RECIPES[recipe]
        method = method_name(method if method is not None else settings["method"], "method",
                             METHODS, fit="fit_mesh", stacklevel=5)
        stochastic = method in _STOCHASTIC
        if coarse_to_fine is None:
            coarse_to_fine = settings.get("coarse_to_fine")
        if isinstance(large_steps, str) and large_steps == "auto" and "large_steps" in settings:
            large_steps = settings["large_steps"]
        c2f = _coarse_to_fine(coarse_to_fine, method)
        target_mesh = _as_mesh(target, "target")
        source, n_degenerate, n_moved = _repair_degenerate(_init_mesh(init, c2f))
        distance = distance or ("points" if stochastic else "surface")
        check_choice(distance, "distance", ("surface", "points"))
        if n_samples is not None:
            n_samples = check_count(n_samples, "n_samples", 400)  # ~2 x sampling's 200 B
        n_iter = check_int(n_iter if n_iter is not None else (2000 if stochastic else 100),
                           "n_iter")
        default_stages = 1 if stochastic or c2f is not None else 3
        n_stages = check_int(n_stages if n_stages is not None else default_stages, "n_stages")
        if stochastic and n_stages != 1:
            raise ValueError("n_stages: SGD/Adam redraw samples at every step; expected 1")
        lr = check_positive(lr if lr is not None else (1.0 if method == "sgd" else 0.01), "lr")
        if time_budget is not None:
            time_budget = check_positive(time_budget, "time_budget")
        if isinstance(large_steps, str):
            check_choice(large_steps, "large_steps", ("auto",))
            large_steps = None if stochastic else 10.0
        lam = check_positive(large_steps, "large_steps") if large_steps is not None else None
        if checkpoint_every is not None:
            checkpoint_every = check_int(checkpoint_every, "checkpoint_every")
        elif stochastic:
            checkpoint_every = 200
        if isinstance(evaluator, str):
            check_choice(evaluator, "evaluator", ("default",))
            evaluator = MeshEvaluator(target_mesh, n_samples=20_000, taus=0.01, normalize=True)
        elif evaluator is not None and not callable(getattr(evaluator, "evaluate", None)):
            raise TypeError(f"evaluator: expected a MeshEvaluator, 'default' or None, "
                            f"got {type(evaluator)!r}")
        return cls(method, recipe, target_mesh, source, n_degenerate, n_moved, c2f, distance,
                   n_samples, n_iter, n_stages, _stage_weights(weights, stochastic), lr,
                   float(momentum), time_budget, lam, checkpoint_every, evaluator,
                   dict(solver_options or {}))

    def stage_weights(self, level: int, stage: int) -> dict:
        """The weights of one solve: per stage, or per coarse-to-fine level."""
        if self.c2f is not None:
            if level == 0 and self.c2f.coarse_weights is not None:
                return self.c2f.coarse_weights
            return self.weights[-1]
        return self.weights[min(stage, len(self.weights) - 1)]

    def stage_samples(self, mesh: Mesh) -> int:
        """Samples a side of one solve (5000, or ``min(5000, max(1000, 8 V))`` for L-BFGS)."""
        if self.n_samples:
            return self.n_samples
        return 5000 if self.stochastic else min(5000, max(1000, 8 * mesh.n_verts))


def _coarse_to_fine(coarse_to_fine, method: str) -> CoarseToFine | None:
    if coarse_to_fine is True:
        coarse_to_fine = CoarseToFine()
    elif coarse_to_fine is False:
        coarse_to_fine = None
    elif coarse_to_fine is not None and not isinstance(coarse_to_fine, CoarseToFine):
        raise TypeError(f"coarse_to_fine: expected a CoarseToFine, bool or None, "
                        f"got {type(coarse_to_fine)!r}")
    if coarse_to_fine is not None and method in _STOCHASTIC:
        raise ValueError(f"coarse_to_fine: needs a deterministic method (lbfgs or "
                         f"lbfgs-nlopt), got method={method!r}")
    return coarse_to_fine


def _init_mesh(init, c2f: CoarseToFine | None) -> Mesh:
    """The starting mesh: ``init`` as a Mesh, an ico-sphere level, or the default sphere."""
    from ..shapes import ico_sphere

    if init is None:
        init = ico_sphere(c2f.start_level if c2f is not None else 4)
    elif isinstance(init, (int, np.integer)) and not isinstance(init, bool):
        init = ico_sphere(int(init))
    return _as_mesh(init, "init")


def _stage_weights(weights, stochastic: bool) -> list[dict]:
    if weights is None:
        weights = [TUTORIAL_WEIGHTS] if stochastic else [TUTORIAL_WEIGHTS, FINE_WEIGHTS]
    elif isinstance(weights, Mapping):
        weights = [weights]
    weights = [mesh_weights(w, f"weights[{i}]") for i, w in enumerate(weights)]
    if not weights:
        raise ValueError("weights: expected at least one dict of weights")
    return weights


def _fit_levels(plan: _MeshPlan, run: _Run) -> tuple[Mesh, str, str]:
    """The solves: ``n_stages`` sample redraws, per coarse-to-fine level (one level without).

    Returns the final mesh (normalised frame), status and message.
    """
    from ..shapes import subdivide

    if plan.n_degenerate:
        run.history.note(0, 0.0, f"source: {plan.n_degenerate} zero-area triangles; moved "
                                 f"{plan.n_moved} vertices to their neighbours' centroid "
                                 "before fitting", n_degenerate=plan.n_degenerate,
                         n_moved=plan.n_moved)
    mesh = plan.init
    status, message = "max_iter", ""
    level = 0
    while True:  # coarse-to-fine levels (a single pass without coarse-to-fine)
        ls = LargeSteps(mesh, plan.lam) if plan.lam is not None else None
        for s in range(plan.n_stages):  # stages: sample redraws
            if plan.time_budget is not None and run.clock.elapsed() >= plan.time_budget:
                return mesh, "time_budget", f"time budget {plan.time_budget:g} s used up"
            obj, res = _solve_stage(plan, run, mesh, ls, level, s)
            mesh = mesh.update_verts(obj.verts_from_params(res.x))
            status, message = res.status, res.message
            run.end_stage(plan, mesh, res, level, obj)
            if res.status in _FAILED or res.status in ("callback", "time_budget"):
                return mesh, status, message
        if plan.c2f is None:
            return mesh, status, message
        stop = _coarse_to_fine_stop(plan, run, mesh, obj, level)
        if stop is not None:
            return mesh, status, f"coarse-to-fine stopped at {mesh.n_verts} vertices ({stop}); " \
                                 f"{message}"
        mesh = subdivide(mesh)
        level += 1


def _solve_stage(plan: _MeshPlan, run: _Run, mesh: Mesh, ls, level: int, stage: int):
    """One solve with fixed (or per-step) samples; returns the objective and the solver's
    result."""
    c2f = plan.c2f
    obj = MeshObjective(mesh, run.target, plan.stage_weights(level, stage),
                        distance=plan.distance, n_samples=plan.stage_samples(mesh),
                        resample="step" if plan.stochastic else "stage", large_steps=ls,
                        seed=run.rng, target_distance=run.p2s)
    # what is left after building the objective (at least a moment: one evaluation, then the
    # solver stops with status "time_budget")
    remaining = (None if plan.time_budget is None
                 else max(plan.time_budget - run.clock.elapsed(), 1e-6))
    stall = (_Stall(c2f.stall_window, c2f.stall_rel)
             if c2f is not None and c2f.stall_window else None)
    res = _solve(plan.method, obj, obj.params_from_verts(mesh.verts), n_iter=plan.n_iter,
                 lr=plan.lr, momentum=plan.momentum, time_budget=remaining,
                 callback=run.callback(obj, len(run.stages), stall), clock=run.clock,
                 opts=plan.opts)
    if res.status == "callback" and run.stalled:
        res.status = "converged"
        res.message = (f"the data term improved by less than {c2f.stall_rel:.0%} over "
                       f"the last {c2f.stall_window} iterations (coarse-to-fine stall "
                       f"test)")
    return obj, res


def _coarse_to_fine_stop(plan: _MeshPlan, run: _Run, mesh: Mesh, obj: MeshObjective,
                         level: int) -> str | None:
    """Why coarse-to-fine stops at this level (None: subdivide): the estimated accuracy is
    reached, or the last level or the vertex cap."""
    c2f = plan.c2f
    est = obj.estimate_accuracy(mesh.verts, tau=c2f.tau)
    run.stages[-1]["estimate"] = est
    ok = est["chamfer_l2"] <= c2f.chamfer_l2 and est["fscore"] >= c2f.fscore
    at_max = level >= c2f.max_level - c2f.start_level
    too_big = c2f.max_verts is not None and mesh.n_verts + len(mesh.edges) > c2f.max_verts
    run.history.note(run.evals, run.clock.elapsed(),
                     f"level {level}: estimated chamfer-L2 {est['chamfer_l2']:.3g}, "
                     f"F@{c2f.tau:g} {est['fscore']:.4f} with {mesh.n_verts} vertices", **est)
    if ok or at_max or too_big:
        return "accuracy reached" if ok else ("max level" if at_max else "max_verts")
    return None


def _mesh_result(plan: _MeshPlan, run: _Run, mesh: Mesh, status: str,
                 message: str) -> MeshFitResult:
    """The final checkpoint and the result, in the target's original frame."""
    run.bar.close()
    run.checkpoint(mesh)  # the final mesh (skipped if just evaluated)
    if not len(run.history):  # no iteration completed (e.g. a non-finite first evaluation)
        run.history.record(run.evals, run.clock.elapsed(), math.inf,
                           {k: math.inf for k in TERMS}, n_params=3 * mesh.n_verts)
    if plan.n_degenerate:
        message = (f"{message}; the source had {plan.n_degenerate} zero-area triangles "
                   f"({plan.n_moved} vertices moved to their neighbours' centroid first)")
    norm = run.norm
    return MeshFitResult(
        status=status, message=message, history=run.history, n_params=3 * mesh.n_verts,
        seconds=run.clock.elapsed(), cpu_seconds=run.clock.cpu_elapsed(),
        n_iterations=run.iters, n_evaluations=run.evals,
        mesh=mesh.update_verts(norm.undo(mesh.verts)), mesh_normalized=mesh,
        center=norm.center.copy(), scale=float(norm.scale), method=plan.method,
        recipe=plan.recipe, init=plan.init, metrics=run.metrics, stages=run.stages,
    )


def _init_argument(target, args: tuple, init, source):
    """``(target, init)`` from the current call form, or from the former ``fit_mesh(source,
    target)`` and ``source=`` (with a DeprecationWarning)."""
    if len(args) > 1:
        raise TypeError(f"fit_mesh: expected one positional argument (target), got "
                        f"{1 + len(args)}")
    if args:
        warn_deprecated("fit_mesh(source, target, ...)", "fit_mesh(target, init=source, ...)",
                        4)
        return args[0], target
    if source is not _UNSET:
        warn_deprecated("fit_mesh(source=...)", "fit_mesh(target, init=...)", 4)
        return target, source
    return target, init


class _Run:
    """The state shared by the solves of one fit: the normalised target, the clock, history
    rows, checkpoints, stage records and the progress bar."""

    def __init__(self, plan: _MeshPlan, *, seed, callback, progress: bool):
        from ..loss import PointToSurface

        # the fit works in the target's normalised frame
        self.norm = plan.target.normalize()
        self.target = self.norm.mesh
        self.rng = as_rng(seed)
        self.p2s = (PointToSurface(self.target)
                    if plan.distance == "surface" or plan.c2f is not None else None)
        self.clock = Clock()
        self.history = FitHistory()
        self.evaluator, self.every = plan.evaluator, plan.checkpoint_every
        self.user_callback = callback
        self.stages: list[dict] = []
        self.evals = 0
        self.iters = 0
        self.last_ckpt = -1
        self.metrics = None
        self.stalled = False
        c2f = plan.c2f
        n_levels = c2f.max_level - c2f.start_level + 1 if c2f is not None else 1
        self.bar = progress_bar(progress, plan.n_iter * plan.n_stages * n_levels,
                                f"fit_mesh[{plan.method}]")

    def end_stage(self, plan: _MeshPlan, mesh: Mesh, res: SolveResult, level: int,
                  obj: MeshObjective) -> None:
        """Record a finished solve (stage list, history event, checkpoint for L-BFGS)."""
        self.evals += res.n_evaluations
        self.stages.append({"stage": len(self.stages), "level": level, "n_verts": mesh.n_verts,
                            "status": res.status, "message": res.message,
                            "n_iterations": res.n_iterations,
                            "n_evaluations": res.n_evaluations, "seconds": res.seconds,
                            "n_samples": obj.n_samples, "large_steps": plan.lam,
                            "weights": dict(obj.weights)})
        self.history.note(self.evals, self.clock.elapsed(),
                          f"stage {len(self.stages) - 1} ended: {res.status}",
                          n_verts=mesh.n_verts)
        if not plan.stochastic and plan.checkpoint_every is None:
            self.checkpoint(mesh)

    def _evaluate(self, mesh: Mesh) -> dict | None:
        """Metrics of ``mesh`` (normalised frame) at the current evaluation count, clock paused."""
        if self.evaluator is None or self.last_ckpt == self.evals:
            return None
        with self.clock.paused():
            self.metrics = self.evaluator.evaluate(mesh.update_verts(self.norm.undo(mesh.verts)))
        self.last_ckpt = self.evals
        return self.metrics.as_dict()

    def checkpoint(self, mesh: Mesh) -> None:
        """Evaluate ``mesh`` and attach the metrics to the last history row."""
        m = self._evaluate(mesh)
        if m is not None and len(self.history):
            self.history.checkpoint(self.history.steps[-1], self.history.seconds[-1], m)

    def callback(self, obj: MeshObjective, stage: int, stall: _Stall | None = None):
        base = self.evals
        self.stalled = False

        def cb(info: StepInfo):
            evals = base + info.n_evaluations
            self.iters += 1
            metrics = None
            if self.every is not None and evals - max(self.last_ckpt, 0) >= self.every:
                with self.clock.paused():
                    mesh = obj.source.update_verts(obj.verts_from_params(info.x))
                saved, self.evals = self.evals, evals
                metrics = self._evaluate(mesh)
                self.evals = saved
            self.history.record(evals, self.clock.elapsed(), info.value, obj.last_terms,
                                metrics, n_params=obj.n_params, stage=stage)
            with self.clock.paused():
                self.bar.update(1)
                if info.iteration % 10 == 0:
                    self.bar.set_postfix(loss=f"{info.value:.3g}", verts=obj.n_verts)
            if self.user_callback is not None and self.user_callback(info):
                return True
            if stall is not None and stall.update(obj.last_terms["chamfer"]):
                self.stalled = True
                return True
            return None

        return cb


def _solve(method, obj, x0, *, n_iter, lr, momentum, time_budget, callback, clock,
           opts) -> SolveResult:
    if method == "sgd":
        return sgd(obj, x0, lr=lr, momentum=momentum, n_iter=n_iter, time_budget=time_budget,
                   callback=callback, clock=clock, **opts)
    if method == "adam":
        return adam(obj, x0, lr=lr, n_iter=n_iter, time_budget=time_budget, callback=callback,
                    clock=clock, **opts)
    if method == "lbfgs":
        return lbfgs_scipy(obj, x0, max_iter=n_iter, time_budget=time_budget,
                           callback=callback, clock=clock, **opts)
    return lbfgs_nlopt(obj, x0, max_eval=int(1.25 * n_iter) + 5, time_budget=time_budget,
                       callback=callback, clock=clock, **opts)
