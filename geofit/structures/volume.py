"""A voxel grid of densities and features placed in the world as PyTorch3D's ``Volumes``.

The grid is ``densities (D, H, W)`` plus optional ``features (C, D, H, W)``. Local coordinates
span [-1, 1] along each axis with x -> W (last axis), y -> H and z -> D, and

    world = local * 0.5 * (size_xyz - 1) * voxel_size - volume_translation

exactly as ``pytorch3d.structures.Volumes`` (``_voxel_size_translation_to_transform``), whatever
``align_corners`` says; ``align_corners`` only changes where the voxel centres sit in local
coordinates (the ends of [-1, 1] when True, half a voxel inside when False) and how
:func:`trilinear_matrix` samples, as ``torch.nn.functional.grid_sample``.

Sampling is linear in the voxel values, so it is a sparse matrix: :func:`trilinear_matrix`
returns ``M (k, D*H*W)`` with ``values_at_points = M @ grid.ravel()``; its transpose carries a
gradient on the samples back to the voxels. Which voxels a point reads (the floor of its
coordinates) is piecewise constant: no gradient flows with respect to the point positions here.

:func:`visual_hull` (space carving of a grid by silhouettes, :func:`carve` for any points) is
geofit's one visual hull: :func:`geofit.fit.volume.fit_volume` and
:meth:`geofit.render.OccupancyGrid.from_silhouettes` both use it.
"""
from __future__ import annotations

import math
import numbers
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy import ndimage

from .._threads import get_num_threads, parallel_map
from .._validate import as_array, check_choice, check_positive

__all__ = ["Volume", "VolumeSamples", "carve", "silhouette_distances", "trilinear_matrix",
           "visual_hull", "voxel_footprint"]

#: Corner offsets (dz, dy, dx) of a trilinear cell, in increasing flat-index order.
_CORNERS = np.array([(dz, dy, dx) for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)],
                    dtype=np.int64)


class VolumeSamples(NamedTuple):
    """Values of a :class:`Volume` at points.

    Attributes
    ----------
    densities : (k,) float64
        Interpolated density at each point (0 outside the grid: zero padding).
    features : (k, C) float64 or None
        Interpolated features, or None when the volume has none.
    """

    densities: np.ndarray
    features: np.ndarray | None


def _grid_size(grid_size, name: str = "grid_size") -> tuple[int, int, int]:
    a = as_array(grid_size, name, (3,), np.int64)
    if np.any(a < 2):
        raise ValueError(f"{name}: expected every size (D, H, W) >= 2, got {tuple(int(v) for v in a)}")
    return int(a[0]), int(a[1]), int(a[2])


def _pixel_coords(local: np.ndarray, grid_size, align_corners: bool) -> np.ndarray:
    """grid_sample's unnormalisation: local [-1, 1] xyz -> continuous voxel indices (x, y, z)."""
    size_xyz = np.array(grid_size[::-1], dtype=np.float64)
    if align_corners:
        return (local + 1.0) * (0.5 * (size_xyz - 1.0))
    return ((local + 1.0) * size_xyz - 1.0) * 0.5


def _trilinear_corners(local: np.ndarray, grid_size, align_corners: bool):
    """Flat voxel indices ``(k, 8)`` int64, weights ``(k, 8)`` float64 and validity ``(k, 8)``.

    Corners outside the grid are invalid (zero padding); their index is clipped into range so it
    can be used for gathering, and the caller drops them.
    """
    D, H, W = grid_size
    pix = _pixel_coords(local, grid_size, align_corners)
    size_xyz = np.array([W, H, D], dtype=np.float64)
    # Points beyond one voxel outside read nothing; clipping keeps the integer casts bounded.
    pix = np.clip(pix, -1.0, size_xyz)
    base = np.floor(pix)
    frac = pix - base
    base = base.astype(np.int64)
    # per corner: index along x, y, z and the 1-D weights
    ix = base[:, 0, None] + _CORNERS[None, :, 2]
    iy = base[:, 1, None] + _CORNERS[None, :, 1]
    iz = base[:, 2, None] + _CORNERS[None, :, 0]
    wx = np.where(_CORNERS[None, :, 2] == 1, frac[:, 0, None], 1.0 - frac[:, 0, None])
    wy = np.where(_CORNERS[None, :, 1] == 1, frac[:, 1, None], 1.0 - frac[:, 1, None])
    wz = np.where(_CORNERS[None, :, 0] == 1, frac[:, 2, None], 1.0 - frac[:, 2, None])
    weights = wx * wy * wz
    valid = ((ix >= 0) & (ix < W) & (iy >= 0) & (iy < H) & (iz >= 0) & (iz < D)
             & (weights != 0.0))
    flat = (np.clip(iz, 0, D - 1) * H + np.clip(iy, 0, H - 1)) * W + np.clip(ix, 0, W - 1)
    return flat, weights, valid


def _nearest_corner(local: np.ndarray, grid_size, align_corners: bool):
    """grid_sample's "nearest" (round half to even): flat index (k, 1), weight 1, validity."""
    D, H, W = grid_size
    size_xyz = np.array([W, H, D], dtype=np.float64)
    pix = np.clip(_pixel_coords(local, grid_size, align_corners), -1.0, size_xyz)
    r = np.rint(pix).astype(np.int64)
    valid = np.all((r >= 0) & (r < np.array([W, H, D])), axis=1)
    rc = np.clip(r, 0, np.array([W, H, D]) - 1)
    flat = (rc[:, 2] * H + rc[:, 1]) * W + rc[:, 0]
    return flat[:, None], np.ones((len(local), 1)), valid[:, None]


def _sparse_rows(flat, weights, valid, n_cols: int, columns_lookup=None,
                 dtype=np.float64) -> sp.csr_matrix:
    """CSR matrix with one row per point from per-corner indices, weights and validity."""
    if columns_lookup is not None:
        col = columns_lookup[flat]
        valid = valid & (col >= 0)
        flat = col
    counts = valid.sum(axis=1)
    indptr = np.zeros(len(flat) + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    idx_dtype = np.int32 if max(n_cols, int(indptr[-1])) < 2**31 - 1 else np.int64
    indices = flat[valid].astype(idx_dtype)
    data = weights[valid].astype(dtype)
    return sp.csr_matrix((data, indices, indptr.astype(idx_dtype)),
                         shape=(len(flat), n_cols))


def trilinear_matrix(local_points, grid_size, *, align_corners: bool = True,
                     mode: str = "bilinear", columns=None, dtype=np.float64) -> sp.csr_matrix:
    """The sparse sampling operator of a voxel grid (``grid_sample`` with zero padding).

    Parameters
    ----------
    local_points : (k, 3) float64
        Points in the grid's local coordinates (x -> W, y -> H, z -> D, [-1, 1] spans the grid).
    grid_size : (3,) int
        ``(D, H, W)``, each at least 2.
    align_corners : bool
        As in ``torch.nn.functional.grid_sample``: True puts the first and last voxel centres at
        -1 and +1 (PyTorch3D's ``Volumes`` default).
    mode : {"bilinear", "nearest"}
        Trilinear interpolation of the 8 surrounding voxels (PyTorch3D calls it "bilinear"), or
        the nearest voxel (rounding half to even, as torch).
    columns : (n,) int64, optional
        Sorted flat voxel indices (``d * H * W + h * W + w``) to keep as the columns of the
        matrix, in that order; entries for other voxels are dropped (they are treated as fixed
        zeros). Default: all ``D * H * W`` voxels.
    dtype : numpy dtype
        dtype of the matrix entries (float64 by default; float32 halves the memory).

    Returns
    -------
    M : (k, n) scipy.sparse.csr_matrix
        ``M[i, j]`` is the weight of voxel ``columns[j]`` (or flat voxel ``j``) at point ``i``;
        rows of points outside the grid are empty (zero padding), and a point within one voxel
        of the border keeps only its in-grid corners, as ``grid_sample(padding_mode="zeros")``.
        ``M @ grid.reshape(-1)`` samples a ``(D, H, W)`` grid and ``M.T @ g`` is the gradient
        of ``<g, M @ grid>`` with respect to the grid.

    Examples
    --------
    >>> M = trilinear_matrix([[0.0, 0.0, 0.0]], (2, 2, 2))
    >>> M.toarray().round(3)
    array([[0.125, 0.125, 0.125, 0.125, 0.125, 0.125, 0.125, 0.125]])
    """
    P = as_array(local_points, "local_points", (None, 3))
    size = _grid_size(grid_size)
    check_choice(mode, "mode", ("bilinear", "nearest"))
    n_vox = size[0] * size[1] * size[2]
    lookup = None
    n_cols = n_vox
    if columns is not None:
        cols = as_array(columns, "columns", (None,), np.int64)
        if cols.size and (cols.min() < 0 or cols.max() >= n_vox):
            raise ValueError(f"columns: expected flat voxel indices in [0, {n_vox - 1}], got "
                             f"range [{int(cols.min())}, {int(cols.max())}]")
        if cols.size > 1 and np.any(np.diff(cols) <= 0):
            raise ValueError("columns: expected strictly increasing flat voxel indices")
        lookup = np.full(n_vox, -1, dtype=np.int64)
        lookup[cols] = np.arange(cols.size)
        n_cols = cols.size
    corners = _trilinear_corners if mode == "bilinear" else _nearest_corner
    return _sparse_rows(*corners(P, size, bool(align_corners)), n_cols, lookup, dtype)


def voxel_footprint(local_points, grid_size, *, align_corners: bool = True) -> np.ndarray:
    """Flat index of the lowest corner of the trilinear cell of each point, -1 outside the grid.

    Parameters
    ----------
    local_points : (k, 3) float64
        Points in local coordinates.
    grid_size : (3,) int
        ``(D, H, W)``.
    align_corners : bool
        As in :func:`trilinear_matrix`.

    Returns
    -------
    cell : (k,) int64
        ``d * H * W + h * W + w`` of the cell corner ``(floor z, floor y, floor x)`` when the
        point reads at least one voxel inside the grid (the floor may be -1 for points within one
        voxel below the grid: those use index -1 too, so test with the grid dilated by one).
    """
    P = as_array(local_points, "local_points", (None, 3))
    D, H, W = _grid_size(grid_size)
    pix = _pixel_coords(P, (D, H, W), bool(align_corners))
    base = np.floor(np.clip(pix, -1.0, np.array([W, H, D], dtype=np.float64))).astype(np.int64)
    inside = np.all((base >= 0) & (base < np.array([W, H, D])), axis=1)
    out = np.full(len(P), -1, dtype=np.int64)
    b = base[inside]
    out[inside] = (b[:, 2] * H + b[:, 1]) * W + b[:, 0]
    return out


class Volume:
    """A voxel grid of densities and optional features placed in the world.

    Parameters
    ----------
    densities : (D, H, W) float64
        Density of each voxel (PyTorch3D's EA raymarcher reads them as per-sample opacities in
        [0, 1]). Axis order as PyTorch3D: depth (z), height (y), width (x).
    features : (C, D, H, W) float64, optional
        Per-voxel features (RGB colours for the tutorial).
    voxel_size : float or (3,) float64
        Voxel edge length(s) in world units, per (x, y, z) (PyTorch3D's order). Must be > 0.
    volume_translation : (3,) float64
        ``world = local * 0.5 * (size - 1) * voxel_size - volume_translation``.
    align_corners : bool
        PyTorch3D's flag (True by default): where voxel centres sit in local coordinates and how
        the grid is sampled.

    Attributes
    ----------
    densities : (D, H, W) float64, read-only
    features : (C, D, H, W) float64 or None, read-only
    voxel_size : (3,) float64
        Per (x, y, z).
    volume_translation : (3,) float64
    align_corners : bool

    Examples
    --------
    >>> v = Volume(np.zeros((4, 4, 4)), voxel_size=0.5)
    >>> v.local_to_world([[1.0, 1.0, 1.0]])
    array([[0.75, 0.75, 0.75]])
    """

    def __init__(self, densities, features=None, voxel_size=1.0,
                 volume_translation=(0.0, 0.0, 0.0), align_corners: bool = True):
        d = as_array(densities, "densities", (None, None, None))
        _grid_size(d.shape, "densities")
        self.densities = d
        self.features = None
        if features is not None:
            self.features = as_array(features, "features", (None,) + d.shape)
            if self.features.shape[0] == 0:
                raise ValueError("features: expected at least one channel, got shape "
                                 f"{self.features.shape}")
        vs = as_array(voxel_size, "voxel_size")
        if vs.ndim == 0 or vs.shape == (1,):
            vs = np.full(3, float(vs.reshape(-1)[0]))
        if vs.shape != (3,):
            raise ValueError(f"voxel_size: expected a scalar or shape (3,), got {vs.shape}")
        if np.any(vs <= 0):
            raise ValueError(f"voxel_size: expected positive sizes, got {vs.tolist()}")
        self.voxel_size = vs
        self.volume_translation = as_array(volume_translation, "volume_translation", (3,))
        if not isinstance(align_corners, (bool, np.bool_)):
            raise TypeError(f"align_corners: expected True or False, got {align_corners!r}")
        self.align_corners = bool(align_corners)
        for a in (self.densities, self.features, self.voxel_size, self.volume_translation):
            if a is not None:
                a.setflags(write=False)

    # ---- sizes ---------------------------------------------------------------------------

    @property
    def grid_size(self) -> tuple[int, int, int]:
        """``(D, H, W)``."""
        return tuple(int(s) for s in self.densities.shape)

    @property
    def n_voxels(self) -> int:
        return int(self.densities.size)

    @property
    def n_features(self) -> int:
        """Number of feature channels C (0 without features)."""
        return 0 if self.features is None else int(self.features.shape[0])

    def __repr__(self) -> str:
        D, H, W = self.grid_size
        return (f"Volume(grid_size=({D}, {H}, {W}), features={self.n_features}, "
                f"voxel_size={self.voxel_size.tolist()}, "
                f"volume_translation={self.volume_translation.tolist()})")

    # ---- coordinates ---------------------------------------------------------------------

    @property
    def _scale(self) -> np.ndarray:
        size_xyz = np.array(self.grid_size[::-1], dtype=np.float64)
        return 0.5 * (size_xyz - 1.0) * self.voxel_size

    def local_to_world(self, points) -> np.ndarray:
        """Local coordinates to world.

        Parameters
        ----------
        points : (k, 3) float64
            Local xyz.

        Returns
        -------
        world : (k, 3) float64
            ``points * 0.5 * (size - 1) * voxel_size - volume_translation``.
        """
        P = as_array(points, "points", (None, 3))
        return P * self._scale - self.volume_translation

    def world_to_local(self, points) -> np.ndarray:
        """World coordinates to local (the inverse of :meth:`local_to_world`).

        Parameters
        ----------
        points : (k, 3) float64

        Returns
        -------
        local : (k, 3) float64
        """
        P = as_array(points, "points", (None, 3))
        return (P + self.volume_translation) / self._scale

    def get_coord_grid(self, world_coordinates: bool = True) -> np.ndarray:
        """Coordinates of every voxel centre.

        Parameters
        ----------
        world_coordinates : bool
            World (default) or local coordinates.

        Returns
        -------
        grid : (D, H, W, 3) float64
            ``grid[d, h, w]`` is the (x, y, z) of voxel ``(d, h, w)``.
        """
        D, H, W = self.grid_size
        adj = (lambda r: 0.0) if self.align_corners else (lambda r: 1.0 / r)
        z, y, x = (np.linspace(-1.0 + adj(r), 1.0 - adj(r), r) for r in (D, H, W))
        grid = np.empty((D, H, W, 3))
        grid[..., 0] = x[None, None, :]
        grid[..., 1] = y[None, :, None]
        grid[..., 2] = z[:, None, None]
        if world_coordinates:
            grid = grid * self._scale - self.volume_translation
        return grid

    def bounds(self) -> np.ndarray:
        """World axis-aligned box of the region the grid can be sampled in.

        Returns
        -------
        box : (2, 3) float64
            Min and max corner of the points whose trilinear sample can be non-zero: one voxel
            beyond the outer voxel centres (zero padding fades out over that voxel).
        """
        corners = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
        if not self.align_corners:
            size_xyz = np.array(self.grid_size[::-1], dtype=np.float64)
            corners = corners * (1.0 - 1.0 / size_xyz)
        w = corners * self._scale - self.volume_translation
        return np.stack([w[0] - self.voxel_size, w[1] + self.voxel_size])

    # ---- sampling ------------------------------------------------------------------------

    def sampling_matrix(self, points, *, mode: str = "bilinear", columns=None,
                        dtype=np.float64) -> sp.csr_matrix:
        """The sparse operator from voxels to world points (see :func:`trilinear_matrix`).

        Parameters
        ----------
        points : (k, 3) float64
            World points.
        mode : {"bilinear", "nearest"}
        columns : (n,) int64, optional
            Sorted flat voxel indices to keep as columns.
        dtype : numpy dtype

        Returns
        -------
        M : (k, n) scipy.sparse.csr_matrix
            ``M @ densities.ravel()`` are the densities at the points.
        """
        return trilinear_matrix(self.world_to_local(points), self.grid_size,
                                align_corners=self.align_corners, mode=mode, columns=columns,
                                dtype=dtype)

    def sample(self, points, *, mode: str = "bilinear") -> VolumeSamples:
        """Densities and features at world points (zero outside the grid).

        Parameters
        ----------
        points : (k, 3) float64
            World points.
        mode : {"bilinear", "nearest"}

        Returns
        -------
        VolumeSamples
            ``densities (k,)`` and ``features (k, C)`` (None without features).
        """
        M = self.sampling_matrix(points, mode=mode)
        dens = M @ self.densities.reshape(-1)
        feats = None
        if self.features is not None:
            feats = M @ self.features.reshape(self.n_features, -1).T
        return VolumeSamples(dens, feats)

    def update(self, densities=None, features=None) -> Volume:
        """A new volume with the same placement and new values (None keeps the current ones)."""
        return Volume(self.densities if densities is None else densities,
                      self.features if features is None else features,
                      self.voxel_size, self.volume_translation, self.align_corners)


# --------------------------------------------------------------------------------------------
# Visual hull (the one of geofit: fit_volume and OccupancyGrid.from_silhouettes use it)
# --------------------------------------------------------------------------------------------


def _check_cameras(cameras, n: int):
    # duck-typed: the structures layer does not import geofit.cameras
    if not callable(getattr(cameras, "get_full_projection_transform", None)):
        raise TypeError(f"cameras: expected a geofit cameras batch, got {type(cameras)!r}")
    if len(cameras) != n:
        raise ValueError(f"cameras: expected {n} cameras (one per image), got {len(cameras)}")
    return cameras


def _grid_size3(volume_size) -> tuple[int, int, int]:
    if isinstance(volume_size, (numbers.Integral, np.integer)) and not isinstance(volume_size,
                                                                                   bool):
        volume_size = (int(volume_size),) * 3
    a = as_array(volume_size, "volume_size", (3,), np.int64)
    if np.any(a < 2):
        raise ValueError(f"volume_size: expected sizes >= 2, got {a.tolist()}")
    return int(a[0]), int(a[1]), int(a[2])


def visual_hull(silhouettes, cameras, volume_size, voxel_size: float, *,
                volume_translation=(0.0, 0.0, 0.0), threshold: float = 0.5,
                tolerance: int = 0, margin: float = 0.0) -> np.ndarray:
    """Voxels of a grid that can be occupied given the silhouettes (space carving).

    A voxel is kept unless more than ``tolerance`` views rule it out. A view rules a voxel out
    when the voxel's trilinear footprint (the ball of radius ``sqrt(3) * voxel_size`` around its
    centre, which contains every point whose sample reads it) projects entirely outside the
    silhouette: the distance in pixels from the projected centre to the nearest silhouette pixel
    exceeds the ball's projected radius plus half a pixel diagonal plus ``margin``. The object is
    assumed to be inside every image (as in the tutorials): a voxel whose centre projects outside
    the image, or lies behind the camera, is ruled out too (no view could show what it holds).

    Parameters
    ----------
    silhouettes : (N, H, W) float64
        Silhouettes in [0, 1]; pixels above ``threshold`` are inside.
    cameras : geofit.cameras.CamerasBase
        The ``N`` cameras.
    volume_size : int or (3,) int
        Grid size ``(D, H, W)`` (an int means a cube).
    voxel_size : float
        Voxel edge length (world units); the grid is placed as a
        :class:`~geofit.structures.volume.Volume` with ``align_corners=True``.
    volume_translation : (3,) float64
        As in :class:`~geofit.structures.volume.Volume`.
    threshold : float
        Silhouette threshold in [0, 1).
    tolerance : int
        Number of views allowed to rule a voxel out before it is carved (robustness to a bad
        view); 0 is the classical hull.
    margin : float
        Extra dilation of every silhouette, in pixels (>= 0).

    Returns
    -------
    hull : (D, H, W) bool
        True for voxels that may be occupied.

    Examples
    --------
    Two views (front and side) of a centred disc carve a cylinder-like hull out of a 16^3 grid:

    >>> from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
    >>> R, T = look_at_view_transform(2.7, 0.0, [0.0, 90.0])
    >>> yy, xx = np.mgrid[:32, :32]
    >>> disc = ((xx - 15.5) ** 2 + (yy - 15.5) ** 2 < 8 ** 2).astype(float)
    >>> from geofit.structures.volume import visual_hull
    >>> hull = visual_hull(np.stack([disc, disc]), FoVPerspectiveCameras(R=R, T=T), 16, 0.15)
    >>> hull.shape, bool(hull[8, 8, 8]), bool(hull[0, 0, 0]), int(hull.sum()) < 16 ** 3
    ((16, 16, 16), True, False, True)
    """
    sil = as_array(silhouettes, "silhouettes", (None, None, None))
    N = sil.shape[0]
    if N == 0:
        raise ValueError(f"silhouettes: expected at least one view, got shape {sil.shape}")
    cameras = _check_cameras(cameras, N)
    size = _grid_size3(volume_size)
    vs = check_positive(voxel_size, "voxel_size")
    thr = float(threshold)
    if not 0.0 <= thr < 1.0:
        raise ValueError(f"threshold: expected a number in [0, 1), got {threshold!r}")
    if not isinstance(tolerance, (numbers.Integral, np.integer)) or tolerance < 0:
        raise ValueError(f"tolerance: expected an integer >= 0, got {tolerance!r}")
    margin = check_positive(margin, "margin", strict=False)
    vol = Volume(np.zeros(size), voxel_size=vs, volume_translation=volume_translation)
    centres = vol.get_coord_grid().reshape(-1, 3)
    return carve(silhouette_distances(sil > thr), cameras, centres, math.sqrt(3.0) * vs,
                 int(tolerance), margin).reshape(size)


def silhouette_distances(inside: np.ndarray) -> np.ndarray:
    """(N, H, W) distance in pixels from each pixel centre to the nearest inside pixel."""
    N, H, W = inside.shape
    out = np.empty((N, H, W))
    for i in range(N):  # views
        out[i] = ndimage.distance_transform_edt(~inside[i]) if inside[i].any() else np.inf
    return out


def carve(dist: np.ndarray, cameras, centres: np.ndarray, radius: float, tolerance: int,
          margin: float, candidates: np.ndarray | None = None, *,
          slack: float = 0.71) -> np.ndarray:
    """Boolean (k,) keep-mask of balls (``centres``, ``radius``) against silhouettes.

    ``dist`` holds, per view, the distance from each pixel to the silhouette
    (:func:`silhouette_distances`). A view rules a ball out when the distance at the pixel of
    its projected centre exceeds its projected radius plus ``slack`` (half a pixel diagonal:
    the ball may cover the pixel's corner) plus ``margin``; a ball is carved once more than
    ``tolerance`` views rule it out. The projected radius uses
    ``|J|_F <= (|M[:3, :2]|_F + |xy| |M[:3, 3]|) / |w|`` for the Jacobian of the projection
    ``[p, 1] @ M`` (an upper bound, so carving stays conservative). With ``radius = slack =
    margin = 0`` a point is kept when its centre's pixel is inside every silhouette.
    """
    N, H, W = dist.shape
    s = min(H, W) / 2.0
    alive = np.ones(len(centres), bool) if candidates is None else candidates.copy()
    Ms = cameras.get_full_projection_transform()
    Rz, Tz = cameras.R[:, :, 2], cameras.T[:, 2]
    a_all = [np.linalg.norm(M[:3, :2]) for M in Ms]  # views
    b_all = [np.linalg.norm(M[:3, 3]) for M in Ms]   # views

    def carve_part(cand):  # each ball on its own: parts of the candidates run on the pool
        votes = np.zeros(len(cand), dtype=np.int64)
        keep = np.ones(len(cand), bool)
        for i in range(N):  # views
            idx = np.flatnonzero(keep)
            if idx.size == 0:
                break
            M = Ms[i]
            P = centres[cand[idx]]
            h = P @ M[:3, :] + M[3]
            w = h[:, 3]
            depth = P @ Rz[i] + Tz[i]
            ok = (depth > 0) & (w != 0)
            wsafe = np.where(ok, w, 1.0)
            xy = h[:, :2] / wsafe[:, None]
            r_px = (s * radius * (a_all[i] + np.linalg.norm(xy, axis=1) * b_all[i])
                    / np.abs(wsafe) + slack + margin)
            ix = np.rint(W / 2.0 - s * xy[:, 0] - 0.5)
            iy = np.rint(H / 2.0 - s * xy[:, 1] - 0.5)
            seen = ok & (ix >= 0) & (ix < W) & (iy >= 0) & (iy < H)
            sidx = np.flatnonzero(seen)
            out = ~seen   # behind the camera or outside the image: outside the silhouette
            out[sidx] = dist[i, iy[sidx].astype(np.int64), ix[sidx].astype(np.int64)] > \
                r_px[sidx]
            votes[idx[out]] += 1
            keep[idx[votes[idx] > tolerance]] = False
        return keep

    cand = np.flatnonzero(alive)
    parts = np.array_split(cand, max(1, min(2 * get_num_threads(), len(cand) // 4096)))
    for part, keep in zip(parts, parallel_map(carve_part, parts)):  # parts of the candidates
        alive[part] = keep
    return alive
