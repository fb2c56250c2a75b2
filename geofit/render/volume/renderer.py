"""Volume rendering: sample a :class:`~geofit.structures.volume.Volume` along rays and raymarch.

:class:`VolumeRenderer` is PyTorch3D's ``VolumeRenderer``: a ray sampler gives a
:class:`~geofit.render.volume.raysampling.RayBundle`, the volume is sampled at every ray point with
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

from ..._memory import check_allocation
from ..._validate import as_array, check_choice
from ...cameras import CamerasBase
from ...structures.volume import Volume, trilinear_matrix
from .raymarching import AbsorptionOnlyRaymarcher, EmissionAbsorptionRaymarcher, sample_deltas
from .raysampling import RayBundle
from .skipping import cell_table, range_layout, range_operator, sample_ranges

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
        :class:`~geofit.render.volume.raysampling.NDCMultinomialRaysampler`).
    raymarcher : EmissionAbsorptionRaymarcher or AbsorptionOnlyRaymarcher
        Composites each ray (it needs a ``vjp`` method for :meth:`vjp`).
    sample_mode : {"bilinear", "nearest"}
        ``grid_sample`` mode: trilinear interpolation (PyTorch3D's default, named "bilinear") or
        the nearest voxel.
    chunk_size : int
        Largest number of ray samples processed at once (memory bound).
    skip_empty : bool
        Empty-space skipping (default True; trilinear mode with ``align_corners=True``): each
        ray samples only the contiguous range between its first and its last sample that reads
        a voxel of non-zero density (for :meth:`vjp`: any voxel of the grid). The skipped
        samples read zeros, so the result is PyTorch3D's: the ``1 + eps`` factors of the
        leading empty samples are applied in closed form (exactly for surface thickness 1,
        within 1e-10 relative otherwise).

    Examples
    --------
    >>> from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
    >>> from geofit.render.volume.raysampling import NDCMultinomialRaysampler
    >>> R, T = look_at_view_transform(2.7, 0.0, 0.0)
    >>> vol = Volume(np.full((8, 8, 8), 0.1), np.ones((3, 8, 8, 8)), voxel_size=0.2)
    >>> renderer = VolumeRenderer(NDCMultinomialRaysampler(image_width=16, image_height=16,
    ...     n_pts_per_ray=64, min_depth=0.1, max_depth=4.0), EmissionAbsorptionRaymarcher())
    >>> images, bundle = renderer(FoVPerspectiveCameras(R=R, T=T), vol)
    >>> images.shape, bool(images[0, 8, 8, 3] > 0.5), bool(images[0, 0, 0, 3] == 0.0)
    ((1, 16, 16, 4), True, True)
    """

    def __init__(self, raysampler, raymarcher, sample_mode: str = "bilinear", *,
                 chunk_size: int = 1 << 20, skip_empty: bool = True):
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
        check_allocation(256 * self.chunk_size, "chunk_size", "one chunk of samples")
        if not isinstance(skip_empty, (bool, np.bool_)):
            raise TypeError(f"skip_empty: expected True or False, got {skip_empty!r}")
        self.skip_empty = bool(skip_empty)

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

    @property
    def _emits(self) -> bool:
        return isinstance(self.raymarcher, EmissionAbsorptionRaymarcher)

    def _ray_chunks(self, bundle: RayBundle):
        """Yield flat ray slices of at most ``chunk_size`` samples."""
        n_rays = int(np.prod(bundle.origins.shape[:-1]))
        n = bundle.lengths.shape[-1]
        per = max(1, self.chunk_size // n)
        for start in range(0, n_rays, per):  # chunks of rays
            yield slice(start, min(start + per, n_rays))

    def _march_chunk(self, volume: Volume, o, d, L, marked: np.ndarray, G=None):
        """Render (and, with ``G``, back-propagate) rays o, d, L (r, ...) over their ranges.

        Only the samples between the first and the last one whose trilinear cell reads a
        ``marked`` voxel are sampled and marched; the others read only zeros. Returns the
        images (r, C + 1) and, with ``G``, the gradients on the read voxels (columns, dens
        (m,), feats (m, C)).
        """
        r, n = L.shape
        C = volume.n_features if self._emits else 0
        grid = volume.grid_size
        half = 0.5 * (np.array(grid[::-1], dtype=np.float64) - 1.0)
        if not volume.align_corners:
            raise NotImplementedError  # handled by the caller (dense path)
        scale = volume._scale
        A = ((o + volume.volume_translation) / scale + 1.0) * half
        B = d / scale * half
        first, last = sample_ranges(A, B, n, grid, cell_table(marked, "any"), lengths=L,
                                     chunk_samples=self.chunk_size)
        lay = range_layout(first, last, self.chunk_size)
        out = np.zeros((r, C + 1))
        if not len(lay.ray_ids):
            return out, None
        Wm, cols = range_operator(A, B, lay, grid, lengths=L)
        X = np.empty((cols.size, C + 1))
        X[:, 0] = volume.densities.reshape(-1)[cols]
        if C:
            X[:, 1:] = volume.features.reshape(C, -1)[:, cols].T
        Y = Wm @ X
        physical = self.raymarcher.physical
        Gs = np.zeros_like(Y) if G is not None else None
        eps = getattr(self.raymarcher, "eps", 0.0)
        for row, a, b, K in lay.chunks:  # chunks of rays
            ids = lay.ray_ids[a:b]
            blk = Y[row:row + (b - a) * K].reshape(b - a, K, C + 1)
            dens = blk[..., 0]
            kk = lay.first[a:b, None] + np.arange(K)[None, :]
            inr = kk <= (lay.first[a:b] + lay.count[a:b] - 1)[:, None]
            deltas = None
            if physical:
                full = sample_deltas(L[ids], d[ids])
                deltas = np.where(inr, np.take_along_axis(full, np.minimum(kk, n - 1), 1), 0.0)
            if self._emits:
                m = self.raymarcher._march(dens, blk[..., 1:], deltas)
                lead = 1.0 if physical else (1.0 + eps) ** lay.first[a:b]
                out[ids, :C] = m.features * (lead[:, None] if not physical else 1.0)
                out[ids, C] = m.opacity
                if G is not None:
                    g = G[ids]
                    gd, gf = self.raymarcher._grads(m, dens, blk[..., 1:], deltas,
                                                    g[:, :C] * (lead[:, None] if not physical
                                                                else 1.0), g[:, C])
                    gblk = Gs[row:row + (b - a) * K].reshape(b - a, K, C + 1)
                    gblk[..., 0] = gd
                    gblk[..., 1:] = gf
            else:
                out[ids, 0] = self.raymarcher(dens, deltas)[:, 0]
                if G is not None:
                    gblk = Gs[row:row + (b - a) * K].reshape(b - a, K, 1)
                    gblk[..., 0] = self.raymarcher.vjp(G[ids], dens, deltas).densities
        if G is None:
            return out, None
        Z = Wm.T @ Gs
        return out, (cols, Z[:, 0], Z[:, 1:])

    def _flat_bundle(self, bundle: RayBundle):
        o = bundle.origins.reshape(-1, 3)
        d = bundle.directions.reshape(-1, 3)
        L = bundle.lengths.reshape(len(o), -1)
        return o, d, L

    def _chunks(self, bundle: RayBundle):
        """Yield (ray slice, world points (r*n, 3), deltas (r, n) or None) over ray chunks."""
        o, d, L = self._flat_bundle(bundle)
        for sl in self._ray_chunks(bundle):  # chunks of rays
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

    def _use_ranges(self, volume: Volume) -> bool:
        return (self.skip_empty and self.sample_mode == "bilinear" and volume.align_corners
                and (not self._emits or volume.features is not None))

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
        volume, bundle, lead, n, emits, C = self._setup(volume, ray_bundle)
        out = np.empty((int(np.prod(lead)), C + 1))
        if self._use_ranges(volume):
            o, d, L = self._flat_bundle(bundle)
            marked = volume.densities != 0.0
            for sl in self._ray_chunks(bundle):  # chunks of rays
                out[sl], _ = self._march_chunk(volume, o[sl], d[sl], L[sl], marked)
            return out.reshape(lead + (C + 1,))
        for sl, pts, deltas in self._chunks(bundle):
            _, dens, feats = self._sample(volume, pts)
            r = sl.stop - sl.start
            if emits:
                f = np.zeros((r, n, 0)) if feats is None else feats.reshape(r, n, C)
                out[sl] = self.raymarcher(dens.reshape(r, n), f, deltas)
            else:
                out[sl] = self.raymarcher(dens.reshape(r, n), deltas)
        return out.reshape(lead + (C + 1,))

    def _setup(self, volume, ray_bundle):
        """Checked volume and bundle, the bundle's leading shape, samples per ray, whether the
        raymarcher emits features, and their count C (0 without)."""
        volume = self._check_volume(volume)
        bundle = _check_bundle(ray_bundle)
        emits = isinstance(self.raymarcher, EmissionAbsorptionRaymarcher)
        return (volume, bundle, bundle.origins.shape[:-1], bundle.lengths.shape[-1], emits,
                volume.n_features if emits else 0)

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
        volume, bundle, lead, n, emits, C = self._setup(volume, ray_bundle)
        G = as_array(grad_images, "grad_images", lead + (C + 1,)).reshape(-1, C + 1)
        g_dens = np.zeros(volume.n_voxels)
        g_feat = np.zeros((volume.n_voxels, C)) if (emits and volume.features is not None) \
            else None
        if self._use_ranges(volume):
            # every voxel is "marked": only samples that read no voxel at all are skipped, which
            # is exact for the gradient too
            o, d, L = self._flat_bundle(bundle)
            marked = np.ones(volume.grid_size, bool)
            for sl in self._ray_chunks(bundle):  # chunks of rays
                _, got = self._march_chunk(volume, o[sl], d[sl], L[sl], marked, G[sl])
                if got is not None:
                    cols, gd, gf = got
                    g_dens[cols] += gd
                    if g_feat is not None:
                        g_feat[cols] += gf
            feats_grad = None
            if g_feat is not None:
                feats_grad = np.ascontiguousarray(g_feat.T).reshape((C,) + volume.grid_size)
            return VolumeGradients(g_dens.reshape(volume.grid_size), feats_grad)
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
