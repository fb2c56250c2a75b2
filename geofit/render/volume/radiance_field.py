"""The NeRF tutorial's network, :class:`NeuralRadianceField`, with its backward pass.

The network of ``fit_simple_neural_radiance_field``: a harmonic embedding of the sample points,
an MLP trunk, a density head ``density = 1 - exp(-softplus(Linear(features)))`` whose bias
starts at -1.5, and a colour head on ``[features, embedding(normalised ray direction)]`` ending
in a sigmoid. Width, depth, number of frequencies and activation are configurable;
``forward``/``backward`` run on packed samples ``(k, 3)`` (so that empty space can be skipped),
``__call__`` on a :class:`RayBundle` as the tutorial's ``volumetric_function``, and
:meth:`NeuralRadianceField.forward_batched` over chunks of rays so that a full-image render
fits in memory. Network arithmetic is in the field's dtype (float32 for fitting, float64 for
finite-difference checks). :class:`~geofit.render.volume.implicit.ImplicitRenderer` marches it.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..._validate import as_array, as_rng, check_choice
from ..._validate import check_int as _int_at_least
from ...nn.layers import Linear, ReLU, Sequential, Sigmoid, Softplus
from .harmonic import HarmonicEmbedding
from .raysampling import RayBundle

__all__ = ["ACTIVATIONS", "NeuralRadianceField"]

#: Hidden-layer activations of :class:`NeuralRadianceField`.
ACTIVATIONS = ("softplus", "relu")


# --------------------------------------------------------------------------------------------
# The field
# --------------------------------------------------------------------------------------------


@dataclass
class _FieldCache:
    k: int
    n_rays: int
    ray_index: np.ndarray | None
    trunk: Any
    features: np.ndarray
    density_lin: Any
    density_act: Any
    tau: np.ndarray
    step_scale: Any
    transmit: np.ndarray            # exp(-tau) = 1 - density
    dir_embedding: np.ndarray       # (n_rays or k, E_dir)
    color_act: Any
    color_out: Any
    color_sig: Any


class NeuralRadianceField:
    """The NeRF tutorial's radiance field, in numpy, with a hand-written backward pass.

    Parameters
    ----------
    n_harmonic_functions : int
        Frequencies of the point embedding (the tutorial: 60).
    n_hidden_neurons : int
        Width of the trunk (the tutorial: 256).
    n_hidden_layers : int
        Linear + activation blocks in the trunk (the tutorial: 2).
    omega0 : float
        Base frequency: ``f_k = omega0 2^k`` (the tutorial: 0.1).
    append_input : bool
        Append the raw coordinates to the point embedding (the tutorial: no).
    n_harmonic_functions_dir : int, optional
        Frequencies of the direction embedding (default: ``n_harmonic_functions``, as the
        tutorial, which embeds directions with the same module).
    omega0_dir : float, optional
        Base frequency of the direction embedding (default ``omega0``).
    n_hidden_color : int, optional
        Width of the colour head's hidden layer (default ``n_hidden_neurons``).
    activation : {"softplus", "relu"}
        Hidden activation; the tutorial's is Softplus(beta=10).
    beta : float
        Softplus sharpness (also used by the density head's Softplus).
    density_bias : float
        Initial bias of the density head (the tutorial: -1.5).
    seed : int or numpy.random.Generator, optional
        Weight initialisation (PyTorch's uniform ``+-1/sqrt(fan_in)``).
    dtype : float32 or float64
        Arithmetic and parameter dtype.

    Attributes
    ----------
    params : dict str -> ndarray
        Named like the tutorial module's ``state_dict``: ``mlp.0.weight``, ...,
        ``density_layer.0.weight``, ``density_layer.0.bias``, ``color_layer.0.weight``, ...
    n_params : int
        Number of scalar parameters (317,188 for the tutorial's network).

    Notes
    -----
    The embeddings use true cosines (the tutorial's own embedding module); with the tutorial's
    float32 frequency buffer ``fl32(omega0) 2^k`` they equal PyTorch3D's to an ulp.

    The colour head's first layer acts on ``[features, direction embedding]``; its direction
    part is computed once per ray and gathered per sample (the same numbers, fewer products).

    Examples
    --------
    >>> field = NeuralRadianceField()
    >>> field.n_params
    317188
    >>> small = NeuralRadianceField(6, 32, omega0=1.0, seed=0)
    >>> d, c, _ = small.forward(np.zeros((4, 3)), np.array([[0.0, 0.0, 1.0]]),
    ...                         ray_index=np.zeros(4, dtype=np.int64), cache=False)
    >>> d.shape, c.shape, bool(np.all((d >= 0) & (d < 1)))
    ((4, 1), (4, 3), True)
    """

    def __init__(self, n_harmonic_functions: int = 60, n_hidden_neurons: int = 256, *,
                 n_hidden_layers: int = 2, omega0: float = 0.1, append_input: bool = False,
                 n_harmonic_functions_dir: int | None = None, omega0_dir: float | None = None,
                 n_hidden_color: int | None = None, activation: str = "softplus",
                 beta: float = 10.0, density_bias: float = -1.5, seed=0, dtype=np.float32):
        check_choice(activation, "activation", ACTIVATIONS)
        H = _int_at_least(n_hidden_neurons, "n_hidden_neurons", 1)
        depth = _int_at_least(n_hidden_layers, "n_hidden_layers", 1)
        Hc = H if n_hidden_color is None else _int_at_least(n_hidden_color, "n_hidden_color", 1)
        self.embedding = HarmonicEmbedding(n_harmonic_functions, omega0,
                                           append_input=append_input, exact_cos=True)
        n_dir = n_harmonic_functions if n_harmonic_functions_dir is None else \
            n_harmonic_functions_dir
        self.dir_embedding = HarmonicEmbedding(n_dir, omega0 if omega0_dir is None else omega0_dir,
                                               append_input=append_input, exact_cos=True)
        self.config = {
            "n_harmonic_functions": int(n_harmonic_functions), "n_hidden_neurons": H,
            "n_hidden_layers": depth, "omega0": float(omega0), "append_input": bool(append_input),
            "n_harmonic_functions_dir": int(n_dir),
            "omega0_dir": float(omega0 if omega0_dir is None else omega0_dir),
            "n_hidden_color": Hc, "activation": activation, "beta": float(beta),
            "density_bias": float(density_bias),
        }
        rng = as_rng(seed)
        dt = np.dtype(dtype)
        E = self.embedding.output_dim(3)
        Ed = self.dir_embedding.output_dim(3)

        def act():
            return Softplus(beta, dtype=dt) if activation == "softplus" else ReLU(dtype=dt)

        trunk = [Linear(E, H, seed=rng, dtype=dt), act()]
        for _ in range(depth - 1):  # layers
            trunk += [Linear(H, H, seed=rng, dtype=dt), act()]
        self.mlp = Sequential(*trunk)
        self.density_layer = Sequential(Linear(H, 1, seed=rng, dtype=dt), Softplus(beta, dtype=dt))
        self.density_layer[0].params["bias"][0] = density_bias
        self.color_layer = Sequential(Linear(H + Ed, Hc, seed=rng, dtype=dt), act(),
                                      Linear(Hc, 3, seed=rng, dtype=dt), Sigmoid(dtype=dt))
        self.dtype = dt
        self.n_hidden_neurons = H

    # ---- parameters ------------------------------------------------------------------------

    _PARTS = ("mlp", "density_layer", "color_layer")

    @property
    def params(self) -> dict[str, np.ndarray]:
        """All parameters, named as the tutorial module's ``state_dict`` (live arrays)."""
        out = {}
        for part in self._PARTS:
            for k, v in getattr(self, part).params.items():
                out[f"{part}.{k}"] = v
        return out

    def set_params(self, values: Mapping[str, np.ndarray]) -> None:
        """Copy parameter values in (names and shapes as :attr:`params`)."""
        current = self.params
        for name, v in values.items():
            if name not in current:
                raise ValueError(f"values: unknown parameter {name!r}")
            v = np.asarray(v)
            if v.shape != current[name].shape:
                raise ValueError(f"values[{name!r}]: expected shape {current[name].shape}, "
                                 f"got {v.shape}")
            current[name][...] = v

    @property
    def n_params(self) -> int:
        return int(sum(v.size for v in self.params.values()))

    def get_flat(self) -> np.ndarray:
        """All parameters as one float64 vector (in :attr:`params` order)."""
        return np.concatenate([v.ravel() for v in self.params.values()]).astype(np.float64)

    def set_flat(self, x) -> None:
        """Set all parameters from a vector made by :meth:`get_flat`."""
        x = as_array(x, "x", (self.n_params,))
        i = 0
        for v in self.params.values():
            v[...] = x[i:i + v.size].reshape(v.shape)
            i += v.size

    def flatten_grads(self, grads: Mapping[str, np.ndarray]) -> np.ndarray:
        """Gradients as one float64 vector, ordered as :meth:`get_flat`."""
        return np.concatenate([np.asarray(grads[k]).ravel() for k in self.params]
                              ).astype(np.float64)

    def astype(self, dtype) -> NeuralRadianceField:
        """A copy of the field with parameters and arithmetic in ``dtype``."""
        new = object.__new__(NeuralRadianceField)
        new.__dict__.update(self.__dict__)
        for part in self._PARTS:
            setattr(new, part, getattr(self, part).astype(dtype))
        new.dtype = np.dtype(dtype)
        return new

    def copy(self) -> NeuralRadianceField:
        """An independent copy (same dtype)."""
        return self.astype(self.dtype)

    def __repr__(self) -> str:
        c = self.config
        return (f"NeuralRadianceField(n_harmonic_functions={c['n_harmonic_functions']}, "
                f"n_hidden_neurons={c['n_hidden_neurons']}, "
                f"n_hidden_layers={c['n_hidden_layers']}, activation={c['activation']!r}, "
                f"n_params={self.n_params})")

    # ---- forward / backward on packed samples ----------------------------------------------

    def forward(self, points, directions, ray_index=None, *, step_scale=None, cache=True):
        """Densities and colours at packed sample points.

        Parameters
        ----------
        points : (k, 3) float
            Sample positions (world).
        directions : (r, 3) float
            Ray directions (any length > 0; normalised here, as the tutorial does). With
            ``ray_index`` they are per ray; without, per sample (``r == k``).
        ray_index : (k,) int64, optional
            ``ray_index[i]`` is the ray of sample ``i``.
        step_scale : float or (k,) float, optional
            Multiplies the raw density before ``1 - exp(-.)`` (the ratio of a sample's step to
            the reference step); None means 1, the tutorial's field.
        cache : bool
            Keep what :meth:`backward` needs.

        Returns
        -------
        densities : (k, 1)
            Per-sample opacities in [0, 1).
        colors : (k, 3)
            RGB in (0, 1).
        cache : object or None
            For :meth:`backward`.
        """
        P = as_array(points, "points", (None, 3))
        D = as_array(directions, "directions", (None, 3))
        k = P.shape[0]
        if ray_index is None:
            if D.shape[0] != k:
                raise ValueError(f"directions: expected shape ({k}, 3) without ray_index, got "
                                 f"{D.shape}")
            idx = None
        else:
            idx = as_array(ray_index, "ray_index", (k,), np.int64)
            if k and (idx.min() < 0 or idx.max() >= D.shape[0]):
                raise ValueError(f"ray_index: expected values in [0, {D.shape[0] - 1}], got "
                                 f"range [{idx.min()}, {idx.max()}]")
        norms = np.linalg.norm(D, axis=1)
        if np.any(norms <= 0):
            raise ValueError("directions: expected non-zero vectors")
        if step_scale is not None:
            step_scale = np.asarray(step_scale, dtype=np.float64)
            if step_scale.ndim == 1:
                step_scale = as_array(step_scale, "step_scale", (k,))[:, None]
            elif step_scale.ndim != 0:
                raise ValueError(f"step_scale: expected a number or shape ({k},), got "
                                 f"{step_scale.shape}")
            if np.any(step_scale < 0) or not np.all(np.isfinite(step_scale)):
                raise ValueError("step_scale: expected finite values >= 0")
        return self._forward(P, D, idx, step_scale, cache)

    def _forward(self, P, D, idx, step_scale, cache):
        dt = self.dtype
        k = P.shape[0]
        Dn = D / np.maximum(np.linalg.norm(D, axis=1, keepdims=True), 1e-12)
        emb = self.embedding._embed(P.astype(dt, copy=False))
        demb = self.dir_embedding._embed(Dn.astype(dt, copy=False))
        feat, c_trunk = self.mlp.forward(emb, cache=cache)
        lin, act = self.density_layer[0], self.density_layer[1]
        pre, c_dl = lin.forward(feat, cache=cache)
        raw, c_da = act.forward(pre, cache=cache)
        tau = raw if step_scale is None else (raw * step_scale).astype(dt)
        transmit = np.exp(-tau)
        densities = 1.0 - transmit
        c0, cact, c2, csig = self.color_layer.layers
        H = self.n_hidden_neurons
        W = c0.params["weight"]
        hid = feat @ W[:, :H].T
        dir_part = demb @ W[:, H:].T
        dir_part += c0.params["bias"]
        hid += dir_part if idx is None else dir_part[idx]
        h, c_ca = cact.forward(hid, cache=cache)
        out, c_c2 = c2.forward(h, cache=cache)
        colors, c_cs = csig.forward(out, cache=cache)
        if not cache:
            return densities, colors, None
        fc = _FieldCache(k=k, n_rays=demb.shape[0], ray_index=idx, trunk=c_trunk,
                         features=feat, density_lin=c_dl, density_act=c_da, tau=tau,
                         step_scale=step_scale, transmit=transmit, dir_embedding=demb,
                         color_act=c_ca, color_out=c_c2, color_sig=c_cs)
        return densities, colors, fc

    def backward(self, cache: _FieldCache, grad_densities, grad_colors) -> dict[str, np.ndarray]:
        """Parameter gradients of ``<grad_densities, densities> + <grad_colors, colors>``.

        Parameters
        ----------
        cache : object
            From :meth:`forward` (``cache=True``).
        grad_densities : (k, 1) float
        grad_colors : (k, 3) float

        Returns
        -------
        grads : dict str -> ndarray
            Named and shaped as :attr:`params`, in the field's dtype.
        """
        if not isinstance(cache, _FieldCache):
            raise TypeError("cache: expected the cache returned by forward(..., cache=True)")
        dt = self.dtype
        gd = as_array(grad_densities, "grad_densities", (cache.k, 1)).astype(dt)
        gc = as_array(grad_colors, "grad_colors", (cache.k, 3)).astype(dt)
        grads: dict[str, np.ndarray] = {}
        # density = 1 - exp(-tau), tau = raw * scale
        g_raw = gd * cache.transmit
        if cache.step_scale is not None:
            g_raw = (g_raw * cache.step_scale).astype(dt)
        lin, act = self.density_layer[0], self.density_layer[1]
        g_pre, _ = act.backward(cache.density_act, g_raw)
        g_feat, gl = lin.backward(cache.density_lin, g_pre)
        grads.update({f"density_layer.0.{n}": v for n, v in gl.items()})
        # colour head
        c0, cact, c2, csig = self.color_layer.layers
        g_out, _ = csig.backward(cache.color_sig, gc)
        g_h, gl = c2.backward(cache.color_out, g_out)
        grads.update({f"color_layer.2.{n}": v for n, v in gl.items()})
        g_hid, _ = cact.backward(cache.color_act, g_h)
        H = self.n_hidden_neurons
        W = c0.params["weight"]
        if cache.ray_index is None:
            g_ray = g_hid
        else:
            S = sp.csr_matrix((np.ones(cache.k, dtype=dt), (cache.ray_index, np.arange(cache.k))),
                              shape=(cache.n_rays, cache.k))
            g_ray = np.asarray(S @ g_hid, dtype=dt)
        gW = np.empty_like(W)
        gW[:, :H] = g_hid.T @ cache.features
        gW[:, H:] = g_ray.T @ cache.dir_embedding
        grads["color_layer.0.weight"] = gW
        grads["color_layer.0.bias"] = g_hid.sum(axis=0)
        g_feat += g_hid @ W[:, :H]
        _, gl = self.mlp.backward(cache.trunk, g_feat, need_input_grad=False)
        grads.update({f"mlp.{n}": v for n, v in gl.items()})
        return {name: grads[name] for name in self.params}

    # ---- the tutorial's volumetric_function -------------------------------------------------

    def forward_rays(self, ray_bundle: RayBundle, *, cache: bool = False):
        """Densities ``(..., n, 1)`` and colours ``(..., n, 3)`` at every sample of a bundle.

        Returns ``(densities, colors, cache)``; ``cache`` is None unless asked for.
        """
        bundle = _check_bundle(ray_bundle)
        o, d, lengths = bundle.origins, bundle.directions, bundle.lengths
        lead = lengths.shape[:-1]
        n = lengths.shape[-1]
        r = int(np.prod(lead, dtype=np.int64))
        pts = (o[..., None, :] + lengths[..., None] * d[..., None, :]).reshape(r * n, 3)
        idx = np.repeat(np.arange(r, dtype=np.int64), n)
        dens, cols, c = self._forward(pts, d.reshape(r, 3), idx, None, cache)
        return dens.reshape(*lead, n, 1), cols.reshape(*lead, n, 3), c

    def __call__(self, ray_bundle: RayBundle, **kwargs):
        """The tutorial's ``forward(ray_bundle)``: ``(densities (..., n, 1), colors (..., n, 3))``.

        Keyword arguments (``cameras=`` from the renderer) are ignored, as in the tutorial.
        """
        dens, cols, _ = self.forward_rays(ray_bundle)
        return dens, cols

    def forward_batched(self, ray_bundle: RayBundle, n_batches: int = 16, **kwargs):
        """:meth:`__call__` over ``n_batches`` chunks of rays (the tutorial's
        ``batched_forward``), so a full-image bundle fits in memory.

        Returns
        -------
        densities : (..., n, 1)
        colors : (..., n, 3)
        """
        bundle = _check_bundle(ray_bundle)
        n_batches = _int_at_least(n_batches, "n_batches", 1)
        lead = bundle.lengths.shape[:-1]
        n = bundle.lengths.shape[-1]
        r = int(np.prod(lead, dtype=np.int64))
        flat = RayBundle(bundle.origins.reshape(r, 3), bundle.directions.reshape(r, 3),
                         bundle.lengths.reshape(r, n), bundle.xys.reshape(r, -1))
        dens = np.empty((r, n, 1), dtype=self.dtype)
        cols = np.empty((r, n, 3), dtype=self.dtype)
        for chunk in np.array_split(np.arange(r), n_batches):  # chunks of rays
            if chunk.size == 0:
                continue
            sl = slice(chunk[0], chunk[-1] + 1)
            sub = RayBundle(flat.origins[sl], flat.directions[sl], flat.lengths[sl],
                            flat.xys[sl])
            dens[sl], cols[sl], _ = self.forward_rays(sub)
        return dens.reshape(*lead, n, 1), cols.reshape(*lead, n, 3)

    batched_forward = forward_batched


def _check_bundle(ray_bundle) -> RayBundle:
    if not isinstance(ray_bundle, RayBundle):
        raise TypeError(f"ray_bundle: expected a RayBundle, got {type(ray_bundle)!r}")
    o, d, lengths = ray_bundle.origins, ray_bundle.directions, ray_bundle.lengths
    if o.shape != d.shape or o.shape[-1] != 3 or lengths.shape[:-1] != o.shape[:-1]:
        raise ValueError("ray_bundle: origins and directions must be (..., 3) and lengths "
                         f"(..., n); got {o.shape}, {d.shape} and {lengths.shape}")
    return ray_bundle
