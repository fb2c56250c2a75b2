"""Rendering helpers of :func:`geofit.fit.nerf.fit_nerf`: the tutorial's target sampling at
NDC ray locations and full-image renders of a field (re-exported by :mod:`geofit.fit.nerf`)."""
from __future__ import annotations

import numpy as np

from .._memory import check_allocation
from .._threads import get_num_threads, parallel_map
from .._validate import as_array
from ..cameras import CamerasBase
from ..render.volume import (
    EmissionAbsorptionRaymarcher,
    ImplicitRenderer,
    NDCMultinomialRaysampler,
    NeuralRadianceField,
    OccupancyGrid,
    RayBundle,
)

__all__ = ["render_nerf", "sample_images_at_xys"]


def sample_images_at_xys(images, xys) -> np.ndarray:
    """The tutorial's ``sample_images_at_mc_locs``: bilinear samples at NDC ``xys``.

    ``grid_sample(images, -xys, align_corners=True)`` with zero padding: image column ``u =
    (1 - x) (W - 1) / 2`` and row ``v = (1 - y) (H - 1) / 2``.

    Parameters
    ----------
    images : (B, H, W, C) float64
    xys : (B, ..., 2) float64

    Returns
    -------
    samples : (B, ..., C) float64
    """
    im = as_array(images, "images", (None, None, None, None))
    xy = as_array(xys, "xys")
    if xy.ndim < 2 or xy.shape[0] != im.shape[0] or xy.shape[-1] != 2:
        raise ValueError(f"xys: expected shape ({im.shape[0]}, ..., 2), got {xy.shape}")
    B, H, W, C = im.shape
    lead = xy.shape[1:-1]
    flat = xy.reshape(B, -1, 2)
    u = (1.0 - flat[..., 0]) * (W - 1) / 2.0
    v = (1.0 - flat[..., 1]) * (H - 1) / 2.0
    u0 = np.floor(u)
    v0 = np.floor(v)
    fu, fv = u - u0, v - v0
    out = np.zeros(flat.shape[:2] + (C,))
    b = np.arange(B)[:, None]
    for du, dv, w in ((0, 0, (1 - fu) * (1 - fv)), (1, 0, fu * (1 - fv)),
                      (0, 1, (1 - fu) * fv), (1, 1, fu * fv)):  # the four corners
        uu = (u0 + du).astype(np.int64)
        vv = (v0 + dv).astype(np.int64)
        ok = (uu >= 0) & (uu < W) & (vv >= 0) & (vv < H)
        val = im[b, np.clip(vv, 0, H - 1), np.clip(uu, 0, W - 1)]
        out += (w * ok)[..., None] * val
    return out.reshape((B,) + lead + (C,))


def render_nerf(field: NeuralRadianceField, cameras: CamerasBase, image_size=128, *,
                n_pts_per_ray: int = 128, min_depth: float = 0.1, max_depth: float = 3.0,
                occupancy: OccupancyGrid | None = None, chunk_rays: int = 4096,
                n_threads: int | None = None, check=None) -> np.ndarray:
    """Full-image renders of a field (the tutorial's grid renderer).

    Parameters
    ----------
    field : NeuralRadianceField
    cameras : CamerasBase
        ``N`` cameras.
    image_size : int or (H, W)
        Output size.
    n_pts_per_ray, min_depth, max_depth
        The ``NDCMultinomialRaysampler`` settings (the field was trained with them).
    occupancy : OccupancyGrid, optional
        Skip samples outside it (exactly the render of the field with density 0 outside).
    chunk_rays : int
        Rays per chunk (bounds memory).
    n_threads : int, optional
        Threads over chunks (None: :func:`geofit.get_num_threads`).
    check : callable, optional
        Called before each chunk; what it raises (a fit's :class:`~geofit.fit.TimeUp`) stops
        the render.

    Returns
    -------
    images : (N, H, W, 4) float64
        RGB and opacity.
    """
    if not isinstance(field, NeuralRadianceField):
        raise TypeError(f"field: expected a NeuralRadianceField, got {type(field)!r}")
    if not isinstance(cameras, CamerasBase):
        raise TypeError(f"cameras: expected a geofit cameras batch, got {type(cameras)!r}")
    H, W = (image_size, image_size) if np.isscalar(image_size) else map(int, image_size)
    sampler = NDCMultinomialRaysampler(image_width=int(W), image_height=int(H),
                                       n_pts_per_ray=n_pts_per_ray, min_depth=min_depth,
                                       max_depth=max_depth)
    renderer = ImplicitRenderer(sampler, EmissionAbsorptionRaymarcher(), occupancy=occupancy)
    n_threads = get_num_threads() if n_threads is None else max(int(n_threads), 1)
    r = len(cameras) * int(H) * int(W)
    # memory guard (issue 18), measured ~7
    per = 7 * np.dtype(field.dtype).itemsize * field.config["n_hidden_neurons"]  # B/sample
    check_allocation(per * min(chunk_rays, r) * n_pts_per_ray * n_threads, "chunk_rays and "
                     "n_pts_per_ray", "the network activations of one chunk of rays per thread")
    if check is not None:
        check()
    bundle = sampler(cameras)
    if check is not None:
        check()
    flat = RayBundle(*(np.asarray(a).reshape(-1, a.shape[-1]) for a in bundle))
    r = flat.origins.shape[0]
    chunks = [slice(s, min(s + chunk_rays, r)) for s in range(0, r, chunk_rays)]

    def work(sl):
        if check is not None:
            check()
        return renderer._render_flat(RayBundle(*(a[sl] for a in flat)), field, cache=False)[0]

    out = np.concatenate(parallel_map(work, chunks, n_threads), axis=0)
    return out.reshape(len(cameras), int(H), int(W), 4)
