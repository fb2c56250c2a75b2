"""The soft rasterizer: PyTorch3D's CPU mesh rasterizer with a blur radius and K faces.

:func:`rasterize_soft` finds, for every pixel, the ``K`` faces nearest in view depth among
those whose projected triangle contains the pixel centre or lies within
``sqrt(blur_radius)`` of it (PyTorch3D's ``rasterize_meshes_cpu.cpp``), without a dense
pixels-by-faces array: (face, pixel) candidate pairs from the faces' NDC bounding boxes,
in chunks of at most ``max_pairs``, tested exactly, sorted per pixel by depth (then face
index) and cut at ``K``. See :mod:`geofit.render.soft` for what is differentiable.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..._memory import check_allocation
from ..._validate import as_instance, check_positive
from ...cameras import CamerasBase
from ...structures import Mesh, as_mesh
from .._settings import float_dtype, image_hw
from .fragments import _EPS, SoftFragments, _EntryGeometry, _map_views, _n_threads, _ranks

__all__ = [
    "TUTORIAL_BLUR_RADIUS",
    "SoftRasterizationSettings",
    "rasterize_soft",
]

#: The tutorial's blur radius ``log(1 / 1e-4 - 1) * 1e-4``: the squared NDC distance at which
#: ``sigmoid(-d / sigma)`` falls to 1e-4 for ``sigma = 1e-4`` (about 2 px at 128 px).
TUTORIAL_BLUR_RADIUS = math.log(1.0 / 1e-4 - 1.0) * 1e-4


# ------------------------------------------------------------------------------------------
# Settings
# ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SoftRasterizationSettings:
    """Settings of the soft rasterizer (PyTorch3D's ``RasterizationSettings`` with blur).

    Parameters
    ----------
    image_size : int or (H, W)
        As :class:`geofit.render.RasterizationSettings` (square for an int).
    blur_radius : float
        Squared NDC distance: a face is kept for a pixel outside it when the squared distance
        from the pixel centre to the projected triangle is below this. 0 keeps only faces whose
        interior contains the pixel centre. The tutorial uses :data:`TUTORIAL_BLUR_RADIUS`.
    faces_per_pixel : int
        ``K``: at most this many faces per pixel, the nearest in view depth.
    perspective_correct : bool or None
        Perspective-correct barycentrics. None means True for perspective cameras (PyTorch3D).
    clip_barycentric_coords : bool or None
        Clamp negative barycentrics to 0 and renormalise (affects ``bary_coords`` and ``zbuf``).
        None means ``blur_radius > 0`` (PyTorch3D).
    cull_backfaces : bool
        Skip faces whose projected winding is clockwise (negative signed area).
    z_clip_value : float or None
        Faces with a vertex at view depth below this are dropped. None means ``znear / 2`` when
        perspective-correct, else none (every face with all depths >= 1e-8 is used), as
        PyTorch3D's default, except that PyTorch3D clips crossing faces instead of dropping them.
    max_pairs : int
        Largest number of (face, pixel) candidate pairs tested at once per thread; bounds the
        memory (about 0.2 kB per pair in flight).
    n_threads : int or None
        Threads over views (default: :func:`geofit.get_num_threads`).
    dtype : numpy.float32 or numpy.float64
        Storage type of the per-entry arrays (distances, barycentrics, depths, the blend's and
        the shading's saved values) and of the images (default float32, as PyTorch3D; a 20-view
        Phong render at 128 px of 3 million entries then keeps about half the memory).
        Geometry and gradients are computed in float64 either way; float64 storage keeps the
        render exact to float64 (finite-difference tests, line searches that need it).

    Examples
    --------
    >>> s = SoftRasterizationSettings.tutorial(64)
    >>> s.image_size, s.faces_per_pixel, round(s.blur_radius, 7)
    ((64, 64), 50, 0.000921)
    """

    image_size: Any = 256
    blur_radius: float = 0.0
    faces_per_pixel: int = 1
    perspective_correct: bool | None = None
    clip_barycentric_coords: bool | None = None
    cull_backfaces: bool = False
    z_clip_value: float | None = None
    max_pairs: int = 250_000
    n_threads: int | None = None
    dtype: Any = np.float32

    def __post_init__(self):
        object.__setattr__(self, "image_size", image_hw(self.image_size))
        object.__setattr__(self, "blur_radius",
                           check_positive(self.blur_radius, "blur_radius", strict=False))
        k = self.faces_per_pixel
        if not isinstance(k, (int, np.integer)) or isinstance(k, (bool, np.bool_)) or k < 1:
            raise ValueError(f"faces_per_pixel: expected an integer >= 1, got {k!r}")
        H, W = self.image_size  # the rasterizer's own estimate, per view, at construction
        check_allocation(H * W * (24 * k + 1024), "image_size and faces_per_pixel",
                         f"soft fragments of 1 view(s) at {(H, W)} with K={k}")
        for name in ("perspective_correct", "clip_barycentric_coords"):
            v = getattr(self, name)
            if v is not None and not isinstance(v, (bool, np.bool_)):
                raise ValueError(f"{name}: expected None, True or False, got {v!r}")
        if not isinstance(self.cull_backfaces, (bool, np.bool_)):
            raise ValueError(  # noqa: TRY004 - a bad setting value, as RasterizationSettings
                f"cull_backfaces: expected True or False, got {self.cull_backfaces!r}")
        if self.z_clip_value is not None:
            object.__setattr__(self, "z_clip_value",
                               check_positive(self.z_clip_value, "z_clip_value", strict=False))
        m = self.max_pairs
        if not isinstance(m, (int, np.integer)) or isinstance(m, (bool, np.bool_)) or m < 1:
            raise ValueError(f"max_pairs: expected an integer >= 1, got {m!r}")
        t = self.n_threads
        if t is not None and (not isinstance(t, (int, np.integer)) or isinstance(t, bool)
                              or t < 1):
            raise ValueError(f"n_threads: expected None or an integer >= 1, got {t!r}")
        object.__setattr__(self, "dtype", float_dtype(self.dtype))

    @classmethod
    def tutorial(cls, image_size=128, **kwargs) -> SoftRasterizationSettings:
        """The fit_textured_mesh tutorial's soft settings: blur 9.21e-4, 50 faces per pixel."""
        kwargs.setdefault("blur_radius", TUTORIAL_BLUR_RADIUS)
        kwargs.setdefault("faces_per_pixel", 50)
        return cls(image_size=image_size, **kwargs)


# ------------------------------------------------------------------------------------------
# Rasterizer
# ------------------------------------------------------------------------------------------


def _check_mesh(mesh) -> Mesh:
    return as_mesh(mesh, "mesh")  # a geofit, trimesh or Open3D mesh


def _check_cameras(cameras) -> CamerasBase:
    if not isinstance(cameras, CamerasBase):
        raise TypeError(f"cameras: expected a geofit camera batch, got {type(cameras)!r}")
    return cameras


def _check_settings(settings) -> SoftRasterizationSettings:
    return as_instance(settings, SoftRasterizationSettings, "raster_settings")


def _pixel_centres(H: int, W: int):
    S = min(H, W)
    px = (W - 1 - 2 * np.arange(W, dtype=np.float64)) / S
    py = (H - 1 - 2 * np.arange(H, dtype=np.float64)) / S
    return px, py


def _seg_sqdist(rx, ry, dx, dy, inv_l2, degenerate):
    """Squared distance from q to segment a + t d (PyTorch3D's PointLineDistanceForward).

    ``r = q - a``; ``inv_l2 = 1 / |d|^2`` (0 for a degenerate segment) and ``degenerate``
    (0/1, or None when no segment is degenerate): a degenerate segment (``|d|^2 <= 1e-8``)
    gives the distance to its second end ``a + d`` (t = 1). Written in place (the same
    operations in the same order as ``clip((r.d) inv_l2 + degenerate, 0, 1)``,
    ``|r - t d|^2``).
    """
    t = rx * dx
    t += ry * dy
    t *= inv_l2
    if degenerate is not None:
        t += degenerate
    np.clip(t, 0.0, 1.0, out=t)
    dx = dx * t
    dy = dy * t
    np.subtract(rx, dx, out=dx)  # ex
    np.subtract(ry, dy, out=dy)  # ey
    dx *= dx
    dy *= dy
    dx += dy
    return dx


_TEMP_FLOATS_PER_PAIR = 24  # float64 temporaries alive per candidate pair (rough count)
_CHUNKS_PER_THREAD = 4  # chunks of candidate pairs per thread and call (load balance)


@dataclass
class _ViewJob:
    """One view's rasterization, split so that chunks of its candidate pairs can run on
    different threads: ``run(start, stop)`` tests the pairs of faces ``start:stop`` (positions
    in the view's kept faces; any split gives the same entries, in the same order, as one
    pass), ``finish(parts)`` concatenates the chunks' entries in order and cuts them at K."""

    cum: np.ndarray  # cumulative candidate pairs over the kept faces
    stats: dict
    run: Any = None
    finish: Any = None

    def chunks(self, limit: int) -> list:
        """(start, stop) runs of faces of at most ``limit`` pairs (or one face)."""
        out, start, cum = [], 0, self.cum
        while start < len(cum):  # chunks of faces (bounded memory)
            base = int(cum[start - 1]) if start else 0
            stop = max(int(np.searchsorted(cum, base + limit, side="right")), start + 1)
            out.append((start, stop))
            start = stop
        return out


def _rasterize_view(x, y, z, faces, H, W, px, py, blur, K, perspective_correct, clip, cull,
                    zclip) -> _ViewJob:
    """One view's job (:class:`_ViewJob`): its ``finish`` gives the kept entries (face,
    pixel, signed dist, edge, inside) and the view's stats."""
    stats = {"candidates": 0, "peak_pairs": 0, "max_faces_per_pixel": 0, "truncated_pixels": 0}
    S = min(H, W)
    x0, x1, x2 = (np.ascontiguousarray(a) for a in x[faces].T)
    y0, y1, y2 = (np.ascontiguousarray(a) for a in y[faces].T)
    zf = z[faces]
    area = (x2 - x0) * (y1 - y0) - (y2 - y0) * (x1 - x0)  # EF(p2; p0, p1) = EF(p0; p1, p2)
    ok = (np.abs(area) > _EPS) & (np.abs(area + _EPS) > 1e-12)
    ok &= zf.min(1) >= max(zclip, _EPS)
    ok &= np.isfinite(x0 + x1 + x2 + y0 + y1 + y2)
    if cull:
        ok &= area >= 0.0
    fids = np.flatnonzero(ok)
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int8),
             np.zeros(0, bool))
    if fids.size == 0:
        return _ViewJob(np.zeros(0, np.int64), stats, finish=lambda parts: (empty, stats))
    r = math.sqrt(blur)
    X = np.stack([x0[fids], x1[fids], x2[fids]], 1)
    Y = np.stack([y0[fids], y1[fids], y2[fids]], 1)
    tol = 1e-9
    # column i sits at x = (W - 1 - 2 i) / S, row j at y = (H - 1 - 2 j) / S
    i_lo = np.maximum(np.ceil((W - 1 - (X.max(1) + r) * S) / 2 - tol), 0).astype(np.int64)
    i_hi = np.minimum(np.floor((W - 1 - (X.min(1) - r) * S) / 2 + tol), W - 1).astype(np.int64)
    j_lo = np.maximum(np.ceil((H - 1 - (Y.max(1) + r) * S) / 2 - tol), 0).astype(np.int64)
    j_hi = np.minimum(np.floor((H - 1 - (Y.min(1) - r) * S) / 2 + tol), H - 1).astype(np.int64)
    nx = np.maximum(i_hi - i_lo + 1, 0)
    ny = np.maximum(j_hi - j_lo + 1, 0)
    counts = nx * ny
    nz = counts > 0
    fids, i_lo, j_lo, nx, ny, counts = (fids[nz], i_lo[nz], j_lo[nz], nx[nz], ny[nz],
                                         counts[nz])
    if fids.size == 0:
        return _ViewJob(np.zeros(0, np.int64), stats, finish=lambda parts: (empty, stats))
    stats["candidates"] = int(counts.sum())
    # Per-face constants (indexed by position in fids). Edge lines scaled to signed distances,
    # positive inside: s_i = a_i qx + b_i qy + c_i, edge i opposite corner i.
    X0, X1, X2 = x0[fids], x1[fids], x2[fids]
    Y0, Y1, Y2 = y0[fids], y1[fids], y2[fids]
    sgn = np.sign(area[fids])
    lines = []
    for (xa, ya, xb, yb) in ((X1, Y1, X2, Y2), (X2, Y2, X0, Y0), (X0, Y0, X1, Y1)):
        a, b = yb - ya, -(xb - xa)
        inv = sgn / np.sqrt(a * a + b * b)
        lines.append((a * inv, b * inv, -(xa * a + ya * b) * inv))
    segs = []  # (ax, ay, dx, dy, inv_l2, degenerate) for edges (0,1), (0,2), (1,2)
    for (xa, ya, xb, yb) in ((X0, Y0, X1, Y1), (X0, Y0, X2, Y2), (X1, Y1, X2, Y2)):
        dx, dy = xb - xa, yb - ya
        l2 = dx * dx + dy * dy
        deg = (l2 <= _EPS).astype(np.float64)
        segs.append((xa, ya, dx, dy, np.where(deg > 0, 0.0, 1.0 / np.where(deg > 0, 1.0, l2)),
                     deg))
    degface = (segs[0][5] + segs[1][5] + segs[2][5]) > 0
    if not clip:
        Zc = zf[fids]
        if perspective_correct:
            zz = (Zc[:, 1] * Zc[:, 2], Zc[:, 0] * Zc[:, 2], Zc[:, 0] * Zc[:, 1])
        Aeps = area[fids] + _EPS
    cut = -r - 1e-12

    def run(start, stop):  # the pairs of faces start:stop
        cc = counts[start:stop]
        n_pairs = int(cc.sum())
        loc = np.repeat(np.arange(start, stop), cc)  # position in fids

        def rep(a, cc=cc, start=start, stop=stop):  # a[loc]: runs, no gather
            return np.repeat(a[start:stop], cc)

        # each face's pixel rectangle row by row (the same pairs in the same order as
        # divmod(offset in the rectangle, nx), without an integer division per pair)
        ny_c = ny[start:stop]
        face_row = np.repeat(np.arange(stop - start), ny_c)  # the face of each rectangle row
        j = np.arange(len(face_row), dtype=np.int64) - np.repeat(np.cumsum(ny_c) - ny_c, ny_c)
        j += j_lo[start:stop][face_row]
        n_row = nx[start:stop][face_row]
        row = np.repeat(j, n_row)
        col = np.arange(n_pairs, dtype=np.int64) - np.repeat(np.cumsum(n_row) - n_row, n_row)
        col += np.repeat(i_lo[start:stop][face_row], n_row)
        del face_row, j, n_row
        qx = px[col]
        qy = py[row]
        # stage 1: signed distances to the three edge lines; a pair whose pixel lies beyond
        # sqrt(blur) outside one of them is farther than sqrt(blur) from the triangle
        sl = [rep(a) * qx + rep(b) * qy + rep(c) for a, b, c in lines]
        s_min = np.minimum(np.minimum(sl[0], sl[1]), sl[2])
        live = np.flatnonzero(s_min > cut)
        row *= W
        row += col
        pix = row  # row * W + col
        del row, col
        loc, pix, qx, qy, s_min = (v[live] for v in (loc, pix, qx, qy, s_min))
        sl = [v[live] for v in sl]
        # stage 2: exact squared distance to the triangle (the nearest of the three segments,
        # PyTorch3D's order e01, e02, e12 on ties). Inside a triangle the nearest segment point
        # is the foot on the nearest edge line, so there it is (min_i s_i)^2 (faces with a
        # degenerate edge, whose distance PyTorch3D takes to an end point, excepted).
        inside = s_min > 0.0
        general = ~inside | degface[loc] if degface[start:stop].any() else ~inside
        gen = np.flatnonzero(general)
        fast = np.flatnonzero(~general)
        n_live = len(loc)
        dist = np.empty(n_live)
        edge = np.empty(n_live, np.int8)
        # edge e01 is line 2 (opposite corner 2), e02 line 1, e12 line 0
        d0, d1, d2 = sl[2][fast], sl[1][fast], sl[0][fast]
        use01 = (d0 <= d1) & (d0 <= d2)
        use02 = ~use01 & (d1 <= d2)
        dmin = np.where(use01, d0, np.where(use02, d1, d2))
        dist[fast] = dmin * dmin
        edge[fast] = np.where(use01, 0, np.where(use02, 1, 2))
        if gen.size:
            # loc[gen] is sorted (runs of faces): its per-face values by np.repeat
            g_cnt = np.bincount(loc[gen] - start, minlength=stop - start)

            def grun(a, g_cnt=g_cnt, start=start, stop=stop):  # a[loc[gen]]
                return np.repeat(a[start:stop], g_cnt)

            qxg, qyg = qx[gen], qy[gen]
            # r = q - a: edges (0, 1) and (0, 2) share their first end; the degenerate
            # term is skipped when no face of the chunk has a degenerate edge (adding 0)
            r0 = (qxg - grun(X0), qyg - grun(Y0))
            r1 = (qxg - grun(X1), qyg - grun(Y1))
            del qxg, qyg
            some = bool(degface[start:stop].any())
            d = [_seg_sqdist(*r, grun(dx), grun(dy), grun(il), grun(dg) if some else None)
                 for r, (_, _, dx, dy, il, dg) in zip((r0, r0, r1), segs)]
            del r0, r1
            use01 = (d[0] <= d[1]) & (d[0] <= d[2])
            use02 = ~use01 & (d[1] <= d[2])
            dist[gen] = np.where(use01, d[0], np.where(use02, d[1], d[2]))
            edge[gen] = np.where(use01, 0, np.where(use02, 1, 2))
        keep = inside | (dist < blur)
        if not clip:  # unclipped barycentrics can put an outside pixel behind the camera
            raw = [_edge_function(i, qx, qy, X0[loc], Y0[loc], X1[loc], Y1[loc], X2[loc],
                                  Y2[loc]) / Aeps[loc] for i in range(3)]
            if perspective_correct:
                top = [raw[i] * zz[i][loc] for i in range(3)]
                den = np.maximum(top[0] + top[1] + top[2], _EPS)
                raw = [t / den for t in top]
            pz = raw[0] * Zc[loc, 0] + raw[1] * Zc[loc, 1] + raw[2] * Zc[loc, 2]
            keep &= pz >= 0.0
        sel = np.flatnonzero(keep)
        return (fids[loc[sel]], pix[sel], np.where(inside[sel], -dist[sel], dist[sel]),
                edge[sel], inside[sel]), n_pairs

    def finish(parts):  # parts: (entries, pairs) of the chunks, in order
        stats["peak_pairs"] = max(n_pairs for _, n_pairs in parts)
        f, pix, sd, edge, inside = (np.concatenate(c) for c in zip(*(e for e, _ in parts)))
        n = len(f)
        if n:
            cnt = np.bincount(pix, minlength=H * W)
            stats["max_faces_per_pixel"] = int(cnt.max())
            over = cnt > K
            stats["truncated_pixels"] = int(np.count_nonzero(over))
            if stats["truncated_pixels"]:
                f, pix, sd, edge, inside = _truncate(f, pix, sd, edge, inside, over[pix], x, y,
                                                     z, faces, px, py, W, K,
                                                     perspective_correct, clip)
        return (f, pix, sd, edge, inside), stats

    return _ViewJob(np.cumsum(counts), stats, run, finish)


def _edge_function(i, qx, qy, x0, y0, x1, y1, x2, y2):
    """PyTorch3D's e_i: EF(q; p1, p2), EF(q; p2, p0) or EF(q; p0, p1)."""
    if i == 0:
        return (qx - x1) * (y2 - y1) - (qy - y1) * (x2 - x1)
    if i == 1:
        return (qx - x2) * (y0 - y2) - (qy - y2) * (x0 - x2)
    return (qx - x0) * (y1 - y0) - (qy - y0) * (x1 - x0)


def _truncate(f, pix, sd, edge, inside, crowded, x, y, z, faces, px, py, W, K,
              perspective_correct, clip):
    """Keep the K nearest entries (in view depth, ties by face) of the pixels with more."""
    sel = np.flatnonzero(crowded)
    ps, fs = pix[sel], f[sel]
    # the entries' view depth as SoftFragments.depth computes it (float64), without the
    # fragments' other arrays and the barycentrics' copy
    tmp = SoftFragments(1, (len(py), W), K, None, ps, fs, None, np.array([0, len(sel)]), {},
                        None, None, {"faces": faces, "x": x[None], "y": y[None], "z": z[None],
                                     "px": px, "py": py})
    g = _EntryGeometry(tmp, 0, slice(0, len(sel)))
    b, _, _ = g.bary(perspective_correct, clip)
    # one view's entries, each pixel's in increasing face order (the chunks' order)
    drop = sel[_ranks(ps, b[0] * g.z0 + b[1] * g.z1 + b[2] * g.z2, fs, True) >= K]
    keep = np.ones(len(f), bool)
    keep[drop] = False
    return f[keep], pix[keep], sd[keep], edge[keep], inside[keep]


def rasterize_soft(mesh: Mesh, cameras: CamerasBase,
                   raster_settings: SoftRasterizationSettings | None = None) -> SoftFragments:
    """Soft-rasterize one mesh seen by a batch of cameras (PyTorch3D's CPU rasterizer).

    Parameters
    ----------
    mesh : Mesh
        ``V`` vertices, ``F`` faces; rendered in every view.
    cameras : FoVPerspectiveCameras or FoVOrthographicCameras
        ``N`` cameras.
    raster_settings : SoftRasterizationSettings, optional
        Default ``SoftRasterizationSettings()`` (PyTorch3D's defaults: 256 px, blur 0, K = 1).

    Returns
    -------
    SoftFragments
        ``fragments.pix_to_face[n, j, i, k]`` is the face of the ``k``-th nearest entry at row
        ``j``, column ``i`` of view ``n`` (-1 if fewer faces), as PyTorch3D's ``Fragments``
        (but face indices are local to the mesh, not packed over views).

    Notes
    -----
    Per pixel centre ``q`` and face with projected corners ``p0, p1, p2`` (NDC x, y) and view
    depths ``z0, z1, z2``, as ``rasterize_meshes_cpu.cpp``:

    - faces with ``|area| <= 1e-8`` (NDC units, ``area`` = twice the signed area) or a depth
      below the clip depth (and below 1e-8) are skipped, back faces too if ``cull_backfaces``;
    - barycentrics ``b_i = e_i(q) / (area + 1e-8)`` from the edge functions, perspective-corrected
      (``b_i z_j z_k`` normalised, denominator clamped at 1e-8) when asked;
    - ``inside`` means every ``b_i > 0``; ``dist`` is the squared distance to the nearest edge
      segment, negated inside; a face with the pixel outside is kept only if
      ``dist < blur_radius``;
    - clipped barycentrics (``max(b, 0)``, renormalised with the sum floored at 1e-5) give the
      depth ``zbuf = sum b_i z_i``; entries with ``zbuf < 0`` are dropped (possible only without
      clipping);
    - the ``K`` entries of smallest depth are kept (ties: smaller face index first).

    Candidates come from each face's pixel rectangle (its NDC bounding box grown by
    ``sqrt(blur_radius)``); a candidate more than ``sqrt(blur_radius)`` outside one of the
    triangle's edge lines is rejected before the exact segment distances are computed. Views are
    processed in parallel threads.

    Examples
    --------
    >>> import numpy as np
    >>> from geofit import FoVPerspectiveCameras, ico_sphere, look_at_view_transform
    >>> R, T = look_at_view_transform(2.7, 0.0, 0.0)
    >>> cams = FoVPerspectiveCameras(R=R, T=T)
    >>> fr = rasterize_soft(ico_sphere(2), cams, SoftRasterizationSettings.tutorial(32))
    >>> fr.pix_to_face.shape, bool((fr.dists[fr.pix_to_face >= 0] < 9.3e-4).all())
    ((1, 32, 32, 50), True)
    """
    mesh = _check_mesh(mesh)
    cameras = _check_cameras(cameras)
    s = _check_settings(raster_settings)
    H, W = s.image_size
    K = int(s.faces_per_pixel)
    persp = cameras.is_perspective() if s.perspective_correct is None else bool(
        s.perspective_correct)
    clip = (s.blur_radius > 0.0) if s.clip_barycentric_coords is None else bool(
        s.clip_barycentric_coords)
    if s.z_clip_value is not None:
        zclip = s.z_clip_value
    elif persp and cameras.is_perspective():
        zclip = float(np.min(cameras.znear)) / 2.0
    else:
        zclip = 0.0
    verts = mesh.verts
    faces = mesh.faces
    N = len(cameras)
    check_allocation(N * H * W * (24 * K + 1024), "image_size and faces_per_pixel",  # /slot
                     f"soft fragments of {N} view(s) at {(H, W)} with K={K}")  # + ~1 KB/px
    with np.errstate(invalid="ignore", divide="ignore"):
        proj = cameras.projection_jacobian(verts)
    xy = proj.xy
    # a vertex on the camera plane has an infinite Jacobian; its faces are never kept
    J = np.where(np.isfinite(proj.jacobian), proj.jacobian, 0.0)
    x = np.ascontiguousarray(xy[..., 0])
    y = np.ascontiguousarray(xy[..., 1])
    zview = np.einsum("va,na->nv", verts, cameras.R[:, :, 2]) + cameras.T[:, None, 2]
    px, py = _pixel_centres(H, W)
    threads = _n_threads(s.n_threads)

    def setup(n):
        with np.errstate(invalid="ignore", divide="ignore"):
            return _rasterize_view(x[n], y[n], zview[n], faces, H, W, px, py, s.blur_radius, K,
                                   persp, clip, s.cull_backfaces, zclip)

    jobs = _map_views(setup, N, threads)
    # the views' candidate pairs in chunks of at most max_pairs, and small enough that the
    # threads share them evenly (5 views on 2 threads would leave one thread idle for a
    # view); any chunking gives the same entries
    limit = int(s.max_pairs)
    if threads > 1:
        total = sum(int(j.cum[-1]) for j in jobs if len(j.cum))
        limit = max(min(limit, -(-total // (_CHUNKS_PER_THREAD * threads))), 1)
    tasks = [(n, a, b) for n, j in enumerate(jobs) for a, b in j.chunks(limit)]

    def run(t):
        with np.errstate(invalid="ignore", divide="ignore"):
            return jobs[t[0]].run(t[1], t[2])

    done = _map_views(lambda i: run(tasks[i]), len(tasks), threads)
    per_view = [[] for _ in range(N)]
    for (n, _, _), part in zip(tasks, done):  # chunks back to their views, in order
        per_view[n].append(part)

    def finish(n):
        return jobs[n].finish(per_view[n])

    results = _map_views(finish, N, threads)
    cols = [r[0] for r in results]
    counts = [len(c[0]) for c in cols]
    f, pix, sd, edge, inside = (np.concatenate(c) for c in zip(*cols))
    sd = sd.astype(s.dtype, copy=False)
    stats = {"candidates": sum(r[1]["candidates"] for r in results), "entries": len(f),
             "peak_pairs": max(r[1]["peak_pairs"] for r in results),
             "max_faces_per_pixel": max(r[1]["max_faces_per_pixel"] for r in results),
             "truncated_pixels": sum(r[1]["truncated_pixels"] for r in results)}
    stats["peak_bytes_estimate"] = int(stats["peak_pairs"] * _TEMP_FLOATS_PER_PAIR * 8
                                       * min(threads, N))
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    view = np.repeat(np.arange(N, dtype=np.int64), counts)
    ctx = {"n_verts": mesh.n_verts, "faces": faces, "x": x, "y": y, "z": zview, "J": J,
           "R": cameras.R, "px": px, "py": py, "perspective_correct": persp, "clip": clip,
           "zclip": zclip, "blur_radius": s.blur_radius, "n_threads": threads,
           "dtype": s.dtype}
    return SoftFragments(N, (H, W), K, view, pix, f, sd, offsets, stats, edge, inside, ctx)
