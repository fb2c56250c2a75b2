"""Neural radiance fields and the implicit renderer that marches them, with backward passes.

* :class:`NeuralRadianceField` -- the NeRF tutorial's network
  (``fit_simple_neural_radiance_field``): a harmonic embedding of the sample points, an MLP trunk, a density head
  ``density = 1 - exp(-softplus(Linear(features)))`` whose bias starts at -1.5, and a colour head
  on ``[features, embedding(normalised ray direction)]`` ending in a sigmoid. Width, depth, number
  of frequencies and activation are configurable; ``forward``/``backward`` run on packed samples
  ``(k, 3)`` (so that empty space can be skipped), ``__call__`` on a :class:`RayBundle` as the
  tutorial's ``volumetric_function``, and :meth:`NeuralRadianceField.forward_batched` over chunks
  of rays so that a full-image render fits in memory.
* :class:`OccupancyGrid` -- a boolean voxel grid saying where the scene can be (a visual hull, a
  thresholded coarse density grid). Samples outside it are skipped: their density is exactly 0.
* :class:`ImplicitRenderer` -- PyTorch3D's ``ImplicitRenderer(raysampler, raymarcher)``: draws a
  ray bundle, evaluates the field at its samples (only the occupied ones when a grid is given) and
  composites them with the emission-absorption raymarcher; :meth:`ImplicitRenderer.backward`
  carries a gradient on the pixels back to the network weights.

The chain rule, in plain sight: pixels ``(R, 4)`` -> raymarcher vjp -> per-sample densities and
colours -> density head (``d density / d raw = 1 - density``) and colour head -> the shared trunk
-> weight gradients. Network arithmetic is in the field's dtype (float32 for fitting, float64
for finite-difference checks); the raymarcher works in float64.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import scipy.sparse as sp

from .._validate import as_array, as_rng, check_choice
from ..nn.layers import Linear, ReLU, Sequential, Sigmoid, Softplus
from ..structures.volume import carve
from .harmonic import HarmonicEmbedding
from .raysampling import RayBundle

__all__ = [
    "ACTIVATIONS",
    "ImplicitRenderer",
    "NeuralRadianceField",
    "OccupancyGrid",
    "RenderCache",
]

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


def _int_at_least(value, name: str, low: int) -> int:
    try:
        v = int(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected an integer >= {low}, got {value!r}") from None
    if v < low or v != value:
        raise ValueError(f"{name}: expected an integer >= {low}, got {value!r}")
    return v


def _check_bundle(ray_bundle) -> RayBundle:
    if not isinstance(ray_bundle, RayBundle):
        raise TypeError(f"ray_bundle: expected a RayBundle, got {type(ray_bundle)!r}")
    o, d, lengths = ray_bundle.origins, ray_bundle.directions, ray_bundle.lengths
    if o.shape != d.shape or o.shape[-1] != 3 or lengths.shape[:-1] != o.shape[:-1]:
        raise ValueError("ray_bundle: origins and directions must be (..., 3) and lengths "
                         f"(..., n); got {o.shape}, {d.shape} and {lengths.shape}")
    return ray_bundle


# --------------------------------------------------------------------------------------------
# Occupancy
# --------------------------------------------------------------------------------------------


class OccupancyGrid:
    """Where the scene can be: a boolean voxel grid over an axis-aligned box.

    Parameters
    ----------
    occupied : (D, H, W) bool
        ``occupied[z, y, x]``: voxel with x index along W, y along H, z along D (PyTorch3D's
        volume layout).
    bounds : (2, 3) float64
        ``[min corner, max corner]`` of the box in world coordinates (x, y, z).
    opacity : (D, H, W) float32, optional
        An estimate of the per-sample opacity in each voxel (a coarse density grid); with it,
        :class:`ImplicitRenderer` can skip samples hidden behind opaque voxels.

    Examples
    --------
    >>> g = OccupancyGrid(np.ones((2, 2, 2), bool), [[-1, -1, -1], [1, 1, 1]])
    >>> g.contains(np.array([[0.5, 0.5, 0.5], [2.0, 0.0, 0.0]])).tolist()
    [True, False]
    """

    def __init__(self, occupied, bounds, opacity=None):
        occ = np.asarray(occupied)
        if occ.ndim != 3 or min(occ.shape) < 1:
            raise ValueError(f"occupied: expected shape (D, H, W), got {occ.shape}")
        self.occupied = np.ascontiguousarray(occ, dtype=bool)
        b = as_array(bounds, "bounds", (2, 3))
        if np.any(b[1] <= b[0]):
            raise ValueError(f"bounds: expected max corner > min corner, got {b.tolist()}")
        self.bounds = b
        D, H, W = self.occupied.shape
        self.shape_xyz = np.array([W, H, D])
        self.voxel_size = (b[1] - b[0]) / self.shape_xyz
        if opacity is not None:
            opacity = as_array(opacity, "opacity", occ.shape, np.float32)
            if np.any((opacity < 0) | (opacity > 1)):
                raise ValueError("opacity: expected values in [0, 1]")
        self.opacity = opacity

    def __repr__(self) -> str:
        return (f"OccupancyGrid(shape={self.occupied.shape}, "
                f"occupied={self.fraction_occupied:.3%})")

    @property
    def fraction_occupied(self) -> float:
        return float(self.occupied.mean())

    def centers(self) -> np.ndarray:
        """World positions of the voxel centres, ``(D, H, W, 3)`` (x, y, z)."""
        D, H, W = self.occupied.shape
        lo, vs = self.bounds[0], self.voxel_size
        z = lo[2] + (np.arange(D) + 0.5) * vs[2]
        y = lo[1] + (np.arange(H) + 0.5) * vs[1]
        x = lo[0] + (np.arange(W) + 0.5) * vs[0]
        Z, Y, X = np.meshgrid(z, y, x, indexing="ij")
        return np.stack([X, Y, Z], axis=-1)

    def voxel_index(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat voxel index ``(z H + y) W + x`` of each point ``(..., 3)`` (0 outside the box)
        and whether it is inside the box."""
        q = (points - self.bounds[0]) * (1.0 / self.voxel_size)
        inside = np.all(q >= 0, axis=-1)
        inside &= np.all(q < self.shape_xyz, axis=-1)
        qi = q.astype(np.int64)
        qi[~inside] = 0
        W, H = int(self.shape_xyz[0]), int(self.shape_xyz[1])
        return qi[..., 0] + W * (qi[..., 1] + H * qi[..., 2]), inside

    def occupied_box(self) -> np.ndarray | None:
        """``(2, 3)`` world box around the occupied voxels, or None when none is occupied."""
        if not hasattr(self, "_box"):
            zyx = np.nonzero(self.occupied)
            if zyx[0].size == 0:
                self._box = None
            else:
                lo = np.array([zyx[2].min(), zyx[1].min(), zyx[0].min()])
                hi = np.array([zyx[2].max(), zyx[1].max(), zyx[0].max()]) + 1
                self._box = np.stack([self.bounds[0] + lo * self.voxel_size,
                                      self.bounds[0] + hi * self.voxel_size])
        return self._box

    def contains(self, points) -> np.ndarray:
        """``(...,)`` bool: whether each point ``(..., 3)`` lies in an occupied voxel."""
        p = np.asarray(points, dtype=np.float64)
        if p.shape[-1:] != (3,):
            raise ValueError(f"points: expected shape (..., 3), got {p.shape}")
        flat, inside = self.voxel_index(p)
        return inside & self.occupied.reshape(-1)[flat]

    def dilate(self, iterations: int = 1) -> OccupancyGrid:
        """A grid grown by ``iterations`` voxels (26-connected)."""
        from scipy.ndimage import binary_dilation

        if iterations < 1:
            return OccupancyGrid(self.occupied.copy(), self.bounds, self.opacity)
        occ = binary_dilation(self.occupied, structure=np.ones((3, 3, 3), bool),
                              iterations=int(iterations))
        return OccupancyGrid(occ, self.bounds, self.opacity)

    @classmethod
    def from_silhouettes(cls, silhouettes, cameras, *, resolution: int = 96,
                         bounds=((-1.2, -1.2, -1.2), (1.2, 1.2, 1.2)), dilate_pixels: int = 2,
                         threshold: float = 0.5) -> OccupancyGrid:
        """The visual hull: voxels whose centre projects inside every silhouette.

        Parameters
        ----------
        silhouettes : (N, H, W) float
            Target silhouettes (> ``threshold`` inside).
        cameras : CamerasBase
            The ``N`` cameras of the silhouettes.
        resolution : int
            Voxels per axis.
        bounds : (2, 3) float
            The box to carve.
        dilate_pixels : int
            Grow each silhouette by this many pixels first, so that a voxel whose centre
            projects just outside while its body overlaps the silhouette is kept.
        threshold : float
            Silhouette threshold.

        Returns
        -------
        OccupancyGrid
            Points projecting outside the image of any camera are carved too.
        """
        from scipy.ndimage import binary_dilation

        sil = as_array(silhouettes, "silhouettes", (None, None, None))
        n = sil.shape[0]
        if len(cameras) != n:
            raise ValueError(f"cameras: expected {n} cameras (one per silhouette), got "
                             f"{len(cameras)}")
        res = _int_at_least(resolution, "resolution", 1)
        masks = sil > threshold
        if dilate_pixels > 0:
            st = np.ones((3, 3), bool)
            masks = np.stack([binary_dilation(m, structure=st, iterations=int(dilate_pixels))
                              for m in masks])  # views
        grid = cls(np.ones((res, res, res), bool), bounds)
        pts = grid.centers().reshape(-1, 3)
        # geofit's one visual hull, on points: kept when the pixel of the centre is inside
        # every (dilated) silhouette
        occ = carve(np.where(masks, 0.0, np.inf), cameras, pts, 0.0, 0, 0.0, slack=0.0)
        return cls(occ.reshape(res, res, res), bounds)


# --------------------------------------------------------------------------------------------
# The renderer
# --------------------------------------------------------------------------------------------


class RenderCache(NamedTuple):
    """What :meth:`ImplicitRenderer.backward` needs from a forward render.

    Attributes
    ----------
    field_cache : object
        The field's cache over the evaluated (packed) samples.
    densities : (r, m) float64
        Densities of the evaluated samples, ray by ray, left-aligned (0 beyond each ray's count).
    colors : (r, m, 3) float64
        Their colours.
    slot : (k,) int64
        Position of packed sample ``i`` in the padded arrays: ``(ray_index[i], slot[i])``.
    ray_index : (k,) int64
        Ray of each packed sample.
    lead_shape : tuple
        Leading shape of the bundle (``(B, ...)``).
    samples_per_ray : float
        Mean number of evaluated samples per ray.
    """

    field_cache: Any
    densities: np.ndarray
    colors: np.ndarray
    slot: np.ndarray
    ray_index: np.ndarray
    lead_shape: tuple
    samples_per_ray: float

    def sample_densities(self) -> np.ndarray:
        """``(k,)`` densities of the evaluated samples, in packed order."""
        return self.densities[self.ray_index, self.slot]


class ImplicitRenderer:
    """Render an implicit field along sampled rays (PyTorch3D's ``ImplicitRenderer``), with a
    backward pass to the field's parameters.

    Parameters
    ----------
    raysampler : NDCMultinomialRaysampler or MonteCarloRaysampler
        Called as ``raysampler(cameras, seed=..., **sampler_kwargs)`` -> :class:`RayBundle`.
    raymarcher : EmissionAbsorptionRaymarcher
        Composites ``(densities, colors)`` per ray into ``(..., 4)`` (RGB, opacity).
    occupancy : OccupancyGrid, optional
        Evaluate the field only at samples inside occupied voxels; the others have density 0
        (empty-space skipping). The render equals the full render of a field whose density is
        0 outside the grid.
    min_transmittance : float
        With a grid that carries an ``opacity`` estimate: skip the samples of a ray lying more
        than ``occlusion_margin`` sample steps behind the first sample where the grid's
        transmittance ``prod (1 - opacity)`` falls below this value (they would add less than
        that to the pixel if the estimate were exact). 0 (default) disables it.
    occlusion_margin : int
        See ``min_transmittance``: sample steps kept behind the estimated surface, so that the
        field can still move it back.

    Examples
    --------
    >>> from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
    >>> from geofit.render.raymarching import EmissionAbsorptionRaymarcher
    >>> from geofit.render.raysampling import MonteCarloRaysampler
    >>> R, T = look_at_view_transform(2.7, 0.0, 180.0)
    >>> renderer = ImplicitRenderer(MonteCarloRaysampler(-1, 1, -1, 1, 8, 16, 0.1, 3.0),
    ...                             EmissionAbsorptionRaymarcher())
    >>> field = NeuralRadianceField(4, 16, omega0=1.0)
    >>> images, bundle = renderer(FoVPerspectiveCameras(R=R, T=T), field, seed=0)
    >>> images.shape, bundle.xys.shape
    ((1, 8, 4), (1, 8, 2))
    """

    def __init__(self, raysampler, raymarcher, *, occupancy: OccupancyGrid | None = None,
                 min_transmittance: float = 0.0, occlusion_margin: int = 3):
        if not callable(raysampler):
            raise TypeError(f"raysampler: expected a callable ray sampler, got "
                            f"{type(raysampler)!r}")
        if not hasattr(raymarcher, "vjp"):
            raise TypeError(f"raymarcher: expected a raymarcher with a vjp, got "
                            f"{type(raymarcher)!r}")
        if occupancy is not None and not isinstance(occupancy, OccupancyGrid):
            raise TypeError(f"occupancy: expected an OccupancyGrid, got {type(occupancy)!r}")
        self.raysampler = raysampler
        self.raymarcher = raymarcher
        self.occupancy = occupancy
        self.min_transmittance = float(min_transmittance)
        if not 0.0 <= self.min_transmittance < 1.0:
            raise ValueError(f"min_transmittance: expected a number in [0, 1), got "
                             f"{min_transmittance!r}")
        self.occlusion_margin = _int_at_least(occlusion_margin, "occlusion_margin", 0)

    def __repr__(self) -> str:
        return (f"ImplicitRenderer(raysampler={self.raysampler!r}, raymarcher={self.raymarcher!r}, "
                f"occupancy={self.occupancy!r})")

    def __call__(self, cameras, volumetric_function, *, seed=None, chunk_rays: int = 8192,
                 **sampler_kwargs):
        """Forward only: ``(images (..., 4), ray_bundle)``, marched in chunks of rays.

        ``volumetric_function`` is a :class:`NeuralRadianceField` (evaluated on the occupied
        samples only when a grid is set) or any callable ``f(ray_bundle) -> (densities,
        colors)`` as in PyTorch3D.
        """
        bundle = self.raysampler(cameras, seed=seed, **sampler_kwargs)
        return self.render_bundle(bundle, volumetric_function, chunk_rays=chunk_rays), bundle

    def render_bundle(self, ray_bundle: RayBundle, field, *, chunk_rays: int = 8192
                      ) -> np.ndarray:
        """Forward render of a given bundle in chunks of ``chunk_rays`` rays: ``(..., 4)``."""
        bundle = _check_bundle(ray_bundle)
        lead = bundle.lengths.shape[:-1]
        flat = _flatten_bundle(bundle)
        r = flat.origins.shape[0]
        out = np.zeros((r, 4))
        chunk_rays = _int_at_least(chunk_rays, "chunk_rays", 1)
        for s in range(0, r, chunk_rays):  # chunks of rays
            sub = RayBundle(*(a[s:s + chunk_rays] for a in flat))
            if isinstance(field, NeuralRadianceField):
                out[s:s + chunk_rays] = self._render_flat(sub, field, cache=False)[0]
            else:
                dens, cols = field(sub)
                out[s:s + chunk_rays] = self.raymarcher(dens, cols)
        return out.reshape(*lead, 4)

    def render(self, cameras, field: NeuralRadianceField, *, ray_bundle: RayBundle | None = None,
               seed=None, **sampler_kwargs):
        """Forward render that keeps what :meth:`backward` needs.

        Parameters
        ----------
        cameras : CamerasBase
            The cameras (ignored when ``ray_bundle`` is given).
        field : NeuralRadianceField
        ray_bundle : RayBundle, optional
            Rays to render instead of drawing them from the raysampler.
        seed : int or numpy.random.Generator, optional
            Passed to the raysampler.

        Returns
        -------
        images : (..., 4) float64
            RGB and opacity per ray (``(B, n_rays, 4)`` for a Monte Carlo sampler).
        ray_bundle : RayBundle
        cache : RenderCache
        """
        if not isinstance(field, NeuralRadianceField):
            raise TypeError(f"field: expected a NeuralRadianceField, got {type(field)!r}")
        bundle = (self.raysampler(cameras, seed=seed, **sampler_kwargs) if ray_bundle is None
                  else _check_bundle(ray_bundle))
        lead = bundle.lengths.shape[:-1]
        images, cache = self._render_flat(_flatten_bundle(bundle), field, cache=True)
        return images.reshape(*lead, 4), bundle, cache._replace(lead_shape=lead)

    def backward(self, field: NeuralRadianceField, cache: RenderCache, grad_images,
                 grad_densities=None) -> dict[str, np.ndarray]:
        """Parameter gradients of ``<grad_images, images>`` for a render made by :meth:`render`.

        Parameters
        ----------
        field : NeuralRadianceField
            The field that was rendered (same parameters).
        cache : RenderCache
        grad_images : (..., 4) float64
            Gradient of the loss with respect to the rendered RGB and opacity.
        grad_densities : (k,) float64, optional
            An extra gradient on the evaluated samples' densities
            (:meth:`RenderCache.sample_densities` order), e.g. from a regulariser.

        Returns
        -------
        grads : dict str -> ndarray
            Named and shaped as ``field.params``.

        Notes
        -----
        Which samples were skipped (outside the occupancy grid) is piecewise constant in the
        sample positions, and the parameters do not move the samples, so the gradient is exact
        for the rendered function.
        """
        if not isinstance(cache, RenderCache):
            raise TypeError("cache: expected the RenderCache returned by render()")
        g = as_array(grad_images, "grad_images", cache.lead_shape + (4,)).reshape(-1, 4)
        if grad_densities is not None:
            grad_densities = as_array(grad_densities, "grad_densities", (cache.ray_index.size,))
        return self._backward_flat(field, cache, g, grad_densities)

    # ---- internals -------------------------------------------------------------------------

    def _select(self, bundle: RayBundle):
        """Packed samples: points (k, 3), ray index (k,), slot (k,), padded width m."""
        o, d, lengths = bundle.origins, bundle.directions, bundle.lengths
        r, n = lengths.shape
        pts = o[:, None, :] + lengths[:, :, None] * d[:, None, :]
        if self.occupancy is None:
            ray_index = np.repeat(np.arange(r, dtype=np.int64), n)
            slot = np.tile(np.arange(n, dtype=np.int64), r)
            return pts.reshape(-1, 3), ray_index, slot, n
        grid = self.occupancy
        box = grid.occupied_box()
        if box is None:
            z = np.zeros(0, dtype=np.int64)
            return np.zeros((0, 3)), z, z, 0
        # only the samples inside the box around the occupied voxels (slab test)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            ta = (box[0] - o) * inv
            tb = (box[1] - o) * inv
        t_in = np.nanmax(np.fmin(ta, tb), axis=1)
        t_out = np.nanmin(np.fmax(ta, tb), axis=1)
        cand = (lengths >= t_in[:, None]) & (lengths <= t_out[:, None])
        ri, si = np.nonzero(cand)
        lc = lengths[ri, si]
        # voxel coordinates along each ray: q(t) = (o - lo) / vs + t d / vs, per component
        inv_vs = 1.0 / grid.voxel_size
        q0 = (o - grid.bounds[0]) * inv_vs
        dq = d * inv_vs
        flat = np.zeros(ri.size, dtype=np.intp)
        for axis, stride in ((2, grid.shape_xyz[0] * grid.shape_xyz[1]),
                             (1, grid.shape_xyz[0]), (0, 1)):  # z, y, x
            qa = q0[:, axis][ri]
            qa += lc * dq[:, axis][ri]
            ia = qa.astype(np.intp)   # samples lie in the box: q >= 0 up to rounding
            np.clip(ia, 0, grid.shape_xyz[axis] - 1, out=ia)
            if stride != 1:
                ia *= int(stride)
            flat += ia
        ok = grid.occupied.reshape(-1)[flat]
        if grid.opacity is not None and self.min_transmittance > 0:
            keep = np.zeros((r, n), bool)
            keep[ri[ok], si[ok]] = True
            op = np.zeros((r, n), np.float32)
            op[ri, si] = grid.opacity.reshape(-1)[flat]
            ok &= self._visible(op, keep)[ri, si]
        ri, lc = ri[ok].astype(np.int64), lc[ok]
        pts = o[ri] + lc[:, None] * d[ri]
        counts = np.bincount(ri, minlength=r)
        starts = np.cumsum(counts) - counts
        slot = np.arange(ri.size, dtype=np.int64) - starts[ri]
        m = int(counts.max()) if r else 0
        return pts, ri, slot, m

    def _visible(self, opacity: np.ndarray, keep: np.ndarray) -> np.ndarray:
        """(r, n) bool: samples at most ``occlusion_margin`` sample steps behind the point where
        the grid's transmittance ``prod (1 - opacity)`` over the kept samples falls below
        ``min_transmittance``."""
        a = np.where(keep, np.minimum(opacity, np.float32(1.0 - 1e-6)), np.float32(0.0))
        L = np.log1p(-a)
        logT = np.cumsum(L, axis=1)
        logT -= L                                  # log transmittance before each sample
        m = self.occlusion_margin
        if m > 0:
            shifted = np.zeros_like(logT)
            shifted[:, m:] = logT[:, :-m]
            logT = shifted
        return logT > np.log(self.min_transmittance)

    def _render_flat(self, bundle: RayBundle, field: NeuralRadianceField, *, cache: bool):
        r = bundle.origins.shape[0]
        pts, ray_index, slot, m = self._select(bundle)
        k = pts.shape[0]
        if k == 0:
            images = np.zeros((r, 4))
            c = RenderCache(None, np.zeros((r, 0)), np.zeros((r, 0, 3)), slot, ray_index, (r,),
                            0.0)
            return images, c
        dens, cols, fc = field._forward(pts, bundle.directions, ray_index, None, cache)
        D = np.zeros((r, m))
        C = np.zeros((r, m, 3))
        D[ray_index, slot] = dens[:, 0]
        C[ray_index, slot] = cols
        images = self.raymarcher(D, C)
        c = RenderCache(fc, D, C, slot, ray_index, (r,), k / max(r, 1)) if cache else None
        return images, c

    def _backward_flat(self, field, cache: RenderCache, g: np.ndarray, extra=None):
        if cache.field_cache is None or cache.ray_index.size == 0:
            return {k: np.zeros_like(v) for k, v in field.params.items()}
        gr = self.raymarcher.vjp(g, cache.densities, cache.colors)
        gD = gr.densities[cache.ray_index, cache.slot][:, None]
        if extra is not None:
            gD += extra[:, None]
        gC = gr.features[cache.ray_index, cache.slot]
        return field.backward(cache.field_cache, gD, gC)


def _flatten_bundle(bundle: RayBundle) -> RayBundle:
    lead = bundle.lengths.shape[:-1]
    r = int(np.prod(lead, dtype=np.int64))
    n = bundle.lengths.shape[-1]
    xys = bundle.xys.reshape(r, -1) if bundle.xys is not None else np.zeros((r, 2))
    return RayBundle(np.asarray(bundle.origins, dtype=np.float64).reshape(r, 3),
                     np.asarray(bundle.directions, dtype=np.float64).reshape(r, 3),
                     np.ascontiguousarray(bundle.lengths, dtype=np.float64).reshape(r, n), xys)
