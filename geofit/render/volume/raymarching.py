"""Raymarchers: per-ray emission-absorption compositing of sampled densities and features.

:class:`EmissionAbsorptionRaymarcher` reproduces PyTorch3D's (``renderer/implicit/raymarching.py``)
by default: the densities ``d_i`` in [0, 1] are used directly as per-sample opacities, with no
sample-spacing factor (PyTorch3D issue #639), and with surface thickness ``s`` (1 by default)

    T_i = prod_{j <= i - s} (1 + eps - d_j)          (1 for i < s)
    w_i = d_i T_i,     features = sum_i w_i f_i,     opacity = 1 - prod_i (1 - d_i).

With ``physical=True`` the densities are extinction coefficients ``sigma_i >= 0`` and each sample
covers a step ``delta_i`` (from the ray lengths): ``alpha_i = 1 - exp(-sigma_i delta_i)`` replaces
``d_i`` and ``exp(-sigma_j delta_j)`` replaces ``1 + eps - d_j``, so the render no longer depends on
how finely the ray is sampled, and ``opacity = 1 - exp(-sum_i sigma_i delta_i)``.

Vector-Jacobian products (:meth:`EmissionAbsorptionRaymarcher.vjp`) use suffix sums instead of
dividing by transmittances (which underflow): with ``h_i = f_i . g`` for the upstream feature
gradient ``g`` and ``S_k = sum_{i >= k + s} w_i h_i`` (a reversed cumulative sum),

    d<g, features>/d f_i = w_i g,
    d<g, features>/d d_k = T_k h_k - S_k / (1 + eps - d_k)      (S_k carries that factor: exact),
    d<g, features>/d sigma_k = delta_k (exp(-sigma_k delta_k) T_k h_k - S_k)   (no division),
    d opacity / d d_k = prod_{j != k} (1 - d_j)    (prefix and suffix products),
    d opacity / d sigma_k = delta_k (1 - opacity).

Only where ``1 + eps - d_k`` is exactly 0 does the division fail; those (ray, sample) pairs are
recomputed with the factor left out of the product.

The transmittance algebra on ``(rays, samples)`` arrays, :func:`shifted_cumprod`,
:func:`suffix_from`, :func:`exclusive_product` and :func:`through_transmittance`, is public within
geofit (geofit's volume fit composes its own objective from it) but not in ``__all__``.
"""
from __future__ import annotations

import warnings
from typing import NamedTuple

import numpy as np

from ..._validate import as_array
from ..._validate import check_int as _as_int_at_least

__all__ = [
    "AbsorptionOnlyRaymarcher",
    "EmissionAbsorptionRaymarcher",
    "RaymarchGradients",
    "sample_deltas",
]


#: Densities this far outside [0, 1] (rounding of interpolated values) do not warn.
_RANGE_TOL = 1e-9


class RaymarchGradients(NamedTuple):
    """Gradients of ``<grad_output, raymarch(densities, features)>``.

    Attributes
    ----------
    densities : (..., n) or (..., n, 1) float64
        Shaped like the ``rays_densities`` input.
    features : (..., n, C) float64 or None
        Shaped like ``rays_features`` (None for the absorption-only raymarcher).
    """

    densities: np.ndarray
    features: np.ndarray | None


def sample_deltas(lengths, directions=None) -> np.ndarray:
    """Step length of each sample along its ray, for the physically based raymarcher.

    Parameters
    ----------
    lengths : (..., n) float64
        Increasing sample positions along each ray (PyTorch3D's ``RayBundle.lengths``).
    directions : (..., 3) float64, optional
        Ray directions; the steps are multiplied by their norms, which turns view depths into
        Euclidean distances for view-z-1 directions.

    Returns
    -------
    deltas : (..., n) float64
        ``lengths[i + 1] - lengths[i]``; the last sample repeats the previous step (n >= 2).

    Examples
    --------
    >>> sample_deltas([0.0, 0.5, 1.0, 2.0])
    array([0.5, 0.5, 1. , 1. ])
    """
    L = as_array(lengths, "lengths")
    if L.ndim < 1 or L.shape[-1] < 2:
        raise ValueError(f"lengths: expected shape (..., n) with n >= 2, got {L.shape}")
    d = np.diff(L, axis=-1)
    if np.any(d < 0):
        raise ValueError("lengths: expected non-decreasing sample positions along each ray")
    deltas = np.concatenate([d, d[..., -1:]], axis=-1)
    if directions is not None:
        D = as_array(directions, "directions", L.shape[:-1] + (3,))
        deltas = deltas * np.linalg.norm(D, axis=-1)[..., None]
    return deltas


def _scan(ufunc, a: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``ufunc.accumulate(a, axis=-1, out=out)`` for (..., n) views (reversed ones too).

    Many short rows (the usual case: thousands of rays, tens of samples) are scanned one
    column at a time: the same operations in the same order, so the same bits, but each step
    runs over all rows at once instead of numpy's per-row inner loop (3x faster measured on
    (20000, 27) float32).
    """
    n = a.shape[-1]
    rows = a.size // max(n, 1)
    if rows < _SCAN_ROWS_PER_COLUMN * n:
        return ufunc.accumulate(a, axis=-1, out=out)
    out[..., 0] = a[..., 0]
    for k in range(1, n):  # columns (samples); all rays at once
        ufunc(out[..., k - 1], a[..., k], out=out[..., k])
    return out


#: Rows per column above which :func:`_scan` loops over the columns (numpy's accumulate costs
#: ~80 ns per row, a column step ~1.5 us).
_SCAN_ROWS_PER_COLUMN = 32


def sequential_sum(q: np.ndarray) -> np.ndarray:
    """``q[..., 0] + q[..., 1] + ...`` added from the first sample on, as ``np.cumsum(q,
    axis=-1)[..., -1]`` (``np.sum`` adds pairwise: other bits); ``q`` is (..., n), n >= 1."""
    n = q.shape[-1]
    if q.size // max(n, 1) < _SCAN_ROWS_PER_COLUMN * n:
        return np.cumsum(q, axis=-1)[..., -1]
    acc = q[..., 0].copy()
    for k in range(1, n):  # columns (samples); all rays at once
        acc += q[..., k]
    return acc


def shifted_cumprod(c: np.ndarray, shift: int) -> np.ndarray:
    """``T[:, i] = prod_{j <= i - shift} c[:, j]`` (1 for ``i < shift``); ``c`` is (r, n)."""
    n = c.shape[1]
    T = np.empty_like(c)
    T[:, :shift] = 1.0
    if shift < n:
        _scan(np.multiply, c[:, : n - shift], T[:, shift:])
    return T


def suffix_from(q: np.ndarray, shift: int) -> np.ndarray:
    """``S[:, k] = sum_{i >= k + shift} q[:, i]`` for (r, n) ``q`` (reversed cumulative sum)."""
    n = q.shape[1]
    S = np.empty_like(q)
    S[:, max(n - shift, 0):] = 0.0
    if shift < n:  # summed from the end: S[:, n - 1 - shift] = q[:, n - 1], ...
        _scan(np.add, q[:, shift:][:, ::-1], S[:, : n - shift][:, ::-1])
    return S


def suffix_products(c: np.ndarray) -> np.ndarray:
    """``U[:, k] = prod_{j > k} c[:, j]`` (1 for the last sample), multiplied from the end."""
    U = np.empty_like(c)
    U[:, -1:] = 1.0
    if c.shape[1] > 1:
        _scan(np.multiply, c[:, :0:-1], U[:, -2::-1])
    return U


def exclusive_product(c: np.ndarray) -> np.ndarray:
    """``E[:, k] = prod_{j != k} c[:, j]`` from prefix and suffix products (no division)."""
    pre = shifted_cumprod(c, 1)
    pre *= suffix_products(c)
    return pre


def _suffix_excluding(c: np.ndarray, alpha: np.ndarray, h: np.ndarray, where, shift: int
                      ) -> np.ndarray:
    """``sum_{i >= k+s} alpha_i h_i prod_{j <= i-s, j != k} c_j`` for (ray, k) pairs ``where``.

    The derivative of the features through the transmittances where ``c_k`` is exactly 0 (so
    the usual ``S_k / c_k`` is 0 / 0): the product is recomputed with ``c_k`` left out.
    """
    rows, ks = where
    cc = c[rows].copy()
    cc[np.arange(len(rows)), ks] = 1.0
    T = shifted_cumprod(cc, shift)
    q = alpha[rows] * h[rows] * T
    n = c.shape[1]
    mask = np.arange(n)[None, :] >= (ks[:, None] + shift)
    return np.sum(np.where(mask, q, 0.0), axis=1)


def through_transmittance(S: np.ndarray, c: np.ndarray, alpha: np.ndarray, h: np.ndarray,
                           shift: int) -> np.ndarray:
    """``S / c`` (the gradient through the transmittances), exact where ``c`` is 0."""
    zero = c == 0.0
    if not zero.any():
        return S / c
    out = np.divide(S, c, out=np.zeros_like(S), where=~zero)
    out[zero] = _suffix_excluding(c, alpha, h, np.nonzero(zero), shift)
    return out


def _density_layout(rays_densities, feature_shape: tuple | None, name="rays_densities"):
    """Validate densities as (..., n) or (..., n, 1); return (array, flat (r, n), had_trailing)."""
    d = as_array(rays_densities, name)
    if d.ndim < 1:
        raise ValueError(f"{name}: expected shape (..., n) or (..., n, 1), got {d.shape}")
    trailing = False
    if feature_shape is not None:
        lead = feature_shape[:-1]
        if d.shape == lead + (1,) and d.shape != lead:
            trailing = True
        elif d.shape != lead:
            raise ValueError(f"{name}: expected shape {lead} or {lead + (1,)} to match "
                             f"rays_features {feature_shape}, got {d.shape}")
    elif d.ndim >= 2 and d.shape[-1] == 1:
        trailing = True
    core = d[..., 0] if trailing else d
    if core.ndim < 1 or core.shape[-1] == 0:
        raise ValueError(f"{name}: expected at least one sample per ray, got shape {d.shape}")
    return d, core.reshape(-1, core.shape[-1]), trailing


class _Marched(NamedTuple):
    """Per-ray intermediates of one forward pass (flat (r, n) layout)."""

    alpha: np.ndarray      # (r, n) per-sample opacity
    c: np.ndarray          # (r, n) absorption factor of each sample
    T: np.ndarray          # (r, n) transmittance before each sample
    w: np.ndarray          # (r, n) weights
    features: np.ndarray   # (r, C)
    opacity: np.ndarray    # (r,)


class EmissionAbsorptionRaymarcher:
    """Emission-absorption raymarching, PyTorch3D's by default (see the module docstring).

    Parameters
    ----------
    surface_thickness : int
        PyTorch3D's shift of the absorption cumprod (>= 1; 1 means T_i uses samples j < i).
    physical : bool
        False (default): densities are per-sample opacities, exactly as PyTorch3D. True:
        densities are extinction coefficients and ``alpha = 1 - exp(-sigma * delta)`` with the
        steps ``delta`` passed to the call (see :func:`sample_deltas`).
    eps : float
        PyTorch3D's ``eps`` added in ``1 + eps - d`` (opacity mode only).

    Examples
    --------
    >>> ea = EmissionAbsorptionRaymarcher()
    >>> d = np.array([[0.5, 0.5]])
    >>> f = np.array([[[1.0], [0.0]]])
    >>> ea(d, f).round(6)        # features 0.5 * 1 + 0.25 * 0, opacity 1 - 0.25
    array([[0.5 , 0.75]])
    """

    def __init__(self, surface_thickness: int = 1, *, physical: bool = False,
                 eps: float = 1e-10):
        self.surface_thickness = _as_int_at_least(surface_thickness, "surface_thickness", 1)
        if not isinstance(physical, (bool, np.bool_)):
            raise TypeError(f"physical: expected True or False, got {physical!r}")
        self.physical = bool(physical)
        eps = float(eps)
        if not np.isfinite(eps) or eps < 0:
            raise ValueError(f"eps: expected a finite number >= 0, got {eps!r}")
        self.eps = eps

    def __repr__(self) -> str:
        return (f"EmissionAbsorptionRaymarcher(surface_thickness={self.surface_thickness}, "
                f"physical={self.physical}, eps={self.eps:g})")

    # ---- validation ------------------------------------------------------------------------

    def _inputs(self, rays_densities, rays_features, deltas):
        f = as_array(rays_features, "rays_features")
        if f.ndim < 2:
            raise ValueError(f"rays_features: expected shape (..., n, C), got {f.shape}")
        d, dflat, trailing = _density_layout(rays_densities, f.shape)
        n, C = f.shape[-2], f.shape[-1]
        fflat = f.reshape(-1, n, C)
        dl = None
        if self.physical:
            if deltas is None:
                raise ValueError("deltas: the physical raymarcher needs the step of every "
                                 "sample (see sample_deltas)")
            dl = as_array(deltas, "deltas", f.shape[:-1])
            if np.any(dl < 0):
                raise ValueError("deltas: expected non-negative steps")
            dl = dl.reshape(-1, n)
            if np.any(dflat < 0):
                raise ValueError("rays_densities: the physical raymarcher needs extinction "
                                 "coefficients >= 0")
        elif dflat.size and (dflat.min() < -_RANGE_TOL or dflat.max() > 1.0 + _RANGE_TOL):
            warnings.warn("EmissionAbsorptionRaymarcher: one or more rays_densities are "
                          "outside the valid range [0, 1]", UserWarning, stacklevel=3)
        return d, dflat, trailing, f, fflat, dl

    # ---- core ------------------------------------------------------------------------------

    def _march(self, dflat: np.ndarray, fflat: np.ndarray, dl: np.ndarray | None) -> _Marched:
        s = self.surface_thickness
        if self.physical:
            tau = dflat * dl
            c = np.exp(-tau)
            alpha = -np.expm1(-tau)
            T = shifted_cumprod(c, s)
            opacity = -np.expm1(-tau.sum(axis=1))
        else:
            alpha = dflat
            c = (1.0 + self.eps) - dflat
            T = shifted_cumprod(c, s)
            opacity = 1.0 - np.prod(1.0 - dflat, axis=1)
        w = alpha * T
        feats = np.einsum("rn,rnc->rc", w, fflat)
        return _Marched(alpha, c, T, w, feats, opacity)

    def _grads(self, m: _Marched, dflat, fflat, dl, g_feat, g_opac):
        """Flat gradients (r, n) and (r, n, C) from the upstream (r, C) and (r,) gradients."""
        s = self.surface_thickness
        h = np.einsum("rnc,rc->rn", fflat, g_feat)
        S = suffix_from(m.w * h, s)
        if self.physical:
            gd = dl * (m.c * m.T * h - S) + (dl * (1.0 - m.opacity)[:, None]) * g_opac[:, None]
        else:
            through_T = through_transmittance(S, m.c, m.alpha, h, s)
            gd = m.T * h - through_T + exclusive_product(1.0 - dflat) * g_opac[:, None]
        gf = m.w[:, :, None] * g_feat[:, None, :]
        return gd, gf

    # ---- public ----------------------------------------------------------------------------

    def __call__(self, rays_densities, rays_features, deltas=None) -> np.ndarray:
        """Composite each ray.

        Parameters
        ----------
        rays_densities : (..., n) or (..., n, 1) float64
            Per-sample densities (opacities in [0, 1], or extinction coefficients >= 0 when
            ``physical``). PyTorch3D passes ``(..., n, 1)``.
        rays_features : (..., n, C) float64
            Per-sample features.
        deltas : (..., n) float64, optional
            Step of each sample (required when ``physical``; see :func:`sample_deltas`).

        Returns
        -------
        out : (..., C + 1) float64
            The composited features followed by the opacity, as PyTorch3D's
            ``concat(features, opacities)``.
        """
        _, dflat, _, f, fflat, dl = self._inputs(rays_densities, rays_features, deltas)
        m = self._march(dflat, fflat, dl)
        out = np.concatenate([m.features, m.opacity[:, None]], axis=1)
        return out.reshape(f.shape[:-2] + (f.shape[-1] + 1,))

    def vjp(self, grad_output, rays_densities, rays_features, deltas=None) -> RaymarchGradients:
        """Gradient of ``<grad_output, self(rays_densities, rays_features)>``.

        Parameters
        ----------
        grad_output : (..., C + 1) float64
            Upstream gradient on the output (features, then opacity).
        rays_densities, rays_features, deltas
            As in :meth:`__call__`.

        Returns
        -------
        RaymarchGradients
            ``densities`` shaped like ``rays_densities`` and ``features`` like
            ``rays_features``.

        Notes
        -----
        The map is smooth in the densities and features; all terms are differentiable.
        """
        d, dflat, _, f, fflat, dl = self._inputs(rays_densities, rays_features, deltas)
        C = f.shape[-1]
        g = as_array(grad_output, "grad_output", f.shape[:-2] + (C + 1,)).reshape(-1, C + 1)
        m = self._march(dflat, fflat, dl)
        gd, gf = self._grads(m, dflat, fflat, dl, g[:, :C], g[:, C])
        return RaymarchGradients(gd.reshape(d.shape), gf.reshape(f.shape))


class AbsorptionOnlyRaymarcher:
    """Opacity only: ``1 - prod_i (1 - d_i)`` (PyTorch3D's ``AbsorptionOnlyRaymarcher``).

    Parameters
    ----------
    physical : bool
        If True, densities are extinction coefficients and ``opacity = 1 - exp(-sum sigma
        delta)`` with the steps passed to the call.

    Examples
    --------
    >>> AbsorptionOnlyRaymarcher()(np.array([[0.5, 0.5]]))
    array([[0.75]])
    """

    def __init__(self, *, physical: bool = False):
        if not isinstance(physical, (bool, np.bool_)):
            raise TypeError(f"physical: expected True or False, got {physical!r}")
        self.physical = bool(physical)

    def __repr__(self) -> str:
        return f"AbsorptionOnlyRaymarcher(physical={self.physical})"

    def _inputs(self, rays_densities, deltas):
        d, dflat, trailing = _density_layout(rays_densities, None)
        dl = None
        if self.physical:
            if deltas is None:
                raise ValueError("deltas: the physical raymarcher needs the step of every "
                                 "sample (see sample_deltas)")
            core_shape = d.shape[:-1] if trailing else d.shape
            dl = as_array(deltas, "deltas", core_shape).reshape(dflat.shape)
            if np.any(dl < 0) or np.any(dflat < 0):
                raise ValueError("rays_densities/deltas: expected non-negative values for the "
                                 "physical raymarcher")
        elif dflat.size and (dflat.min() < -_RANGE_TOL or dflat.max() > 1.0 + _RANGE_TOL):
            warnings.warn("AbsorptionOnlyRaymarcher: one or more rays_densities are outside "
                          "the valid range [0, 1]", UserWarning, stacklevel=3)
        lead = (d.shape[:-2] if trailing else d.shape[:-1])
        return d, dflat, dl, lead

    def __call__(self, rays_densities, deltas=None) -> np.ndarray:
        """Opacity of each ray.

        Parameters
        ----------
        rays_densities : (..., n) or (..., n, 1) float64
        deltas : (..., n) float64, optional
            Required when ``physical``.

        Returns
        -------
        opacities : (..., 1) float64
        """
        _, dflat, dl, lead = self._inputs(rays_densities, deltas)
        if self.physical:
            op = -np.expm1(-(dflat * dl).sum(axis=1))
        else:
            op = 1.0 - np.prod(1.0 - dflat, axis=1)
        return op.reshape(lead + (1,))

    def vjp(self, grad_output, rays_densities, deltas=None) -> RaymarchGradients:
        """Gradient of ``<grad_output, self(rays_densities)>``.

        Parameters
        ----------
        grad_output : (..., 1) float64
        rays_densities, deltas
            As in :meth:`__call__`.

        Returns
        -------
        RaymarchGradients
            ``densities`` shaped like ``rays_densities``; ``features`` is None.
        """
        d, dflat, dl, lead = self._inputs(rays_densities, deltas)
        g = as_array(grad_output, "grad_output", lead + (1,)).reshape(-1)
        if self.physical:
            trans = np.exp(-(dflat * dl).sum(axis=1))
            gd = dl * (trans * g)[:, None]
        else:
            gd = exclusive_product(1.0 - dflat) * g[:, None]
        return RaymarchGradients(gd.reshape(d.shape), None)
