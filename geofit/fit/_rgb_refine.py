"""The views fit's RGB stage: refine a mesh against the RGB images with the hard image term.

:func:`refine_rgb` minimises over the vertex positions ``V`` ::

    f(V) = min_C  L(V, C) + reg |L_u C|^2 / V_count + smooth sum_c C_c^T K_0 C_c,

``L`` the hard image loss (:class:`geofit.render.mesh.HardImageLoss`: interior shading and
barycentric gradient, visibility by edge sampling) and ``C`` the vertex colours (the albedo
when the dataset has lights). ``K_0`` is the cotangent stiffness matrix of the *starting* mesh:
``C^T K_0 C`` is the Dirichlet energy ``int |grad C|^2 dA`` of the piecewise-linear colours,
which does not depend on the shape's size nor on its vertex count (it converges under
refinement), so ``smooth`` means the same on any shape; it makes shading (a function of the
normals) cheaper to explain by the geometry than by the colours (shape from shading). For fixed
geometry the image is affine in the colours (:meth:`HardImageLoss.color_operator`), so the inner
minimum is one sparse least-squares solve per channel (variable projection). At the minimiser
``dL/dC + prior terms = 0``, so ``df/dV = dL/dV`` at ``C*`` (the envelope theorem; ``L_u`` and
``K_0`` do not depend on ``V``): the residual moves the geometry, not the colours.
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
from scipy.ndimage import binary_erosion

from .._threads import parallel_map
from ..ops import cot_laplacian, uniform_laplacian
from ..render.mesh.image_term import HardImageLoss
from ..structures import Mesh
from .._validate import check_positive
from .history import TimeUp
from .solvers import adam
from .large_steps import vertex_parameterization

__all__ = ["RGBRefineResult", "dirichlet_stiffness", "interior_masks", "projected_image_loss",
           "refine_rgb", "solve_vertex_colors"]


@dataclass
class RGBRefineResult:
    """Result of :func:`refine_rgb`.

    Attributes
    ----------
    mesh : Mesh
        Refined geometry.
    colors : (V, 3) float64 or None
        The colours solved for it (None when the clock or budget stopped the refinement
        before its first evaluation).
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


def dirichlet_stiffness(mesh: Mesh) -> sp.csr_matrix:
    """(V, V) cotangent stiffness ``K``: ``u^T K u = int |grad u|^2 dA`` for the piecewise-linear
    function with vertex values ``u`` (symmetric, positive semi-definite, zero row sums)."""
    L, _ = cot_laplacian(mesh.verts, mesh.faces)
    return ((sp.diags(np.asarray(L.sum(axis=1)).ravel()) - L) * 0.5).tocsr()


def interior_masks(silhouettes, px: int) -> np.ndarray:
    """(N, H, W) float64: 1 on the pixels at least ``px`` pixels inside the silhouettes
    (thresholded at 0.5, eroded ``px`` times with the 3 x 3 cross), else 0.

    As the image term's ``masks`` it leaves the outline to the silhouettes: there the hard
    render and the targets differ by sub-pixel sampling more than by anything the geometry
    inside the outline does.
    """
    inside = np.asarray(silhouettes) > 0.5
    if px <= 0:
        return inside.astype(np.float64)
    return np.stack([binary_erosion(s, iterations=int(px)) for s in inside]).astype(np.float64)


class _ColorSolve:
    """``argmin_C L(V, C) + reg |L_u C|^2 / V + smooth sum_c C_c^T K_0 C_c`` for one topology
    (faces fixed, vertices free; ``K_0`` of the mesh it is built for).

    The normal equations ``(A_c^T A_c / n + R) C_c = A_c^T y_c / n`` (:meth:`HardImageLoss.
    color_operator`'s ``A``, ``y``; ``n = N H W``; ``R`` the smoothness terms and a 1e-9 ridge
    towards grey) are assembled face by face: a ray that hits face ``f`` at barycentrics ``b`` adds
    ``w b b^T`` to ``f``'s 3 x 3 block, so per evaluation the blocks are six bincounts over the
    hits and the matrix is one bincount into a sparsity pattern built once (instead of forming
    the ray-by-vertex ``A`` and ``A^T A``: measured 0.37 -> 0.05 CPU s per evaluation on the
    cow's 1,659 vertices). One factorisation serves the three channels when the shading is
    grey (white lights and materials), else one per channel.
    """

    def __init__(self, mesh: Mesh, reg: float, smooth: float = 0.0):
        F = mesh.faces
        Vn = mesh.n_verts
        self.V, self.F, self.reg = Vn, F, reg
        keys = (np.repeat(F, 3, axis=1) * Vn + np.tile(F, (1, 3))).ravel()  # (9 F,) i_j V + i_l
        uniq, self.slot = np.unique(keys, return_inverse=True)
        self.indices = (uniq % Vn).astype(np.int32)
        self.indptr = np.zeros(Vn + 1, np.int64)
        np.cumsum(np.bincount(uniq // Vn, minlength=Vn), out=self.indptr[1:])
        self.Lu = uniform_laplacian(mesh)
        self.Q = (self.Lu.T @ self.Lu) * (reg / Vn)  # the smoothness terms' quadratic form
        if smooth:
            self.Q = self.Q + smooth * dirichlet_stiffness(mesh)
        self.R = (self.Q + 1e-9 * sp.identity(Vn)).tocsr()

    def _matrix(self, face, bary, w):
        """``sum_hits w b b^T`` scattered onto the vertices (csr, the pattern of the faces)."""
        nf = len(self.F)
        blocks = np.empty((nf, 3, 3))
        pairs = [(j, k) for j in range(3) for k in range(j, 3)]  # corners (symmetric)

        def block(jk):
            j, k = jk
            blocks[:, j, k] = np.bincount(face, w * bary[:, j] * bary[:, k], nf)
            blocks[:, k, j] = blocks[:, j, k]

        parallel_map(block, pairs)  # the six bincounts on the threads
        data = np.bincount(self.slot, blocks.ravel(), len(self.indices))
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.V, self.V))

    def __call__(self, loss, mesh: Mesh, hits=None):
        """The colours ``C (V, 3)`` and the value of the minimised smoothness and ridge terms."""
        h = loss.shaded_hits(mesh, hits)
        N = len(loss.cameras)
        H, W = loss.image_size
        n = N * H * W
        m = loss.masks.ravel()[h.pixel] / (loss.supersample ** 2 * n)  # (k,) sqrt(m)^2 / s^2 n
        T = loss.targets.reshape(-1, 3)[h.pixel]
        tri = self.F[h.face]
        grey = np.array_equal(h.shade[:, 0], h.shade[:, 1]) and \
            np.array_equal(h.shade[:, 0], h.shade[:, 2])
        C = np.empty((self.V, 3))
        lu = None

        def rhs_of(c):  # one channel's right-hand side (channels on the threads)
            wy = m * h.shade[:, c] * (T[:, c] - h.specular[:, c])
            rhs = sum(np.bincount(tri[:, j], wy * h.bary[:, j], self.V) for j in range(3))
            return rhs + 1e-9 * 0.5

        rhss = parallel_map(rhs_of, range(3))
        for c in range(3):  # colour channels
            rhs = rhss[c]
            if lu is None or not grey:
                lhs = self._matrix(h.face, h.bary, m * h.shade[:, c] ** 2) + self.R
                lu = spla.splu(lhs.tocsc())
            C[:, c] = lu.solve(rhs)
        return C, float(np.sum(C * (self.Q @ C)) + 1e-9 * np.sum((C - 0.5) ** 2))


def solve_vertex_colors(loss, mesh: Mesh, reg: float = 1e-4, smooth: float = 0.0
                        ) -> np.ndarray:
    """``argmin_C L(mesh, C) + reg |L_u C|^2 / V + smooth sum_c C_c^T K C_c`` by one sparse
    solve per channel."""
    return _ColorSolve(mesh, reg, smooth)(loss, mesh)[0]


def projected_image_loss(loss, mesh: Mesh, reg: float = 1e-4, solver=None,
                         smooth: float = 0.0):
    """``f(V) = min_C L(V, C) + reg |L_u C|^2 / V`` and its gradient to the vertices.

    The colours are solved (:func:`solve_vertex_colors`); at that minimum the colour gradient
    vanishes, so ``df/dV = dL/dV`` at ``C*`` (the envelope theorem). One cast of the pixel
    rays serves the solve and the loss.

    Parameters
    ----------
    loss : HardImageLoss
    mesh : Mesh
    reg : float
    solver : _ColorSolve, optional
        Built once for ``mesh``'s faces, ``reg`` and ``smooth`` (reused between evaluations;
        its stiffness is that of the mesh it was built for).
    smooth : float
        Weight of the colours' Dirichlet energy (when ``solver`` is not given).

    Returns
    -------
    value : float
    grad_verts : (V, 3) float64
    colors : (V, 3) float64
        ``C*``.
    """
    solver = solver if solver is not None else _ColorSolve(mesh, reg, smooth)
    hits = loss.pixel_hits(mesh)  # one cast for the colour solve and the loss
    C, r = solver(loss, mesh, hits)
    value, gv, _ = loss(mesh, C, hits=hits)
    return value + r, gv, C


def refine_rgb(mesh: Mesh, cameras, images, *, lights=None, background=(1.0, 1.0, 1.0),
               lam: float = 10.0, reg: float = 1e-4, maxiter: int = 30,
               supersample: int = 2, time_budget: float | None = None,
               image_weight: float = 1.0, extra=None, masks=None,
               clock=None, smooth: float = 0.0, method: str = "lbfgs",
               lr: float = 0.0) -> RGBRefineResult:
    """Refine ``mesh`` against RGB ``images`` (variable projection of the colours, L-BFGS
    or Adam).

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
        Weight of the colours' uniform-Laplacian smoothness ``|L_u C|^2 / V``.
    smooth : float
        Weight of the colours' Dirichlet energy ``int |grad C|^2 dA`` (cotangent stiffness of
        ``mesh``, held fixed during the refinement; 0: none).
    maxiter : int
        L-BFGS iterations (``method="lbfgs"``) or Adam steps (one evaluation each).
    method : {"lbfgs", "adam"}
        scipy's L-BFGS-B on the parameters, or Adam (:func:`geofit.fit.solvers.adam`) with
        step ``lr``: Adam's per-coordinate normalisation moves a vertex whose gradient is
        small (shading inside the outline) as far per step as one the silhouettes hold
        stiffly, which L-BFGS's line search, limited by the stiffest direction, does not.
        Either way the result is the evaluated point of least objective.
    lr : float
        Adam's step in the parameters' units (world units; > 0 with ``method="adam"``).
    supersample : int
        Rays per pixel ``s x s`` of the loss: the value then follows the continuous loss the
        edge gradient differentiates more closely, which the line search needs.
    time_budget : float, optional
        Stop (at the next evaluation) after this many seconds.
    clock : geofit.fit.history.Clock, optional
        The fit's clock: stop (at the next evaluation, or inside ``extra`` where it checks
        the clock) once it passes its deadline.
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

    if method not in ("lbfgs", "adam"):
        raise ValueError(f"method: expected 'lbfgs' or 'adam', got {method!r}")
    if method == "adam":
        lr = check_positive(lr, "lr")
    t0 = time.perf_counter()
    loss = HardImageLoss(cameras, images, lights=lights, background=background,
                         supersample=supersample, masks=masks)
    F = mesh.faces
    param = vertex_parameterization(mesh, lam)
    solver = _ColorSolve(mesh, reg, smooth)  # the faces are fixed: pattern and priors once
    u0 = param.to_params(mesh.verts).ravel()
    values: list = []
    best = {"value": np.inf, "V": mesh.verts, "C": None}

    class _Stop(Exception):
        pass

    def fun(u):
        if time_budget is not None and time.perf_counter() - t0 > time_budget:
            raise _Stop
        if clock is not None:
            clock.check()  # TimeUp past the deadline
        V = param.to_verts(u.reshape(-1, 3))
        m = Mesh(V, F)
        value, gv, C = projected_image_loss(loss, m, reg, solver)
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
        if method == "adam":
            def step_fun(u):  # the fit's TimeUp ends the stage here, not inside the solver
                try:
                    return fun(u)
                except TimeUp:
                    raise _Stop from None

            adam(step_fun, u0, lr=lr, n_iter=int(maxiter))
        else:
            minimize(fun, u0, jac=True, method="L-BFGS-B", options={"maxiter": int(maxiter)})
    except (_Stop, TimeUp):
        stopped = True
    C = best["C"]  # None: stopped before the first evaluation
    return RGBRefineResult(Mesh(best["V"], F), C, values, time.perf_counter() - t0,
                           len(values), stopped)
