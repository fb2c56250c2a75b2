"""The objectives of :func:`geofit.fit.fit_mesh_to_views`: soft silhouettes and soft Phong RGB
(:class:`_Objective`), the hard silhouette's contour term (:class:`_ContourObjective`), the mesh
regularisers, and vertex colours by sparse least squares (:func:`_lstsq_colors`).

Each objective maps a flat float64 vector ``x`` to ``(value, grad)``; the vertices come from a
parameterisation of :mod:`geofit.fit.large_steps` (identity or large steps), and the chain rule
is composed in plain sight: renderer vector-Jacobian products to vertex gradients, then the
parameterisation's ``grad_params``.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .._threads import get_num_threads, parallel_map
from ..structures import MultiViewDataset
from ..loss import (
    mesh_edge_loss, mesh_laplacian_smoothing, mesh_normal_consistency, mesh_normal_variation,
)
from ..ops import uniform_laplacian
from ..render import AmbientLights
from ..render.blending import BlendParams
from ..render.soft import (
    SoftPhongRenderer,
    SoftRasterizationSettings,
    rasterize_soft,
    sigmoid_alpha_blend,
    sigmoid_alpha_blend_vjp,
)
from ..structures import Mesh
from .large_steps import IdentityParameterization

__all__ = ["REG_TERMS", "SIGMA", "dataset_lights", "regularizers"]

#: The soft rasterizer's sigma (the tutorial's).
SIGMA = 1e-4


def _silhouette_residual(S: np.ndarray, T: np.ndarray, log_eps: float):
    """Residual of the silhouette term and its derivative in ``S``.

    ``log_eps`` 0: ``r = S - T`` (the tutorial's). ``log_eps = e > 0``: where the target is
    background (``T < e``) and the mesh covers more than it (``S > T``), the residual of the
    log-transmittance ``g(S) = -log(1 - S + e)``, ``r = g(S) - g(T)``,
    ``dr/dS = 1 / (1 - S + e)``; elsewhere ``S - T``. The product coverage
    ``S = 1 - prod_k (1 - p_k)`` has ``dS/dd_k = -(p_k / sigma) (1 - S)``: the pull on a pixel
    the mesh covers and the target leaves empty fades with ``1 - S`` (on a closed mesh the
    front and the back faces multiply it), while an uncovered pixel the target fills pulls
    with full strength; with ``g`` the factor is ``(1 - S) / (1 - S + e)``, about 1. Both
    branches vanish with zero slope at ``S = T`` (the loss is C1), so a mesh whose soft render
    equals the targets (the true surface) stays a minimum. Applied to every pixel (not only
    ``T < e``) the transform also magnifies the under-coverage just inside the outline that a
    mesh coarser than the target's leaves, and the fit grows (the cow's held-out outline
    0.08 -> 0.23 px too wide, measured); applied to every over-covered pixel it shrinks a
    mesh finer than the target's (Suzanne 0.08 -> 0.39 px too narrow).

    Returns
    -------
    r : ndarray
        The residual (same shape as ``S``).
    dr : ndarray or float
        ``dr/dS``.
    """
    if log_eps == 0.0:
        return S - T, 1.0
    den = 1.0 - S + log_eps
    over = (S > T) & (T < log_eps)
    r = np.where(over, np.log((1.0 - T + log_eps) / den), S - T)
    return r, np.where(over, 1.0 / den, 1.0)


def dataset_lights(data: MultiViewDataset):
    """The dataset's lights, or ``AmbientLights()`` (unlit colour: what the camera saw) when it
    has none (a capture: its lighting is in its pixels)."""
    if data.lights is not None:
        return data.lights

    return AmbientLights()


def dataset_background(data: MultiViewDataset) -> tuple:
    """The dataset's background colour, or white (the renderer's default
    :class:`~geofit.render.BlendParams`) when it has none: the one background choice of the
    views fit's texture and RGB stages and of its held-out renders."""
    if data.background is None:
        return (1.0, 1.0, 1.0)
    return tuple(np.asarray(data.background, np.float64).tolist())


#: The mesh regularisers of both stages.
REG_TERMS = ("edge", "normal", "laplacian", "normal_variation")


def regularizers(mesh: Mesh, weights: Mapping[str, float], anchor: np.ndarray | None = None,
                 pin: np.ndarray | None = None):
    """Weighted edge / normal-consistency / uniform-Laplacian / normal-variation terms and
    their gradient.

    ``anchor`` (V, 3) float64, optional: the Laplacian term acts on the displacement
    ``V - anchor`` (``mean_i |(L (V - anchor))_i|``) instead of on ``V``: smooth moves cost
    nothing, so the curvature the surface already has (creases, flat faces, a head's
    features) is no cost that pulls it away from the silhouettes' equilibrium. The uniform
    ``L`` depends on the faces alone, so its gradient is that of
    :func:`geofit.loss.mesh_laplacian_smoothing` at the displaced vertices.

    ``pin`` (V,) float64 in [0, 1], optional (with ``anchor``): a per-vertex mix of the two,
    ``mean_i [pin_i |(L (V - anchor))_i| + (1 - pin_i) |(L V)_i|]``: the anchored term where
    the silhouettes pin the surface (:func:`silhouette_pinning`), the plain, shrinking one
    where they do not. ``pin`` is held constant (computed once per solve).
    """
    g = np.zeros((mesh.n_verts, 3))
    terms = {}
    lap = mesh if anchor is None else mesh.update_verts(mesh.verts - anchor)
    lap_fn = ((lambda m: mesh_laplacian_smoothing(lap, "uniform")) if pin is None
              else (lambda m: _pinned_laplacian(m, anchor, pin)))
    for name, fn in (("edge", mesh_edge_loss), ("normal", mesh_normal_consistency),
                     ("laplacian", lap_fn), ("normal_variation", mesh_normal_variation)):
        w = float(weights.get(name, 0.0))
        if w == 0.0:
            continue
        v, gv = fn(mesh)
        terms[name] = w * float(v)
        g += w * gv
    return terms, g


def _unit(r: np.ndarray):
    """Row norms of ``r`` (n, 3) and the unit rows (0 where a row is 0: the zero subgradient
    of the norm's kink, never NaN)."""
    n = np.sqrt(np.einsum("ij,ij->i", r, r))
    return n, r / np.where(n > 0.0, n, 1.0)[:, None]


def _pinned_laplacian(mesh: Mesh, anchor: np.ndarray, pin: np.ndarray):
    """``mean_i [pin_i |(L (V - A))_i| + (1 - pin_i) |(L V)_i|]`` with the uniform ``L`` and
    its gradient ``L^T (pin u_A + (1 - pin) u) / V`` (``u`` the unit rows; ``L`` depends on
    the faces alone)."""
    L = uniform_laplacian(mesh)
    V = mesh.verts
    na, ua = _unit(L @ (V - anchor))
    n0, u0 = _unit(L @ V)
    nv = max(mesh.n_verts, 1)
    value = float(np.sum(pin * na + (1.0 - pin) * n0) / nv)
    grad = L.T @ (pin[:, None] * ua + (1.0 - pin)[:, None] * u0) / nv
    return value, np.asarray(grad)


class _Objective:
    """``fun(x) -> (value, grad)`` for one stage: soft silhouettes (and soft Phong RGB).

    ``x = [u (3V), colours (3V, textured only)]``; vertices come from the parameterisation.
    Data terms are the tutorial's: per view the mean over pixels of the squared error, averaged
    over the views used (all of them, or ``views_per_step`` random ones per call); with
    ``log_eps > 0`` (untextured only) the silhouette residual of :func:`_silhouette_residual`.
    Views are rendered in batches of at most ``max_views`` (bounded memory).
    """

    def __init__(self, base: Mesh, data: MultiViewDataset, weights: Mapping[str, float], *,
                 textured: bool, param, settings: SoftRasterizationSettings,
                 views_per_step: int | None = None, rng=None, sigma: float = SIGMA,
                 max_views: int = 5, anchor: np.ndarray | None = None, log_eps: float = 0.0,
                 pin: np.ndarray | None = None):
        self.base = base
        self.anchor = anchor  # the Laplacian's rest vertices (regularizers), None: V itself
        self.pin = pin  # per-vertex share of the anchored Laplacian (regularizers)
        self.max_views = max_views
        self.data = data
        self.weights = dict(weights)
        self.textured = textured
        self.param = param
        self.settings = settings
        self.views_per_step = views_per_step
        self.rng = rng
        self.clock = None  # the fit's Clock, whose deadline is checked between view batches
        self.sigma = sigma
        self.log_eps = float(log_eps)  # silhouette residual in log-transmittance (0: S - T)
        self.V = base.n_verts
        self.last: dict = {}
        self.n_calls = 0
        if textured:
            self.renderer = SoftPhongRenderer(
                lights=dataset_lights(data), raster_settings=settings,
                blend_params=BlendParams(sigma=sigma, gamma=1e-4))

    def split(self, x):
        n = 3 * self.V
        verts = self.param.to_verts(x[:n])
        colors = x[n:].reshape(-1, 3) if self.textured else None
        return verts, colors

    def __call__(self, x):
        self.n_calls += 1
        verts, colors = self.split(x)
        mesh = self.base.update_verts(verts)
        idx = np.arange(len(self.data))
        if self.views_per_step is not None:
            idx = self.rng.permutation(len(self.data))[:self.views_per_step]
        nv = len(idx)
        H, W = self.data.image_size
        terms, g_verts = regularizers(mesh, self.weights, self.anchor, self.pin)
        w_s = float(self.weights.get("silhouette", 0.0))
        w_rgb = float(self.weights.get("rgb", 0.0))
        sil = 0.0
        rgb = 0.0
        g_colors = np.zeros((self.V, 3)) if self.textured else None

        def batch(b):  # one batch of views: (silhouette sum, rgb sum, vertex, colour grads)
            if self.clock is not None:  # a time budget holds inside long evaluations
                self.clock.check()
            cams = self.data.cameras[b]
            tgt_s = self.data.silhouettes[b]
            if not self.textured:
                fr = rasterize_soft(mesh, cams, self.settings)
                S = sigmoid_alpha_blend(fr, self.sigma)
                res, dres = _silhouette_residual(S, tgt_s, self.log_eps)
                gS = (2.0 * w_s / (nv * H * W)) * res * dres
                gd = sigmoid_alpha_blend_vjp(fr, gS, self.sigma, S)
                return float(np.sum(res * res)), 0.0, fr.vjp(grad_dists=gd), None
            out = self.renderer(mesh, colors, cameras=cams)
            res_s = out.images[..., 3] - tgt_s
            res_c = out.images[..., :3] - self.data.images[b]
            gi = np.empty(out.images.shape)
            gi[..., 3] = (2.0 * w_s / (nv * H * W)) * res_s
            gi[..., :3] = (2.0 * w_rgb / (nv * H * W * 3)) * res_c
            grads = out.vjp(gi)
            return (float(np.sum(res_s * res_s)), float(np.sum(res_c * res_c)), grads.verts,
                    grads.colors)

        # views in batches of at most max_views: memory stays bounded, sums are the same.
        # When the batches split evenly over the threads, each thread renders whole batches
        # (the renderers run single-threaded inside a pool worker; no barrier per phase, no
        # idle thread on a batch of 5 views): the same values, summed in batch order
        batches = np.array_split(idx, -(-nv // self.max_views))
        n_threads = get_num_threads()
        per_batch = n_threads > 1 and len(batches) % n_threads == 0
        parts = (parallel_map(batch, batches, n_threads) if per_batch
                 else (batch(b) for b in batches))
        for s_b, c_b, gv_b, gc_b in parts:  # view batches, in order
            sil += s_b
            rgb += c_b
            g_verts = g_verts + gv_b
            if self.textured:
                g_colors += gc_b
        terms["silhouette"] = w_s * sil / (nv * H * W)
        if self.textured:
            terms["rgb"] = w_rgb * rgb / (nv * H * W * 3)
        value = float(sum(terms.values()))
        g = self.param.grad_params(g_verts).ravel()
        if self.textured:
            g = np.concatenate([g, g_colors.ravel()])
        self.last = {"x": x, "value": value, "terms": terms, "grad_norm": float(np.linalg.norm(g))}
        _remember(self, x, self.last)
        return value, g


def _lstsq_colors(mesh: Mesh, data: MultiViewDataset, reg: float) -> np.ndarray:
    """Vertex colours minimising the RGB error of the hard render (geometry fixed).

    The hard render (one face per pixel, blur 0; PyTorch3D's ``SoftPhongShader`` at K = 1) is
    affine in the colours, ``rgb_c = A_c colours_c + b_c`` per channel; this solves the normal
    equations ``(A^T A + reg L^T L) c = A^T (target - b)`` with the uniform Laplacian ``L``
    (which fills vertices no view sees from their neighbours), for each channel.
    """
    settings = SoftRasterizationSettings(image_size=data.image_size, blur_radius=0.0,
                                         faces_per_pixel=1, dtype=np.float64)
    r = SoftPhongRenderer(data.cameras, dataset_lights(data), raster_settings=settings)
    out = r(mesh, np.full((mesh.n_verts, 3), 0.5))
    A, b = out.color_operator()
    L = uniform_laplacian(mesh)
    LtL = (L.T @ L).tocsc()
    n_pix = A[0].shape[0]
    colors = np.empty((mesh.n_verts, 3))
    tgt = data.images.reshape(-1, 3)
    bb = b.reshape(-1, 3)
    eye = sp.identity(mesh.n_verts, format="csc")
    for c in range(3):  # colour channels
        Ac = A[c]
        lhs = (Ac.T @ Ac).tocsc() / n_pix + reg * LtL + 1e-9 * eye
        rhs = Ac.T @ (tgt[:, c] - bb[:, c]) / n_pix + 1e-9 * 0.5
        colors[:, c] = spla.spsolve(lhs, rhs)
    return colors


class _ContourObjective:
    """Geometry-first silhouette objective (see :mod:`geofit.render.soft.contour`) plus
    regularisers."""

    def __init__(self, base: Mesh, closs, weights, param, anchor: np.ndarray | None = None,
                 pin: np.ndarray | None = None):
        self.base = base
        self.anchor = anchor
        self.pin = pin
        self.closs = closs
        self.weights = dict(weights)
        self.param = param
        self.textured = False
        self.last: dict = {}

    def split(self, x):
        return self.param.to_verts(x), None

    def __call__(self, x):
        verts, _ = self.split(x)
        mesh = self.base.update_verts(verts)
        terms, g = regularizers(mesh, self.weights, self.anchor, self.pin)
        v, gv = self.closs(mesh)
        w = float(self.weights.get("silhouette", 0.0))
        terms["silhouette"] = w * v
        g = g + w * gv
        value = float(sum(terms.values()))
        gu = self.param.grad_params(g).ravel()
        self.last = {"x": x, "value": value, "terms": terms,
                     "grad_norm": float(np.linalg.norm(gu))}
        _remember(self, x, self.last)
        return value, gu


def silhouette_pinning(obj, mesh: Mesh, spread: int = 1) -> np.ndarray:
    """How much the silhouettes pin each vertex of ``mesh`` (the ``pin`` of
    :func:`regularizers`), (V,) float64 in [0, 1].

    The share of the silhouette term's force in the forces on the vertex,
    ``p_i = |g_s,i| / (|g_s,i| + |g_L,i|)`` (``g_s`` the weighted silhouette term's vertex
    gradient under ``obj``'s weights and data, ``g_L`` the plain Laplacian's), doubled (at
    an equilibrium where the silhouettes hold the surface against the Laplacian the two are
    equal: ``p = 1/2``) and clipped to [0, 1], then widened ``spread`` times to the mean of
    the vertex's neighbours where that is larger (a rim is a curve; the surface it holds is
    a strip). Surface no silhouette sees (a concavity, a flat face between the rims) has
    ``g_s = 0``: ``p = 0``, the plain Laplacian.
    """
    w_s = float(obj.weights.get("silhouette", 0.0))
    if isinstance(obj, _ContourObjective):
        gs = w_s * obj.closs(mesh)[1]
    else:
        sil = _Objective(mesh, obj.data, {"silhouette": w_s}, textured=False,
                         param=IdentityParameterization(mesh), settings=obj.settings,
                         sigma=obj.sigma, max_views=obj.max_views, log_eps=obj.log_eps)
        sil.clock = obj.clock
        gs = sil(mesh.verts.ravel())[1].reshape(-1, 3)
    gl = regularizers(mesh, {"laplacian": float(obj.weights.get("laplacian", 0.0))})[1]
    ns, nl = _unit(gs)[0], _unit(gl)[0]
    tot = ns + nl
    p = np.clip(2.0 * np.where(tot > 0.0, ns / np.where(tot > 0.0, tot, 1.0), 0.0), 0.0, 1.0)
    L = uniform_laplacian(mesh)
    for _ in range(spread):  # (L + I) p: the neighbours' mean
        p = np.maximum(p, L @ p + p)
    return p


def _remember(obj, x, rec, keep: int = 8):
    """Keep the last evaluations by parameter vector (a line search evaluates several points
    before the solver reports the accepted one)."""
    cache = obj.__dict__.setdefault("_cache", {})
    cache[x.tobytes()] = rec
    while len(cache) > keep:
        cache.pop(next(iter(cache)))
