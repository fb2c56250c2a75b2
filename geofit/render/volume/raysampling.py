"""Ray samplers with PyTorch3D's semantics: which rays a volume renderer marches, and where.

* :class:`NDCMultinomialRaysampler` -- one ray per pixel centre (the rasterizer's pixel centres,
  +X left, +Y up, row 0 at the top), or ``n_rays_per_image`` pixels drawn at random without
  replacement (optionally weighted by a mask);
* :class:`MonteCarloRaysampler` -- ray origins at xy drawn uniformly in an NDC box.

Both follow ``pytorch3d.renderer.implicit.raysampling._xy_to_ray_bundle``: each xy is unprojected
at view depths 1 and 2, ``directions = p2 - p1`` (view-space z component 1, *not* unit length)
and ``origins = p1 - directions`` (the camera centre of a perspective camera). The sample
``lengths`` are ``linspace(min_depth, max_depth, n_pts_per_ray)``, which are therefore view depths,
not Euclidean distances (unless ``unit_directions`` is set, as in PyTorch3D).

Random choices take ``seed`` (int or ``numpy.random.Generator``); PyTorch3D's torch RNG stream is
not reproduced, only the distribution.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..._memory import check_allocation
from ..._validate import as_array, as_rng, check_finite as _finite_float, check_int as _positive_int
from ...cameras import CamerasBase, ndc_grid


def _check_rays(n_cameras: int, n_rays: int, n_pts: int) -> None:
    """Refuse a ray bundle whose lengths, points and pixel draws exceed the memory limit."""
    from ..._memory import check_allocation

    check_allocation(8 * n_cameras * n_rays * (2 * n_pts + 12),
                     "n_rays_per_image and n_pts_per_ray",
                     f"{n_cameras} x {n_rays:,} rays of {n_pts} points")

__all__ = [
    "MonteCarloRaysampler",
    "NDCMultinomialRaysampler",
    "RayBundle",
    "ray_bundle_to_ray_points",
]


class RayBundle(NamedTuple):
    """Rays and the depths of their samples (PyTorch3D's ``RayBundle``).

    Attributes
    ----------
    origins : (B, ..., 3) float64
        World-space ray origins (the camera centre for perspective cameras).
    directions : (B, ..., 3) float64
        World-space directions; view-space z component 1 unless the sampler normalised them.
    lengths : (B, ..., n) float64
        Sample positions along each ray: sample ``s`` is ``origins + lengths[..., s] *
        directions``, so they are view depths for view-z-1 directions.
    xys : (B, ..., 2) float64
        NDC x, y of each ray (+X left, +Y up).

    ``...`` is ``(H, W)`` for a full image grid, ``(n_rays, 1)`` for
    ``NDCMultinomialRaysampler(n_rays_per_image=n_rays)`` and ``(n_rays,)`` for
    ``MonteCarloRaysampler``.
    """

    origins: np.ndarray
    directions: np.ndarray
    lengths: np.ndarray
    xys: np.ndarray

    def points(self) -> np.ndarray:
        """The sample points; see :func:`ray_bundle_to_ray_points`."""
        return ray_bundle_to_ray_points(self)


def ray_bundle_to_ray_points(ray_bundle: RayBundle) -> np.ndarray:
    """Points along the rays: ``origins + lengths * directions``.

    Parameters
    ----------
    ray_bundle : RayBundle
        ``origins``/``directions`` (B, ..., 3) and ``lengths`` (B, ..., n).

    Returns
    -------
    points : (B, ..., n, 3) float64
        ``points[b, ..., s]`` is sample ``s`` of the ray.
    """
    if not isinstance(ray_bundle, RayBundle):
        raise TypeError(f"ray_bundle: expected a RayBundle, got {type(ray_bundle)!r}")
    o, d, lengths = ray_bundle.origins, ray_bundle.directions, ray_bundle.lengths
    if o.shape != d.shape or o.shape[:-1] != lengths.shape[:-1] or o.shape[-1] != 3:
        raise ValueError("ray_bundle: origins and directions must be (B, ..., 3) and lengths "
                         f"(B, ..., n); got {o.shape}, {d.shape} and {lengths.shape}")
    return o[..., None, :] + lengths[..., :, None] * d[..., None, :]


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------


def _check_cameras(cameras) -> CamerasBase:
    if not isinstance(cameras, CamerasBase):
        raise TypeError(f"cameras: expected a geofit cameras batch (CamerasBase), got "
                        f"{type(cameras)!r}")
    return cameras


def _depth_range(min_depth, max_depth) -> tuple[float, float]:
    lo = _finite_float(min_depth, "min_depth")
    hi = _finite_float(max_depth, "max_depth")
    if hi < lo:
        raise ValueError(f"max_depth: expected >= min_depth = {lo:g}, got {hi:g}")
    return lo, hi


def _jiggle_within_stratas(bin_centers: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One uniform sample per bin around each centre (PyTorch3D's ``_jiggle_within_stratas``)."""
    mids = 0.5 * (bin_centers[..., 1:] + bin_centers[..., :-1])
    upper = np.concatenate([mids, bin_centers[..., -1:]], axis=-1)
    lower = np.concatenate([bin_centers[..., :1], mids], axis=-1)
    return lower + (upper - lower) * rng.random(lower.shape)


def _xy_to_ray_bundle(cameras: CamerasBase, xy: np.ndarray, min_depth: float, max_depth: float,
                      n_pts_per_ray: int, unit_directions: bool, stratified: bool,
                      rng: np.random.Generator | None) -> RayBundle:
    """Rays through NDC points ``xy (B, ..., 2)`` of each camera (PyTorch3D's construction)."""
    B = xy.shape[0]
    spatial = xy.shape[1:-1]
    k = int(np.prod(spatial, dtype=np.int64))
    check_allocation(8 * B * k * (2 * n_pts_per_ray + 12), "n_pts_per_ray and image size",
                     f"a bundle of {B} x {k} rays with {n_pts_per_ray} samples each")
    flat = xy.reshape(B, k, 2)
    p1 = cameras.unproject_points(np.concatenate([flat, np.ones((B, k, 1))], axis=-1))
    p2 = cameras.unproject_points(np.concatenate([flat, np.full((B, k, 1), 2.0)], axis=-1))
    directions = p2 - p1
    origins = p1 - directions
    if unit_directions:
        norm = np.linalg.norm(directions, axis=-1, keepdims=True)
        directions = directions / np.maximum(norm, 1e-12)
    lengths = np.broadcast_to(np.linspace(min_depth, max_depth, n_pts_per_ray),
                              (B, k, n_pts_per_ray))
    if stratified:
        lengths = _jiggle_within_stratas(lengths, rng)
    return RayBundle(origins.reshape(B, *spatial, 3), directions.reshape(B, *spatial, 3),
                     np.ascontiguousarray(lengths).reshape(B, *spatial, n_pts_per_ray),
                     np.ascontiguousarray(xy))


# --------------------------------------------------------------------------------------------
# samplers
# --------------------------------------------------------------------------------------------


class NDCMultinomialRaysampler:
    """Rays through pixel centres, on PyTorch3D's NDC grid (``NDCMultinomialRaysampler``).

    Parameters
    ----------
    image_width, image_height : int
        Image size in pixels. The shorter side spans NDC [-1, 1], the longer
        [-long/short, long/short]; pixel centres are those of the mesh and point rasterizers.
    n_pts_per_ray : int
        Samples per ray.
    min_depth, max_depth : float
        Depth range of the samples (view depths, since directions have view z 1).
    n_rays_per_image : int, optional
        If given, draw this many pixels per camera at random without replacement (with
        replacement only when a mask has fewer non-zero pixels), instead of the full grid.
    unit_directions : bool
        Normalise the directions (then ``lengths`` are Euclidean distances).
    stratified_sampling : bool
        Jiggle each sample uniformly within its bin (PyTorch3D's ``_jiggle_within_stratas``).

    Examples
    --------
    >>> from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
    >>> R, T = look_at_view_transform(2.7, 0.0, 180.0)
    >>> sampler = NDCMultinomialRaysampler(image_width=4, image_height=3, n_pts_per_ray=5,
    ...                                    min_depth=0.1, max_depth=3.0)
    >>> bundle = sampler(FoVPerspectiveCameras(R=R, T=T))
    >>> bundle.origins.shape, bundle.lengths.shape, bundle.xys[0, 0, 0].tolist()
    ((1, 3, 4, 3), (1, 3, 4, 5), [1.0, 0.6666666666666666])
    """

    def __init__(self, *, image_width: int, image_height: int, n_pts_per_ray: int,
                 min_depth: float, max_depth: float, n_rays_per_image: int | None = None,
                 unit_directions: bool = False, stratified_sampling: bool = False):
        self.image_width = _positive_int(image_width, "image_width")
        self.image_height = _positive_int(image_height, "image_height")
        self.n_pts_per_ray = _positive_int(n_pts_per_ray, "n_pts_per_ray")
        self.min_depth, self.max_depth = _depth_range(min_depth, max_depth)
        self.n_rays_per_image = _positive_int(n_rays_per_image, "n_rays_per_image",
                                              allow_none=True)
        self.unit_directions = bool(unit_directions)
        self.stratified_sampling = bool(stratified_sampling)

    def __repr__(self) -> str:
        return (f"NDCMultinomialRaysampler(image_width={self.image_width}, "
                f"image_height={self.image_height}, n_pts_per_ray={self.n_pts_per_ray}, "
                f"min_depth={self.min_depth:g}, max_depth={self.max_depth:g}, "
                f"n_rays_per_image={self.n_rays_per_image})")

    def xy_grid(self) -> np.ndarray:
        """NDC pixel centres ``(H, W, 2)`` (row 0 top = largest y, column 0 left = largest x)."""
        return ndc_grid((self.image_height, self.image_width))

    def __call__(self, cameras: CamerasBase, *, mask=None, n_rays_per_image: int | None = None,
                 n_pts_per_ray: int | None = None, min_depth: float | None = None,
                 max_depth: float | None = None, stratified_sampling: bool | None = None,
                 seed=None) -> RayBundle:
        """Rays of a batch of cameras.

        Parameters
        ----------
        cameras : CamerasBase
            ``B`` cameras.
        mask : (B, H, W) float64, optional
            Non-negative pixel weights for the random choice (PyTorch3D's ``mask``); without
            ``n_rays_per_image`` the smallest mask count is used as the number of rays.
        n_rays_per_image, n_pts_per_ray, min_depth, max_depth, stratified_sampling
            Override the constructor's values for this call.
        seed : int or numpy.random.Generator, optional
            For the random pixel choice and the stratified jiggle.

        Returns
        -------
        RayBundle
            Fields shaped ``(B, H, W, ...)`` for the full grid, ``(B, n_rays, 1, ...)`` for a
            random subset (as PyTorch3D).
        """
        cameras = _check_cameras(cameras)
        B, H, W = len(cameras), self.image_height, self.image_width
        n_rays = _positive_int(n_rays_per_image, "n_rays_per_image", allow_none=True)
        n_rays = self.n_rays_per_image if n_rays is None else n_rays
        n_pts = self.n_pts_per_ray if n_pts_per_ray is None else _positive_int(
            n_pts_per_ray, "n_pts_per_ray")
        if n_rays is not None:  # a random subset: checked before the draw (the full grid is
            _check_rays(B, n_rays, n_pts)  # checked where its bundle is built)
        lo = self.min_depth if min_depth is None else min_depth
        hi = self.max_depth if max_depth is None else max_depth
        lo, hi = _depth_range(lo, hi)
        strat = self.stratified_sampling if stratified_sampling is None else bool(
            stratified_sampling)
        rng = as_rng(seed) if (strat or n_rays is not None or mask is not None) else None
        xy = np.broadcast_to(self.xy_grid(), (B, H, W, 2))
        weights = None
        if mask is not None:
            weights = as_array(mask, "mask", (B, H, W)).reshape(B, H * W)
            if np.any(weights < 0):
                raise ValueError("mask: expected non-negative weights")
            if np.any(weights.sum(axis=1) <= 0):
                raise ValueError("mask: every camera needs at least one pixel with weight > 0")
            if n_rays is None:
                n_rays = int(np.count_nonzero(weights, axis=1).min())
        if n_rays is not None:
            flat = xy.reshape(B, H * W, 2)
            chosen = np.empty((B, n_rays), dtype=np.int64)
            for b in range(B):  # batch members
                p = None if weights is None else weights[b] / weights[b].sum()
                n_nonzero = H * W if p is None else int(np.count_nonzero(p))
                chosen[b] = rng.choice(H * W, size=n_rays, replace=n_rays > n_nonzero, p=p)
            xy = np.take_along_axis(flat, chosen[..., None], axis=1)[:, :, None, :]
        return _xy_to_ray_bundle(cameras, np.ascontiguousarray(xy), lo, hi, n_pts,
                                 self.unit_directions, strat, rng)


class MonteCarloRaysampler:
    """Rays through NDC points drawn uniformly in a box (PyTorch3D's ``MonteCarloRaysampler``).

    Parameters
    ----------
    min_x, max_x, min_y, max_y : float
        The NDC box (x uniform in [min_x, max_x), y in [min_y, max_y)).
    n_rays_per_image : int
        Rays per camera.
    n_pts_per_ray : int
        Samples per ray.
    min_depth, max_depth : float
        Depth range of the samples.
    unit_directions : bool
        Normalise the directions.
    stratified_sampling : bool
        Jiggle each sample uniformly within its bin.

    Examples
    --------
    >>> from geofit.cameras import FoVPerspectiveCameras
    >>> sampler = MonteCarloRaysampler(-1.0, 1.0, -1.0, 1.0, 750, 128, 0.1, 3.0)
    >>> bundle = sampler(FoVPerspectiveCameras(), seed=0)
    >>> bundle.xys.shape, bool(np.abs(bundle.xys).max() <= 1.0)
    ((1, 750, 2), True)
    """

    def __init__(self, min_x: float, max_x: float, min_y: float, max_y: float,
                 n_rays_per_image: int, n_pts_per_ray: int, min_depth: float,
                 max_depth: float, *, unit_directions: bool = False,
                 stratified_sampling: bool = False):
        self.min_x, self.max_x, self.min_y, self.max_y = (
            _finite_float(v, n) for v, n in ((min_x, "min_x"), (max_x, "max_x"),
                                             (min_y, "min_y"), (max_y, "max_y")))
        self.n_rays_per_image = _positive_int(n_rays_per_image, "n_rays_per_image")
        self.n_pts_per_ray = _positive_int(n_pts_per_ray, "n_pts_per_ray")
        self.min_depth, self.max_depth = _depth_range(min_depth, max_depth)
        self.unit_directions = bool(unit_directions)
        self.stratified_sampling = bool(stratified_sampling)

    def __repr__(self) -> str:
        return (f"MonteCarloRaysampler(x=[{self.min_x:g}, {self.max_x:g}], "
                f"y=[{self.min_y:g}, {self.max_y:g}], n_rays_per_image={self.n_rays_per_image}, "
                f"n_pts_per_ray={self.n_pts_per_ray})")

    def __call__(self, cameras: CamerasBase, *, stratified_sampling: bool | None = None,
                 seed=None) -> RayBundle:
        """Rays of a batch of cameras.

        Parameters
        ----------
        cameras : CamerasBase
            ``B`` cameras.
        stratified_sampling : bool, optional
            Overrides the constructor's value.
        seed : int or numpy.random.Generator, optional
            For the xy draw and the stratified jiggle.

        Returns
        -------
        RayBundle
            Fields shaped ``(B, n_rays_per_image, ...)``.
        """
        cameras = _check_cameras(cameras)
        rng = as_rng(seed)
        B, n = len(cameras), self.n_rays_per_image
        u = rng.random((B, n, 2))
        xy = np.empty((B, n, 2))
        xy[..., 0] = u[..., 0] * (self.max_x - self.min_x) + self.min_x
        xy[..., 1] = u[..., 1] * (self.max_y - self.min_y) + self.min_y
        strat = self.stratified_sampling if stratified_sampling is None else bool(
            stratified_sampling)
        return _xy_to_ray_bundle(cameras, xy, self.min_depth, self.max_depth,
                                 self.n_pts_per_ray, self.unit_directions, strat, rng)

