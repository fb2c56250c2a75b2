"""Volume rendering: sample a :class:`~geofit.structures.volume.Volume` along rays and raymarch.

:class:`VolumeRenderer` is PyTorch3D's ``VolumeRenderer``: a ray sampler gives a
:class:`~geofit.render.raysampling.RayBundle`, the volume is sampled at every ray point with
``grid_sample`` semantics (trilinear, zero padding, the volume's ``align_corners``) and a raymarcher
composites each ray. The sampling step is the sparse matrix of
:func:`~geofit.structures.volume.trilinear_matrix`, so :meth:`VolumeRenderer.vjp` carries an image
gradient back to the voxel grid with its transpose, after the raymarcher's own vector-Jacobian
product. Rays are processed in chunks of at most ``chunk_size`` samples, so memory stays bounded
whatever the image size.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._validate import as_array, check_choice
from ..cameras import CamerasBase
from ..structures.volume import Volume, trilinear_matrix
from .raymarching import AbsorptionOnlyRaymarcher, EmissionAbsorptionRaymarcher, sample_deltas
from .raysampling import RayBundle

__all__ = ["VolumeGradients", "VolumeRenderer"]


class VolumeGradients(NamedTuple):
    """Gradient of ``<grad_images, render(volume)>`` with respect to the voxel values.

    Attributes
    ----------
    densities : (D, H, W) float64
    features : (C, D, H, W) float64 or None
        None when the volume has no features.
    """

    densities: np.ndarray
    features: np.ndarray | None


def _check_bundle(ray_bundle) -> RayBundle:
    if not isinstance(ray_bundle, RayBundle):
        raise TypeError(f"ray_bundle: expected a RayBundle, got {type(ray_bundle)!r}")
    o = as_array(ray_bundle.origins, "ray_bundle.origins")
    d = as_array(ray_bundle.directions, "ray_bundle.directions")
    L = as_array(ray_bundle.lengths, "ray_bundle.lengths")
    if o.ndim < 2 or o.shape[-1] != 3 or d.shape != o.shape or L.shape[:-1] != o.shape[:-1]:
        raise ValueError("ray_bundle: expected origins and directions (B, ..., 3) and lengths "
                         f"(B, ..., n); got {o.shape}, {d.shape} and {L.shape}")
    if L.shape[-1] == 0:
        raise ValueError("ray_bundle.lengths: expected at least one sample per ray")
    return RayBundle(o, d, L, ray_bundle.xys)


class VolumeRenderer:
    """Render a :class:`Volume` from cameras (PyTorch3D's ``VolumeRenderer``).

    Parameters
    ----------
    raysampler : callable
        ``raysampler(cameras, **kwargs) -> RayBundle`` (e.g.
        :class:`~geofit.render.raysampling.NDCMultinomialRaysampler`).
    raymarcher : EmissionAbsorptionRaymarcher or AbsorptionOnlyRaymarcher
        Composites each ray (it needs a ``vjp`` method for :meth:`vjp`).
    sample_mode : {"bilinear", "nearest"}
        ``grid_sample`` mode: trilinear interpolation (PyTorch3D's default, named "bilinear") or
        the nearest voxel.
    chunk_size : int
        Largest number of ray samples processed at once (memory bound).

    Examples
    --------
    >>> from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
    >>> from geofit.render.raysampling import NDCMultinomialRaysampler
    >>> R, T = look_at_view_transform(2.7, 0.0, 0.0)
    >>> vol = Volume(np.full((8, 8, 8), 0.1), np.ones((3, 8, 8, 8)), voxel_size=0.2)
    >>> renderer = VolumeRenderer(NDCMultinomialRaysampler(image_width=16, image_height=16,
    ...     n_pts_per_ray=64, min_depth=0.1, max_depth=4.0), EmissionAbsorptionRaymarcher())
    >>> images, bundle = renderer(FoVPerspectiveCameras(R=R, T=T), vol)
    >>> images.shape, bool(images[0, 8, 8, 3] > 0.5), bool(images[0, 0, 0, 3] == 0.0)
    ((1, 16, 16, 4), True, True)
    """

    def __init__(self, raysampler, raymarcher, sample_mode: str = "bilinear", *,
                 chunk_size: int = 1 << 20):
        if not callable(raysampler):
            raise TypeError(f"raysampler: expected a callable, got {type(raysampler)!r}")
        if not isinstance(raymarcher, (EmissionAbsorptionRaymarcher, AbsorptionOnlyRaymarcher)):
            raise TypeError("raymarcher: expected an EmissionAbsorptionRaymarcher or "
                            f"AbsorptionOnlyRaymarcher, got {type(raymarcher)!r}")
        check_choice(sample_mode, "sample_mode", ("bilinear", "nearest"))
        if not isinstance(chunk_size, (int, np.integer)) or isinstance(chunk_size, bool) \
                or chunk_size < 1:
            raise ValueError(f"chunk_size: expected an integer >= 1, got {chunk_size!r}")
        self.raysampler = raysampler
        self.raymarcher = raymarcher
        self.sample_mode = sample_mode
        self.chunk_size = int(chunk_size)

    def __repr__(self) -> str:
        return (f"VolumeRenderer(raysampler={self.raysampler!r}, raymarcher={self.raymarcher!r}, "
                f"sample_mode={self.sample_mode!r})")

    def __call__(self, cameras: CamerasBase, volume: Volume, **sampler_kwargs):
        """Sample rays from ``cameras`` and render ``volume`` along them.

        Parameters
        ----------
        cameras : CamerasBase
            ``B`` cameras.
        volume : Volume
            The scene (the same volume for every camera).
        **sampler_kwargs
            Passed to the ray sampler (e.g. ``seed``, ``n_rays_per_image``).

        Returns
        -------
        images : (B, ..., C + 1) float64
            Raymarched features and opacity for every ray of the bundle (``(B, H, W, C + 1)``
            for a full-grid sampler).
        ray_bundle : RayBundle
            The rays that were rendered (pass them to :meth:`vjp`).
        """
        if not isinstance(cameras, CamerasBase):
            raise TypeError(f"cameras: expected a geofit cameras batch, got {type(cameras)!r}")
        bundle = self.raysampler(cameras, **sampler_kwargs)
        return self.render_rays(volume, bundle), bundle

    # ---- internals ---------------------------------------------------------------------------

    def _check_volume(self, volume) -> Volume:
        if not isinstance(volume, Volume):
            raise TypeError(f"volume: expected a geofit Volume, got {type(volume)!r}")
        return volume

    def _chunks(self, bundle: RayBundle):
        """Yield (ray slice, local points (r*n, 3), deltas (r, n) or None) over ray chunks."""
        o = bundle.origins.reshape(-1, 3)
        d = bundle.directions.reshape(-1, 3)
        L = bundle.lengths.reshape(len(o), -1)
        n = L.shape[1]
        per = max(1, self.chunk_size // n)
        for start in range(0, len(o), per):  # chunks of rays
            sl = slice(start, min(start + per, len(o)))
            pts = o[sl, None, :] + L[sl, :, None] * d[sl, None, :]
            deltas = None
            if self.raymarcher.physical:
                deltas = sample_deltas(L[sl], d[sl])
            yield sl, pts.reshape(-1, 3), deltas

    def _sample(self, volume: Volume, pts: np.ndarray):
        M = trilinear_matrix(volume.world_to_local(pts), volume.grid_size,
                             align_corners=volume.align_corners, mode=self.sample_mode)
        dens = M @ volume.densities.reshape(-1)
        feats = None
        if volume.features is not None:
            feats = M @ volume.features.reshape(volume.n_features, -1).T
        return M, dens, feats

    # ---- public ------------------------------------------------------------------------------

    def render_rays(self, volume: Volume, ray_bundle: RayBundle) -> np.ndarray:
        """Render ``volume`` along given rays.

        Parameters
        ----------
        volume : Volume
        ray_bundle : RayBundle
            ``origins``/``directions`` (B, ..., 3), ``lengths`` (B, ..., n).

        Returns
        -------
        images : (B, ..., C + 1) float64
            Features and opacity per ray (only the opacity, ``(B, ..., 1)``, for an
            absorption-only raymarcher or a volume without features).
        """
        volume = self._check_volume(volume)
        bundle = _check_bundle(ray_bundle)
        lead = bundle.origins.shape[:-1]
        n = bundle.lengths.shape[-1]
        emits = isinstance(self.raymarcher, EmissionAbsorptionRaymarcher)
        C = volume.n_features if emits else 0
        out = np.empty((int(np.prod(lead)), C + 1))
        for sl, pts, deltas in self._chunks(bundle):
            _, dens, feats = self._sample(volume, pts)
            r = sl.stop - sl.start
            if emits:
                f = np.zeros((r, n, 0)) if feats is None else feats.reshape(r, n, C)
                out[sl] = self.raymarcher(dens.reshape(r, n), f, deltas)
            else:
                out[sl] = self.raymarcher(dens.reshape(r, n), deltas)
        return out.reshape(lead + (C + 1,))

    def vjp(self, grad_images, volume: Volume, ray_bundle: RayBundle) -> VolumeGradients:
        """Gradient of ``<grad_images, render_rays(volume, ray_bundle)>`` w.r.t. the voxels.

        Parameters
        ----------
        grad_images : (B, ..., C + 1) float64
            Upstream gradient, shaped like the rendered images.
        volume : Volume
        ray_bundle : RayBundle
            The rays that were rendered (the bundle returned by :meth:`__call__`).

        Returns
        -------
        VolumeGradients
            ``densities (D, H, W)`` and ``features (C, D, H, W)`` (None without features).

        Notes
        -----
        Which voxels a sample reads is piecewise constant in the sample position; the gradient
        is with respect to the voxel values only, and is exact (the map is smooth in them).
        """
        volume = self._check_volume(volume)
        bundle = _check_bundle(ray_bundle)
        lead = bundle.origins.shape[:-1]
        n = bundle.lengths.shape[-1]
        emits = isinstance(self.raymarcher, EmissionAbsorptionRaymarcher)
        C = volume.n_features if emits else 0
        G = as_array(grad_images, "grad_images", lead + (C + 1,)).reshape(-1, C + 1)
        g_dens = np.zeros(volume.n_voxels)
        g_feat = np.zeros((volume.n_voxels, C)) if (emits and volume.features is not None) \
            else None
        for sl, pts, deltas in self._chunks(bundle):
            M, dens, feats = self._sample(volume, pts)
            r = sl.stop - sl.start
            if emits:
                f = np.zeros((r, n, 0)) if feats is None else feats.reshape(r, n, C)
                gd, gf = self.raymarcher.vjp(G[sl], dens.reshape(r, n), f, deltas)
                if g_feat is not None:
                    g_feat += M.T @ gf.reshape(r * n, C)
            else:
                gd, _ = self.raymarcher.vjp(G[sl], dens.reshape(r, n), deltas)
            g_dens += M.T @ gd.reshape(-1)
        feats_grad = None
        if g_feat is not None:
            feats_grad = np.ascontiguousarray(g_feat.T).reshape((C,) + volume.grid_size)
        return VolumeGradients(g_dens.reshape(volume.grid_size), feats_grad)
