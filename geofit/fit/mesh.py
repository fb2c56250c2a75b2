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

The fit has one shape (as every fit of :mod:`geofit.fit`): the target is normalised once at the
door (:func:`geofit.fit._mesh_plan.as_target`), the recipe and the options become a plan
(:func:`geofit.fit._mesh_plan.plan`), the objective is :class:`MeshObjective`, the solver is
either the stages and levels below (:class:`_Solver`) or the remeshing rounds of
:mod:`geofit.fit.adaptive` (the default recipe), and both return a :class:`MeshFitResult`.

Coarse-to-fine (:class:`CoarseToFine`): start from a coarse ico-sphere, fit, estimate the
accuracy on fresh samples, and subdivide (midpoint, :func:`geofit.subdivide`) only while the
estimate misses the requested accuracy, so the result has no more vertices than needed.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from .._validate import as_rng
from ..shapes import subdivide
from ..structures import Mesh
from ._mesh_objective import MeshObjective
from ._mesh_plan import (
    ADAPTIVE_WEIGHTS,
    FINE_WEIGHTS,
    METHODS,
    RECIPES,
    TUTORIAL_WEIGHTS,
    CoarseToFine,
    MeshFitOptions,
    MeshFitResult,
    MeshTarget,
    Plan,
    Remeshing,
    as_target,
    empty_row_terms,
    plan,
    repair_degenerate,
    sphere_init,
)
from ._progress import advance, progress_bar
from .adaptive import solve_remeshing
from .history import Clock, FitHistory, budget_status
from .large_steps import LargeSteps
from .solvers import SolveResult, StepInfo, adam, lbfgs_nlopt, lbfgs_scipy, sgd

__all__ = [
    "ADAPTIVE_WEIGHTS",
    "FINE_WEIGHTS",
    "METHODS",
    "RECIPES",
    "TUTORIAL_WEIGHTS",
    "CoarseToFine",
    "LargeSteps",
    "MeshFitOptions",
    "MeshFitResult",
    "MeshObjective",
    "Remeshing",
    "fit_mesh",
]

_FAILED = ("nonfinite", "diverged", "failed")


def fit_mesh(target, *, recipe: str = "default", options: MeshFitOptions | None = None,
             time_budget: float | None = None, seed=0, evaluator: Any = "default",
             eval_every: int | None = None,
             callback: Callable[[StepInfo], bool | None] | None = None,
             progress: bool = True) -> MeshFitResult:
    """Fit a mesh to ``target``: PyTorch3D's deform tutorial, and geofit's faster, more
    accurate recipes.

    Parameters
    ----------
    target : Mesh, (verts, faces) or point cloud
        Target surface, any frame: the fit normalises it (centre on the vertex mean, divide by
        the largest absolute coordinate) and returns the result in the original frame. A point
        cloud ((k, 3) float64 array, geofit ``PointCloud``/one-cloud ``Pointclouds``, trimesh or
        Open3D point cloud) is fitted by the default recipe: a first mesh from the points
        (Poisson reconstruction, trimmed, decimated), then the remeshing fit to the points.
    recipe : {"default", "sphere", "coarse-to-fine", "tutorial"}
        Named settings (:data:`RECIPES`, presets of :class:`MeshFitOptions`):
        ``"default"``, geofit's best for any shape: a first mesh from the target (its genus,
        boundaries and parts), L-BFGS with large steps on exact distances, error-driven
        remeshing (:mod:`geofit.fit.adaptive`); ``"sphere"``: L-BFGS with large steps from the
        tutorial's ``ico_sphere(4)``; ``"coarse-to-fine"``: the same from ``ico_sphere(2)``,
        subdividing while the accuracy asks for it; ``"tutorial"``: the tutorial's SGD exactly.
    options : MeshFitOptions, optional
        Settings that override the recipe's (every field left None keeps the recipe's).
    time_budget : float, optional
        A cap in wall-clock seconds on the whole call (set-up, solves, remeshing, the default
        evaluator's checkpoints and the final report; not the time spent in an evaluator or a
        callback you pass). Default: none (``math.inf`` too): every recipe stops on its own
        iteration and accuracy tests, so the result does not depend on the machine's load.
    seed : int or numpy.random.Generator
        Sampling randomness (results are reproducible for a given seed).
    evaluator : MeshEvaluator, "default" or None
        Accuracy at checkpoints. ``"default"``: ``MeshEvaluator(target, n_samples=20000,
        taus=0.01, normalize=True)`` (None for a point cloud, which has no surface to score
        against); it is given the mesh in the original frame.
    eval_every : int, optional
        Evaluations between checkpoints (default: 200 steps for SGD/Adam; the end of each stage
        or round for L-BFGS). The final mesh is always evaluated.
    callback : callable, optional
        ``callback(StepInfo) -> bool | None`` after each iteration (``info.x`` holds the
        solver's parameters); True stops the fit with status ``"callback"``.
    progress : bool
        Show a tqdm progress bar (on stderr).

    Returns
    -------
    MeshFitResult
        ``mesh`` in the original frame, ``n_verts``, ``history`` (seconds, loss, each unweighted
        term, metric checkpoints), ``status`` / ``message``, ``metrics``, ``stages``; the
        remeshing fit also ``init`` (its name) and ``topology``.

    Raises
    ------
    ValueError
        For invalid options or meshes (a target with NaN or inf coordinates, no faces or zero
        area), coarse-to-fine with SGD/Adam, or a point cloud with a recipe other than the
        default.
    TypeError
        If ``target`` is not a mesh or a point cloud, or ``options`` not a MeshFitOptions.

    Notes
    -----
    A starting mesh with zero-area (collapsed) triangles is repaired first: their vertices are
    moved to the centroid of their neighbours (the message and ``history.events`` say how
    many), because the normal-consistency gradient is of order 1e8 at a collapsed triangle.

    The non-finite guard of :mod:`geofit.fit.solvers` makes every method end with finite
    vertices: a blow-up stops it with status ``"nonfinite"`` or ``"diverged"`` and the best
    finite vertices.

    Examples
    --------
    >>> from geofit import ico_sphere
    >>> target = ico_sphere(3).scale_verts(2.0)
    >>> opts = MeshFitOptions(init=1, n_samples=500, n_stages=1)
    >>> res = fit_mesh(target, recipe="sphere", options=opts, evaluator=None, progress=False)
    >>> res.status in ("converged", "max_iter"), res.n_verts, bool(res.mesh.verts.max() > 1.5)
    (True, 42, True)
    """
    tgt = as_target(target)
    p = plan(tgt, recipe, options, time_budget=time_budget, evaluator=evaluator,
             eval_every=eval_every)
    if p.remeshing:
        return solve_remeshing(p, tgt, seed=seed, callback=callback, progress=progress)
    run = _Solver(p, tgt, seed=seed, callback=callback, progress=progress)
    mesh, status, message = _fit_levels(p, run)
    return _mesh_result(p, run, mesh, status, message)


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


def _fit_levels(plan: Plan, run: _Solver) -> tuple[Mesh, str, str]:
    """The solves: ``n_stages`` sample redraws, per coarse-to-fine level (one level without).

    Returns the final mesh (normalised frame), status and message.
    """
    if run.n_degenerate:
        run.history.note(0, 0.0, f"source: {run.n_degenerate} zero-area triangles; moved "
                                 f"{run.n_moved} vertices to their neighbours' centroid "
                                 "before fitting", n_degenerate=run.n_degenerate,
                         n_moved=run.n_moved)
    mesh = run.init
    status, message = "max_iter", ""
    level = 0
    while True:  # coarse-to-fine levels (a single pass without coarse-to-fine)
        ls = LargeSteps(mesh, plan.lam) if plan.lam is not None else None
        for s in range(plan.n_stages):  # stages: sample redraws
            if run.clock.over():
                return mesh, "time_budget", budget_status(plan.time_budget, run.iters)
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


def _solve_stage(plan: Plan, run: _Solver, mesh: Mesh, ls, level: int, stage: int):
    """One solve with fixed (or per-step) samples; returns the objective and the solver's
    result."""
    c2f = plan.c2f
    obj = MeshObjective(mesh, run.target.normalized, plan.stage_weights(level, stage),
                        distance=plan.distance, n_samples=plan.stage_samples(mesh),
                        resample="step" if plan.stochastic else "stage", large_steps=ls,
                        seed=run.rng, target_distance=run.p2s)
    # what is left after building the objective (at least a moment: one evaluation, then the
    # solver stops with status "time_budget")
    remaining = (None if plan.time_budget is None
                 else max(run.clock.remaining(), 1e-6))
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


def _coarse_to_fine_stop(plan: Plan, run: _Solver, mesh: Mesh, obj: MeshObjective,
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


def _mesh_result(plan: Plan, run: _Solver, mesh: Mesh, status: str,
                 message: str) -> MeshFitResult:
    """The final checkpoint and the result, in the target's original frame."""
    run.bar.close()
    run.checkpoint(mesh)  # the final mesh (skipped if just evaluated)
    if not len(run.history):  # no iteration completed (e.g. a non-finite first evaluation)
        run.history.record(run.evals, run.clock.elapsed(), math.inf,
                           empty_row_terms(), n_params=3 * mesh.n_verts)
    if run.n_degenerate:
        message = (f"{message}; the source had {run.n_degenerate} zero-area triangles "
                   f"({run.n_moved} vertices moved to their neighbours' centroid first)")
    target = run.target
    return MeshFitResult(
        status=status, message=message, history=run.history, n_params=3 * mesh.n_verts,
        seconds=run.clock.elapsed(), cpu_seconds=run.clock.cpu_elapsed(),
        wall_seconds=run.clock.wall(), total_cpu_seconds=run.clock.cpu_total(),
        n_iterations=run.iters, n_evaluations=run.evals,
        mesh=mesh.update_verts(target.undo(mesh.verts)), mesh_normalized=mesh,
        center=target.center.copy(), scale=float(target.scale), method=plan.method,
        recipe=plan.recipe, init=run.init, metrics=run.metrics, stages=run.stages,
    )


class _Solver:
    """The state shared by the solves of one fit: the normalised target, the clock, history
    rows, checkpoints, stage records and the progress bar."""

    def __init__(self, plan: Plan, target: MeshTarget, *, seed, callback, progress: bool):
        c2f = plan.c2f
        self.init, self.n_degenerate, self.n_moved = repair_degenerate(
            sphere_init(plan.init, c2f.start_level if c2f is not None else 4))
        # the fit works in the target's normalised frame
        self.target = target
        self.rng = as_rng(seed)
        self.p2s = (target.distance()
                    if plan.distance == "surface" or plan.c2f is not None else None)
        self.clock = Clock(plan.time_budget)
        self.own_evaluator = plan.own_evaluator
        self.history = FitHistory()
        self.evaluator, self.every = plan.evaluator, plan.eval_every
        self.user_callback = callback
        self.stages: list[dict] = []
        self.evals = 0
        self.iters = 0
        self.last_ckpt = -1
        self.metrics = None
        self.stalled = False
        n_levels = c2f.max_level - c2f.start_level + 1 if c2f is not None else 1
        self.bar = progress_bar(progress, plan.n_iter * plan.n_stages * n_levels,
                                f"fit_mesh[{plan.recipe}]")

    def end_stage(self, plan: Plan, mesh: Mesh, res: SolveResult, level: int,
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
        if not plan.stochastic and plan.eval_every is None:
            self.checkpoint(mesh)

    def _evaluate(self, mesh: Mesh) -> dict | None:
        """Metrics of ``mesh`` (normalised frame) at the current evaluation count, clock paused."""
        if self.evaluator is None or self.last_ckpt == self.evals:
            return None
        with self.clock.paused(caller=not self.own_evaluator):
            self.metrics = self.evaluator.evaluate(mesh.update_verts(self.target.undo(mesh.verts)))
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
            advance(self.bar, self.clock, dict(loss=f"{info.value:.3g}", verts=obj.n_verts)
                    if info.iteration % 10 == 0 else None)
            if self.user_callback is not None:
                with self.clock.paused(caller=True):
                    if self.user_callback(info):
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
