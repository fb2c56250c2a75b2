"""Deform a source mesh into a target surface (PyTorch3D's deform tutorial, and faster ways).

The objective is a weighted sum of a data term and three regularisers of the source vertices
``V`` (all in the target's normalised frame, see :meth:`geofit.Mesh.normalize`)::

    E(V) = w_chamfer * D(V) + w_edge * edge(V) + w_normal * normal(V) + w_laplacian * lap(V)

* ``edge``, ``normal``, ``lap``: :func:`geofit.loss.mesh_edge_loss`,
  :func:`~geofit.loss.mesh_normal_consistency`, :func:`~geofit.loss.mesh_laplacian_smoothing`
  (uniform), PyTorch3D's definitions.
* ``D`` with ``distance="points"``: PyTorch3D's ``chamfer_distance`` between ``n`` samples of the
  source, ``P = B V`` (``B`` the sparse sampling matrix of :func:`geofit.ops.sample_points_from_meshes`),
  and ``n`` samples ``Y`` of the target. ``dD/dV = B^T dD/dP``.
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
import scipy.sparse as sp

from .._validate import as_array, as_faces, as_rng, check_choice, check_positive
from ..structures import Mesh, as_mesh
from .history import Clock, FitHistory, FitResult
from .solvers import SolveResult, StepInfo, adam, lbfgs_nlopt, lbfgs_scipy, sgd

__all__ = [
    "FINE_WEIGHTS",
    "METHODS",
    "TUTORIAL_WEIGHTS",
    "CoarseToFine",
    "LargeSteps",
    "MeshFitResult",
    "MeshObjective",
    "fit_mesh",
]

#: Solvers :func:`fit_mesh` accepts.
METHODS = ("sgd", "adam", "scipy-lbfgs", "nlopt-lbfgs")

#: The tutorial's weights (chamfer 1, edge 1, normal consistency 0.01, Laplacian 0.1).
TUTORIAL_WEIGHTS = {"chamfer": 1.0, "edge": 1.0, "normal": 0.01, "laplacian": 0.1}

#: Lighter regularisation for the later, fine stages of the quasi-Newton fits: with exact
#: point-to-surface distances there is no sampling noise for the regularisers to smooth out.
FINE_WEIGHTS = {"chamfer": 1.0, "edge": 0.03, "normal": 0.003, "laplacian": 0.01}

#: Named settings of :func:`fit_mesh` used by the benchmark, the command line and the notebook:
#: ``fit_mesh(source, target, **RECIPES[name])``.
RECIPES: dict[str, dict] = {
    # the tutorial exactly: SGD lr 1.0 momentum 0.9, 2000 steps, 5000 fresh samples a side
    "tutorial": {"method": "sgd"},
    # the same stochastic objective with Adam
    "adam": {"method": "adam", "lr": 0.01},
    # quasi-Newton, deterministic stages, exact point-to-surface distances
    "scipy-lbfgs": {"method": "scipy-lbfgs", "large_steps": None},
    "nlopt-lbfgs": {"method": "nlopt-lbfgs", "large_steps": None},
    # the same with the large-steps parameterisation
    "large-steps": {"method": "scipy-lbfgs", "large_steps": 10.0},
    # ico 2 -> 3 -> 4, subdividing only while the accuracy asks for it
    "coarse-to-fine": {"method": "scipy-lbfgs", "large_steps": 10.0, "coarse_to_fine": True},
}

_TERMS = ("chamfer", "edge", "normal", "laplacian")
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


def _check_weights(w, name="weights") -> dict[str, float]:
    if not isinstance(w, Mapping):
        raise TypeError(f"{name}: expected a dict of term weights, got {type(w)!r}")
    unknown = set(w) - set(_TERMS)
    if unknown:
        raise ValueError(f"{name}: unknown terms {sorted(unknown)}; expected some of {_TERMS}")
    out = {k: check_positive(w.get(k, 0.0), f"{name}[{k!r}]", strict=False) for k in _TERMS}
    if out["chamfer"] == 0.0:
        raise ValueError(f"{name}: the data term 'chamfer' needs a weight > 0")
    return out


def _check_int(v, name: str, lo: int = 1) -> int:
    if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < lo:
        raise ValueError(f"{name}: expected an integer >= {lo}, got {v!r}")
    return int(v)


# ------------------------------------------------------------------------------------ large steps
class LargeSteps:
    """The large-steps reparameterisation ``u = (I + lambda L) V`` of Nicolet et al. (2021).

    Parameters
    ----------
    mesh : Mesh
        Its topology defines ``L = D - A``, the combinatorial Laplacian of the edge graph
        (``D`` the degrees, ``A`` the 0/1 adjacency).
    lam : float
        ``lambda > 0``; larger means smoother steps (19 in the paper's examples; 10 here by
        default in :func:`fit_mesh`).

    Notes
    -----
    ``M = I + lambda L`` is symmetric positive definite, factorised once with
    ``scipy.sparse.linalg.splu``. The map ``V -> u`` is linear with Jacobian ``M``
    (:attr:`matrix`), so ``dE/du = M^-T dE/dV = M^-1 dE/dV``.

    Examples
    --------
    >>> from geofit import ico_sphere
    >>> ls = LargeSteps(ico_sphere(2), 10.0)
    >>> V = ico_sphere(2).verts
    >>> bool(abs(ls.to_verts(ls.to_params(V)) - V).max() < 1e-12)
    True
    """

    def __init__(self, mesh: Mesh, lam: float):
        from scipy.sparse.linalg import splu

        mesh = as_mesh(mesh, "mesh")  # a geofit, trimesh or Open3D mesh
        self.lam = check_positive(lam, "large_steps")
        A = mesh.topology.adjacency.astype(np.float64)
        deg = np.asarray(A.sum(axis=1)).ravel()
        L = sp.diags(deg) - A
        self.matrix = (sp.identity(mesh.n_verts, format="csc") + self.lam * L).tocsc()
        self._lu = splu(self.matrix)
        self.n_verts = mesh.n_verts

    def to_params(self, verts: np.ndarray) -> np.ndarray:
        """(V, 3) vertices -> (V, 3) parameters ``u = M V``."""
        return np.asarray(self.matrix @ verts)

    def to_verts(self, u: np.ndarray) -> np.ndarray:
        """(V, 3) parameters -> (V, 3) vertices ``V = M^-1 u``."""
        return self._lu.solve(np.ascontiguousarray(u, dtype=np.float64))

    def grad_params(self, grad_verts: np.ndarray) -> np.ndarray:
        """(V, 3) ``dE/dV`` -> (V, 3) ``dE/du = M^-1 dE/dV`` (M is symmetric)."""
        return self._lu.solve(np.ascontiguousarray(grad_verts, dtype=np.float64))

    def __repr__(self) -> str:
        return f"LargeSteps(n_verts={self.n_verts}, lam={self.lam:g})"


# ------------------------------------------------------------------------------------ objective
class MeshObjective:
    """The fit objective as a function of a flat float64 vector: ``E(x) -> (value, grad)``.

    Parameters
    ----------
    source : Mesh
        The mesh being deformed (its faces are fixed; its vertices are the starting point).
    target : Mesh
        The target surface, in the frame the fit works in (normally normalised).
    weights : dict
        Weights of ``"chamfer"`` (the data term, whatever ``distance``), ``"edge"``,
        ``"normal"`` and ``"laplacian"``; missing terms weigh 0 and are not computed.
    distance : {"surface", "points"}
        Data term (see the module docstring).
    n_samples : int
        Samples drawn on each surface (per step or per stage).
    resample : {"stage", "step"}
        ``"step"``: fresh samples at every call (stochastic, the tutorial); ``"stage"``: samples
        fixed until :meth:`resample` is called (deterministic).
    large_steps : LargeSteps, optional
        When given, ``x`` holds the parameters ``u`` instead of the vertices.
    seed : int or numpy.random.Generator
        Sampling randomness.
    target_distance : geofit.loss.PointToSurface, optional
        A prebuilt closest-point structure of ``target`` to share between objectives.

    Attributes
    ----------
    last_terms : dict
        Unweighted values of all four terms at the last evaluation (the regularisers are
        computed even at weight 0, so every history has the same columns).
    n_evaluations : int
        Calls so far.
    """

    def __init__(self, source: Mesh, target: Mesh, weights: Mapping[str, float], *,
                 distance: str = "surface", n_samples: int = 5000, resample: str = "stage",
                 large_steps: LargeSteps | None = None, seed=0, target_distance=None):
        from ..loss import PointToSurface

        check_choice(distance, "distance", ("surface", "points"))
        check_choice(resample, "resample", ("stage", "step"))
        self.source = source
        self.target = target
        self.weights = _check_weights(weights)
        self.distance = distance
        self.n_samples = _check_int(n_samples, "n_samples")
        self.resample_mode = resample
        self.large_steps = large_steps
        self.rng = as_rng(seed)
        self.n_verts = source.n_verts
        if distance == "surface":
            self._p2s = target_distance if target_distance is not None else PointToSurface(target)
        else:
            self._p2s = None
        self.last_terms: dict[str, float] = {}
        self.n_evaluations = 0
        self._B = self._Y = self._target_cloud = None
        if resample == "stage":
            self.resample(source.verts)

    # -- parameters
    @property
    def n_params(self) -> int:
        return 3 * self.n_verts

    def params_from_verts(self, verts: np.ndarray) -> np.ndarray:
        """(V, 3) vertices -> (3V,) parameter vector."""
        v = np.asarray(verts, dtype=np.float64)
        if self.large_steps is not None:
            v = self.large_steps.to_params(v)
        return np.array(v, dtype=np.float64).ravel()  # a writable copy

    def verts_from_params(self, x: np.ndarray) -> np.ndarray:
        """(3V,) parameter vector -> (V, 3) vertices."""
        v = np.asarray(x, dtype=np.float64).reshape(self.n_verts, 3)
        if self.large_steps is not None:
            v = self.large_steps.to_verts(v)
        return v

    # -- sampling
    def resample(self, verts: np.ndarray | None = None) -> None:
        """Draw new fixed samples: source barycentrics on ``verts`` (area-weighted there) and
        target points (for ``resample="stage"``)."""
        from ..loss import ChamferTarget
        from ..ops import sample_points_from_meshes

        mesh = self.source if verts is None else self.source.update_verts(verts)
        self._B = sample_points_from_meshes(mesh, self.n_samples, seed=self.rng).B
        self._Y = sample_points_from_meshes(self.target, self.n_samples, seed=self.rng).points
        self._target_cloud = ChamferTarget(self._Y) if self.distance == "points" else None

    # -- evaluation
    def _data(self, mesh: Mesh, V: np.ndarray):
        from ..loss import chamfer_distance
        from ..ops import barycentric_matrix, sample_points_from_meshes
        from ..raycast import PointToMeshDistance

        if self.resample_mode == "step":
            B = sample_points_from_meshes(mesh, self.n_samples, seed=self.rng).B
            Y = sample_points_from_meshes(self.target, self.n_samples, seed=self.rng).points
            cloud = None
        else:
            B, Y, cloud = self._B, self._Y, self._target_cloud
        P = B @ V
        if self.distance == "points":
            if cloud is not None:
                value, gP = cloud.loss(P)
            else:
                r = chamfer_distance(P, Y)
                value, gP = r.loss, r.grad_x
            return float(value), B.T @ gP
        # exact point-to-surface: source samples -> target surface ...
        v_pt, gP = self._p2s.loss(P)
        grad = B.T @ gP
        # ... and target samples -> source surface (closest point C = Bc V, envelope theorem)
        c = PointToMeshDistance(mesh).query(Y)
        r = Y - c.points
        v_tp = float(np.einsum("ij,ij->", r, r)) / len(Y)
        Bc = barycentric_matrix(mesh.faces, c.face_ids, c.bary, mesh.n_verts)
        grad -= Bc.T @ ((2.0 / len(Y)) * r)
        return float(v_pt) + v_tp, grad

    def __call__(self, x: np.ndarray):
        """``(value, grad)`` at the (3V,) parameter vector ``x``.

        A non-finite ``x`` (a solver that blew up) gives ``(nan, zeros)``, which every geofit
        solver turns into the status ``"nonfinite"``.
        """
        from ..loss import mesh_edge_loss, mesh_laplacian_smoothing, mesh_normal_consistency

        self.n_evaluations += 1
        x = np.asarray(x, dtype=np.float64)
        V = self.verts_from_params(x) if np.all(np.isfinite(x)) else x
        if not np.all(np.isfinite(V)):
            self.last_terms = {k: math.nan for k in _TERMS}
            return math.nan, np.zeros_like(x)
        mesh = self.source.update_verts(V)
        w = self.weights
        d, grad = self._data(mesh, V)
        grad = w["chamfer"] * grad
        value = w["chamfer"] * d
        terms = {"chamfer": d}
        for name, fn in (("edge", mesh_edge_loss), ("normal", mesh_normal_consistency),
                         ("laplacian", lambda m: mesh_laplacian_smoothing(m, "uniform"))):
            t, g = fn(mesh)  # computed even at weight 0, so the history has every term
            terms[name] = float(t)
            if w[name] > 0:
                value += w[name] * t
                grad += w[name] * g
        self.last_terms = terms
        if self.large_steps is not None:
            grad = self.large_steps.grad_params(grad)
        return float(value), np.ascontiguousarray(grad).ravel()

    def estimate_accuracy(self, verts: np.ndarray, *, tau: float = 0.01,
                          seed=None) -> dict[str, float]:
        """Chamfer-L2 and F-score at ``tau`` of ``verts`` from *fresh* samples (n_samples a side).

        Exact point-to-surface distances both ways, as :mod:`geofit.metrics` does, but with
        ``n_samples`` instead of 100 000 points: an unbiased, cheap estimate used by
        coarse-to-fine to decide whether to subdivide.
        """
        from ..loss import PointToSurface
        from ..ops import sample_points_from_meshes
        from ..raycast import PointToMeshDistance

        rng = self.rng if seed is None else as_rng(seed)
        mesh = self.source.update_verts(verts)
        P = sample_points_from_meshes(mesh, self.n_samples, seed=rng).points
        Y = sample_points_from_meshes(self.target, self.n_samples, seed=rng).points
        p2s = self._p2s if self._p2s is not None else PointToSurface(self.target)
        d_pt = p2s.query(P).distances
        d_tp = PointToMeshDistance(mesh).query(Y).distances
        prec, rec = float(np.mean(d_pt < tau)), float(np.mean(d_tp < tau))
        f = 2 * prec * rec / (prec + rec) if prec + rec > 0 else 0.0
        return {"chamfer_l2": float(np.mean(d_pt ** 2) + np.mean(d_tp ** 2)), "fscore": f}


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
        self.start_level = _check_int(self.start_level, "start_level", 0)
        self.max_level = _check_int(self.max_level, "max_level", self.start_level)
        self.chamfer_l2 = check_positive(self.chamfer_l2, "chamfer_l2", strict=False)
        self.fscore = float(self.fscore)
        if not 0.0 <= self.fscore <= 1.0:
            raise ValueError(f"fscore: expected a number in [0, 1], got {self.fscore!r}")
        self.tau = check_positive(self.tau, "tau")
        if self.max_verts is not None:
            self.max_verts = _check_int(self.max_verts, "max_verts", 4)
        if self.coarse_weights is not None:
            self.coarse_weights = _check_weights(self.coarse_weights, "coarse_weights")
        if self.stall_window is not None:
            self.stall_window = _check_int(self.stall_window, "stall_window")
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
    method : str
        The solver.
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
    method: str = ""
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


def fit_mesh(source, target, *, method: str = "scipy-lbfgs",
             weights: Mapping[str, float] | Sequence[Mapping[str, float]] | None = None,
             distance: str | None = None, n_samples: int | None = None,
             n_iter: int | None = None,
             n_stages: int | None = None, lr: float | None = None, momentum: float = 0.9,
             large_steps: float | str | None = "auto",
             coarse_to_fine: CoarseToFine | bool | None = None,
             time_budget: float | None = None, seed=0, evaluator: Any = "default",
             checkpoint_every: int | None = None, progress: bool = True,
             callback: Callable[[StepInfo], bool | None] | None = None,
             solver_options: Mapping[str, Any] | None = None) -> MeshFitResult:
    """Deform ``source`` into ``target`` (PyTorch3D's deform tutorial, and faster solvers).

    Parameters
    ----------
    source : Mesh, (verts, faces), int or None
        Starting mesh, an ico-sphere level, or None: ``ico_sphere(4)`` (the tutorial's), or
        ``ico_sphere(coarse_to_fine.start_level)`` with coarse-to-fine. It is placed as given
        in the target's *normalised* frame (the unit ico-sphere, as in the tutorial).
    target : Mesh or (verts, faces)
        Target surface, any frame: the fit normalises it (centre on the vertex mean, divide by
        the largest absolute coordinate) and returns the result in the original frame.
    method : {"scipy-lbfgs", "nlopt-lbfgs", "sgd", "adam"}
        Solver. ``"sgd"`` reproduces the tutorial exactly by default (5000 fresh samples a side
        per step, point-to-point chamfer, weights 1 / 1 / 0.01 / 0.1, lr 1.0, momentum 0.9,
        2000 steps). ``"adam"`` uses the same stochastic objective. The L-BFGS solvers use
        deterministic stages (fixed samples, redrawn between stages).
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
    >>> res = fit_mesh(1, target, n_samples=500, n_stages=1, evaluator=None, progress=False)
    >>> res.status in ("converged", "max_iter"), res.n_verts, bool(res.mesh.verts.max() > 1.5)
    (True, 42, True)
    """
    from ..loss import PointToSurface
    from ..metrics import MeshEvaluator
    from ..shapes import ico_sphere, subdivide

    # ---- validate once
    check_choice(method, "method", METHODS)
    stochastic = method in _STOCHASTIC
    if coarse_to_fine is True:
        coarse_to_fine = CoarseToFine()
    elif coarse_to_fine is False:
        coarse_to_fine = None
    elif coarse_to_fine is not None and not isinstance(coarse_to_fine, CoarseToFine):
        raise TypeError(f"coarse_to_fine: expected a CoarseToFine, bool or None, "
                        f"got {type(coarse_to_fine)!r}")
    c2f = coarse_to_fine
    if c2f is not None and stochastic:
        raise ValueError(f"coarse_to_fine: needs a deterministic method (scipy-lbfgs or "
                         f"nlopt-lbfgs), got method={method!r}")
    target_mesh = _as_mesh(target, "target")
    if source is None:
        source = ico_sphere(c2f.start_level if c2f is not None else 4)
    elif isinstance(source, (int, np.integer)) and not isinstance(source, bool):
        source = ico_sphere(int(source))
    source = _as_mesh(source, "source")
    source, n_degenerate, n_moved = _repair_degenerate(source)
    distance = distance or ("points" if stochastic else "surface")
    check_choice(distance, "distance", ("surface", "points"))
    if n_samples is not None:
        n_samples = _check_int(n_samples, "n_samples")
    n_iter = _check_int(n_iter if n_iter is not None else (2000 if stochastic else 100), "n_iter")
    default_stages = 1 if stochastic or c2f is not None else 3
    n_stages = _check_int(n_stages if n_stages is not None else default_stages, "n_stages")
    if stochastic and n_stages != 1:
        raise ValueError("n_stages: SGD/Adam redraw samples at every step; expected 1")
    if weights is None:
        weights = [TUTORIAL_WEIGHTS] if stochastic else [TUTORIAL_WEIGHTS, FINE_WEIGHTS]
    elif isinstance(weights, Mapping):
        weights = [weights]
    weights = [_check_weights(w, f"weights[{i}]") for i, w in enumerate(weights)]
    if not weights:
        raise ValueError("weights: expected at least one dict of weights")
    lr = check_positive(lr if lr is not None else (1.0 if method == "sgd" else 0.01), "lr")
    if time_budget is not None:
        time_budget = check_positive(time_budget, "time_budget")
    if isinstance(large_steps, str):
        check_choice(large_steps, "large_steps", ("auto",))
        large_steps = None if stochastic else 10.0
    lam = check_positive(large_steps, "large_steps") if large_steps is not None else None
    if checkpoint_every is not None:
        checkpoint_every = _check_int(checkpoint_every, "checkpoint_every")
    elif stochastic:
        checkpoint_every = 200
    if isinstance(evaluator, str):
        check_choice(evaluator, "evaluator", ("default",))
        evaluator = MeshEvaluator(target_mesh, n_samples=20_000, taus=0.01, normalize=True)
    elif evaluator is not None and not callable(getattr(evaluator, "evaluate", None)):
        raise TypeError(f"evaluator: expected a MeshEvaluator, 'default' or None, "
                        f"got {type(evaluator)!r}")
    opts = dict(solver_options or {})

    # ---- set up (the fit works in the target's normalised frame)
    norm = target_mesh.normalize()
    tgt = norm.mesh
    rng = as_rng(seed)
    p2s = PointToSurface(tgt) if distance == "surface" or c2f is not None else None
    clock = Clock()
    history = FitHistory()
    stages: list[dict] = []
    run = _Run(clock, history, evaluator, norm, checkpoint_every, callback)
    n_levels = c2f.max_level - c2f.start_level + 1 if c2f is not None else 1
    run.bar = _progress(progress, n_iter * n_stages * n_levels, f"fit_mesh[{method}]")

    if n_degenerate:
        history.note(0, 0.0, f"source: {n_degenerate} zero-area triangles; moved {n_moved} "
                             "vertices to their neighbours' centroid before fitting",
                     n_degenerate=n_degenerate, n_moved=n_moved)
    mesh = source
    status, message = "max_iter", ""
    level = 0
    done = False
    while not done:  # coarse-to-fine levels (a single pass without coarse-to-fine)
        ls = LargeSteps(mesh, lam) if lam is not None else None
        for s in range(n_stages):  # stages: sample redraws
            if c2f is not None:
                w = (c2f.coarse_weights if level == 0 and c2f.coarse_weights is not None
                     else weights[-1])
            else:
                w = weights[min(s, len(weights) - 1)]
            if time_budget is not None and clock.elapsed() >= time_budget:
                status, message = "time_budget", f"time budget {time_budget:g} s used up"
                done = True
                break
            ns = n_samples or (5000 if stochastic else min(5000, max(1000, 8 * mesh.n_verts)))
            obj = MeshObjective(mesh, tgt, w, distance=distance, n_samples=ns,
                                resample="step" if stochastic else "stage", large_steps=ls,
                                seed=rng, target_distance=p2s)
            remaining = None if time_budget is None else time_budget - clock.elapsed()
            stall = (_Stall(c2f.stall_window, c2f.stall_rel)
                     if c2f is not None and c2f.stall_window else None)
            res = _solve(method, obj, obj.params_from_verts(mesh.verts), n_iter=n_iter, lr=lr,
                         momentum=momentum, time_budget=remaining,
                         callback=run.callback(obj, len(stages), stall), clock=clock, opts=opts)
            if res.status == "callback" and run.stalled:
                res.status = "converged"
                res.message = (f"the data term improved by less than {c2f.stall_rel:.0%} over "
                               f"the last {c2f.stall_window} iterations (coarse-to-fine stall "
                               f"test)")
            run.evals += res.n_evaluations
            mesh = mesh.update_verts(obj.verts_from_params(res.x))
            stages.append({"stage": len(stages), "level": level, "n_verts": mesh.n_verts,
                           "status": res.status, "message": res.message,
                           "n_iterations": res.n_iterations,
                           "n_evaluations": res.n_evaluations, "seconds": res.seconds,
                           "n_samples": ns, "large_steps": lam, "weights": dict(w)})
            history.note(run.evals, clock.elapsed(),
                         f"stage {len(stages) - 1} ended: {res.status}", n_verts=mesh.n_verts)
            status, message = res.status, res.message
            if not stochastic and checkpoint_every is None:
                run.checkpoint(mesh)
            if res.status in _FAILED or res.status in ("callback", "time_budget"):
                done = True
                break
        if done or c2f is None:
            break
        # coarse-to-fine: subdivide only while the estimated accuracy asks for it
        est = obj.estimate_accuracy(mesh.verts, tau=c2f.tau)
        stages[-1]["estimate"] = est
        ok = est["chamfer_l2"] <= c2f.chamfer_l2 and est["fscore"] >= c2f.fscore
        at_max = level >= c2f.max_level - c2f.start_level
        too_big = (c2f.max_verts is not None
                   and mesh.n_verts + len(mesh.edges) > c2f.max_verts)
        history.note(run.evals, clock.elapsed(),
                     f"level {level}: estimated chamfer-L2 {est['chamfer_l2']:.3g}, "
                     f"F@{c2f.tau:g} {est['fscore']:.4f} with {mesh.n_verts} vertices", **est)
        if ok or at_max or too_big:
            why = "accuracy reached" if ok else ("max level" if at_max else "max_verts")
            message = f"coarse-to-fine stopped at {mesh.n_verts} vertices ({why}); {message}"
            break
        mesh = subdivide(mesh)
        level += 1
    run.bar.close()

    run.checkpoint(mesh)  # the final mesh (skipped if just evaluated)
    if not len(history):  # no iteration completed (e.g. a non-finite first evaluation)
        history.record(run.evals, clock.elapsed(), math.inf,
                       {k: math.inf for k in _TERMS}, n_params=3 * mesh.n_verts)
    if n_degenerate:
        message = (f"{message}; the source had {n_degenerate} zero-area triangles "
                   f"({n_moved} vertices moved to their neighbours' centroid first)")
    return MeshFitResult(
        status=status, message=message, history=history, n_params=3 * mesh.n_verts,
        seconds=clock.elapsed(), cpu_seconds=clock.cpu_elapsed(), n_iterations=run.iters,
        n_evaluations=run.evals,
        mesh=mesh.update_verts(norm.undo(mesh.verts)), mesh_normalized=mesh,
        center=norm.center.copy(), scale=float(norm.scale), method=method,
        metrics=run.metrics, stages=stages,
    )


class _Run:
    """Book-keeping shared by the stages of one fit: history rows, checkpoints, progress."""

    def __init__(self, clock, history, evaluator, norm, checkpoint_every, user_callback):
        self.clock, self.history, self.evaluator = clock, history, evaluator
        self.norm, self.every, self.user_callback = norm, checkpoint_every, user_callback
        self.evals = 0
        self.iters = 0
        self.last_ckpt = -1
        self.metrics = None
        self.stalled = False
        self.bar = _NoBar()

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
    if method == "scipy-lbfgs":
        return lbfgs_scipy(obj, x0, max_iter=n_iter, time_budget=time_budget,
                           callback=callback, clock=clock, **opts)
    return lbfgs_nlopt(obj, x0, max_eval=int(1.25 * n_iter) + 5, time_budget=time_budget,
                       callback=callback, clock=clock, **opts)


class _NoBar:
    def update(self, n=1):
        pass

    def set_postfix(self, **kw):
        pass

    def close(self):
        pass


def _progress(enabled: bool, total: int, desc: str):
    if not enabled:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, leave=False, dynamic_ncols=True)
