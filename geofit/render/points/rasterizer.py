"""Point cloud rasterization with PyTorch3D's semantics, vectorised in numpy.

Every point is a disc of radius ``r`` in NDC units (PyTorch3D's convention: not scaled by depth,
even for perspective cameras). Each pixel keeps the ``K`` points nearest in view depth whose disc
covers its centre (squared NDC distance ``< r**2``, strict), sorted front to back; ties in depth go
to the lower point index. Points with view depth ``z < 0`` are dropped. Outputs are
``PointFragments``: ``idx`` (-1 where empty), ``zbuf`` (view depth) and ``dists`` (squared NDC
distance), as ``pytorch3d.renderer.PointsRasterizer`` returns them, but channel-last
``(N, H, W, K)``.

How it is vectorised: all points are projected at once and put in front-to-back order (a stable
sort by depth, so equal depths keep index order). Each point's disc covers a small box of pixel
centres; the (point, pixel) candidates of every box are generated with ``np.repeat``, the ones
inside the disc are kept, and one integer sort on ``pixel * M + depth_rank`` groups them by pixel
in front-to-back order. The rank of a hit within its pixel is its position in the group; hits of
rank ``< K`` are scattered into the output. Candidates are processed in chunks of bounded size
in front-to-back order, so the memory stays bounded for any radius, and a pixel that already holds
``K`` points ignores later chunks: a summed-area table of the open pixels lets a point whose whole
box is full be skipped before any candidate is generated.

Beyond PyTorch3D: ``radius_units="world"`` makes the radius a world-space size that shrinks with
depth (``r_ndc = r * K00 / z`` for a perspective camera, ``r * K00`` for an orthographic one),
``radius`` may be one value per point, and ``PointFragments.depth`` is the depth image.
"""
from __future__ import annotations

import itertools
import numbers
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from ..._memory import check_allocation
from ..._threads import get_num_threads, parallel_map
from ..._validate import as_array, as_instance, check_choice, check_int
from ...cameras import CamerasBase
from ...structures.pointcloud import Pointclouds, as_pointclouds
from .._settings import float_dtype
from .compositing import AlphaCompositor, NormWeightedCompositor

__all__ = [
    "PointFragments",
    "PointsRasterizationSettings",
    "PointsRasterizer",
    "PointsRenderer",
    "PointsRendering",
    "rasterize_points",
]

# Number of (point, pixel) candidates processed at once (bounds the working memory to a few
# hundred MB whatever the radius).
_CHUNK_CANDIDATES = 1 << 22
# Slack, in pixels, when bounding a disc by pixel centres: the exact distance test decides.
_BOX_SLACK = 1e-7
# Threads (row bands of the image) for large clouds; numpy releases the GIL in the heavy steps.
_THREAD_MIN_POINTS = 50_000


def _check_int(value, name: str, minimum: int) -> int:
    return check_int(value, name, minimum, error=TypeError)  # not an integer: TypeError here


def _image_hw(image_size) -> tuple[int, int]:
    if isinstance(image_size, (numbers.Integral, np.integer)) and not isinstance(
            image_size, (bool, np.bool_)):
        s = _check_int(image_size, "image_size", 1)
        return s, s
    try:
        h, w = image_size
    except (TypeError, ValueError):
        raise ValueError(f"image_size: expected an int or (H, W), got {image_size!r}") from None
    return _check_int(h, "image_size[0]", 1), _check_int(w, "image_size[1]", 1)


@dataclass(frozen=True)
class PointsRasterizationSettings:
    """How points are rasterized (PyTorch3D's ``PointsRasterizationSettings``).

    Parameters
    ----------
    image_size : int or (2,) int
        Image size; an int is a square image, ``(H, W)`` a rectangular one (the shorter side
        spans NDC [-1, 1]).
    radius : float or (P,) float64
        Point radius, ``>= 0``; one value for every point, or one per packed point of the
        clouds rendered. In NDC units by default (a radius of 0 covers no pixel).
    points_per_pixel : int
        ``K``, the number of points kept per pixel (nearest in view depth first).
    radius_units : {"ndc", "world"}
        ``"ndc"`` (PyTorch3D): the radius is an NDC distance, the same at every depth.
        ``"world"``: the radius is a world-space length; a point at view depth ``z`` gets the NDC
        radius ``radius * K00 / z`` for a perspective camera and ``radius * K00`` for an
        orthographic one (``K00`` the camera's x scale, ``get_projection_transform()[:, 0, 0]``).
    dtype : numpy.float32 or numpy.float64
        Type of the fragments' ``zbuf``, ``dists`` and ``radius`` and of the rendered images
        (default float32, as PyTorch3D; projection and distances are computed in float64).

    Examples
    --------
    >>> s = PointsRasterizationSettings(image_size=512, radius=0.003, points_per_pixel=10)
    >>> s.hw, s.points_per_pixel
    ((512, 512), 10)
    """

    image_size: int | tuple[int, int] = 256
    radius: float | np.ndarray = 0.01
    points_per_pixel: int = 8
    radius_units: str = "ndc"
    dtype: Any = np.float32

    def __post_init__(self):
        _image_hw(self.image_size)
        object.__setattr__(self, "dtype", float_dtype(self.dtype))
        _check_int(self.points_per_pixel, "points_per_pixel", 1)
        check_choice(self.radius_units, "radius_units", ("ndc", "world"))
        r = np.asarray(self.radius)
        if r.ndim == 0:
            try:
                v = float(r)
            except (TypeError, ValueError):
                raise ValueError(f"radius: expected a number, got {self.radius!r}") from None
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"radius: expected a finite number >= 0, got {self.radius!r}")
        else:
            r = as_array(r, "radius", (None,))
            if np.any(r < 0):
                raise ValueError(f"radius: expected values >= 0, got minimum {r.min():g}")
            r.setflags(write=False)
            object.__setattr__(self, "radius", r)

    @property
    def hw(self) -> tuple[int, int]:
        """``(H, W)`` in pixels."""
        return _image_hw(self.image_size)


@dataclass(frozen=True)
class PointFragments:
    """What each pixel sees: the ``K`` nearest points covering its centre.

    Attributes
    ----------
    idx : (N, H, W, K) int64
        If ``idx[n, j, i, k] = p >= 0`` then packed point ``p`` of the clouds is the ``k``-th
        nearest (in view depth) point covering pixel row ``j``, column ``i`` of image ``n``.
        Slots past the last hit are -1; entries are sorted front to back.
    zbuf : (N, H, W, K) float32 (the settings' ``dtype``)
        View depth of that point; -1 where ``idx`` is -1.
    dists : (N, H, W, K) float32 (the settings' ``dtype``)
        Squared NDC distance from the pixel centre to the point's projection, ``< radius**2``;
        -1 where ``idx`` is -1.
    radius : (N, H, W, K) float32 (the settings' ``dtype``)
        NDC radius of that point's disc (the settings' radius, or per point / world-scaled);
        0 where ``idx`` is -1.
    """

    idx: np.ndarray
    zbuf: np.ndarray
    dists: np.ndarray
    radius: np.ndarray

    @property
    def depth(self) -> np.ndarray:
        """(N, H, W) float64 view depth of the nearest point per pixel; -1 where none."""
        return self.zbuf[..., 0]

    @property
    def mask(self) -> np.ndarray:
        """(N, H, W) bool: pixels covered by at least one point."""
        return self.idx[..., 0] >= 0

    def weights(self) -> np.ndarray:
        """(N, H, W, K) compositing weights ``1 - dists / radius**2`` (the fragments' dtype);
        0 where empty.

        The weights of ``pytorch3d.renderer.PointsRenderer`` (SynSin's), in ``(0, 1]``.
        """
        w = np.zeros(self.dists.shape, self.dists.dtype)
        valid = self.idx >= 0
        w[valid] = 1.0 - self.dists[valid] / (self.radius[valid] ** 2)
        return w


def _pixel_hits(x, y, r, img, H, W, band, full=None):
    """Candidate generation for entries already in front-to-back order.

    Returns the image-flat pixel index and entry position of every (entry, pixel) pair whose
    pixel centre lies strictly inside the entry's disc, in entry order then row-major pixel order,
    for the pixel rows ``band = (lo, hi)`` only. ``full`` (N, hi - lo, W) bool marks the band's
    pixels that already hold K points: entries whose box holds only full pixels are skipped (a
    summed-area table counts the open pixels of each box), and candidates at full pixels are
    dropped.
    """
    lo, hi = band
    S = min(H, W)
    with np.errstate(over="ignore"):   # far-off projections become +-inf, clipped below
        cx = (W - 1 - S * x) * 0.5     # continuous column of the projection
        cy = (H - 1 - S * y) * 0.5     # continuous row
        rp = r * (0.5 * S)             # radius in pixels
    c0 = np.ceil(np.clip(cx - rp - _BOX_SLACK, 0, W)).astype(np.int64)
    c1 = np.floor(np.clip(cx + rp + _BOX_SLACK, -1, W - 1)).astype(np.int64)
    r0 = np.ceil(np.clip(cy - rp - _BOX_SLACK, lo, hi)).astype(np.int64)
    r1 = np.floor(np.clip(cy + rp + _BOX_SLACK, lo - 1, hi - 1)).astype(np.int64)
    nx = np.maximum(c1 - c0 + 1, 0)
    ny = np.maximum(r1 - r0 + 1, 0)
    count = nx * ny
    if full is not None:
        sat = np.zeros((full.shape[0], hi - lo + 1, W + 1), dtype=np.int64)
        np.cumsum(np.cumsum(~full, axis=1), axis=2, out=sat[:, 1:, 1:])
        b0, b1 = r0 - lo, r1 - lo + 1
        n_open = (sat[img, b1, c1 + 1] - sat[img, b0, c1 + 1]
                  - sat[img, b1, c0] + sat[img, b0, c0])
        count[n_open <= 0] = 0
    total = int(count.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    ent = np.repeat(np.arange(len(x)), count)
    start = np.cumsum(count) - count
    local = np.arange(total, dtype=np.int64) - start[ent]
    nxe = nx[ent]
    row, col = np.divmod(local, nxe)
    col += c0[ent]
    row += r0[ent]
    if full is not None:
        keep = ~full[img[ent], row - lo, col]
        ent, row, col = ent[keep], row[keep], col[keep]
    d2 = _dist2(x[ent], y[ent], row, col, H, W)
    hit = d2 < (r * r)[ent]
    ent = ent[hit]
    return img[ent] * (H * W) + row[hit] * W + col[hit], ent


def _dist2(x, y, row, col, H, W):
    """Squared NDC distance from pixel centres ``(row, col)`` to points ``(x, y)``."""
    S = min(H, W)
    dx = (W - 1 - 2 * col) / S - x
    dy = (H - 1 - 2 * row) / S - y
    return dx * dx + dy * dy


def rasterize_points(xy, z, radius, image_index, n_images: int, image_size, K: int):
    """Rasterize projected points (the numeric core of ``PointsRasterizer``).

    Parameters
    ----------
    xy : (M, 2) float64
        NDC x, y of every entry (+X left, +Y up).
    z : (M,) float64
        View depth of every entry; entries with ``z < 0`` are dropped.
    radius : (M,) float64
        NDC radius of every entry, ``>= 0``.
    image_index : (M,) int64
        Image each entry is drawn into, in ``[0, n_images)``; within one image entries must be
        in increasing point order (their position breaks depth ties).
    n_images : int
        ``N``.
    image_size : (2,) int
        ``(H, W)``.
    K : int
        Points kept per pixel.

    Returns
    -------
    entry : (N, H, W, K) int64
        Index into the M entries (-1 where empty), front to back.
    zbuf, dists : (N, H, W, K) float64
        View depth and squared NDC distance (-1 where empty).

    Raises
    ------
    ValueError
        For mismatched lengths, non-finite values, negative radii, image indices outside
        ``[0, n_images)``, or sizes / ``K`` below 1.
    """
    xy = as_array(xy, "xy", (None, 2))
    M = len(xy)
    z = as_array(z, "z", (M,))
    radius = as_array(radius, "radius", (M,))
    if np.any(radius < 0):
        raise ValueError(f"radius: expected values >= 0, got minimum {radius.min():g}")
    n_images = _check_int(n_images, "n_images", 1)
    image_index = as_array(image_index, "image_index", (M,), np.int64)
    if M and (image_index.min() < 0 or image_index.max() >= n_images):
        raise ValueError(f"image_index: expected values in [0, {n_images - 1}], got range "
                         f"[{image_index.min()}, {image_index.max()}]")
    return _rasterize(xy, z, radius, image_index, n_images, _image_hw(image_size),
                      _check_int(K, "K", 1))


def _rasterize(xy, z, radius, image_index, n_images, image_size, K, dtype=np.float64):
    """``rasterize_points`` on validated inputs; ``zbuf`` and ``dists`` of type ``dtype``."""
    H, W = image_size
    check_allocation(64 * n_images * H * W * K, "points_per_pixel and image_size",
                     f"the ({n_images}, {H}, {W}, K={K}) point fragments")
    n_pix = n_images * H * W
    entry_out = np.full(n_pix * K, -1, dtype=np.int64)
    dist_out = np.full(n_pix * K, -1.0, dtype)
    filled = np.zeros(n_pix, dtype=np.int64)
    keep = (z >= 0) & (radius > 0)
    sel = np.flatnonzero(keep)
    # Front-to-back order; the stable sort keeps the entry (point index) order on equal depths.
    sel = sel[np.argsort(z[sel], kind="stable")]
    x, y, r, img = xy[sel, 0], xy[sel, 1], radius[sel], image_index[sel]

    def band_job(band):
        """Rasterize the pixel rows ``band``: chunks of candidates, front to back."""
        lo, hi = band
        S = min(H, W)
        with np.errstate(over="ignore"):
            cy = (H - 1 - S * y) * 0.5
            rp = r * (0.5 * S)
        mine = np.flatnonzero((cy + rp + _BOX_SLACK >= lo) & (cy - rp - _BOX_SLACK <= hi - 1))
        if len(mine) == 0:
            return
        bx, by, br, bimg = x[mine], y[mine], r[mine], img[mine]
        # Upper bound on each entry's candidate count, for chunking.
        box = np.minimum(2 * rp[mine] + 1, W + 1) * np.minimum(2 * rp[mine] + 1, hi - lo + 1)
        csum = np.cumsum(box)
        cuts = np.searchsorted(csum, np.arange(1, int(csum[-1] // _CHUNK_CANDIDATES) + 1)
                               * float(_CHUNK_CANDIDATES))
        bounds = np.unique(np.concatenate([[0], cuts, [len(mine)]]))
        view = filled.reshape(n_images, H, W)
        for a, b in itertools.pairwise(bounds):
            full = None if a == 0 else view[:, lo:hi] >= K
            pix, ent = _pixel_hits(bx[a:b], by[a:b], br[a:b], bimg[a:b], H, W, band, full)
            if len(pix) == 0:
                continue
            # One integer sort of the unique keys pixel * m + depth rank groups the hits by
            # pixel, front to back within a pixel.
            m = b - a
            pix, ent = np.divmod(np.sort(pix * m + ent), m)
            new = np.empty(len(pix), dtype=bool)
            new[0] = True
            np.not_equal(pix[1:], pix[:-1], out=new[1:])
            first = np.flatnonzero(new)
            size = np.diff(np.append(first, len(pix)))
            group_pix = pix[first]
            before = filled[group_pix]
            rank = np.arange(len(pix)) - np.repeat(first - before, size)
            ok = rank < K
            pix, ent = pix[ok], ent[ok] + a
            slot = pix * K + rank[ok]
            entry_out[slot] = sel[mine[ent]]
            rc = pix % (H * W)
            dist_out[slot] = _dist2(bx[ent], by[ent], rc // W, rc % W, H, W)
            # Bands own disjoint pixels, so this update does not race with other threads.
            filled[group_pix] = np.minimum(before + size, K)

    if len(sel):
        n_threads = get_num_threads()
        n_bands = n_threads if len(sel) >= _THREAD_MIN_POINTS and H >= 2 * n_threads else 1
        edges = np.linspace(0, H, n_bands + 1).round().astype(int)
        bands = list(itertools.pairwise(edges.tolist()))
        parallel_map(band_job, bands, n_bands)   # numpy releases the GIL
    shape = (n_images, H, W, K)
    entry_out = entry_out.reshape(shape)
    valid = entry_out >= 0
    zbuf = np.full(shape, -1.0, dtype)
    zbuf[valid] = z[entry_out[valid]]
    return entry_out, zbuf, dist_out.reshape(shape)


def _affine(P, A, b):
    """``P @ A + b`` for ``P (k, 3)``, ``A (3, c)``, ``b (c,)`` without BLAS.

    A (k, 3) x (3, c) product is memory-bound; written out it avoids waking BLAS threads, which
    spin and compete with the rasterizer's own threads on a busy machine.
    """
    return P[:, 0:1] * A[0] + P[:, 1:2] * A[1] + P[:, 2:3] * A[2] + b


def _batch(point_clouds, cameras) -> tuple[Pointclouds, CamerasBase, int]:
    clouds = as_pointclouds(point_clouds)
    if not isinstance(cameras, CamerasBase):
        raise TypeError(f"cameras: expected a geofit camera batch (FoVPerspectiveCameras, "
                        f"FoVOrthographicCameras), got {type(cameras)!r}")
    nc, nk = len(clouds), len(cameras)
    if nc == 0:
        raise ValueError("point_clouds: expected at least one cloud, got an empty batch")
    if nc != nk and nc != 1 and nk != 1:
        raise ValueError(f"cameras: expected 1 or {nc} cameras for {nc} clouds, got {nk}")
    return clouds, cameras, max(nc, nk)


class PointsRasterizer:
    """Rasterize point clouds seen by cameras into ``PointFragments`` (PyTorch3D's class).

    Parameters
    ----------
    cameras : CamerasBase, optional
        Default cameras (``FoVPerspectiveCameras`` or ``FoVOrthographicCameras``); can be
        given per call instead.
    raster_settings : PointsRasterizationSettings, optional
        Defaults to ``PointsRasterizationSettings()``.

    Notes
    -----
    Batches: ``N`` clouds with ``N`` cameras render cloud ``n`` with camera ``n``; one cloud
    with ``N`` cameras renders it from every camera; ``N`` clouds with one camera render them all
    from it. ``idx`` always indexes the packed points of the clouds given
    (``point_clouds.points_packed()``), so a shared cloud's images index the same points.
    Nothing here is differentiable (which points a pixel keeps is piecewise constant).

    Examples
    --------
    >>> from geofit import PointCloud
    >>> from geofit.cameras import FoVOrthographicCameras
    >>> cloud = PointCloud([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]], [[1, 0, 0], [0, 1, 0]])
    >>> settings = PointsRasterizationSettings(image_size=4, radius=0.5, points_per_pixel=2)
    >>> frags = PointsRasterizer(FoVOrthographicCameras(), settings)(cloud)
    >>> frags.idx[0, 1, 1].tolist(), frags.zbuf[0, 1, 1].tolist()
    ([0, 1], [1.0, 2.0])
    """

    def __init__(self, cameras: CamerasBase | None = None,
                 raster_settings: PointsRasterizationSettings | None = None):
        raster_settings = as_instance(raster_settings, PointsRasterizationSettings,
                                      "raster_settings")
        if cameras is not None and not isinstance(cameras, CamerasBase):
            raise TypeError(f"cameras: expected a geofit camera batch, got {type(cameras)!r}")
        self.cameras = cameras
        self.raster_settings = raster_settings

    def _settings(self, raster_settings):
        s = self.raster_settings if raster_settings is None else raster_settings
        return as_instance(s, PointsRasterizationSettings, "raster_settings")

    def transform(self, point_clouds, cameras: CamerasBase | None = None, *,
                  raster_settings: PointsRasterizationSettings | None = None):
        """Project the clouds: NDC x, y, view depth and NDC radius of every (image, point).

        Parameters
        ----------
        point_clouds : PointCloud or Pointclouds
            ``N`` (or 1) clouds with ``P`` packed points in total.
        cameras : CamerasBase, optional
            Overrides the rasterizer's cameras.
        raster_settings : PointsRasterizationSettings, optional
            Overrides the rasterizer's settings.

        Returns
        -------
        xy : (M, 2) float64
            NDC x, y of each entry.
        z : (M,) float64
            View depth of each entry.
        radius : (M,) float64
            NDC radius of each entry.
        image : (M,) int64
            Image of each entry.
        point : (M,) int64
            Packed point index of each entry.
        n_images : int
            ``N``.
        """
        cameras = self.cameras if cameras is None else cameras
        if cameras is None:
            raise ValueError("cameras: none given to the rasterizer or to this call")
        s = self._settings(raster_settings)
        clouds, cameras, n_images = _batch(point_clouds, cameras)
        n_pts = clouds.num_points_per_cloud()
        P = int(n_pts.sum())
        r = np.asarray(s.radius, dtype=np.float64)
        if r.ndim == 1 and len(r) != P:
            raise ValueError(f"radius: expected a scalar or shape ({P},) (one per packed point), "
                             f"got shape {r.shape}")
        packed = clouds.points_packed()
        first = clouds.cloud_to_packed_first_idx()
        proj = cameras.get_projection_transform()        # (Nc, 4, 4) row vectors
        xy_l, z_l, r_l, img_l, pt_l = [], [], [], [], []
        for n in range(n_images):                       # loop over the batch, not points
            c = 0 if len(clouds) == 1 else n
            k = 0 if len(cameras) == 1 else n
            lo, hi = int(first[c]), int(first[c]) + int(n_pts[c])
            with np.errstate(over="ignore", invalid="ignore"):
                view = _affine(packed[lo:hi], cameras.R[k], cameras.T[k])
                h = _affine(view, proj[k, :3, :], proj[k, 3, :])
                w = h[:, 3]
                z = view[:, 2].copy()
                # z < 0: behind the camera (PyTorch3D); w <= 0 only for perspective points at
                # z == 0; non-finite values only for coordinates near the float64 limit.
                ok = (z >= 0) & (w > 0) & np.isfinite(h).all(axis=1)
                xy = h[:, :2] / np.where(ok, w, 1.0)[:, None]
                ok &= np.isfinite(xy).all(axis=1)
            z[~ok] = -1.0
            xy[~ok] = 0.0
            rr = np.broadcast_to(r, (P,))[lo:hi] if r.ndim else np.full(hi - lo, float(r))
            if s.radius_units == "world":
                rr = np.where(ok, rr * abs(proj[k, 0, 0]) / np.where(ok, w, 1.0), 0.0)
            xy_l.append(xy)
            z_l.append(z)
            r_l.append(rr)
            img_l.append(np.full(hi - lo, n, dtype=np.int64))
            pt_l.append(np.arange(lo, hi, dtype=np.int64))
        return (np.concatenate(xy_l), np.concatenate(z_l), np.concatenate(r_l),
                np.concatenate(img_l), np.concatenate(pt_l), n_images)

    def __call__(self, point_clouds, cameras: CamerasBase | None = None, *,
                 raster_settings: PointsRasterizationSettings | None = None) -> PointFragments:
        """Rasterize.

        Parameters
        ----------
        point_clouds, cameras, raster_settings
            As :meth:`transform` (the points must be finite; ``PointCloud`` checks this).

        Returns
        -------
        PointFragments
            ``(N, H, W, K)`` arrays. A pixel no point covers (empty cloud, zero radius, every
            point behind the camera) has ``idx == -1``.
        """
        s = self._settings(raster_settings)
        xy, z, r, img, pt, n_images = self.transform(point_clouds, cameras, raster_settings=s)
        K = s.points_per_pixel
        entry, zbuf, dists = _rasterize(xy, z, r, img, n_images, s.hw, K, s.dtype)
        valid = entry >= 0
        idx = np.full(entry.shape, -1, dtype=np.int64)
        idx[valid] = pt[entry[valid]]
        radius = np.zeros(entry.shape, s.dtype)
        radius[valid] = r[entry[valid]]
        return PointFragments(idx=idx, zbuf=zbuf, dists=dists, radius=radius)


class PointsRendering(NamedTuple):
    """Everything a point render produces.

    Attributes
    ----------
    images : (N, H, W, C) float32 (the settings' ``dtype``)
        The composited features (C channels, or C + 1 with a background of C channels).
    depth : (N, H, W) float32 (the settings' ``dtype``)
        View depth of the nearest point per pixel; -1 where no point.
    fragments : PointFragments
        The rasterizer's output.
    """

    images: np.ndarray
    depth: np.ndarray
    fragments: PointFragments


class PointsRenderer:
    """Rasterize point clouds and composite their features (PyTorch3D's ``PointsRenderer``).

    The compositing weights are ``1 - dists / r**2`` (PyTorch3D's, from SynSin): 1 at a point's
    centre, 0 at its rim.

    Parameters
    ----------
    rasterizer : PointsRasterizer
    compositor : AlphaCompositor or NormWeightedCompositor

    Examples
    --------
    >>> from geofit import PointCloud
    >>> from geofit.cameras import FoVOrthographicCameras
    >>> cloud = PointCloud([[0.0, 0.0, 1.0]], [[1.0, 0.5, 0.0]])
    >>> renderer = PointsRenderer(
    ...     PointsRasterizer(FoVOrthographicCameras(),
    ...                      PointsRasterizationSettings(image_size=2, radius=1.5)),
    ...     AlphaCompositor(background_color=(0, 0, 1)))
    >>> renderer(cloud).shape
    (1, 2, 2, 3)
    """

    def __init__(self, rasterizer: PointsRasterizer, compositor):
        if not isinstance(rasterizer, PointsRasterizer):
            raise TypeError(f"rasterizer: expected a PointsRasterizer, got {type(rasterizer)!r}")
        if not isinstance(compositor, (AlphaCompositor, NormWeightedCompositor)):
            raise TypeError("compositor: expected an AlphaCompositor or NormWeightedCompositor, "
                            f"got {type(compositor)!r}")
        self.rasterizer = rasterizer
        self.compositor = compositor

    _UNSET = object()

    def render(self, point_clouds, cameras: CamerasBase | None = None, *,
               raster_settings: PointsRasterizationSettings | None = None,
               background_color=_UNSET) -> PointsRendering:
        """Rasterize and composite, returning images, depth image and fragments.

        Parameters
        ----------
        point_clouds : PointCloud or Pointclouds
            Clouds with features (``(k, C)`` per cloud, e.g. RGB).
        cameras : CamerasBase, optional
            Overrides the rasterizer's cameras.
        raster_settings : PointsRasterizationSettings, optional
            Overrides the rasterizer's settings.
        background_color : (C,) or (C - 1,) float or None, optional
            Overrides the compositor's background colour for this call.

        Returns
        -------
        PointsRendering
        """
        clouds = as_pointclouds(point_clouds)
        features = clouds.features_packed()
        if features is None:
            raise ValueError("point_clouds: the clouds have no features to render "
                             "(give PointCloud(points, features))")
        frags = self.rasterizer(clouds, cameras, raster_settings=raster_settings)
        kw = {} if background_color is self._UNSET else {"background_color": background_color}
        images = self.compositor(frags.idx, frags.weights(), features, **kw)
        return PointsRendering(images.astype(frags.dists.dtype, copy=False), frags.depth, frags)

    def __call__(self, point_clouds, cameras: CamerasBase | None = None, *,
                 raster_settings: PointsRasterizationSettings | None = None,
                 background_color=_UNSET) -> np.ndarray:
        """The images ``(N, H, W, C)`` float64 (see ``render`` for the parameters)."""
        return self.render(point_clouds, cameras, raster_settings=raster_settings,
                           background_color=background_color).images
