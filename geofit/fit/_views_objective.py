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

__all__ = ["REG_TERMS", "SIGMA", "dataset_lights", "regularizers"]

#: The soft rasterizer's sigma (the tutorial's).
SIGMA = 1e-4


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


def regularizers(mesh: Mesh, weights: Mapping[str, float]):
    """Weighted edge / normal-consistency / uniform-Laplacian / normal-variation terms and
    their gradient."""
    g = np.zeros((mesh.n_verts, 3))
    terms = {}
    for name, fn in (("edge", mesh_edge_loss), ("normal", mesh_normal_consistency),
                     ("laplacian", lambda m: mesh_laplacian_smoothing(m, "uniform")),
                     ("normal_variation", mesh_normal_variation)):
        w = float(weights.get(name, 0.0))
        if w == 0.0:
            continue
        v, gv = fn(mesh)
        terms[name] = w * float(v)
        g += w * gv
    return terms, g


class _Objective:
    """``fun(x) -> (value, grad)`` for one stage: soft silhouettes (and soft Phong RGB).

    ``x = [u (3V), colours (3V, textured only)]``; vertices come from the parameterisation.
    Data terms are the tutorial's: per view the mean over pixels of the squared error, averaged
    over the views used (all of them, or ``views_per_step`` random ones per call). Views are
    rendered in batches of at most ``max_views`` (bounded memory).
    """

    def __init__(self, base: Mesh, data: MultiViewDataset, weights: Mapping[str, float], *,
                 textured: bool, param, settings: SoftRasterizationSettings,
                 views_per_step: int | None = None, rng=None, sigma: float = SIGMA,
                 max_views: int = 5):
        self.base = base
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
        terms, g_verts = regularizers(mesh, self.weights)
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
                res = S - tgt_s
                gS = (2.0 * w_s / (nv * H * W)) * res
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

    def __init__(self, base: Mesh, closs, weights, param):
        self.base = base
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
        terms, g = regularizers(mesh, self.weights)
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


def _remember(obj, x, rec, keep: int = 8):
    """Keep the last evaluations by parameter vector (a line search evaluates several points
    before the solver reports the accepted one)."""
    cache = obj.__dict__.setdefault("_cache", {})
    cache[x.tobytes()] = rec
    while len(cache) > keep:
        cache.pop(next(iter(cache)))
