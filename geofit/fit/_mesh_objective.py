"""The objective of :func:`geofit.fit.fit_mesh`: data term and regularisers of the vertices.

See :mod:`geofit.fit.mesh` for the terms, the data terms and the sampling schedule.

With ``distance="cloud"`` the target is a point cloud (:class:`geofit.fit._cloud.CloudTarget`):
the data term is ``mean_i ((P_i - y_i) . n_i)^2`` (source sample ``P_i = (B V)_i`` to the
tangent plane of its nearest target point ``y_i``, unoriented PCA normal ``n_i``; gradient
``B^T 2 r_i n_i / n``, the nearest point piecewise constant) plus, as with ``"surface"``,
``mean_j |Y_j - C_j|^2`` from the target points ``Y_j`` (a fixed subsample per stage) to their
closest points ``C_j`` on the source surface.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from .._validate import as_rng, check_choice
from ..loss import (
    ChamferTarget,
    PointToSurface,
    chamfer_distance,
    mesh_edge_loss,
    mesh_laplacian_smoothing,
    mesh_normal_consistency,
)
from ..loss.chamfer import morton_order
from ..ops import barycentric_matrix, sample_points_from_meshes, sample_points_with_jacobian
from ..raycast import PointToMeshDistance
from ..structures import Mesh
from ._cloud import CloudTarget
from ._options import check_int, check_weights
from .large_steps import LargeSteps

__all__ = ["TERMS", "MeshObjective", "mesh_weights"]

#: The terms of the objective, in the order of the histories' columns.
TERMS = ("chamfer", "edge", "normal", "laplacian")


def mesh_weights(w, name: str = "weights") -> dict[str, float]:
    """Weights of :data:`TERMS` (missing terms weigh 0; the data term must weigh > 0)."""
    if w is None:
        raise TypeError(f"{name}: expected a dict of term weights, got None")
    return check_weights(w, dict.fromkeys(TERMS, 0.0), name, required="chamfer")


class MeshObjective:
    """The fit objective as a function of a flat float64 vector: ``E(x) -> (value, grad)``.

    Parameters
    ----------
    source : Mesh
        The mesh being deformed (its faces are fixed; its vertices are the starting point).
    target : Mesh or (k, 3) float64
        The target surface, in the frame the fit works in (normally normalised); a point
        cloud with ``distance="cloud"``.
    weights : dict
        Weights of ``"chamfer"`` (the data term, whatever ``distance``), ``"edge"``,
        ``"normal"`` and ``"laplacian"``; missing terms weigh 0 and are not computed.
    distance : {"surface", "points", "cloud"}
        Data term (see the module docstring); ``"cloud"`` for a point-cloud target.
    n_samples : int
        Samples drawn on each surface (per step or per stage).
    resample : {"stage", "step"}
        ``"step"``: fresh samples at every call (stochastic, the tutorial); ``"stage"``: samples
        fixed until :meth:`resample` is called (deterministic).
    large_steps : LargeSteps, optional
        When given, ``x`` holds the parameters ``u`` instead of the vertices.
    seed : int or numpy.random.Generator
        Sampling randomness.
    target_distance : geofit.loss.PointToSurface or CloudTarget, optional
        A prebuilt closest-point structure of ``target`` to share between objectives (a
        :class:`~geofit.fit._cloud.CloudTarget` with ``distance="cloud"``).

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

        check_choice(distance, "distance", ("surface", "points", "cloud"))
        check_choice(resample, "resample", ("stage", "step"))
        self.source = source
        self.target = target
        self.weights = mesh_weights(weights)
        self.distance = distance
        self.n_samples = check_int(n_samples, "n_samples")
        self.resample_mode = resample
        self.large_steps = large_steps
        self.rng = as_rng(seed)
        self.n_verts = source.n_verts
        self._p2s = self._cloud = None
        if distance == "surface":
            self._p2s = target_distance if target_distance is not None else PointToSurface(target)
        elif distance == "cloud":

            self._cloud = (target_distance if target_distance is not None
                           else CloudTarget(np.asarray(target, dtype=np.float64)))
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

        mesh = self.source if verts is None else self.source.update_verts(verts)
        sp = sample_points_with_jacobian(mesh, self.n_samples, seed=self.rng)
        self._B = sp.B
        if self.distance == "cloud":  # samples in Z-order: the cloud's KD-tree reads memory in
            # order (12,000 queries of 100,000 points: 33 -> 11 CPU ms, load 9)
            self._B = sp.B[morton_order(sp.points)]
        self._Y = self._target_samples(self.rng)
        self._target_cloud = ChamferTarget(self._Y) if self.distance == "points" else None

    def _target_samples(self, rng) -> np.ndarray:
        """``n_samples`` points of the target: surface samples, or a subsample of the cloud."""

        if self._cloud is not None:
            return self._cloud.subsample(self.n_samples, rng)
        return sample_points_from_meshes(self.target, self.n_samples, seed=rng)

    # -- evaluation
    def _data(self, mesh: Mesh, V: np.ndarray):

        if self.resample_mode == "step":
            B = sample_points_with_jacobian(mesh, self.n_samples, seed=self.rng).B
            Y = self._target_samples(self.rng)
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
        # exact point-to-surface (or point-to-plane of the cloud): source samples -> target ...
        v_pt, gP = (self._cloud if self._cloud is not None else self._p2s).loss(P)
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

        self.n_evaluations += 1
        x = np.asarray(x, dtype=np.float64)
        V = self.verts_from_params(x) if np.all(np.isfinite(x)) else x
        if not np.all(np.isfinite(V)):
            self.last_terms = {k: math.nan for k in TERMS}
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

        rng = self.rng if seed is None else as_rng(seed)
        mesh = self.source.update_verts(verts)
        P = sample_points_from_meshes(mesh, self.n_samples, seed=rng)
        Y = self._target_samples(rng)
        if self._cloud is not None:  # point-to-plane distances to the cloud
            d_pt = self._cloud.distances(P)
        else:
            p2s = self._p2s if self._p2s is not None else PointToSurface(self.target)
            d_pt = p2s.query(P).distances
        d_tp = PointToMeshDistance(mesh).query(Y).distances
        prec, rec = float(np.mean(d_pt < tau)), float(np.mean(d_tp < tau))
        f = 2 * prec * rec / (prec + rec) if prec + rec > 0 else 0.0
        return {"chamfer_l2": float(np.mean(d_pt ** 2) + np.mean(d_tp ** 2)), "fscore": f}
