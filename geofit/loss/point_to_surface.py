"""Exact squared distance from points to a fixed target surface, with its gradient.

Chamfer against random samples of a target surface measures the distance to the *samples*, so
its minimum is not zero even for a perfect fit, and it changes when the samples are redrawn.
:class:`PointToSurface` measures the distance to the surface itself: for every point ``p_i`` the
closest surface point ``c_i`` is found (Open3D/Embree picks the face, float64 finds the point, see
:class:`geofit.raycast.PointToMeshDistance`), and the loss is ``mean_i |p_i - c_i|^2``.

Gradient: the squared distance function ``D(p) = min_{c in S} |p - c|^2`` has gradient
``2 (p - c(p))`` wherever the closest point is unique (everywhere except the medial axis,
a measure-zero set), whether ``c`` lies inside a face, on an edge or at a vertex: this is the
envelope theorem, the closest point moves but to first order that does not change ``D``. So
``grad = 2 (p_i - c_i) / n`` is the exact gradient almost everywhere, with no derivative of the
closest-point search itself.

The reverse direction (every point of the target surface to the moving source) is *not* a
point-to-surface query on a fixed structure: the source moves, so there is no fixed surface to
build a tree over. :meth:`PointToSurface.symmetric_loss` therefore adds the usual one-sided
chamfer term from fixed target samples to their nearest source points (a KD-tree over the source
points, rebuilt per call).
"""
from __future__ import annotations

import numpy as np

from .._validate import as_points, check_choice
from ..raycast import ClosestPoints, PointToMeshDistance
from ..structures.mesh import Mesh
from .chamfer import _NearestIndex, _nearest, _scatter

__all__ = ["PointToSurface"]


class PointToSurface:
    """Squared point-to-surface distance to a fixed target mesh: build once, query many.

    Parameters
    ----------
    target_mesh : Mesh
        The target surface (at least one face).
    n_threads : int, optional
        Threads for Open3D's queries (0: all cores).

    Raises
    ------
    TypeError
        If ``target_mesh`` is not a Mesh.
    ValueError
        If it has no faces.

    Examples
    --------
    >>> import numpy as np
    >>> from geofit import ico_sphere
    >>> from geofit.loss import PointToSurface
    >>> target = PointToSurface(ico_sphere(2))
    >>> value, grad = target.loss(np.array([[0.0, 0.0, 2.0]]))
    >>> bool(abs(value - 1.0) < 1e-12), grad.round(12).tolist()
    (True, [[0.0, 0.0, 2.0]])
    """

    def __init__(self, target_mesh: Mesh, *, n_threads: int = 0):
        self._distance = PointToMeshDistance(target_mesh, n_threads=n_threads)
        self.mesh = target_mesh

    def __repr__(self) -> str:
        return f"PointToSurface(target={self.mesh!r})"

    def query(self, points) -> ClosestPoints:
        """Closest surface points (distances, points, face ids, barycentrics) of (k, 3) points."""
        return self._distance.query(as_points(points, "points"))

    def loss(self, points, *, reduction: str = "mean"):
        """Mean (or sum) of the squared distances from ``points`` to the target surface.

        Parameters
        ----------
        points : (n, 3) float64
            Query points (e.g. samples of a moving mesh: chain with ``B.T @ grad``).
        reduction : {"mean", "sum"}

        Returns
        -------
        value : float
            ``mean_i |p_i - c_i|^2`` (0 for no points).
        grad : (n, 3) float64
            ``2 (p_i - c_i) / n`` (``/ 1`` for "sum"): the exact gradient wherever each closest
            point is unique (not on the target's medial axis).
        """
        check_choice(reduction, "reduction", ("mean", "sum"))
        P = as_points(points, "points")
        if len(P) == 0:
            return 0.0, np.zeros((0, 3))
        res = self._distance.query(P)
        diff = P - res.points
        d2 = np.einsum("ij,ij->i", diff, diff)
        scale = 1.0 / len(P) if reduction == "mean" else 1.0
        return float(d2.sum() * scale), (2.0 * scale) * diff

    def symmetric_loss(self, points, target_samples, *, reduction: str = "mean"):
        """Point-to-surface from ``points`` plus chamfer from fixed target samples to ``points``.

        Parameters
        ----------
        points : (n, 3) float64
            Source points (at least one).
        target_samples : (m, 3) float64
            Points on the target surface, drawn once (e.g. with
            :func:`geofit.ops.sample_points_from_meshes`) and kept fixed for a deterministic
            objective.
        reduction : {"mean", "sum"}
            Per term.

        Returns
        -------
        value : float
            ``mean_i dist(p_i, S)^2 + mean_j |t_j - p_nn(j)|^2``.
        grad : (n, 3) float64
            Gradient with respect to ``points``: the first term's ``2 (p_i - c_i) / n`` plus
            ``2 (p_nn(j) - t_j) / m`` scattered onto each ``p_nn(j)`` (no gradient through the
            neighbour choice).
        """
        check_choice(reduction, "reduction", ("mean", "sum"))
        P = as_points(points, "points", allow_empty=False)
        T = as_points(target_samples, "target_samples")
        value, grad = self.loss(P, reduction=reduction)
        if len(T) == 0:
            return value, grad
        idx, d, dd = _nearest(_NearestIndex(P, "auto"), T, 2)  # dd = 2 (t - p_nn)
        scale = 1.0 / len(T) if reduction == "mean" else 1.0
        value += float(d.sum() * scale)
        grad = grad - _scatter(idx, dd * scale, len(P))
        return value, grad
