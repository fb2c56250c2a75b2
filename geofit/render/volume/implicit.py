"""Neural radiance fields and the implicit renderer that marches them, with backward passes.

* :class:`NeuralRadianceField` -- the NeRF tutorial's network (in :mod:`.radiance_field`;
  imported here too).
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

from typing import Any, NamedTuple

import numpy as np

from ..._validate import as_array
from ...structures.volume import carve
from .radiance_field import ACTIVATIONS, NeuralRadianceField, _check_bundle, _int_at_least
from .raysampling import RayBundle

__all__ = [
    "ACTIVATIONS",
    "ImplicitRenderer",
    "NeuralRadianceField",
    "OccupancyGrid",
    "RenderCache",
]


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
        from scipy.ndimage import binary_dilation  # kept local: start-up

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
        from scipy.ndimage import binary_dilation  # kept local: start-up

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
    >>> from geofit.render.volume.raymarching import EmissionAbsorptionRaymarcher
    >>> from geofit.render.volume.raysampling import MonteCarloRaysampler
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
