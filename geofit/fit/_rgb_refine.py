"""Prototype (not in the default): refine a mesh against the RGB images with the hard image term.

:func:`refine_rgb` minimises over the vertex positions ``V`` ::

    f(V) = min_C  L(V, C) + reg |L_u C|^2 / V_count,

``L`` the hard image loss (:class:`geofit.render.mesh.HardImageLoss`: interior shading and
barycentric gradient, visibility by edge sampling) and ``C`` the vertex colours. For fixed
geometry the image is affine in the colours (:meth:`HardImageLoss.color_operator`), so the inner
minimum is one sparse least-squares solve per channel (variable projection). At the minimiser
``dL/dC + reg term = 0``, so ``df/dV = dL/dV`` at ``C*`` (the envelope theorem; the uniform
Laplacian ``L_u`` does not depend on ``V``): the residual moves the geometry, not the colours.
The vertices are parameterised with large steps (Nicolet et al. 2021,
:class:`geofit.fit.large_steps.LargeSteps`), and scipy's L-BFGS-B runs on ``u``.

The edge gradient is that of the continuous loss, the value that of the pixel (or
supersampled) loss, so the line search sees a slightly inconsistent pair; ``maxiter`` bounds the
work.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..ops import uniform_laplacian
from ..render.mesh.image_term import HardImageLoss
from ..structures import Mesh
from .large_steps import vertex_parameterization

__all__ = ["RGBRefineResult", "projected_image_loss", "refine_rgb", "solve_vertex_colors"]


@dataclass
class RGBRefineResult:
    """Result of :func:`refine_rgb`.

    Attributes
    ----------
    mesh : Mesh
        Refined geometry.
    colors : (V, 3) float64
        The colours solved for it.
    values : list of float
        Objective per evaluation.
    seconds : float
    n_evaluations : int
    stopped : bool
        True when the time budget ended it.
    """

    mesh: Mesh
    colors: np.ndarray
    values: list
    seconds: float
    n_evaluations: int
    stopped: bool = False


def solve_vertex_colors(loss, mesh: Mesh, reg: float = 1e-4) -> np.ndarray:
    """``argmin_C L(mesh, C) + reg |L_u C|^2 / V`` by one sparse solve per channel."""
    return _solve_colors(loss, mesh, reg)[0]


def _solve_colors(loss, mesh: Mesh, reg: float):
    """The colours of :func:`solve_vertex_colors` and their smoothness term's value."""

    A, y = loss.color_operator(mesh)
    N = len(loss.cameras)
    H, W = loss.image_size
    n = N * H * W
    Lu = uniform_laplacian(mesh)
    R = (Lu.T @ Lu) * (reg / mesh.n_verts)
    eye = sp.identity(mesh.n_verts)
    C = np.empty((mesh.n_verts, 3))
    for c in range(3):  # channels
        lhs = ((A[c].T @ A[c]) / n + R + 1e-9 * eye).tocsc()
        C[:, c] = spla.spsolve(lhs, A[c].T @ y[:, c] / n + 1e-9 * 0.5)
    LC = Lu @ C
    # the value of the minimised terms: smoothness and the 1e-9 ridge towards grey
    return C, float(reg / mesh.n_verts * np.sum(LC * LC) + 1e-9 * np.sum((C - 0.5) ** 2))


def projected_image_loss(loss, mesh: Mesh, reg: float = 1e-4):
    """``f(V) = min_C L(V, C) + reg |L_u C|^2 / V`` and its gradient to the vertices.

    The colours are solved (:func:`solve_vertex_colors`); at that minimum the colour gradient
    vanishes, so ``df/dV = dL/dV`` at ``C*`` (the envelope theorem).

    Returns
    -------
    value : float
    grad_verts : (V, 3) float64
    colors : (V, 3) float64
        ``C*``.
    """
    C, r = _solve_colors(loss, mesh, reg)
    value, gv, _ = loss(mesh, C)
    return value + r, gv, C


def refine_rgb(mesh: Mesh, cameras, images, *, lights=None, background=(1.0, 1.0, 1.0),
               lam: float = 10.0, reg: float = 1e-4, maxiter: int = 30,
               supersample: int = 2, time_budget: float | None = None,
               image_weight: float = 1.0, extra=None, masks=None) -> RGBRefineResult:
    """Refine ``mesh`` against RGB ``images`` (variable projection of the colours, L-BFGS).

    Parameters
    ----------
    mesh : Mesh
        Starting geometry (e.g. the default fit's result).
    cameras : CamerasBase
    images : (N, H, W, 3) float64
    lights : lights, optional
        The lights the images were shot with.
    background : (3,) float64
    lam : float
        Large-steps weight (0: plain vertex positions).
    reg : float
        Colour smoothness weight.
    maxiter : int
        L-BFGS iterations.
    supersample : int
        Rays per pixel ``s x s`` of the loss: the value then follows the continuous loss the
        edge gradient differentiates more closely, which the line search needs.
    time_budget : float, optional
        Stop (at the next evaluation) after this many seconds.
    image_weight : float
        Weight of the image term.
    extra : callable, optional
        ``extra(verts) -> (value, grad)`` ((V, 3) float64 gradient): terms added to the
        objective (e.g. the silhouettes and the mesh regularisers of the silhouette stage).
    masks : (N, H, W) float64, optional
        Per-pixel weights of the image term (:class:`HardImageLoss`'s ``masks``).

    Returns
    -------
    RGBRefineResult
    """
    from scipy.optimize import minimize

    t0 = time.perf_counter()
    loss = HardImageLoss(cameras, images, lights=lights, background=background,
                         supersample=supersample, masks=masks)
    F = mesh.faces
    param = vertex_parameterization(mesh, lam)
    u0 = param.to_params(mesh.verts).ravel()
    values: list = []
    best = {"value": np.inf, "V": mesh.verts, "C": None}

    class _Stop(Exception):
        pass

    def fun(u):
        if time_budget is not None and time.perf_counter() - t0 > time_budget:
            raise _Stop
        V = param.to_verts(u.reshape(-1, 3))
        m = Mesh(V, F)
        value, gv, C = projected_image_loss(loss, m, reg)
        value, gv = image_weight * value, image_weight * gv
        if extra is not None:
            e, ge = extra(V)
            value, gv = value + e, gv + ge
        values.append(float(value))
        if value < best["value"]:
            best.update(value=value, V=V, C=C)
        return value, param.grad_params(gv).ravel()

    stopped = False
    try:
        minimize(fun, u0, jac=True, method="L-BFGS-B", options={"maxiter": int(maxiter)})
    except _Stop:
        stopped = True
    C = best["C"] if best["C"] is not None else solve_vertex_colors(loss, mesh, reg)
    return RGBRefineResult(Mesh(best["V"], F), C, values, time.perf_counter() - t0,
                           len(values), stopped)
