"""The remeshing solver of :func:`geofit.fit.fit_mesh` (its default recipe): a fit that starts
from the data's topology and remeshes where the error is.

``fit_mesh(target)`` (tutorial 1 for any shape; options in
:class:`~geofit.fit.MeshFitOptions` with ``refine=Remeshing(...)``):

1. **Initialisation from the data** (:func:`geofit.fit.init.initial_mesh`): by default the
   normalised target decimated to ``n_faces`` faces (quadric error, Open3D), which keeps its
   genus, boundary loops and parts; ``init="sphere"`` keeps the tutorial's ico-sphere.
2. **Rounds** of: an L-BFGS solve (scipy) in the large-steps parameterisation
   (:class:`~geofit.fit.LargeSteps`) of the exact two-way point-to-surface objective
   (:class:`~geofit.fit.MeshObjective`, samples redrawn each round); an accuracy estimate on
   fresh samples; and, while the estimate misses the target, **remeshing**
   (:func:`geofit.ops.remesh`) towards a per-vertex edge length set by the error: an edge whose
   midpoint lies ``d`` from the target asks for the length ``l sqrt(eps / d)`` (the error of
   linear interpolation grows as ``l^2``), clipped to ``[l / 2, 3 l / 2]``, and each vertex takes
   the smallest of its edges'. Refinement stops once the accuracy is met.
   A **point-cloud** target (a ``(k, 3)`` array, a geofit, trimesh or Open3D point cloud)
   starts instead from a screened Poisson reconstruction of the points, trimmed and decimated
   (:func:`geofit.fit._cloud.mesh_from_points`, ``init="points"``), and is fitted with the
   point-to-plane distance to the cloud plus the exact distance from the points to the mesh
   (``MeshObjective(distance="cloud")``); the edge errors that drive the remeshing are
   point-to-plane distances too. The scan is first measured
   (:func:`geofit.fit._scan_report.scan_report`: spacing, noise, strays, reported in
   ``fit.data_report`` and the message); the strays are left out of the start and the fit, the
   accuracy targets are relaxed to the noise floor, edges are not refined for residuals within
   the noise a face's points leave, the normal-consistency weight follows the noise
   (``NOISE_NORMAL_WEIGHT * noise^2``, the recipe's 1e-5 on clean scans), and the model never
   has more faces than the scan has points (:func:`geofit.fit._scan_report.evidence_limits`).
   Each round fits 12 samples a side per vertex, the refined rounds of a precise scan 8 to 12
   (:func:`cloud_samples_per_vert`; at most the points and :data:`CLOUD_MAX_SAMPLES`); the
   refinement also stops when a round lowered the residual by less than :data:`NOISE_STALL`
   noise levels, and before a mesh of more vertices than :data:`CLOUD_MAX_SAMPLES` fit.
   No surface is kept where the scan has no point: the start is trimmed to the points, the
   distance past the cloud's boundary pulls surface back, and at the end the surface over
   the scan's holes (gaps wider than the sampling explains) is removed
   (:func:`geofit.fit._cloud.trim_to_evidence`), so the holes of a one-sided scan stay holes
   and a closed, well-sampled scan stays closed; the boundary left (the scan's rims, its
   holes' edges) is then placed where the points' evidence ends, 2.5 clean spacings past the
   last points whatever the noise (:func:`geofit.fit._cloud.place_boundary`,
   :func:`~geofit.fit._cloud.boundary_distance`).
   ``MeshFitOptions(watertight=True)`` closes them instead: the untrimmed Poisson start, and no
   data term where there is no point.
3. The result reports the initialisation, the vertex count and the
   :class:`~geofit.ops.TopologyReport` of the fitted mesh; a self-intersecting result says so
   in its message.

The gradients are those of :class:`~geofit.fit.MeshObjective` (tested there, the cloud mode
included); this module adds no new gradient.
"""
from __future__ import annotations

import math

import numpy as np

from .._validate import as_rng
from ..loss.chamfer import morton_order
from ..ops import remesh, topology
from ..structures import Mesh
from ._cloud import CloudTarget, mesh_from_points, place_boundary, trim_to_evidence
from ._mesh_objective import MeshObjective
from ._mesh_plan import MeshFitResult, MeshTarget, Plan, empty_row_terms, repair_degenerate
from ._progress import advance, progress_bar
from ._scan_report import evidence_limits, scan_report
from .history import Clock, FitHistory, budget_status
from .init import InitialMesh, initial_mesh
from .large_steps import LargeSteps
from .solvers import lbfgs_scipy

__all__ = ["cloud_samples_per_vert", "refine_lengths", "solve_remeshing", "start_points"]


def refine_lengths(mesh: Mesh, edge_error: np.ndarray, eps: float, *, lo: float = 0.5,
                   hi: float = 1.5) -> np.ndarray:
    """Per-vertex target edge lengths from the error at the edges' midpoints.

    Parameters
    ----------
    mesh : Mesh
        The current mesh.
    edge_error : (E,) float64
        Distance of each edge's midpoint (``mesh.edges`` order) to the target surface.
    eps : float
        Error to aim for (> 0).
    lo, hi : float
        Bounds of the length change per round, as factors of the current length.

    Returns
    -------
    (V,) float64
        ``min`` over each vertex's edges of ``l_e clip(sqrt(eps / d_e), lo, hi)``.

    Examples
    --------
    >>> from geofit import ico_sphere
    >>> m = ico_sphere(1)
    >>> small = refine_lengths(m, np.full(len(m.edges), 1e-9), 1e-4)  # error far below eps
    >>> bool(small.min() >= 1.5 * m.edge_lengths.min() - 1e-12)  # lengths grow by up to 1.5
    True
    """
    E = mesh.edges
    le = mesh.edge_lengths
    f = np.clip(np.sqrt(eps / np.maximum(edge_error, 1e-30)), lo, hi)
    want = le * f
    lv = np.full(mesh.n_verts, np.inf)
    np.minimum.at(lv, E[:, 0], want)
    np.minimum.at(lv, E[:, 1], want)
    lv[~np.isfinite(lv)] = float(le.mean())
    return lv


#: Samples a side per vertex of the first round of a point-cloud fit, and of the later rounds
#: of a noisy scan; the later rounds of a precise scan take fewer, at least
#: ``CLOUD_MIN_SAMPLES_PER_VERT`` (see :func:`cloud_samples_per_vert`). A noisy scan fitted
#: with 4 samples a vertex fits the noise: on 50,000 points of Suzanne (noise 0.005) the round
#: at 2,300 vertices gave chamfer-L2 4.1e-5 with 8,000 samples, 3.0e-5 with 12 a vertex
#: (27,600), 3.4e-5 with 8 a vertex (true surface; Poisson at the same size 3.4e-5); the first
#: round (1,000 vertices) 6.8e-5 with 4,000 samples, 5.6e-5 with 12,000 (Poisson 7.8e-5).
CLOUD_SAMPLES_PER_VERT = 12
CLOUD_MIN_SAMPLES_PER_VERT = 8
#: Most samples a side of a round (at most the scan's points, too). A point-cloud fit refines
#: to at most what they fit, ``CLOUD_MAX_SAMPLES // samples per vertex`` vertices (1,666 at 12
#: a vertex, 2,500 at 8): past it, a round either fits the noise or costs more than 10 s on
#: 2 cores (the round at 2,300 vertices with 27,000 samples took ~10 CPU s on 100,000 points,
#: measured under load 12-15, as much as all the rest).
CLOUD_MAX_SAMPLES = 20_000
#: Share of the accuracy goal (``Remeshing.chamfer_l2``) that the noise of a round's samples
#: may add (:func:`cloud_samples_per_vert`).
SAMPLE_NOISE_SHARE = 0.1

#: A point-cloud fit stops refining when a round lowered the residual (the estimated
#: chamfer-L2's root mean square a side, ``sqrt(chamfer / 2)``) by less than this many noise
#: levels: more faces no longer bring the surface nearer the points than their noise.
NOISE_STALL = 0.1

#: A scan's fit stops refining at its noise floor, not at the unit-box goal: the rounds go on
#: until the estimated chamfer-L2 to the points is at most ``2.5 sigma^2`` (their noise's own
#: ``2 sigma^2`` plus a model residual of half the noise a side,
#: :func:`geofit.fit._scan_report.evidence_limits`), or at most this share of
#: ``Remeshing.chamfer_l2`` where the noise is lower still. The unit-box goal itself (3e-5)
#: stopped a precise scan after its first round: on 50,000 points of the teapot at noise 0.002
#: the first round's estimate fell just under or just over 3e-5 depending on the process's
#: Poisson start (a model residual of 1.5 noise levels; stopped there: chamfer-L2 2.65e-5, F
#: 0.974 against 0.978 for Poisson at the same size), and the second round's 1.5e-5 won.
CLOUD_GOAL_SHARE = 0.1


def cloud_samples_per_vert(noise: float, chamfer_l2: float) -> int:
    """Samples a side per vertex of the refined rounds of a point-cloud fit (the first round
    takes :data:`CLOUD_SAMPLES_PER_VERT`).

    A vertex fitted to ``s`` samples of a scan of noise ``sigma`` is off by about
    ``sigma / sqrt(s)``, which adds about ``2 sigma^2 / s`` to the chamfer-L2 (both sides; the
    Suzanne rounds of :data:`CLOUD_SAMPLES_PER_VERT`: 1.1e-5 from 12 to 3.5 a vertex at
    ``sigma`` 0.005, against 1.0e-5 predicted). That is kept under :data:`SAMPLE_NOISE_SHARE`
    of the goal ``chamfer_l2``: ``s = ceil(2 sigma^2 / (SAMPLE_NOISE_SHARE chamfer_l2))``,
    within [:data:`CLOUD_MIN_SAMPLES_PER_VERT`, :data:`CLOUD_SAMPLES_PER_VERT`] (the default
    goal 3e-5: 12 from a measured noise of 0.0042, 8 below 0.0035). A precise scan's refined
    rounds need fewer samples a vertex, so the same samples fit more vertices. The first
    round's fit starts from the Poisson start, whose error (not the noise) is what its samples
    average: it takes 12 a vertex even on clean scans (on 50,000 points of the teapot, noise
    0.002, one round: chamfer-L2 1.5e-5 with 12 a vertex, 1.8e-5 with 8, 2.1e-5 with 4).

    Parameters
    ----------
    noise : float
        The scan's noise (normalised frame).
    chamfer_l2 : float
        The accuracy goal (normalised frame, > 0).

    Returns
    -------
    int

    Examples
    --------
    >>> cloud_samples_per_vert(0.0, 3e-5), cloud_samples_per_vert(0.01, 3e-5)
    (8, 12)
    """
    s = math.ceil(2.0 * noise * noise / (SAMPLE_NOISE_SHARE * chamfer_l2))
    return int(min(max(s, CLOUD_MIN_SAMPLES_PER_VERT), CLOUD_SAMPLES_PER_VERT))


def _round_samples(n_verts: int, n_points: int | None,
                   per_vert: int = CLOUD_SAMPLES_PER_VERT) -> int:
    """Samples a side of one round: a mesh target ``min(8000, max(2000, 4 V))``; a point
    cloud of ``n_points`` points ``min(n_points, CLOUD_MAX_SAMPLES, max(2000, per_vert V))``."""
    if n_points is None:
        return min(8000, max(2000, 4 * n_verts))
    return min(n_points, CLOUD_MAX_SAMPLES, max(2000, per_vert * n_verts))


def _residual_gain(stages: list[dict], noise: float) -> float:
    """How much the last round lowered the residual, in units of the noise ``noise``:
    ``(sqrt(c_prev / 2) - sqrt(c_last / 2)) / noise`` with ``c`` the rounds' estimated
    chamfer-L2 (the root mean square distance a side)."""
    a, b = (math.sqrt(st["estimate"]["chamfer_l2"] / 2.0) for st in stages[-2:])
    return (a - b) / noise


#: Points of a scan's Poisson start: at least this many (the scan's, if fewer) ...
START_MIN_POINTS = 20_000
#: ... and at most this many ...
START_MAX_POINTS = 50_000
#: ... as many as keep the spacing of those used at least this many noise levels, so that the
#: start's 12-neighbour normals see the surface, not the noise (:func:`start_points`).
START_SPACING_NOISE = 3.0


def start_points(n_points: int, spacing: float, noise: float) -> int:
    """How many of a scan's points its Poisson start uses.

    ``n`` points drawn from ``n_points`` of spacing ``spacing`` have a spacing of about
    ``spacing sqrt(n_points / n)``; the start uses as many as keep it at least
    :data:`START_SPACING_NOISE` noise levels, ``n_points (spacing / (3 noise))^2``, within
    [:data:`START_MIN_POINTS`, :data:`START_MAX_POINTS`] (and at most ``n_points``). A noisy
    dense scan keeps about the 20,000-point subsample it had (100,000 points at noise 0.005,
    measured spacing 0.0063 and noise 0.0044: 22,778; 50,000: 20,000; all 100,000 gave
    mis-oriented normals and starts of genus 1-20 for the genus-0 fandisk); a precise one
    uses more: the 50,000-point scans at noise 0.002 of the scans grid 23,000 (ogre) to
    50,000 (torus, open cylinder). Suzanne's (34,930 points) fit: chamfer-L2 1.93e-5-1.95e-5,
    F@0.01 0.980-0.981 in three processes from 20,000 points -> 1.42e-5, 0.987 (Poisson at the
    same size 2.0e-5, 0.981; all 50,000 points: 1.25e-5, 0.990): the 20,000-point start left
    one ear off the surface.

    Parameters
    ----------
    n_points : int
        The scan's points (inliers).
    spacing, noise : float
        Their spacing and noise (the same frame).

    Returns
    -------
    int

    Examples
    --------
    >>> start_points(100_000, 0.0063, 0.0044), start_points(50_000, 0.0064, 0.002)
    (22778, 50000)
    """
    n = n_points * (spacing / (START_SPACING_NOISE * max(noise, 1e-12))) ** 2
    return int(min(n_points, START_MAX_POINTS, max(START_MIN_POINTS, n)))


def _start(plan: Plan, target: MeshTarget, p2s, rng, n_faces: int,
           noise: float = 0.0) -> InitialMesh:
    """The initial mesh: from the data (decimated target, or the cloud's Poisson
    reconstruction of :func:`start_points` of its points, ``noise`` the scan's), an
    ico-sphere, or the user's mesh."""
    init = plan.init
    if init is None:
        init = "auto"
    if not target.cloud:
        return initial_mesh(init, target.normalized, n_faces=n_faces)
    if isinstance(init, str) and init in ("auto", "target"):
        m0 = mesh_from_points(p2s, n_faces=n_faces, seed=rng, trim=not plan.watertight,
                              n_max=start_points(len(p2s.points), p2s.spacing, noise))
        return InitialMesh(m0, "points", f"Poisson reconstruction of the "
                                         f"{len(p2s.points)} points, "
                                         f"{'closed' if plan.watertight else 'trimmed'} and "
                                         f"decimated to {m0.n_faces} faces ({m0.n_verts} "
                                         "vertices, Open3D)")
    return initial_mesh(init, None, n_faces=n_faces)


def solve_remeshing(plan: Plan, target: MeshTarget, *, seed, callback,
                    progress: bool) -> MeshFitResult:
    """Rounds of solve, accuracy estimate and remeshing (see the module's docstring).

    Checkpoints (the evaluator's metrics, clock paused) follow the initial mesh and each round,
    and every ``plan.eval_every`` evaluations when set.
    """
    rem = plan.refine
    time_budget, evaluator, w = plan.time_budget, plan.evaluator, plan.weights[0]
    rng = as_rng(seed)
    clock = Clock(time_budget)  # the budget counts all of it but the caller's evaluator/callback
    history = FitHistory()
    cloud = target.cloud
    tgt = target.normalized
    report = limits = None
    chamfer_goal, fscore_goal, max_verts = rem.chamfer_l2, rem.fscore, rem.max_verts
    n_faces = rem.n_faces
    per_vert = refined_per_vert = CLOUD_SAMPLES_PER_VERT  # the first round's, the others'
    if cloud:  # what the scan supports: outliers out, targets at the noise floor
        # the points in Z-order: every KD-tree over them, and every query by them, then reads
        # memory in order (100,000 points' 17 neighbours: 1.32 -> 0.26-0.37 CPU s under load 9)
        tgt = tgt[morton_order(tgt)]
        report, keep = scan_report(tgt)
        if report.n_outliers:
            tgt = tgt[keep]
        p2s = CloudTarget(tgt)
        # how far from its points the scan is evidence of a surface
        reach = 3.0 * (p2s.spacing + report.noise)
        if plan.watertight:
            p2s.reach = reach
        limits = evidence_limits(report, CLOUD_GOAL_SHARE * rem.chamfer_l2, rem.fscore,
                                 rem.tau)
        chamfer_goal, fscore_goal = limits.chamfer_l2, limits.fscore
        refined_per_vert = cloud_samples_per_vert(limits.noise, rem.chamfer_l2)
        max_verts = min(max_verts, max(limits.max_faces // 2, 4))
        n_faces = min(n_faces, limits.max_faces)
        if not plan.weights_given:  # smoothing where the scan is noisy, none where clean
            w = limits.weights(w)
    else:
        p2s = target.distance()
    start = _start(plan, target, p2s, rng, n_faces, 0.0 if limits is None else limits.noise)
    mesh, n_bad, n_moved = repair_degenerate(start.mesh)  # a given start may have them
    lam = plan.lam
    if lam is None:
        lam = 2.0 if start.name in ("target", "points") else 10.0
    history.note(0, clock.elapsed(), f"initial mesh: {start.description}", init=start.name,
                 n_verts=mesh.n_verts)
    if n_bad:
        history.note(0, clock.elapsed(), f"repaired {n_bad} zero-area faces of the initial "
                     f"mesh ({n_moved} vertices moved)", n_degenerate=n_bad, n_moved=n_moved)
    metrics = None
    last_ckpt = 0

    def checkpoint(m: Mesh, step: int) -> None:
        """Evaluator metrics of ``m`` (normalised frame) as a history row, clock paused."""
        nonlocal metrics, last_ckpt
        if evaluator is None:
            return
        with clock.paused(caller=not plan.own_evaluator):
            metrics = evaluator.evaluate(m.update_verts(target.undo(m.verts)))
        last_ckpt = step
        history.checkpoint(step, clock.elapsed(), dict(metrics.as_dict(), n_verts=m.n_verts))

    bar = progress_bar(progress, rem.max_rounds * plan.n_iter, "fit_mesh[default]")
    t_ckpt = clock.budget_elapsed()
    checkpoint(mesh, 0)
    # with a time budget, the solves leave the time of the final checkpoint and report (the
    # first checkpoint's, timed here) inside it
    reserve = clock.budget_elapsed() - t_ckpt
    stages: list[dict] = []
    evals = iters = 0
    status, message = "max_iter", ""
    for rnd in range(rem.max_rounds):  # solve-and-remesh rounds
        if clock.remaining() <= reserve:
            status, message = "time_budget", budget_status(time_budget, iters)
            break
        ls = LargeSteps(mesh, lam)
        ns = _round_samples(mesh.n_verts, len(tgt) if cloud else None, per_vert)
        obj = MeshObjective(mesh, tgt, w, distance="cloud" if cloud else "surface",
                            n_samples=ns, large_steps=ls, seed=rng, target_distance=p2s)
        base = evals

        def cb(info, _obj=obj, _base=base, _rnd=rnd):
            nonlocal iters
            iters += 1
            step = _base + info.n_evaluations
            history.record(step, clock.elapsed(), info.value, _obj.last_terms,
                           n_params=_obj.n_params, stage=_rnd)
            advance(bar, clock)
            if plan.eval_every is not None and step - last_ckpt >= plan.eval_every:
                with clock.paused():
                    m = _obj.source.update_verts(_obj.verts_from_params(info.x))
                checkpoint(m, step)
            if callback is not None:
                with clock.paused(caller=True):
                    if callback(info):
                        return True
            return None

        remaining = None  # what is left after building the objective
        if time_budget is not None:
            remaining = max(clock.remaining() - reserve, 1e-6)
        with clock.until(None if time_budget is None else time_budget - reserve):
            res = lbfgs_scipy(obj, obj.params_from_verts(mesh.verts), max_iter=plan.n_iter,
                              time_budget=remaining, callback=cb, clock=clock)
        evals += res.n_evaluations
        mesh = mesh.update_verts(obj.verts_from_params(res.x))
        if last_ckpt != evals:
            checkpoint(mesh, evals)
        est = obj.estimate_accuracy(mesh.verts, tau=rem.tau)
        stage = {"stage": rnd, "n_verts": mesh.n_verts, "status": res.status,
                 "message": res.message, "n_iterations": res.n_iterations,
                 "n_evaluations": res.n_evaluations, "seconds": res.seconds,
                 "n_samples": ns, "large_steps": lam, "weights": dict(w), "estimate": est,
                 "goal": {"chamfer_l2": chamfer_goal, "fscore": fscore_goal}}
        stages.append(stage)
        status, message = res.status, res.message
        history.note(evals, clock.elapsed(),
                     f"round {rnd}: estimated chamfer-L2 {est['chamfer_l2']:.3g}, "
                     f"F@{rem.tau:g} {est['fscore']:.4f} with {mesh.n_verts} vertices", **est)
        if res.status in ("nonfinite", "diverged", "failed", "time_budget", "callback"):
            break
        if est["chamfer_l2"] <= chamfer_goal and est["fscore"] >= fscore_goal:
            message = (f"accuracy reached with {mesh.n_verts} vertices after {rnd + 1} rounds; "
                       f"{message}")
            break
        gain = None if limits is None or rnd == 0 else _residual_gain(stages, limits.noise)
        if gain is not None and gain < NOISE_STALL:
            message = (f"stopped at {mesh.n_verts} vertices after {rnd + 1} rounds (the last "
                       f"refinement lowered the residual by {gain:.2f} noise levels: it is at "
                       f"the noise level); {message}")
            break
        if rnd == rem.max_rounds - 1 or mesh.n_verts >= max_verts:
            message = (f"stopped at {mesh.n_verts} vertices after {rnd + 1} rounds "
                       f"({'max_rounds' if rnd == rem.max_rounds - 1 else 'max_verts'}); "
                       f"{message}")
            break
        if clock.remaining() <= reserve:  # no time for another remesh and solve
            status, message = "time_budget", budget_status(time_budget, iters)
            break
        # remesh towards lengths set by the error at the edge midpoints
        E = mesh.edges
        mid = 0.5 * (mesh.verts[E[:, 0]] + mesh.verts[E[:, 1]])
        err = p2s.distances(mid) if cloud else p2s.query(mid).distances
        eps = 0.25 * math.sqrt(rem.chamfer_l2 / 2.0)
        if limits is not None:  # do not refine for residuals at the noise level
            eps = max(eps, limits.eps_floor(mesh.n_faces))
        lv = refine_lengths(mesh, err, eps)
        r = remesh(mesh, lv, n_passes=2)
        if limits is not None and r.mesh.n_faces > limits.max_faces:
            message = (f"stopped at {mesh.n_verts} vertices after {rnd + 1} rounds (refining "
                       f"would give {r.mesh.n_faces} faces, more than the "
                       f"{limits.max_faces} points); {message}")
            break
        per_vert = refined_per_vert
        if cloud and r.mesh.n_verts > CLOUD_MAX_SAMPLES // per_vert:
            message = (f"stopped at {mesh.n_verts} vertices after {rnd + 1} rounds (refining "
                       f"would give {r.mesh.n_verts} vertices, more than a round's "
                       f"{CLOUD_MAX_SAMPLES} samples fit at {per_vert} a vertex); {message}")
            break
        stage["remesh"] = {"n_split": r.n_split, "n_collapse": r.n_collapse, "n_flip": r.n_flip,
                           "n_verts": r.mesh.n_verts}
        history.note(evals, clock.elapsed(),
                     f"remeshed: {r.n_split} splits, {r.n_collapse} collapses, {r.n_flip} flips "
                     f"-> {r.mesh.n_verts} vertices", n_verts=r.mesh.n_verts)
        mesh = r.mesh
    bar.close()
    if cloud and not plan.watertight:  # no surface where the scan has no point
        trim = trim_to_evidence(mesh, p2s, report.noise)
        mesh = trim.mesh
        if trim.n_removed:
            history.note(evals, clock.elapsed(), trim.describe(), n_trimmed=trim.n_removed)
        placed = place_boundary(mesh, p2s, report.noise)  # where the evidence ends
        mesh = placed.mesh
        if placed.n_boundary:
            history.note(evals, clock.elapsed(), placed.describe(), n_boundary=placed.n_boundary)
    with clock.paused():  # not solver time; counted by the budget (its reserve)
        topo = topology(mesh)
    if not len(history):
        history.record(evals, clock.elapsed(), math.inf, empty_row_terms(),
                       n_params=3 * mesh.n_verts)
    message = f"{message}; init: {start.description}; result: {topo.describe()}"
    if report is not None:
        report = report.scaled(target.scale)
        message += f"; {report.describe()}"
    if topo.n_self_intersecting_pairs > 0:
        message += " (the fitted surface self-intersects)"
    return MeshFitResult(
        status=status, message=message, history=history, n_params=3 * mesh.n_verts,
        seconds=clock.elapsed(), cpu_seconds=clock.cpu_elapsed(), wall_seconds=clock.wall(),
        total_cpu_seconds=clock.cpu_total(), n_iterations=iters,
        n_evaluations=evals, mesh=mesh.update_verts(target.undo(mesh.verts)),
        mesh_normalized=mesh, center=np.array(target.center, dtype=np.float64),
        scale=target.scale, method=plan.method, recipe=plan.recipe, metrics=metrics,
        stages=stages, init=start.name, topology=topo, data_report=report)
