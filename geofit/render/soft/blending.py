"""Soft blends with their vjps: the sigmoid silhouette and the depth-softmax RGB blend.

:func:`sigmoid_alpha_blend` (PyTorch3D's ``SoftSilhouetteShader``):
``S = 1 - prod_k (1 - p_k)`` with ``p_k = sigmoid(-d_k / sigma)``;
:func:`softmax_rgb_blend_soft` (``softmax_rgb_blend``) over the K entries of a pixel.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..._validate import as_array, check_positive
from ..blending import BlendParams
from .fragments import (
    SoftFragments, _BLEND_EPS, _check_fragments, _map_views, _n_threads,
)

__all__ = [
    "SoftBlend",
    "SoftSilhouetteShader",
    "sigmoid_alpha_blend",
    "sigmoid_alpha_blend_vjp",
    "softmax_rgb_blend_soft",
]

# ------------------------------------------------------------------------------------------
# Silhouette blend
# ------------------------------------------------------------------------------------------


def _sigmoid_terms(fr: SoftFragments, sigma: float):
    """``p = sigmoid(-d / sigma)`` and ``log(1 - p)`` per entry, cached on the fragments.

    With ``e = exp(-d / sigma)`` (exponent capped at 700): ``p = e / (1 + e)`` and
    ``log(1 - p) = -log1p(e)``, finite for every distance (a cap only changes ``log(1 - p)``
    below -700, where ``1 - S`` underflows to 0 either way).
    """
    cache = fr.__dict__.setdefault("_sigmoid_cache", {})
    if sigma not in cache:
        dtype = fr.dist.dtype
        p = np.empty(len(fr.dist), dtype)
        logq = np.empty(len(fr.dist), dtype)

        def one(b):  # element-wise: the same values whatever the split
            lo, hi = bounds[b], bounds[b + 1]
            e = np.exp(np.minimum(fr.dist[lo:hi].astype(np.float64) * (-1.0 / sigma), 700.0))
            p[lo:hi] = e / (1.0 + e)
            logq[lo:hi] = -np.log1p(e)

        # in blocks on the rasterizer's threads (on the main thread alone this was a tenth of
        # a 128 px silhouette evaluation, measured on the procedural box)
        n = _n_threads(fr._ctx.get("n_threads")) if fr._ctx else 1
        bounds = np.linspace(0, len(fr.dist), max(min(n, len(fr.dist) // 65536), 1) + 1
                             ).astype(np.int64)
        _map_views(one, len(bounds) - 1, n)
        cache.clear()
        cache[sigma] = (p, logq)
    return cache[sigma]


def _log_one_minus_p(dist: np.ndarray, sigma: float) -> np.ndarray:
    """log(1 - sigmoid(-d / sigma)) = log sigmoid(d / sigma), finite for every d."""
    return -np.log1p(np.exp(np.minimum(dist * (-1.0 / sigma), 700.0)))


def sigmoid_alpha_blend(fragments: SoftFragments, sigma: float = 1e-4) -> np.ndarray:
    """Soft silhouettes ``S = 1 - prod_k (1 - sigmoid(-d_k / sigma))`` (PyTorch3D's op).

    Parameters
    ----------
    fragments : SoftFragments
    sigma : float
        Falloff width in squared NDC units (> 0).

    Returns
    -------
    alpha : (N, H, W) float64
        0 where no face was kept. The product is evaluated as ``exp(sum log sigmoid(d/sigma))``,
        which is finite for every distance.
    """
    fr = _check_fragments(fragments)
    sigma = check_positive(sigma, "sigma")
    H, W = fr.image_size
    tot = fr.n_views * H * W
    logq = np.bincount(fr.global_pixel, _sigmoid_terms(fr, sigma)[1], tot)
    return (-np.expm1(logq)).reshape(fr.n_views, H, W)


def sigmoid_alpha_blend_vjp(fragments: SoftFragments, grad_alpha, sigma: float = 1e-4,
                            alpha=None) -> np.ndarray:
    """dL/d dists from dL/d alpha for :func:`sigmoid_alpha_blend`.

    ``dS/dd_k = -(p_k / sigma) (1 - S)``: exact, no division by ``1 - p_k`` (PyTorch3D's
    backward uses the same identity).

    Parameters
    ----------
    fragments : SoftFragments
    grad_alpha : (N, H, W) float64
    sigma : float
    alpha : (N, H, W) float64, optional
        The forward result (recomputed if omitted).

    Returns
    -------
    grad_dists : (m,) float64
    """
    fr = _check_fragments(fragments)
    sigma = check_positive(sigma, "sigma")
    H, W = fr.image_size
    g = as_array(grad_alpha, "grad_alpha", (fr.n_views, H, W)).reshape(-1)
    if alpha is None:
        alpha = sigmoid_alpha_blend(fr, sigma)
    gp = fr.global_pixel
    coef = g * (1.0 - np.asarray(alpha).reshape(-1)) * (-1.0 / sigma)   # per pixel
    return coef[gp] * _sigmoid_terms(fr, sigma)[0]


class SoftSilhouetteShader:
    """PyTorch3D's ``SoftSilhouetteShader``: RGBA with RGB = 1 and A the soft silhouette.

    Parameters
    ----------
    blend_params : BlendParams, optional
        Only ``sigma`` is used (default 1e-4).
    """

    def __init__(self, blend_params: BlendParams | None = None):
        self.blend_params = _check_blend(blend_params)

    def __call__(self, fragments: SoftFragments) -> np.ndarray:
        """(N, H, W, 4) float64 images."""
        fr = _check_fragments(fragments)
        a = sigmoid_alpha_blend(fr, self.blend_params.sigma)
        out = np.ones(a.shape + (4,))
        out[..., 3] = a
        return out


def _check_blend(blend_params) -> BlendParams:
    if blend_params is None:
        return BlendParams()
    if not isinstance(blend_params, BlendParams):
        raise TypeError(f"blend_params: expected a BlendParams, got {type(blend_params)!r}")
    check_positive(blend_params.sigma, "blend_params.sigma")
    check_positive(blend_params.gamma, "blend_params.gamma")
    as_array(blend_params.background_color, "blend_params.background_color", (3,))
    return blend_params


# ------------------------------------------------------------------------------------------
# Softmax RGB blend
# ------------------------------------------------------------------------------------------


@dataclass(eq=False)
class SoftBlend:
    """Result of :func:`softmax_rgb_blend_soft` with what its vjp needs.

    Attributes
    ----------
    images : (N, H, W, 4) float64
        RGB and alpha.
    weights : (m,) float64
        ``w_k / (sum_j w_j + delta)``: the weight of each entry's colour in its pixel.
    background_weight : (N * H * W,) float64
        ``delta / (sum_j w_j + delta)`` per pixel.
    """

    images: np.ndarray
    weights: np.ndarray
    background_weight: np.ndarray
    _saved: dict = field(default_factory=dict, repr=False)

    def vjp(self, grad_images) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Backward of the blend.

        Parameters
        ----------
        grad_images : (N, H, W, 4) float64

        Returns
        -------
        grad_colors : (m, 3) float64
        grad_dists : (m,) float64
        grad_zbuf : (m,) float64
        """
        s = self._saved
        fr = s["fragments"]
        shape = self.images.shape
        g = as_array(grad_images, "grad_images", shape).reshape(-1, 4)
        gp = fr.global_pixel
        out = self.images.reshape(-1, 4)
        D = s["D"]
        inv_D = 1.0 / D
        g_num = [g[:, c] * inv_D for c in range(3)]           # per pixel
        g_D = -(g[:, 0] * out[:, 0] + g[:, 1] * out[:, 1] + g[:, 2] * out[:, 2]) * inv_D
        w = s["w"]
        cols = s["colors"]
        dt = w.dtype  # per-entry work in the fragments' storage type (float32 by default)
        gn_e = [gn.astype(dt)[gp] for gn in g_num]             # per entry
        g_col = np.empty((len(w), 3), dt)
        for c in range(3):  # colour channels
            g_col[:, c] = w * gn_e[c]
        # (the per-entry temporaries are freed as soon as they are used: they are the size of
        # the fragments)
        g_w = gn_e[0] * cols[:, 0]
        g_w += gn_e[1] * cols[:, 1]
        g_w += gn_e[2] * cols[:, 2]
        del gn_e
        g_w += g_D.astype(dt)[gp]
        bg = s["bg"]
        g_delta = g_num[0] * bg[0] + g_num[1] * bg[1] + g_num[2] * bg[2] + g_D
        p = s["p"]
        gamma = s["gamma"]
        g_p = g_w * s["E"]
        g_w *= w                                               # d/d w_k * w_k
        G = len(D)
        g_zm = -np.bincount(gp, g_w, G) / gamma
        g_zm += np.where(s["delta_free"], -g_delta * s["delta"] / gamma, 0.0)
        g_zbuf = g_w
        del g_w
        g_zbuf /= gamma                                        # now d/d z_inv
        # zm = max(z_inv) (one entry per pixel holds it), clamped at 1e-10
        first = s["first"]
        g_zbuf[first] += np.where(s["zm_free"], g_zm, 0.0)[gp[first]]
        g_zbuf /= s["zrange"]
        np.negative(g_zbuf, out=g_zbuf)                        # z_inv = (zfar - zbuf) / range
        sigma = s["sigma"]
        # p = sigmoid(-d / sigma); alpha = 1 - prod(1 - p): dA/dd_k = -(p_k / sigma)(1 - A)
        ga = (g[:, 3] * (1.0 - out[:, 3])).astype(dt)         # per pixel
        g_d = 1.0 - p
        g_d *= g_p
        del g_p
        g_d += ga[gp]
        g_d *= p
        g_d *= -1.0 / sigma
        return g_col, g_d, g_zbuf


def _softmax_weights(fr: SoftFragments, bp: BlendParams, znear, zfar) -> dict:
    """The colour-independent part of softmax_rgb_blend: weights, normaliser, alpha.

    Computed one view at a time in float64 (the per-entry temporaries are a view's), stored in
    the fragments' dtype.
    """
    H, W = fr.image_size
    HW = H * W
    G = fr.n_views * HW
    gp = fr.global_pixel
    zn = np.broadcast_to(np.asarray(znear, np.float64).reshape(-1), (fr.n_views,))
    zf = np.broadcast_to(np.asarray(zfar, np.float64).reshape(-1), (fr.n_views,))
    sigma, gamma = float(bp.sigma), float(bp.gamma)
    p, log1mp = _sigmoid_terms(fr, sigma)
    dt = fr.dist.dtype
    m = len(fr)
    w, E, zrange = np.empty(m, dt), np.empty(m, dt), np.empty(m, dt)
    zmax = np.full(G, -np.inf)
    firsts = []
    depth = fr.depth
    for n, s in fr._views():  # loop over views
        if s.start == s.stop:
            continue
        pix = fr.pixel[s]
        zr = zf[n] - zn[n]
        zinv = (zf[n] - depth[s].astype(np.float64)) / zr
        zmax_n = zmax[n * HW:(n + 1) * HW]
        np.maximum.at(zmax_n, pix, zinv)
        # the entry holding each pixel's maximum (torch.max sends the gradient to one of them)
        cand = np.flatnonzero(zinv == zmax_n[pix])
        _, first_idx = np.unique(pix[cand], return_index=True)
        firsts.append(s.start + cand[first_idx])
        En = np.exp((zinv - np.maximum(zmax_n, _BLEND_EPS)[pix]) / gamma)
        E[s] = En
        w[s] = p[s] * En
        zrange[s] = zr
    first = np.concatenate(firsts) if firsts else np.zeros(0, np.int64)
    zm = np.maximum(zmax, _BLEND_EPS)
    zm_free = zmax > _BLEND_EPS
    delta_raw = np.exp((_BLEND_EPS - zm) / gamma)
    delta = np.maximum(delta_raw, _BLEND_EPS)
    delta_free = delta_raw > _BLEND_EPS
    D = np.bincount(gp, w, G) + delta
    alpha = -np.expm1(np.bincount(gp, log1mp, G))
    return {"D": D, "w": w, "p": p, "E": E, "gamma": gamma, "sigma": sigma, "delta": delta,
            "delta_free": delta_free, "first": first, "zm_free": zm_free, "zrange": zrange,
            "alpha": alpha}


def softmax_rgb_blend_soft(colors, fragments: SoftFragments,
                           blend_params: BlendParams | None = None, znear=1.0,
                           zfar=100.0) -> SoftBlend:
    """PyTorch3D's ``softmax_rgb_blend`` over the sparse entries, in float64.

    With ``p_k = sigmoid(-d_k / sigma)``, ``z_k = (zfar - zbuf_k) / (zfar - znear)``,
    ``zm = max(max_k z_k, 1e-10)``, ``w_k = p_k exp((z_k - zm) / gamma)`` and
    ``delta = max(exp((1e-10 - zm) / gamma), 1e-10)``::

        RGB = (sum_k w_k c_k + delta bg) / (sum_k w_k + delta),   A = 1 - prod_k (1 - p_k).

    Parameters
    ----------
    colors : (m, 3) float64
        Colour of each entry.
    fragments : SoftFragments
    blend_params : BlendParams, optional
    znear, zfar : float or (N,) float64
        The cameras' clipping planes (from the camera in PyTorch3D's shader).

    Returns
    -------
    SoftBlend
    """
    fr = _check_fragments(fragments)
    bp = _check_blend(blend_params)
    m = len(fr)
    col = as_array(colors, "colors", (m, 3), fr.dist.dtype)
    pre = _softmax_weights(fr, bp, znear, zfar)
    H, W = fr.image_size
    G = fr.n_views * H * W
    gp = fr.global_pixel
    w, D, delta = pre["w"], pre["D"], pre["delta"]
    bg = np.asarray(bp.background_color, np.float64)
    out = np.empty((G, 4))
    for c in range(3):  # colour channels
        out[:, c] = (np.bincount(gp, w * col[:, c], G) + delta * bg[c]) / D
    out[:, 3] = pre["alpha"]
    dtype = fr.dist.dtype
    saved = dict(pre, fragments=fr, colors=col, bg=bg)
    return SoftBlend(out.reshape(fr.n_views, H, W, 4).astype(dtype, copy=False),
                     (w / D[gp]).astype(dtype, copy=False), delta / D, saved)
