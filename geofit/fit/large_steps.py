"""The large-steps parameterisation of Nicolet et al. (2021), shared by the mesh fits.

"Large Steps in Inverse Rendering of Geometry" (ACM TOG 40(6)): optimise ``u = (I + lambda L) V``
with ``L = D - A`` the combinatorial graph Laplacian of the mesh. Then ``V = M^-1 u`` with
``M = I + lambda L`` (symmetric positive definite, factorised once per topology with
``scipy.sparse.linalg.splu``) and ``dE/du = M^-1 dE/dV``: gradient steps in ``u`` are smooth
(Sobolev) steps in ``V``, so large deformations keep a well-shaped mesh.

:class:`LargeSteps` and :class:`IdentityParameterization` share one interface (``to_params``,
``to_verts``, ``grad_params``), so a fit can switch between them without branching.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .._validate import check_positive
from ..structures import Mesh, as_mesh

__all__ = ["IdentityParameterization", "LargeSteps", "vertex_parameterization"]


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
    >>> from geofit.fit import LargeSteps
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
        """(V, 3) or (3V,) parameters -> (V, 3) vertices ``V = M^-1 u``."""
        return self._lu.solve(np.ascontiguousarray(u, dtype=np.float64).reshape(-1, 3))

    def grad_params(self, grad_verts: np.ndarray) -> np.ndarray:
        """(V, 3) ``dE/dV`` -> (V, 3) ``dE/du = M^-1 dE/dV`` (M is symmetric)."""
        return self._lu.solve(np.ascontiguousarray(grad_verts, dtype=np.float64))

    def __repr__(self) -> str:
        return f"LargeSteps(n_verts={self.n_verts}, lam={self.lam:g})"




class IdentityParameterization:
    """``u = V``: the vertices themselves (the interface of :class:`LargeSteps`)."""

    def __init__(self, mesh: Mesh):
        self.n_verts = mesh.n_verts

    def to_params(self, verts: np.ndarray) -> np.ndarray:
        """(V, 3) vertices -> (V, 3) parameters (a copy)."""
        return np.array(verts, dtype=np.float64)

    def to_verts(self, u: np.ndarray) -> np.ndarray:
        """(V, 3) or (3V,) parameters -> (V, 3) vertices."""
        return np.asarray(u, dtype=np.float64).reshape(-1, 3)

    def grad_params(self, grad_verts: np.ndarray) -> np.ndarray:
        """(V, 3) ``dE/dV`` -> (V, 3) ``dE/du`` (the same)."""
        return np.asarray(grad_verts, dtype=np.float64)

    def __repr__(self) -> str:
        return f"IdentityParameterization(n_verts={self.n_verts})"


def vertex_parameterization(mesh: Mesh, lam: float | None):
    """:class:`LargeSteps` of ``mesh`` with ``lambda = lam``, or the identity for None / 0."""
    if lam:
        return LargeSteps(mesh, lam)
    return IdentityParameterization(mesh)
