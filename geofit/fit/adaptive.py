"""Mesh-to-mesh fit that starts from the data's topology and remeshes where the error is.

:func:`fit_mesh_adaptive` (tutorial 1 for any shape):

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
   point-to-plane distances too.
3. The result reports the initialisation, the vertex count and the
   :class:`~geofit.ops.TopologyReport` of the fitted mesh; a self-intersecting result says so
   in its message.

The gradients are those of :class:`~geofit.fit.MeshObjective` (tested there, the cloud mode
included); this module adds no new gradient.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validate import as_rng, check_positive
from ..structures import Mesh
from .history import Clock, FitHistory
from ._mesh_objective import MeshObjective, mesh_weights
from ._options import check_int
from .large_steps import LargeSteps
from .mesh import MeshFitResult, _as_mesh, _repair_degenerate
from .solvers import lbfgs_scipy

__all__ = ["ADAPTIVE_WEIGHTS", "AdaptiveMeshFitResult", "fit_mesh_adaptive", "refine_lengths"]

#: Weights of the adaptive fit: the exact two-way distance, and a light normal-consistency term.
#: Starting on the target's own surface there is little for the smoothing terms to do, and the
#: edge-length term (mean squared edge length) would shrink the surface; the large-steps
#: parameterisation keeps the steps smooth.
ADAPTIVE_WEIGHTS = {"chamfer": 1.0, "edge": 0.0, "normal": 1e-5, "laplacian": 0.0}


@dataclass(kw_only=True)
class AdaptiveMeshFitResult(MeshFitResult):
    """Result of :func:`fit_mesh_adaptive` (a :class:`~geofit.fit.MeshFitResult`).

    Attributes
    ----------
    init : str
        The initialisation used: ``"target"`` (decimated target), ``"points"`` (Poisson
        reconstruction of a point-cloud target), ``"sphere"`` or ``"user"``.
    topology : geofit.ops.TopologyReport
        Topology of the fitted mesh (genus, boundary loops, parts, non-manifold edges,
        self-intersecting face pairs).
    """

    init: str = ""
    topology: Any = None

    def summary(self) -> dict[str, Any]:
        d = super().summary()
        d["init"] = self.init
        if self.topology is not None:
            d["topology"] = self.topology.as_dict()
        return d


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


def fit_mesh_adaptive(target, *, init="auto", n_faces: int = 2000,
                      chamfer_l2: float = 3e-5, fscore: float = 0.97, tau: float = 0.01,
                      max_rounds: int = 4, max_verts: int = 30000, n_iter: int = 40,
                      large_steps: float | None = None, weights=None, time_budget: float | None = 10.0,
                      seed=0, evaluator="default") -> AdaptiveMeshFitResult:
    """Fit a mesh to ``target`` from an initial shape with its topology, remeshing as it goes.

    Parameters
    ----------
    target : Mesh, (verts, faces) or point cloud
        The surface to fit (any genus, open, several parts), or a point cloud: a (k, 3) float64
        array, a geofit ``PointCloud`` (or one-cloud ``Pointclouds``), a trimesh or Open3D point
        cloud, at least 20 points.
    init : {"auto", "sphere", "target"}, int or Mesh
        Initial mesh (:func:`geofit.fit.init.initial_mesh`); ``"auto"`` (or ``"target"``) is the
        decimated target, or for a point cloud the trimmed, decimated Poisson reconstruction of
        the points. A given Mesh is taken in the target's normalised frame.
    n_faces : int
        Face budget of the decimated target.
    chamfer_l2, fscore, tau : float
        Accuracy target (normalised frame, estimated on fresh samples): stop refining once the
        estimated chamfer-L2 is at most ``chamfer_l2`` and the F-score at ``tau`` at least
        ``fscore``.
    max_rounds : int
        Solve-and-remesh rounds at most.
    max_verts : int
        Do not refine past this many vertices.
    n_iter : int
        L-BFGS iterations per round.
    large_steps : float, optional
        ``lambda`` of the large-steps parameterisation. Default: 2 from the data's own shape
        (``init`` ``"target"`` or ``"points"``, already close), 10 from an ico-sphere or a
        given mesh, which travel far and need smoother steps (on the dolphin from a collapsed
        ``ico_sphere(4)``, F@0.01 0.87 with 10 against 0.18 with 2 in 10 s;
        ``benchmarks/fit_mesh.py``'s stability part).
    weights : dict, optional
        Term weights (default :data:`ADAPTIVE_WEIGHTS`).
    time_budget : float or None
        Seconds of solver time for the whole fit.
    seed : int or numpy.random.Generator
        Sampling randomness.
    evaluator : MeshEvaluator, "default" or None
        Accuracy checkpoints of the initial mesh and after each round (``"default"``: 20 000
        samples a side, F@0.01, normalised frame; each checkpoint also records ``n_verts``);
        their time is not counted. A point-cloud target has no surface to score against, so
        its ``"default"`` is None (pass a MeshEvaluator of the true surface when there is one).

    Returns
    -------
    AdaptiveMeshFitResult
        The fitted mesh (original and normalised frames), ``init``, ``topology``, ``stages``
        (one per round: vertices, solver status, accuracy estimate, remeshing counts).

    Raises
    ------
    ValueError, TypeError
        For invalid options or meshes.

    Examples
    --------
    >>> from geofit.shapes import torus
    >>> res = fit_mesh_adaptive(torus(), n_faces=500, max_rounds=1, n_iter=5, evaluator=None)
    >>> res.init, res.topology.genus
    ('target', 1)
    """
    from ..loss import PointToSurface
    from ..metrics import MeshEvaluator
    from ..ops import remesh, topology
    from ._cloud import CloudTarget, as_cloud_points, is_cloud, mesh_from_points
    from .init import InitialMesh, initial_mesh

    cloud = is_cloud(target)
    if cloud:
        points = as_cloud_points(target, "target")
        target_mesh = None
    else:
        target_mesh = _as_mesh(target, "target")
    n_faces = check_int(n_faces, "n_faces", 4)
    max_rounds = check_int(max_rounds, "max_rounds")
    max_verts = check_int(max_verts, "max_verts", 4)
    n_iter = check_int(n_iter, "n_iter")
    lam = None if large_steps is None else check_positive(large_steps, "large_steps")
    chamfer_l2 = check_positive(chamfer_l2, "chamfer_l2", strict=False)
    tau = check_positive(tau, "tau")
    if not 0.0 <= float(fscore) <= 1.0:
        raise ValueError(f"fscore: expected a number in [0, 1], got {fscore!r}")
    if time_budget is not None:
        time_budget = check_positive(time_budget, "time_budget")
    w = mesh_weights(weights if weights is not None else ADAPTIVE_WEIGHTS)
    if isinstance(evaluator, str):
        if evaluator != "default":
            raise ValueError(f"evaluator: expected a MeshEvaluator, 'default' or None, "
                             f"got {evaluator!r}")
        evaluator = None if cloud else MeshEvaluator(target_mesh, n_samples=20_000, taus=0.01,
                                                     normalize=True)

    rng = as_rng(seed)
    clock = Clock()
    history = FitHistory()
    if cloud:  # the same normalisation as Mesh.normalize, on the points
        center = points.mean(0)
        scale = float(np.abs(points - center).max())
        tgt = (points - center) / scale
        p2s = CloudTarget(tgt)
        if isinstance(init, str) and init in ("auto", "target"):
            m0 = mesh_from_points(p2s, n_faces=n_faces, seed=rng)
            start = InitialMesh(m0, "points", f"Poisson reconstruction of the {len(tgt)} points,"
                                f" trimmed and decimated to {m0.n_faces} faces "
                                f"({m0.n_verts} vertices, Open3D)")
        else:
            start = initial_mesh(init, None, n_faces=n_faces)
    else:
        norm = target_mesh.normalize()
        center, scale = norm.center, float(norm.scale)
        tgt = norm.mesh
        p2s = PointToSurface(tgt)
        start = initial_mesh(init, tgt, n_faces=n_faces)
    mesh, n_bad, n_moved = _repair_degenerate(start.mesh)  # a given start may have them
    if lam is None:
        lam = 2.0 if start.name in ("target", "points") else 10.0
    history.note(0, clock.elapsed(), f"initial mesh: {start.description}", init=start.name,
                 n_verts=mesh.n_verts)
    if n_bad:
        history.note(0, clock.elapsed(), f"repaired {n_bad} zero-area faces of the initial "
                     f"mesh ({n_moved} vertices moved)", n_degenerate=n_bad, n_moved=n_moved)
    metrics = None

    def checkpoint(m: Mesh, step: int) -> None:
        """Evaluator metrics of ``m`` (normalised frame) as a history row, clock paused."""
        nonlocal metrics
        if evaluator is None:
            return
        with clock.paused():
            metrics = evaluator.evaluate(m.update_verts(m.verts * scale + center))
        history.checkpoint(step, clock.elapsed(), dict(metrics.as_dict(), n_verts=m.n_verts))

    checkpoint(mesh, 0)
    stages: list[dict] = []
    evals = iters = 0
    status, message = "max_iter", ""
    for rnd in range(max_rounds):  # solve-and-remesh rounds
        remaining = None if time_budget is None else time_budget - clock.elapsed()
        if remaining is not None and remaining <= 0:
            status, message = "time_budget", f"time budget {time_budget:g} s used up"
            break
        ls = LargeSteps(mesh, lam)
        ns = min(8000, max(2000, 4 * mesh.n_verts))
        obj = MeshObjective(mesh, tgt, w, distance="cloud" if cloud else "surface",
                            n_samples=ns, large_steps=ls, seed=rng, target_distance=p2s)
        base = evals

        def cb(info, _obj=obj, _base=base, _rnd=rnd):
            nonlocal iters
            iters += 1
            history.record(_base + info.n_evaluations, clock.elapsed(), info.value,
                           _obj.last_terms, n_params=_obj.n_params, stage=_rnd)

        if time_budget is not None:  # what is left after building the objective
            remaining = max(time_budget - clock.elapsed(), 1e-6)
        res = lbfgs_scipy(obj, obj.params_from_verts(mesh.verts), max_iter=n_iter,
                          time_budget=remaining, callback=cb, clock=clock)
        evals += res.n_evaluations
        mesh = mesh.update_verts(obj.verts_from_params(res.x))
        checkpoint(mesh, evals)
        est = obj.estimate_accuracy(mesh.verts, tau=tau)
        stage = {"stage": rnd, "n_verts": mesh.n_verts, "status": res.status,
                 "message": res.message, "n_iterations": res.n_iterations,
                 "n_evaluations": res.n_evaluations, "seconds": res.seconds,
                 "n_samples": ns, "large_steps": lam, "weights": dict(w), "estimate": est}
        stages.append(stage)
        status, message = res.status, res.message
        history.note(evals, clock.elapsed(),
                     f"round {rnd}: estimated chamfer-L2 {est['chamfer_l2']:.3g}, "
                     f"F@{tau:g} {est['fscore']:.4f} with {mesh.n_verts} vertices", **est)
        if res.status in ("nonfinite", "diverged", "failed", "time_budget"):
            break
        if est["chamfer_l2"] <= chamfer_l2 and est["fscore"] >= fscore:
            message = f"accuracy reached with {mesh.n_verts} vertices; {message}"
            break
        if rnd == max_rounds - 1 or mesh.n_verts >= max_verts:
            message = (f"stopped at {mesh.n_verts} vertices "
                       f"({'max_rounds' if rnd == max_rounds - 1 else 'max_verts'}); {message}")
            break
        # remesh towards lengths set by the error at the edge midpoints
        E = mesh.edges
        mid = 0.5 * (mesh.verts[E[:, 0]] + mesh.verts[E[:, 1]])
        err = p2s.distances(mid) if cloud else p2s.query(mid).distances
        eps = 0.25 * math.sqrt(chamfer_l2 / 2.0)
        lv = refine_lengths(mesh, err, eps)
        r = remesh(mesh, lv, n_passes=2)
        stage["remesh"] = {"n_split": r.n_split, "n_collapse": r.n_collapse, "n_flip": r.n_flip,
                           "n_verts": r.mesh.n_verts}
        history.note(evals, clock.elapsed(),
                     f"remeshed: {r.n_split} splits, {r.n_collapse} collapses, {r.n_flip} flips "
                     f"-> {r.mesh.n_verts} vertices", n_verts=r.mesh.n_verts)
        mesh = r.mesh
    with clock.paused():
        topo = topology(mesh)
    if not len(history):
        history.record(evals, clock.elapsed(), math.inf, {k: math.inf for k in w},
                       n_params=3 * mesh.n_verts)
    message = f"init: {start.description}; {message}; result: {topo.describe()}"
    if topo.n_self_intersecting_pairs > 0:
        message += " (the fitted surface self-intersects)"
    return AdaptiveMeshFitResult(
        status=status, message=message, history=history, n_params=3 * mesh.n_verts,
        seconds=clock.elapsed(), cpu_seconds=clock.cpu_elapsed(), n_iterations=iters,
        n_evaluations=evals, mesh=mesh.update_verts(mesh.verts * scale + center),
        mesh_normalized=mesh, center=np.array(center, dtype=np.float64), scale=scale,
        method="adaptive", metrics=metrics, stages=stages, init=start.name, topology=topo)
