"""The visual hull of silhouettes as a signed-distance field (one home for its carving).

Each silhouette, cut at ``threshold``, becomes a signed distance in pixels (positive inside,
:func:`signed_distance_images`, scipy's Euclidean distance transform with the pixel-centre
half-pixel offset). A world point is read in every view at its projection
(``cameras.transform_points_screen``, bilinear, far outside beyond the image or behind the
camera); the minimum over the views (:func:`hull_field`) is positive exactly inside the visual
hull and, being continuous, locates the hull's surface to a fraction of a voxel by marching
cubes. :func:`carve_hull` evaluates it on a grid of ``voxel_px`` pixels over the occupied box
(found by a coarse pass over a cube every camera sits outside of).
:func:`geofit.fit.init.visual_hull_mesh` turns that grid into a mesh.

The conservative, dilated carving of voxel grids for the volume fits (a voxel may be occupied
unless a view rules its whole footprint out) is :func:`geofit.structures.volume.visual_hull`.

Cameras are duck-typed (``transform_points_screen``, ``transform_points_view``,
``get_camera_center``, indexing): the structures layer does not import :mod:`geofit.cameras`.
No gradient is defined here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ClosedHandles", "HullGrid", "carve_hull", "close_unsupported_handles",
           "fill_grey_cores", "grey_cores", "hull_field", "pixel_footprint",
           "signed_distance_images"]

_COARSE = 32  # nodes per side of the first, coarse carving grid


def pixel_footprint(cameras, image_size, point) -> float:
    """Median over the views of the world length that one pixel spans at ``point``.

    Parameters
    ----------
    cameras : CamerasBase
        ``N`` cameras.
    image_size : (2,) int
        ``(H, W)``.
    point : (3,) float64
        World point (e.g. the centre of the object).

    Returns
    -------
    float
        World units per pixel (> 0).
    """
    p = np.asarray(point, dtype=np.float64).reshape(1, 3)
    eps = 1e-3 * max(1.0, float(np.abs(p).max()))
    P = np.concatenate([p, p + eps * np.eye(3)])
    s = cameras.transform_points_screen(P, tuple(image_size))[..., :2]  # (N, 4, 2)
    moved = np.linalg.norm(s[:, 1:] - s[:, :1], axis=-1).max(axis=1)  # pixels per eps
    return float(np.median(eps / np.maximum(moved, 1e-12)))


def signed_distance_images(silhouettes: np.ndarray, threshold: float = 0.5, *,
                           upsample: int = 1, close_px: float = 0.0,
                           fill_px: float = 0.0, grey_px: float = 0.0,
                           grey_level: float = 0.05) -> np.ndarray:
    """(N, H u, W u) float64 signed pixel distance to the ``threshold`` outline (positive
    inside), on a grid ``u = upsample`` times finer than the images.

    Parameters
    ----------
    silhouettes : (N, H, W) float64
        Silhouettes in [0, 1]; pixels above ``threshold`` are inside.
    threshold : float
    upsample : int
        Sub-pixel outlines: the silhouettes are interpolated (bilinear, pixel centres kept)
        on a grid ``upsample`` times finer before the threshold, so the outline follows the
        soft values between pixel centres (a limb that crosses a pixel between centres stays
        connected where its soft values exceed ``threshold`` there). 1: the pixels as they are.
    close_px : float
        Morphological closing of each thresholded silhouette with a disk of this radius (image
        pixels; 0: none): pinholes and slits narrower than about ``2 close_px`` pixels -- the
        cracks between the parts of a multi-part mesh, a sheet seen edge-on breaking between
        pixel centres -- are filled, so they carve no tunnel through the hull. Holes wider than
        that (a torus's) stay.
    fill_px : float
        Fill the pinholes of each thresholded silhouette: background regions that do not reach
        the image's border (4-connected) and cover at most this many image pixels (0: none).
        Unlike the closing, the outline is left as it is. A soft rasterizer that blends its
        K nearest faces leaves such pinholes where a dense mesh puts more than K faces within
        the blur radius of a pixel (the covering face is cut): 206 of the ogre's 227 enclosed
        background regions in the tutorial's 20 views are of 1-4 pixels.
    grey_px, grey_level : float
        Where the silhouette is known to be background: at or below ``grey_level``. Pixels
        above it and more than ``grey_px`` image pixels (0: none) from every such pixel count
        as inside whatever their value: the core of a part thinner than a pixel, whose soft
        value peaks below ``threshold`` (a thin plate seen edge-on: 308 px of the table's
        thin plate, all inside the true mask), and the grey regions a K-nearest-faces soft
        rasterizer leaves inside dense meshes (the ogre: 1 253 of 1 301 inside the true
        mask). The soft outline's ramp (about 2 px wide) and holes seen through stay.

    Returns
    -------
    (N, H u, W u) float64
        ``edt(inside) - 0.5`` inside, ``0.5 - edt(outside)`` outside, in image pixels (fine
        distances divided by ``u``): the outline sits half a fine pixel from the centres of
        the fine pixels on either side of it. Fine pixel ``(i, j)`` has its centre at image
        pixel coordinate ``((i + 0.5) / u - 0.5, (j + 0.5) / u - 0.5)``.
    """
    from scipy.ndimage import binary_closing, distance_transform_edt, label, map_coordinates

    sil = np.asarray(silhouettes, dtype=np.float64)
    N, H, W = sil.shape
    u = int(upsample)
    if u > 1:  # bilinear at the fine pixel centres, edge values beyond the outer centres
        r = (np.arange(H * u) + 0.5) / u - 0.5
        c = (np.arange(W * u) + 0.5) / u - 0.5
        rr, cc = np.meshgrid(r, c, indexing="ij")
    disk = _disk(close_px * u) if close_px > 0 else None
    out = np.empty((N, H * u, W * u))
    for i, s in enumerate(sil):  # views (each one vectorised transform)
        if u > 1:
            s = map_coordinates(s, [rr, cc], order=1, mode="nearest")
        inside = s > threshold
        if disk is not None:  # pad: a silhouette touching the border is not closed by it
            k = disk.shape[0] // 2
            inside = binary_closing(np.pad(inside, k), structure=disk)[k:-k, k:-k]
        if grey_px > 0:  # grey pixels deeper than grey_px inside the certain background
            inside = inside | _grey_core(s, grey_px * u, grey_level)
        if fill_px > 0:  # enclosed background regions of at most fill_px image pixels
            lab, n = label(np.pad(~inside, 1))  # the padded border is one background region
            size = np.bincount(lab.ravel(), minlength=n + 1)
            small = size <= fill_px * u * u
            small[0] = small[lab[0, 0]] = False
            inside = inside | small[lab[1:-1, 1:-1]]
        out[i] = np.where(inside, distance_transform_edt(inside) - 0.5,
                          0.5 - distance_transform_edt(~inside)) / u
    return out


def _grey_core(s: np.ndarray, radius: float, level: float) -> np.ndarray:
    """(H, W) bool: pixels of ``s (H, W)`` above ``level`` and more than ``radius`` pixels
    from every pixel at or below it (the image's border counts as background)."""
    from scipy.ndimage import distance_transform_edt

    grey = s > level
    return grey & (distance_transform_edt(np.pad(grey, 1))[1:-1, 1:-1] > radius)


def grey_cores(silhouettes: np.ndarray, radius_px: float = 2.0,
               level: float = 1e-3) -> np.ndarray:
    """(N, H, W) bool: the pixels of soft silhouettes that some face must cover although their
    value is low -- those above ``level`` and more than ``radius_px`` pixels from every pixel
    at or below it.

    A soft rasterizer gives a pixel a value above zero only if a face lies within its blur
    radius; outside the object such pixels form a ramp at most a blur radius wide along the
    outline. A pixel farther than that from every empty pixel is covered (or sits in a gap
    between parts narrower than about two blur radii). Its value can still be low: a
    rasterizer that keeps the K faces nearest the camera among those within the blur radius
    drops the covering face where more than K nearer faces of a dense mesh pass close by (at
    the inner occlusion contours of the 124 008-face ogre: 2 948 of its 28 881 true
    silhouette pixels in the tutorial's 20 views of 128 px are at or below 0.5, some at 0.01;
    with ``radius_px=2``, ``level=1e-3`` 2 938 of them are found, with 387 gap pixels; the
    cow's 5 856 faces: none below 0.5, 31 gap pixels).

    Parameters
    ----------
    silhouettes : (N, H, W) float64
        Soft silhouettes in [0, 1].
    radius_px : float
        The soft rasterizer's blur radius in pixels (PyTorch3D's tutorial blur, sigma 1e-4 at
        128 px: 1.94) (> 0).
    level : float
        Values at or below it count as empty (>= 0; a little above 0 keeps a pixel whose only
        face is at the edge of the blur radius, about 1e-4, empty).

    Returns
    -------
    (N, H, W) bool

    Raises
    ------
    ValueError
        If ``silhouettes`` is not (N, H, W), ``radius_px`` is not > 0 or ``level`` < 0.
    """
    s = np.asarray(silhouettes, dtype=np.float64)
    if s.ndim != 3:
        raise ValueError(f"silhouettes: expected (N, H, W), got shape {s.shape}")
    if not np.isfinite(radius_px) or radius_px <= 0:
        raise ValueError(f"radius_px: expected a number > 0, got {radius_px!r}")
    if not np.isfinite(level) or level < 0:
        raise ValueError(f"level: expected a number >= 0, got {level!r}")
    return np.stack([_grey_core(x, float(radius_px), float(level)) for x in s])  # views


def fill_grey_cores(silhouettes: np.ndarray, radius_px: float = 2.0, level: float = 1e-3, *,
                    images=None, background=None, tolerance: float = 0.01):
    """Soft silhouettes with their covered grey pixels raised to 1, and how many.

    A pixel is raised when it is one of the :func:`grey_cores`, at or below 0.5 (a 0.5
    outline misses it), and -- given the views' ``images`` and ``background`` colour -- its
    colour differs from the background by more than ``tolerance`` in some channel (the hard
    RGB render shows the face the soft silhouette's K-nearest cut dropped; a gap between two
    parts narrower than two blur radii shows the background and stays: on the tutorial's 20
    views of 128 px, the ogre's 3 280 cores inside its true mask are all kept and its 410 gap
    cores all left, the beetle's 585 and 307, woody's 0 and 84, the cow's 6 and 32). Pixels
    above 0.5 are left as they are, so silhouettes without such pixels come back unchanged.

    Parameters
    ----------
    silhouettes : (N, H, W) float64
    radius_px, level : float
        As in :func:`grey_cores`.
    images : (N, H, W, 3) float64, optional
        The views' RGB images (None: no colour test).
    background : (3,) float64, optional
        Their background colour (needed with ``images``).
    tolerance : float
        Largest channel difference from ``background`` still counted as background.

    Returns
    -------
    (N, H, W) float64
        The silhouettes, 1 at the raised pixels.
    int
        Pixels raised.
    """
    s = np.asarray(silhouettes, dtype=np.float64)
    raise_ = grey_cores(s, radius_px, level) & (s <= 0.5)
    if images is not None and background is not None:
        img = np.asarray(images, dtype=np.float64)
        if img.shape[:3] != s.shape:
            raise ValueError(f"images: expected shape {s.shape + (3,)} (the silhouettes'), "
                             f"got {img.shape}")
        bg = np.asarray(background, dtype=np.float64).reshape(-1)
        raise_ &= np.abs(img - bg).max(axis=-1) > float(tolerance)
    return np.where(raise_, 1.0, s), int(raise_.sum())


def _disk(radius: float) -> np.ndarray:
    """(2k+1, 2k+1) bool disk of radius ``k = max(1, round(radius))`` pixels."""
    k = max(1, int(round(radius)))
    y, x = np.mgrid[-k:k + 1, -k:k + 1]
    return x * x + y * y <= k * k


def hull_field(sd: np.ndarray, cameras, P: np.ndarray, image_size=None,
               check=None, margins=(0.0,), with_min: bool = False):
    """(k,) float64 signed distance (pixels) of ``P (k, 3)`` to the hull: the minimum over the
    views of the signed distance at the projections; ``-(H + W)`` for points outside an image
    or behind a camera.

    ``sd`` is :func:`signed_distance_images`' output; ``image_size`` ``(H, W)`` the images'
    size when it was upsampled (None: ``sd``'s own). ``check()`` (optional) is called after
    each view: a fit's time budget raises there.

    ``margins`` ``(m_1, ..., m_j)`` (pixels, non-increasing) make the carving a vote: with the
    views' values sorted, ``s_1 <= s_2 <= ...``, the field is ``min_i (s_i + m_i)``, so a point
    is carved only if one view puts it more than ``m_1`` pixels outside its silhouette, or two
    views more than ``m_2``, ... (``(0,)``: the plain minimum). With ``(1, 0)`` a background
    line or pinhole at most 2 pixels wide in one view (the dark seams a soft rasterizer leaves
    between overlapping parts, a sheet seen edge-on breaking between pixel centres) carves
    nothing unless a second view agrees. ``with_min``: also return the plain minimum (what
    carving by any one view gives)."""
    from scipy.ndimage import map_coordinates

    N, Hu, Wu = sd.shape
    H, W = (Hu, Wu) if image_size is None else tuple(image_size)
    u = Hu // H  # the fine grid of signed_distance_images(upsample=u)
    m = np.asarray(margins, dtype=np.float64)
    low = np.full((min(len(m), N), len(P)), np.inf)  # the smallest values so far, sorted
    far = -float(H + W)
    for i in range(N):  # views (each one vectorised call over all points)
        cam = cameras[i]
        # fine pixel centres at integers
        xy = cam.transform_points_screen(P, (H, W))[0, :, :2] * u - 0.5
        val = map_coordinates(sd[i], [xy[:, 1], xy[:, 0]], order=1, cval=far)
        val[cam.transform_points_view(P)[0, :, 2] <= 0] = far  # behind the camera
        for row in low:  # insert val into the sorted rows (as many as margins)
            lo = np.minimum(row, val)
            np.maximum(row, val, out=val)
            row[:] = lo
        if check is not None:
            check()
    field = (low + m[:len(low), None]).min(axis=0)
    return (field, low[0]) if with_min else field


def _grid(lo: np.ndarray, hi: np.ndarray, h: float):
    """Grid nodes covering [lo, hi] with spacing h: (axes, (k, 3) points)."""
    axes = [np.arange(a, b + 0.5 * h, h) for a, b in zip(lo, hi)]
    P = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return axes, P


@dataclass
class HullGrid:
    """The hull field sampled on a grid (:func:`carve_hull`).

    Attributes
    ----------
    field : (D, H, W) float64
        Signed distance in pixels at the nodes, axes in x, y, z order (positive inside).
    origin : (3,) float64
        World position of node ``(0, 0, 0)``.
    voxel_size : float
        Node spacing (world units).
    pixel_size : float
        World size of a pixel at the grid's centre (:func:`pixel_footprint`).
    n_closed_pixels : float
        Silhouette pixels (summed over the views) that ``close_px`` or ``fill_px`` turned
        from outside to inside: the pinholes and slits that carved nothing (0 without them).
    n_vote_kept : int
        Nodes of the ``voxel_px`` grid inside the hull by the carving vote (``margins``) that
        one view alone would have carved (0 with ``margins=(0,)``).
    """

    field: np.ndarray
    origin: np.ndarray
    voxel_size: float
    pixel_size: float
    n_closed_pixels: float = 0.0
    n_vote_kept: int = 0


def carve_hull(silhouettes, cameras, *, threshold: float = 0.5, shrink_px: float = 0.0,
               voxel_px: float = 1.5, refine: int = 1, upsample: int = 1,
               close_px: float = 0.0, margins=(0.0,), vote_depth: float = 0.0,
               check=None, fill_px: float = 0.0, grey_px: float = 0.0,
               grey_level: float = 0.05) -> HullGrid:
    """The visual hull's signed-distance field on a grid of ``voxel_px`` pixels.

    A coarse pass (32 nodes per side over a cube every camera sits outside of) finds the box the
    hull occupies; nodes within a coarse voxel of the hull are kept, so parts thinner than a
    coarse voxel survive. The fine grid spans that box.

    Parameters
    ----------
    silhouettes : (N, H, W) float64
        Silhouettes in [0, 1] (soft or binary).
    cameras : CamerasBase
        The ``N`` cameras.
    threshold : float
        Silhouette level of the outline.
    shrink_px : float
        Carve the outline this many pixels inwards.
    voxel_px : float
        Fine node spacing in pixels at the hull's centre.
    refine : int
        Subdivide the fine grid ``refine`` times per axis, evaluating the field only in the
        band where the surface can be (nodes whose nearest grid node reads within
        ``sqrt(3) voxel_px`` pixels of zero: the field moves at most about a pixel per pixel
        of distance, and a node is at most ``sqrt(3) voxel_px / 2`` from its nearest grid
        node); elsewhere the nearest node's value is kept. Parts thinner than the grid step
        that fall between the nodes are found this way.
    upsample, close_px, fill_px
        Sub-pixel outlines, the closing of pinholes and slits, the filling of pinholes
        (:func:`signed_distance_images`).
    margins : sequence of float
        The carving vote (:func:`hull_field`): ``(0,)`` carves what any view puts outside
        its silhouette; ``(1, 0)`` what one view puts more than a pixel outside or two views
        outside.
    check : callable, optional
        Called between views (:func:`hull_field`); whatever it raises (a fit's
        ``geofit.fit.TimeUp``) stops the carving.

    Returns
    -------
    HullGrid

    Raises
    ------
    ValueError
        If the hull is empty (no point is inside every silhouette).
    """
    sil = np.asarray(silhouettes, dtype=np.float64)
    N, H, W = sil.shape
    sd = signed_distance_images(sil, threshold, upsample=upsample, close_px=close_px,
                                fill_px=fill_px, grey_px=grey_px, grey_level=grey_level)
    n_closed = 0.0
    if close_px > 0 or fill_px > 0 or grey_px > 0:  # what closing and filling added, image px
        plain = signed_distance_images(sil, threshold, upsample=upsample)
        n_closed = float(((sd > 0) & (plain <= 0)).sum()) / (upsample * upsample)
    sd -= shrink_px
    C = cameras.get_camera_center()
    r = 0.95 * float(np.linalg.norm(C, axis=1).min())
    h0 = 2.0 * r / (_COARSE - 1)
    _, P0 = _grid(np.full(3, -r), np.full(3, r), h0)
    px0 = pixel_footprint(cameras, (H, W), np.zeros(3))
    keep = hull_field(sd, cameras, P0, (H, W), check, margins) > -np.sqrt(3.0) * h0 / px0
    if not keep.any():
        raise ValueError("silhouettes: the visual hull is empty (no point projects inside "
                         "every silhouette); check the cameras")
    lo, hi = P0[keep].min(0) - h0, P0[keep].max(0) + h0
    px = pixel_footprint(cameras, (H, W), 0.5 * (lo + hi))
    h = voxel_px * px
    axes, P = _grid(lo, hi, h)
    occ, plain_min = hull_field(sd, cameras, P, (H, W), check, margins, with_min=True)
    shape = [len(a) for a in axes]
    if vote_depth > 0:
        occ = _deep_vote(occ.reshape(shape), plain_min.reshape(shape), h / px,
                         float(vote_depth)).ravel()
    n_kept = int(((occ > 0) & (plain_min <= 0)).sum())
    occ = occ.reshape(shape)
    if refine > 1:
        occ, h = _refine_band(occ, lo, h, px, int(refine), sd, cameras, (H, W), check,
                              margins)
    if not (occ > 0).any():
        raise ValueError("silhouettes: the visual hull is empty after carving; check the "
                         "cameras")
    return HullGrid(occ, lo, h, px, n_closed, n_kept)


def _deep_vote(vote: np.ndarray, plain: np.ndarray, node_px: float, depth: float):
    """The plain field, raised where the vote's hull is deeper than ``depth`` pixels
    (:func:`carve_hull`'s ``vote_depth``; ``node_px``: pixels per node)."""
    from scipy.ndimage import distance_transform_edt

    inside = np.pad(vote > 0, 1)  # the box's border is outside
    deep = distance_transform_edt(inside)[(slice(1, -1),) * 3] * node_px - depth
    return np.maximum(plain, np.minimum(vote, deep))


def _refine_band(occ: np.ndarray, lo: np.ndarray, h: float, px: float, k: int, sd, cameras,
                 image_size, check=None, margins=(0.0,)):
    """The field on a grid ``k`` times finer, evaluated only in the surface's band."""
    margin = np.sqrt(3.0) * h / px
    n = np.array(occ.shape)
    m = (n - 1) * k + 1
    idx = [np.minimum((np.arange(mi) + k // 2) // k, ni - 1) for mi, ni in zip(m, n)]
    near = occ[np.ix_(*idx)]  # the nearest coarse node's value
    band = np.flatnonzero(np.abs(near).ravel() <= margin)
    out = near.ravel().copy()
    hf = h / k
    ii = np.unravel_index(band, tuple(m))
    P = lo + hf * np.stack(ii, axis=1)
    out[band] = hull_field(sd, cameras, P, image_size, check, margins)
    return out.reshape(tuple(m)), hf


@dataclass
class ClosedHandles:
    """What :func:`close_unsupported_handles` filled.

    Attributes
    ----------
    grid : HullGrid
        The hull field with the filled nodes raised to ``+fill_value``.
    n_filled : int
        Nodes filled.
    filled : (D, H, W) bool
        Which.
    """

    grid: HullGrid
    n_filled: int
    filled: np.ndarray


def close_unsupported_handles(grid: HullGrid, *, radius_px: float = 4.0,
                              tolerance_px: float = 1.0) -> ClosedHandles:
    """Fill the hull's narrow tunnels and crevices that no silhouette insists on.

    A handle of the hull whose tunnel is narrow and lies within ``tolerance_px`` pixels of
    every silhouette (the hull field there is above ``-tolerance_px``) is an artefact of
    carving at a finite resolution: no view sees through it (the 31 handles of an open
    cylinder's hull, whose zero-thickness wall the 1.5 px grid cuts where the wall is thinner
    than a node). A true hole (a torus's) is seen through by some view, so the field in it is
    far below zero and it stays open.

    A node is a tunnel's (or a narrow crevice's) when it is bridged: along one of the 13
    lattice directions, occupied nodes lie on both sides of it within ``radius_px`` pixels
    (the union of the binary closings with a line segment in each direction, scipy's
    ``binary_closing``). Unlike a closing with a ball, the lines fill a hole in a wall one
    node thick (the ball's dilation does not reach the nodes beside a thin wall, so its
    erosion opens the hole again: the open cylinder keeps genus 26 of 31 with a ball of 6
    pixels; 2 with lines of 4 pixels, measured). The outside of a convex or flat surface and
    a concave corner are not bridged; a concave crevice narrower than ``2 radius_px`` is
    filled by at most ``tolerance_px`` pixels.

    Parameters
    ----------
    grid : HullGrid
        From :func:`carve_hull`.
    radius_px : float
        Reach of the bridging lines on either side of a node (pixels; at least one node).
    tolerance_px : float
        How far outside a silhouette (pixels) a filled node may project.

    Returns
    -------
    ClosedHandles
    """
    from scipy.ndimage import binary_closing

    occ = grid.field > 0
    k = max(1, int(round(radius_px * grid.pixel_size / grid.voxel_size)))
    pad = np.pad(occ, k + 1)
    inner = (slice(k + 1, -k - 1),) * 3
    bridged = np.zeros_like(occ)
    t = np.arange(-k, k + 1)
    for d in _DIRECTIONS:  # 13 lattice directions (each one vectorised closing)
        line = np.zeros((2 * k + 1,) * 3, dtype=bool)
        line[tuple(k + t * c for c in d)] = True
        bridged |= binary_closing(pad, structure=line)[inner]
    filled = bridged & ~occ & (grid.field > -float(tolerance_px))
    field = grid.field.copy()
    field[filled] = 0.5  # half a pixel inside: marching cubes puts the surface past the node
    return ClosedHandles(HullGrid(field, grid.origin, grid.voxel_size, grid.pixel_size,
                                  grid.n_closed_pixels, grid.n_vote_kept),
                         int(filled.sum()), filled)


#: The 13 lattice directions of a 3 x 3 x 3 neighbourhood, one of each +-pair.
_DIRECTIONS = ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, -1, 0), (1, 0, 1), (1, 0, -1),
               (0, 1, 1), (0, 1, -1), (1, 1, 1), (1, 1, -1), (1, -1, 1), (1, -1, -1))
