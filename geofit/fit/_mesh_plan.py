"""The door and the plan of :func:`geofit.fit.fit_mesh`: options, recipes, target, result.

Both solvers of ``fit_mesh`` (the stages and coarse-to-fine levels of :mod:`geofit.fit.mesh`, the
remeshing rounds of :mod:`geofit.fit.adaptive`) start here:

* :func:`as_target` normalises the target once (a mesh or a point cloud, see
  :mod:`geofit.fit._cloud`) into a :class:`MeshTarget`;
* :func:`plan` resolves the recipe and the :class:`MeshFitOptions` into a :class:`Plan`;
* :class:`MeshFitResult` is what both return.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._memory import check_count
from .._validate import as_array, as_faces, check_choice, check_coordinates, check_positive
from ..io import save_obj
from ..loss import PointToSurface
from ..metrics import MeshEvaluator
from ..shapes import ico_sphere
from ..structures import Mesh, as_mesh
from ._cloud import CloudTarget, as_cloud_points, is_cloud
from ._mesh_objective import TERMS, mesh_weights
from ._options import check_int, merge_options, recipe_name
from .history import FitResult

__all__ = ["ADAPTIVE_WEIGHTS", "FINE_WEIGHTS", "METHODS", "RECIPES", "TUTORIAL_WEIGHTS",
           "CoarseToFine", "MeshFitOptions", "MeshFitResult", "MeshTarget", "Plan", "Remeshing",
           "as_mesh_argument", "as_target", "plan", "repair_degenerate"]

#: Methods (solvers) :func:`~geofit.fit.fit_mesh` accepts.
METHODS = ("lbfgs", "lbfgs-nlopt", "sgd", "adam")
_STOCHASTIC = ("sgd", "adam")

#: The tutorial's weights (chamfer 1, edge 1, normal consistency 0.01, Laplacian 0.1).
TUTORIAL_WEIGHTS = {"chamfer": 1.0, "edge": 1.0, "normal": 0.01, "laplacian": 0.1}

#: Lighter regularisation for the later, fine stages of the quasi-Newton fits: with exact
#: point-to-surface distances there is no sampling noise for the regularisers to smooth out.
FINE_WEIGHTS = {"chamfer": 1.0, "edge": 0.03, "normal": 0.003, "laplacian": 0.01}

#: Weights of the remeshing fit (the default recipe): the exact two-way distance, and a light
#: normal-consistency term. Starting on the target's own surface there is little for the
#: smoothing terms to do, and the edge-length term (mean squared edge length) would shrink the
#: surface; the large-steps parameterisation keeps the steps smooth.
ADAPTIVE_WEIGHTS = {"chamfer": 1.0, "edge": 0.0, "normal": 1e-5, "laplacian": 0.0}


def _check_accuracy(obj, chamfer_l2, fscore, tau) -> None:
    object.__setattr__(obj, "chamfer_l2", check_positive(chamfer_l2, "chamfer_l2", strict=False))
    fscore = float(fscore)
    if not 0.0 <= fscore <= 1.0:
        raise ValueError(f"fscore: expected a number in [0, 1], got {fscore!r}")
    object.__setattr__(obj, "fscore", fscore)
    object.__setattr__(obj, "tau", check_positive(tau, "tau"))


@dataclass(frozen=True)
class Remeshing:
    """Refinement by error-driven remeshing (the default recipe of ``fit_mesh``).

    Rounds of an L-BFGS solve, an accuracy estimate on fresh samples and, while the estimate
    misses the target, a remeshing (:func:`geofit.ops.remesh`) towards edge lengths set by the
    error (:func:`geofit.fit.adaptive.refine_lengths`).

    Attributes
    ----------
    n_faces : int
        Face budget of the initial mesh made from the data (the decimated target, or the
        decimated Poisson reconstruction of a point cloud).
    chamfer_l2, fscore, tau : float
        Stop refining once the estimated chamfer-L2 (normalised frame) is at most
        ``chamfer_l2`` and the F-score at ``tau`` at least ``fscore``. A point cloud: once
        the estimate (to the points) is at most ``2.5 sigma^2`` for the scan's noise
        ``sigma`` (the noise's own ``2 sigma^2`` and a model residual of half the noise), or
        :data:`geofit.fit.adaptive.CLOUD_GOAL_SHARE` of ``chamfer_l2`` where that is larger,
        and the F-score at least ``fscore`` (lowered to what the noise allows).
    max_rounds : int
        Solve-and-remesh rounds at most.
    max_verts : int
        Do not refine past this many vertices (a point cloud: nor past what a round's samples
        fit, :data:`geofit.fit.adaptive.CLOUD_MAX_SAMPLES` at
        :func:`geofit.fit.adaptive.cloud_samples_per_vert` a vertex).
    """

    n_faces: int = 2000
    chamfer_l2: float = 3e-5
    fscore: float = 0.97
    tau: float = 0.01
    max_rounds: int = 4
    max_verts: int = 30000

    def __post_init__(self) -> None:
        object.__setattr__(self, "n_faces", check_int(self.n_faces, "n_faces", 4))
        object.__setattr__(self, "max_rounds", check_int(self.max_rounds, "max_rounds"))
        object.__setattr__(self, "max_verts", check_int(self.max_verts, "max_verts", 4))
        _check_accuracy(self, self.chamfer_l2, self.fscore, self.tau)


@dataclass(frozen=True)
class CoarseToFine:
    """Refinement by subdivision: start coarse, subdivide only while the accuracy asks for it.

    Attributes
    ----------
    start_level : int
        Ico-sphere level of the starting mesh when no ``init`` is given (2: 162 vertices).
    max_level : int
        Stop subdividing at this ico level (4: 2562 vertices); for a given starting mesh, the
        number of subdivisions is ``max_level - start_level``.
    chamfer_l2, fscore, tau : float
        Accept a level when its estimated chamfer-L2 (normalised frame, fresh samples, exact
        distances) is at most ``chamfer_l2`` and its F-score at ``tau`` at least ``fscore``.
    max_verts : int or None
        Never subdivide past this many vertices.
    coarse_weights : dict or None
        Weights of the first (coarsest) level, where the mesh travels far from the sphere and
        needs strong regularisation; later levels use the fit's last ``weights``. Default: the
        tutorial's.
    stall_window, stall_rel : int or None, float
        Stall test ending a level early: stop when the lowest data term of the last
        ``stall_window`` iterations is not ``stall_rel`` (relative) below the lowest before them
        (default 10 iterations, 1%; None disables it).

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
    coarse_weights: Mapping[str, float] | None = field(
        default_factory=lambda: dict(TUTORIAL_WEIGHTS))
    stall_window: int | None = 10
    stall_rel: float = 0.01

    def __post_init__(self) -> None:
        start = check_int(self.start_level, "start_level", 0)
        object.__setattr__(self, "start_level", start)
        object.__setattr__(self, "max_level", check_int(self.max_level, "max_level", start))
        _check_accuracy(self, self.chamfer_l2, self.fscore, self.tau)
        if self.max_verts is not None:
            object.__setattr__(self, "max_verts", check_int(self.max_verts, "max_verts", 4))
        if self.coarse_weights is not None:
            object.__setattr__(self, "coarse_weights",
                               mesh_weights(self.coarse_weights, "coarse_weights"))
        if self.stall_window is not None:
            object.__setattr__(self, "stall_window", check_int(self.stall_window,
                                                               "stall_window"))
        object.__setattr__(self, "stall_rel",
                           check_positive(self.stall_rel, "stall_rel", strict=False))


@dataclass(frozen=True)
class MeshFitOptions:
    """The settings of :func:`~geofit.fit.fit_mesh`; None means "the recipe's" (or, where the
    recipe leaves it open, the method's default).

    Attributes
    ----------
    init : Mesh, (verts, faces), int, {"auto", "sphere", "target"} or None
        Starting mesh, placed as given in the target's *normalised* frame, or an ico-sphere
        level. ``"auto"``/``"target"``: a mesh from the data (remeshing only: the decimated
        target, or the Poisson reconstruction of a point cloud). ``"sphere"``: the tutorial's
        ``ico_sphere(4)`` (``ico_sphere(2)`` for the remeshing fit,
        ``ico_sphere(refine.start_level)`` with coarse-to-fine).
    method : {"lbfgs", "lbfgs-nlopt", "sgd", "adam"}
        Solver. ``"lbfgs"`` is scipy's L-BFGS-B, ``"lbfgs-nlopt"`` nlopt's LD_LBFGS (both on
        deterministic stages: samples fixed within a stage, redrawn between stages); ``"sgd"``
        and ``"adam"`` redraw samples at every step (the tutorial). The remeshing refinement
        takes ``"lbfgs"`` only.
    refine : Remeshing, CoarseToFine or None
        Refinement between solves: error-driven remeshing (the default recipe), subdivision
        (``"coarse-to-fine"``), or none (``"sphere"``, ``"tutorial"``).
    weights : dict or sequence of dict
        Term weights (``"chamfer"``, ``"edge"``, ``"normal"``, ``"laplacian"``). A sequence
        gives the weights of stage 0, 1, ... (the last one repeats). Default: the tutorial's for
        SGD/Adam; for L-BFGS the tutorial's in the first stage, then :data:`FINE_WEIGHTS`;
        :data:`ADAPTIVE_WEIGHTS` for the remeshing fit (one dict).
    distance : {"surface", "points"}
        Data term (not for the remeshing fit, which always uses exact distances). Default
        ``"points"`` for SGD/Adam (the tutorial), ``"surface"`` for L-BFGS.
    n_samples : int
        Samples per surface per step (SGD/Adam, default 5000 as the tutorial) or per stage
        (L-BFGS, default ``min(5000, max(1000, 8 V))``). Not for the remeshing fit
        (``min(8000, max(2000, 4 V))`` per round; a point cloud's
        ``min(points, 20000, max(2000, s V))``, ``s`` 4 to 12 by the scan's noise).
    n_iter : int
        Steps (SGD/Adam, default 2000) or iterations per stage, level or round (L-BFGS,
        default 100; 40 per remeshing round).
    n_stages : int
        L-BFGS stages (sample redraws) without refinement (default 3) or per coarse-to-fine
        level (default 1).
    lr, momentum : float
        Step size of SGD (default 1.0) or Adam (default 0.01); SGD momentum (default 0.9).
    large_steps : float
        ``lambda`` of the large-steps parameterisation; 0 optimises the vertices directly.
        Default: 10 for L-BFGS, 0 for SGD/Adam (the tutorial); remeshing: 2 from the data's own
        shape, 10 from an ico-sphere or a given mesh.
    solver_options : dict
        Extra keyword options of the solver (``{"ftol": 1e-12}``, ``{"betas": ...}``).
    watertight : bool
        A point-cloud target only. False (the default): no surface where the scan has no
        points: the start is trimmed to the points, surface past the scan's boundary is pulled
        back, and at the end faces whose centroid lies farther than ``3 spacing + 3 noise``
        from every point are removed, so the holes of a one-sided scan stay holes. True: a
        closed surface; the start is the untrimmed Poisson reconstruction, and where there are
        no points the surface has no data term (only the large-steps smoothness shapes it).
    """

    init: Any = None
    method: str | None = None
    refine: Remeshing | CoarseToFine | None = None
    weights: Mapping[str, float] | Sequence[Mapping[str, float]] | None = None
    distance: str | None = None
    n_samples: int | None = None
    n_iter: int | None = None
    n_stages: int | None = None
    lr: float | None = None
    momentum: float | None = None
    large_steps: float | None = None
    solver_options: Mapping[str, Any] | None = None
    watertight: bool | None = None


#: Recipes of :func:`~geofit.fit.fit_mesh`: named :class:`MeshFitOptions` presets.
RECIPES: dict[str, MeshFitOptions] = {
    # geofit's best for any shape: a first mesh from the data (its topology), L-BFGS with
    # large steps on exact distances, error-driven remeshing
    "default": MeshFitOptions(init="auto", method="lbfgs", refine=Remeshing()),
    # L-BFGS from the tutorial's ico_sphere(4), deterministic stages, exact distances,
    # large steps (lambda 10)
    "sphere": MeshFitOptions(init="sphere", method="lbfgs"),
    # ico 2 -> 3 -> 4, subdividing only while the accuracy asks for it
    "coarse-to-fine": MeshFitOptions(init="sphere", method="lbfgs", refine=CoarseToFine(),
                                     large_steps=10.0),
    # the tutorial exactly: SGD lr 1.0 momentum 0.9, 2000 steps, 5000 fresh samples a side
    "tutorial": MeshFitOptions(init="sphere", method="sgd"),
}


# ------------------------------------------------------------------------------------ target
def as_mesh_argument(m, name: str) -> Mesh:
    """A Mesh from a Mesh (geofit, trimesh, Open3D) or a ``(verts, faces)`` pair, checked:
    finite vertices, at least one face, non-zero area."""
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


@dataclass
class MeshTarget:
    """The target of a mesh fit, normalised once (centre on the mean, divide by the largest
    absolute centred coordinate: PyTorch3D's tutorial normalisation).

    Attributes
    ----------
    mesh : Mesh or None
        The target mesh in its original frame (None for a point cloud).
    normalized : Mesh or (k, 3) float64
        The target in the normalised frame the fit works in (a mesh, or the cloud's points).
    center : (3,) float64
    scale : float
        ``original = normalised * scale + center``.
    cloud : bool
        Whether the target is a point cloud.
    """

    mesh: Mesh | None
    normalized: Any
    center: np.ndarray
    scale: float
    cloud: bool

    def undo(self, verts: np.ndarray) -> np.ndarray:
        """Vertices in the target's original frame."""
        return verts * self.scale + self.center

    def distance(self):
        """The exact distance to the normalised target (:class:`geofit.loss.PointToSurface`, or
        the cloud's :class:`~geofit.fit._cloud.CloudTarget`), built on demand."""
        return CloudTarget(self.normalized) if self.cloud else PointToSurface(self.normalized)


def as_target(target) -> MeshTarget:
    """The normalised :class:`MeshTarget` of a mesh or point-cloud target (validated)."""
    if is_cloud(target):
        points = as_cloud_points(target, "target")
        center = points.mean(0)  # the same normalisation as Mesh.normalize, on the points
        scale = float(np.abs(points - center).max())
        return MeshTarget(None, (points - center) / scale, center, scale, True)
    mesh = as_mesh_argument(target, "target")
    norm = mesh.normalize()
    return MeshTarget(mesh, norm.mesh, norm.center, float(norm.scale), False)


def repair_degenerate(mesh: Mesh, max_rounds: int = 10) -> tuple[Mesh, int, int]:
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


# ------------------------------------------------------------------------------------ plan
@dataclass
class Plan:
    """The validated settings of one :func:`~geofit.fit.fit_mesh` call (defaults resolved)."""

    recipe: str
    method: str
    refine: Remeshing | CoarseToFine | None
    init: Any                    # the user's init (a Mesh or a name), resolved by the solver
    distance: str
    n_samples: int | None
    n_iter: int
    n_stages: int
    weights: list
    lr: float
    momentum: float
    lam: float | None            # None: the solver's automatic choice (remeshing)
    time_budget: float | None
    evaluator: Any
    eval_every: int | None
    opts: dict
    own_evaluator: bool = False  # the "default" evaluator: its time counts in the budget
    watertight: bool = False
    weights_given: bool = False  # the user's weights (else the recipe's, which a scan adapts)

    @property
    def stochastic(self) -> bool:
        return self.method in _STOCHASTIC

    @property
    def remeshing(self) -> bool:
        return isinstance(self.refine, Remeshing)

    @property
    def c2f(self) -> CoarseToFine | None:
        return self.refine if isinstance(self.refine, CoarseToFine) else None

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


def plan(target: MeshTarget, recipe: str, options: MeshFitOptions | None, *, time_budget,
         evaluator, eval_every) -> Plan:
    """Check every option once and fill in the recipe's and the method's defaults."""
    recipe = recipe_name(recipe, RECIPES, fit="fit_mesh")
    o = merge_options(RECIPES[recipe], options, MeshFitOptions, "options")
    if o.refine is not None and not isinstance(o.refine, (Remeshing, CoarseToFine)):
        raise TypeError(f"options.refine: expected a Remeshing, a CoarseToFine or None, got "
                        f"{type(o.refine)!r}")
    check_choice(o.method, "options.method", METHODS)
    method = o.method
    stochastic = method in _STOCHASTIC
    remeshing = isinstance(o.refine, Remeshing)
    if remeshing:
        if method != "lbfgs":
            raise ValueError(f"options.method: the remeshing refinement solves with 'lbfgs', "
                             f"got {method!r} (use recipe='sphere' for the other solvers)")
        for name in ("distance", "n_samples", "n_stages", "lr", "momentum", "solver_options"):
            if getattr(o, name) is not None:
                raise ValueError(f"options.{name}: not a setting of the remeshing refinement "
                                 f"(recipe {recipe!r}); use recipe='sphere' or "
                                 "'coarse-to-fine' for it")
    elif target.cloud:
        raise ValueError("target: a point cloud is fitted by the remeshing refinement (the "
                         f"default recipe); recipe {recipe!r} needs a target mesh")
    if isinstance(o.refine, CoarseToFine) and stochastic:
        raise ValueError(f"options.refine: coarse-to-fine needs a deterministic method (lbfgs "
                         f"or lbfgs-nlopt), got method={method!r}")
    if o.watertight is not None and not isinstance(o.watertight, (bool, np.bool_)):
        raise TypeError(f"options.watertight: expected True, False or None, got "
                        f"{type(o.watertight).__name__} {o.watertight!r}")
    watertight = bool(o.watertight)
    if watertight and not target.cloud:
        raise ValueError("options.watertight: a setting of point-cloud targets (closing the "
                         "holes of a scan); the target is a mesh")
    distance = o.distance or ("points" if stochastic else "surface")
    check_choice(distance, "options.distance", ("surface", "points"))
    n_samples = None if o.n_samples is None else check_count(o.n_samples, "options.n_samples",
                                                             400)  # ~2 x sampling's 200 B
    n_iter = o.n_iter if o.n_iter is not None else (
        40 if remeshing else (2000 if stochastic else 100))
    n_iter = check_int(n_iter, "options.n_iter")
    default_stages = 1 if stochastic or o.refine is not None else 3
    n_stages = check_int(o.n_stages if o.n_stages is not None else default_stages,
                         "options.n_stages")
    if stochastic and n_stages != 1:
        raise ValueError("options.n_stages: SGD/Adam redraw samples at every step; expected 1")
    lr = check_positive(o.lr if o.lr is not None else (1.0 if method == "sgd" else 0.01),
                        "options.lr")
    momentum = 0.9 if o.momentum is None else check_positive(o.momentum, "options.momentum",
                                                             strict=False)
    if o.large_steps is None:
        lam = None if remeshing else (None if stochastic else 10.0)
    else:
        lam = check_positive(o.large_steps, "options.large_steps", strict=False) or None
        if lam is None and remeshing:
            raise ValueError("options.large_steps: the remeshing refinement needs a lambda > 0")
    if remeshing:
        weights = [mesh_weights(o.weights if o.weights is not None else ADAPTIVE_WEIGHTS,
                                "options.weights")]
    else:
        weights = _stage_weights(o.weights, stochastic)
    if time_budget is not None:  # a cap only: every recipe stops on its own tests without it
        if not (isinstance(time_budget, (int, float)) and math.isinf(time_budget)
                and time_budget > 0):
            time_budget = check_positive(time_budget, "time_budget")
        time_budget = None if math.isinf(time_budget) else float(time_budget)
    if eval_every is not None:
        eval_every = check_int(eval_every, "eval_every")
    elif stochastic:
        eval_every = 200
    own = isinstance(evaluator, str)
    if own:
        check_choice(evaluator, "evaluator", ("default",))
        evaluator = None if target.cloud else MeshEvaluator(
            target.mesh, n_samples=20_000, taus=0.01, normalize=True)
    elif evaluator is not None and not callable(getattr(evaluator, "evaluate", None)):
        raise TypeError(f"evaluator: expected a MeshEvaluator, 'default' or None, "
                        f"got {type(evaluator)!r}")
    return Plan(recipe, method, o.refine, o.init, distance, n_samples, n_iter, n_stages,
                weights, lr, momentum, lam, time_budget, evaluator, eval_every,
                dict(o.solver_options or {}), own, watertight,
                options is not None and options.weights is not None)


def _stage_weights(weights, stochastic: bool) -> list[dict]:
    if weights is None:
        weights = [TUTORIAL_WEIGHTS] if stochastic else [TUTORIAL_WEIGHTS, FINE_WEIGHTS]
    elif isinstance(weights, Mapping):
        weights = [weights]
    weights = [mesh_weights(w, f"options.weights[{i}]") for i, w in enumerate(weights)]
    if not weights:
        raise ValueError("options.weights: expected at least one dict of weights")
    return weights


def sphere_init(init, start_level: int) -> Mesh:
    """The starting mesh of the stage and level solvers: ``init`` as a Mesh, an ico-sphere
    level, or ``ico_sphere(start_level)`` for ``"sphere"``/None."""
    if init is None or (isinstance(init, str) and init in ("sphere", "auto")):
        init = ico_sphere(start_level)
    elif isinstance(init, (int, np.integer)) and not isinstance(init, bool):
        init = ico_sphere(int(init))
    elif isinstance(init, str):
        raise ValueError(f"options.init: expected a Mesh, (verts, faces), an ico-sphere level, "
                         f"'sphere' or 'auto', got {init!r} (a mesh from the target is the "
                         "default recipe's)")
    return as_mesh_argument(init, "init")


# ------------------------------------------------------------------------------------ result
@dataclass(kw_only=True)
class MeshFitResult(FitResult):
    """Result of :func:`~geofit.fit.fit_mesh` (a :class:`~geofit.fit.FitResult`).

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
        Final accuracy (the evaluator's), None without an evaluator.
    stages : list of dict
        One entry per solve: level or round, vertices, solver status and message,
        evaluations, seconds, and (with refinement) the accuracy estimate (the remeshing
        fit: and the ``goal`` it was held to, a scan's at its noise floor).
    init : str or Mesh
        The remeshing fit: the initialisation's name (``"target"``, ``"points"``,
        ``"sphere"``, ``"user"``); the other recipes: the starting mesh.
    topology : geofit.ops.TopologyReport or None
        The remeshing fit: topology of the fitted mesh (genus, boundary loops, parts,
        non-manifold edges, self-intersecting face pairs).
    data_report : DataReport or None
        A point-cloud target: its noise, spacing and outliers (target frame; see
        :func:`geofit.fit._scan_report.scan_report`); None for a mesh target.
    """

    mesh: Mesh
    mesh_normalized: Mesh
    center: np.ndarray
    scale: float
    metrics: Any = None
    stages: list = field(default_factory=list)
    topology: Any = None
    data_report: Any = None

    @property
    def n_verts(self) -> int:
        """Number of vertices of the fitted mesh."""
        return self.mesh.n_verts

    def save_obj(self, path) -> None:
        """Write the fitted mesh (original frame) as Wavefront OBJ (:func:`geofit.io.save_obj`)."""
        save_obj(path, self.mesh)

    def summary(self) -> dict[str, Any]:
        d = super().summary()
        d.update(method=self.method, n_verts=self.n_verts, n_faces=self.mesh.n_faces,
                 stages=self.stages)
        if self.metrics is not None:
            d["metrics"] = self.metrics.as_dict()
        if isinstance(self.init, str):
            d["init"] = self.init
        if self.topology is not None:
            d["topology"] = self.topology.as_dict()
        if self.data_report is not None:
            d["data_report"] = self.data_report.as_dict()
        return d


def empty_row_terms() -> dict:
    """History terms of a fit that completed no iteration."""
    return {k: math.inf for k in TERMS}

