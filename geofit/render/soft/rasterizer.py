"""Differentiable soft mesh rendering with PyTorch3D's semantics: forward passes and vjps in numpy.

Three pieces, each a forward map with its vector-Jacobian product (vjp), composed by the chain
rule in plain sight:

1. :func:`rasterize_soft` -- PyTorch3D's CPU mesh rasterizer with a blur radius
   (``csrc/rasterize_meshes/rasterize_meshes_cpu.cpp``): for every pixel the ``K`` faces nearest
   in view depth among those whose projected triangle contains the pixel centre or lies within
   ``sqrt(blur_radius)`` of it (squared NDC distance ``< blur_radius``). Outputs
   :class:`SoftFragments`: signed squared NDC distances (negative inside), view depths and
   barycentrics per (pixel, face) entry, stored sparsely, with dense ``(N, H, W, K)`` views.
   :meth:`SoftFragments.vjp` carries gradients on the distances, depths and barycentrics back to
   the world vertex positions through the 2-D geometry and the projection Jacobians.
2. :func:`sigmoid_alpha_blend` (``SoftSilhouetteShader``): ``S = 1 - prod_k (1 - p_k)`` with
   ``p_k = sigmoid(-d_k / sigma)``; :func:`sigmoid_alpha_blend_vjp`.
3. :func:`phong_vertex_colors` (``SoftPhongShader`` with ``TexturesVertex``) and
   :func:`softmax_rgb_blend_soft` (``softmax_rgb_blend``): per-entry Phong colours from
   interpolated world positions, vertex normals and vertex colours, then the depth-softmax blend;
   each with its vjp (positions through the 2-D distances, barycentrics, depths *and* the shading
   normals; colours linearly).

The renderers :class:`SoftSilhouetteRenderer` and :class:`SoftPhongRenderer` chain them and return
a :class:`SoftRender` whose :meth:`~SoftRender.vjp` maps an image gradient to the vertex positions
(and colours). For fixed geometry the Phong image is affine in the vertex colours;
:meth:`SoftRender.color_operator` returns that map as scipy.sparse matrices (a least-squares
solve for colours is then one sparse solve).

How candidates are found (no dense pixels-by-faces array): each face's NDC bounding box, grown
by ``sqrt(blur_radius)``, gives a pixel rectangle; the (face, pixel) pairs of all rectangles are
enumerated with ``np.repeat`` in chunks of at most ``max_pairs`` pairs, tested exactly, and the
survivors are sorted per pixel by depth (then face index, PyTorch3D's tie order) and cut at
``K``. Memory is bounded by the chunk size plus the kept entries; :attr:`SoftFragments.stats`
reports both.

Non-differentiable parts (gradients are those of the piecewise-smooth pieces, as in PyTorch3D):
which faces a pixel keeps (the blur cut-off, the top-K cut, the ``z >= 0`` test), the inside /
outside sign switch (continuous: ``d = 0`` on the edge), the choice of the nearest of the three
edges, the clamping of the segment parameter, the clipping of barycentrics, ``relu`` in the
diffuse term, the specular mask ``n . l > 0`` and the ``max`` over depths in the softmax blend.
Finite-difference tests must stay away from those switching points.

Differences from PyTorch3D, all documented where they act:

- everything is float64 (PyTorch3D rasterizes and shades in float32);
- faces with a vertex in front of the clip depth (``z_clip_value``, default ``znear / 2`` when
  perspective-correct) are *dropped*, where PyTorch3D clips them into smaller triangles; the two
  agree whenever no face crosses that plane (the tutorial's cow at distance 2.7 is nowhere nearer
  than 1.6);
- a back face whose signed area is within 1e-12 of ``-1e-8`` is skipped: PyTorch3D adds 1e-8 to
  the area before dividing and would divide by almost 0 there;
- the distance to a degenerate edge (squared length <= 1e-8, distance taken to its second end,
  as PyTorch3D) gets the exact gradient of that distance, where PyTorch3D's backward divides by
  the near-zero length.

References
----------
S. Liu, T. Li, W. Chen, H. Li, "Soft Rasterizer: A Differentiable Renderer for Image-based 3D
Reasoning", ICCV 2019. PyTorch3D v0.7.9: ``renderer/mesh/rasterizer.py``, ``renderer/blending.py``,
``renderer/mesh/shading.py``, ``renderer/lighting.py``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, NamedTuple

import numpy as np
import scipy.sparse as sp

from ..._threads import get_num_threads, parallel_map
from ..._validate import as_array, check_positive
from ...cameras import CamerasBase
from ...structures import Mesh
from .._settings import image_hw
from ..blending import BlendParams

__all__ = [
    "TUTORIAL_BLUR_RADIUS",
    "PhongColors",
    "SoftBlend",
    "SoftFragments",
    "SoftGrads",
    "SoftPhongRenderer",
    "SoftRasterizationSettings",
    "SoftRender",
    "SoftSilhouetteRenderer",
    "SoftSilhouetteShader",
    "phong_vertex_colors",
    "rasterize_soft",
    "sigmoid_alpha_blend",
    "sigmoid_alpha_blend_vjp",
    "softmax_rgb_blend_soft",
]

#: The tutorial's blur radius ``log(1 / 1e-4 - 1) * 1e-4``: the squared NDC distance at which
#: ``sigmoid(-d / sigma)`` falls to 1e-4 for ``sigma = 1e-4`` (about 2 px at 128 px).
TUTORIAL_BLUR_RADIUS = math.log(1.0 / 1e-4 - 1.0) * 1e-4

_EPS = 1e-8          # kEpsilon of PyTorch3D's geometry utilities
_CLIP_SUM_EPS = 1e-5  # BarycentricClipForward's floor on the clipped sum
_NORM_EPS = 1e-6     # F.normalize eps in lighting and vertex normals
_BLEND_EPS = 1e-10   # softmax_rgb_blend's eps
_NEGLIGIBLE = 1e-20  # softmax weight ratio below which an entry's colour is not computed


# ------------------------------------------------------------------------------------------
# Settings
# ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SoftRasterizationSettings:
    """Settings of the soft rasterizer (PyTorch3D's ``RasterizationSettings`` with blur).

    Parameters
    ----------
    image_size : int or (H, W)
        Output size in pixels; an int means square. For ``H != W`` the shorter side spans NDC
        [-1, 1] (PyTorch3D's convention).
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

    def __post_init__(self):
        object.__setattr__(self, "image_size", image_hw(self.image_size))
        object.__setattr__(self, "blur_radius",
                           check_positive(self.blur_radius, "blur_radius", strict=False))
        k = self.faces_per_pixel
        if not isinstance(k, (int, np.integer)) or isinstance(k, (bool, np.bool_)) or k < 1:
            raise ValueError(f"faces_per_pixel: expected an integer >= 1, got {k!r}")
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

    @classmethod
    def tutorial(cls, image_size=128, **kwargs) -> SoftRasterizationSettings:
        """The fit_textured_mesh tutorial's soft settings: blur 9.21e-4, 50 faces per pixel."""
        kwargs.setdefault("blur_radius", TUTORIAL_BLUR_RADIUS)
        kwargs.setdefault("faces_per_pixel", 50)
        return cls(image_size=image_size, **kwargs)


# ------------------------------------------------------------------------------------------
# Fragments
# ------------------------------------------------------------------------------------------


def _n_threads(n) -> int:
    if n is None:
        return get_num_threads()
    return int(n)


def _map_views(fn, n_views: int, n_threads: int) -> list:
    """``[fn(v) for v in range(n_views)]``, on a thread pool when it helps (numpy releases the
    GIL in its array loops)."""
    return parallel_map(fn, range(n_views), n_threads)


@dataclass(eq=False)
class SoftFragments:
    """Sparse output of :func:`rasterize_soft`: one entry per kept (pixel, face) pair.

    Entries are grouped by view (view ``n`` holds ``view_offsets[n]:view_offsets[n + 1]``); within
    a view their order is unspecified, and :attr:`k` gives each entry's rank in its pixel (0 =
    nearest in view depth, ties by face index). Dense ``(N, H, W, K)`` arrays
    (:attr:`pix_to_face`, :attr:`zbuf`, :attr:`dists`, :attr:`bary_coords`) follow PyTorch3D's
    layout with -1 in unused slots.

    Attributes
    ----------
    n_views : int
    image_size : (H, W)
    faces_per_pixel : int
    view : (m,) int64
        View of each entry.
    pixel : (m,) int64
        Row-major pixel index ``row * W + col`` within its view (row 0 at the top).
    face : (m,) int64
        Face index (into the mesh's faces, not packed over views).
    dist : (m,) float64
        Signed squared NDC distance from the pixel centre to the projected triangle, negative
        inside (PyTorch3D's ``dists``).
    view_offsets : (N + 1,) int64
    stats : dict
        ``candidates`` (pairs tested), ``entries`` (kept), ``peak_pairs`` (largest chunk in
        flight), ``peak_bytes_estimate`` (its temporaries), ``max_faces_per_pixel`` (before the
        K cut) and ``truncated_pixels`` (pixels that had more than K faces).

    The view depth :attr:`depth`, the barycentrics :attr:`bary` and the ranks :attr:`k` are
    computed on first use (a silhouette needs none of them).
    """

    n_views: int
    image_size: tuple
    faces_per_pixel: int
    view: np.ndarray
    pixel: np.ndarray
    face: np.ndarray
    dist: np.ndarray
    view_offsets: np.ndarray
    stats: dict = field(default_factory=dict)
    _edge: np.ndarray = field(default=None, repr=False)      # nearest edge 0:(0,1) 1:(0,2) 2:(1,2)
    _inside: np.ndarray = field(default=None, repr=False)    # bool
    _ctx: dict = field(default_factory=dict, repr=False)

    def __len__(self) -> int:
        return len(self.face)

    def __repr__(self) -> str:
        return (f"SoftFragments(n_views={self.n_views}, image_size={self.image_size}, "
                f"K={self.faces_per_pixel}, entries={len(self)})")

    @cached_property
    def global_pixel(self) -> np.ndarray:
        """(m,) int64 ``view * H * W + pixel``: the entry's pixel in the flattened batch."""
        H, W = self.image_size
        return self.view * (H * W) + self.pixel

    def _views(self):
        for n in range(self.n_views):  # loop over views
            yield n, slice(int(self.view_offsets[n]), int(self.view_offsets[n + 1]))

    @cached_property
    def _bary_depth(self) -> tuple[np.ndarray, np.ndarray]:
        bary = np.empty((len(self), 3))
        depth = np.empty(len(self))
        c = self._ctx
        for n, s in self._views():
            if s.start == s.stop:
                continue
            g = _EntryGeometry(self, n, s)
            b, _, _ = g.bary(c["perspective_correct"], c["clip"])
            bary[s] = np.stack(b, 1)
            depth[s] = b[0] * g.z0 + b[1] * g.z1 + b[2] * g.z2
        return bary, depth

    @property
    def bary(self) -> np.ndarray:
        """(m, 3) float64 barycentrics as PyTorch3D outputs them (perspective-corrected and
        clipped per the settings)."""
        return self._bary_depth[0]

    @property
    def depth(self) -> np.ndarray:
        """(m,) float64 view depth of the pixel's point on the face (PyTorch3D's ``zbuf``),
        interpolated with :attr:`bary`."""
        return self._bary_depth[1]

    @cached_property
    def k(self) -> np.ndarray:
        """(m,) int64 rank of each entry in its pixel (0 = nearest; ties by face index)."""
        gp = self.global_pixel
        order = np.lexsort((self.face, self.depth, gp))
        sg = gp[order]
        start = np.r_[True, sg[1:] != sg[:-1]] if len(sg) else np.zeros(0, bool)
        first = np.flatnonzero(start)
        rank_sorted = np.arange(len(sg)) - np.repeat(first, np.diff(np.r_[first, len(sg)]))
        rank = np.empty(len(sg), np.int64)
        rank[order] = rank_sorted
        return rank

    def _dense(self, values, fill, dtype, trailing=()) -> np.ndarray:
        H, W = self.image_size
        K = self.faces_per_pixel
        out = np.full((self.n_views * H * W, K) + trailing, fill, dtype=dtype)
        out[self.global_pixel, self.k] = values
        return out.reshape((self.n_views, H, W, K) + trailing)

    @property
    def pix_to_face(self) -> np.ndarray:
        """(N, H, W, K) int64 face index per slot, -1 where unused (not packed: local faces)."""
        return self._dense(self.face, -1, np.int64)

    @property
    def zbuf(self) -> np.ndarray:
        """(N, H, W, K) float64 view depth per slot, -1 where unused."""
        return self._dense(self.depth, -1.0, np.float64)

    @property
    def dists(self) -> np.ndarray:
        """(N, H, W, K) float64 signed squared NDC distance per slot, -1 where unused."""
        return self._dense(self.dist, -1.0, np.float64)

    @property
    def bary_coords(self) -> np.ndarray:
        """(N, H, W, K, 3) float64 barycentrics per slot, -1 where unused."""
        return self._dense(self.bary, -1.0, np.float64, (3,))

    # ------------------------------------------------------------------ backward
    def vjp(self, grad_dists=None, grad_zbuf=None, grad_bary=None) -> np.ndarray:
        """Carry gradients on the entries back to the world vertex positions.

        Parameters
        ----------
        grad_dists : (m,) float64, optional
            dL/d ``dist`` per entry.
        grad_zbuf : (m,) float64, optional
            dL/d ``depth`` per entry.
        grad_bary : (m, 3) float64, optional
            dL/d ``bary`` per entry.

        Returns
        -------
        grad_verts : (V, 3) float64
            Summed over the views. Which faces a pixel keeps is held fixed (no gradient flows
            through that choice); see the module notes for the other switches.
        """
        ctx = self._ctx
        V = ctx["n_verts"]
        m = len(self)
        if m == 0 or (grad_dists is None and grad_zbuf is None and grad_bary is None):
            return np.zeros((V, 3))
        gd_all = None if grad_dists is None else as_array(grad_dists, "grad_dists", (m,))
        gz_all = None if grad_zbuf is None else as_array(grad_zbuf, "grad_zbuf", (m,))
        gb_all = None if grad_bary is None else as_array(grad_bary, "grad_bary", (m, 3))
        faces = ctx["faces"]

        def one(n):
            s = slice(int(self.view_offsets[n]), int(self.view_offsets[n + 1]))
            if s.start == s.stop:
                return None
            if gz_all is None and gb_all is None:
                return _dist_vjp(self, n, s, gd_all[s], V)
            g = _EntryGeometry(self, n, s)
            gx, gy, gz = g.vjp(None if gd_all is None else gd_all[s],
                               None if gz_all is None else gz_all[s],
                               None if gb_all is None else gb_all[s],
                               ctx["perspective_correct"], ctx["clip"])
            f = self.face[s]
            J = ctx["J"][n]
            out = np.zeros((V, 3))
            for c in range(3):  # the three corners
                vid = faces[f, c]
                bx = np.bincount(vid, gx[c], V)
                by = np.bincount(vid, gy[c], V)
                out += bx[:, None] * J[:, 0, :] + by[:, None] * J[:, 1, :]
                if gz is not None:
                    out += np.bincount(vid, gz[c], V)[:, None] * ctx["R"][n][:, 2][None, :]
            return out

        parts = _map_views(one, self.n_views, ctx["n_threads"])
        return sum((p for p in parts if p is not None), np.zeros((V, 3)))


_EDGE_ENDS = np.array([[0, 1], [0, 2], [1, 2]])


def _dist_vjp(fr: SoftFragments, n: int, s: slice, gd: np.ndarray, V: int) -> np.ndarray:
    """World-vertex gradient of one view from gradients on the signed distances only: only the
    two ends of each entry's nearest edge move (``dD/da = 2 (1 - t)(c - q)``,
    ``dD/db = 2 t (c - q)``, ``c = a + t (b - a)``; the sign flips inside)."""
    ctx = fr._ctx
    X, Y = ctx["x"][n], ctx["y"][n]
    ends = _EDGE_ENDS[fr._edge[s]]
    f = fr.face[s]
    faces = ctx["faces"]
    va = faces[f, ends[:, 0]]
    vb = faces[f, ends[:, 1]]
    W = fr.image_size[1]
    pix = fr.pixel[s]
    ax, ay = X[va], Y[va]
    dx, dy = X[vb] - ax, Y[vb] - ay
    rx, ry = ctx["px"][pix % W] - ax, ctx["py"][pix // W] - ay
    l2 = dx * dx + dy * dy
    degenerate = l2 <= _EPS
    t = np.clip((rx * dx + ry * dy) / np.where(degenerate, 1.0, l2), 0.0, 1.0)
    t[degenerate] = 1.0
    g = np.where(fr._inside[s], 2.0 * gd, -2.0 * gd)   # 2 * sign * gd, and c - q = -(r - t d)
    cx = (rx - t * dx) * g
    cy = (ry - t * dy) * g
    ta = 1.0 - t
    gx = np.bincount(va, ta * cx, V) + np.bincount(vb, t * cx, V)
    gy = np.bincount(va, ta * cy, V) + np.bincount(vb, t * cy, V)
    J = ctx["J"][n]
    return gx[:, None] * J[:, 0, :] + gy[:, None] * J[:, 1, :]


class _EntryGeometry:
    """Per-entry projected corners, depths and pixel centres of one view (1-D arrays)."""

    def __init__(self, fr: SoftFragments, n: int, s: slice):
        ctx = fr._ctx
        faces = ctx["faces"]
        f = fr.face[s]
        self.fr, self.s = fr, s
        X, Y, Z = ctx["x"][n], ctx["y"][n], ctx["z"][n]
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        self.x0, self.y0, self.z0 = X[i0], Y[i0], Z[i0]
        self.x1, self.y1, self.z1 = X[i1], Y[i1], Z[i1]
        self.x2, self.y2, self.z2 = X[i2], Y[i2], Z[i2]
        W = fr.image_size[1]
        pix = fr.pixel[s]
        self.qx = ctx["px"][pix % W]
        self.qy = ctx["py"][pix // W]

    def edge_functions(self):
        qx, qy = self.qx, self.qy
        x0, y0, x1, y1, x2, y2 = self.x0, self.y0, self.x1, self.y1, self.x2, self.y2
        area = (x2 - x0) * (y1 - y0) - (y2 - y0) * (x1 - x0) + _EPS
        e0 = (qx - x1) * (y2 - y1) - (qy - y1) * (x2 - x1)
        e1 = (qx - x2) * (y0 - y2) - (qy - y2) * (x0 - x2)
        e2 = (qx - x0) * (y1 - y0) - (qy - y0) * (x1 - x0)
        return area, (e0, e1, e2)

    def bary(self, perspective_correct: bool, clip: bool):
        """Output barycentrics and the intermediates of their vjp."""
        area, e = self.edge_functions()
        b0 = [ei / area for ei in e]
        saved = {"area": area, "b0": b0}
        if perspective_correct:
            zz = (self.z1 * self.z2, self.z0 * self.z2, self.z0 * self.z1)
            top = [b0[i] * zz[i] for i in range(3)]
            den_raw = top[0] + top[1] + top[2]
            den = np.maximum(den_raw, _EPS)
            b = [t / den for t in top]
            saved.update(zz=zz, top=top, den=den, den_free=den_raw >= _EPS)
        else:
            b = b0
        saved["b"] = b
        if clip:
            w = [np.maximum(bi, 0.0) for bi in b]
            s_raw = w[0] + w[1] + w[2]
            ssum = np.maximum(s_raw, _CLIP_SUM_EPS)
            bc = [wi / ssum for wi in w]
            saved.update(w=w, ssum=ssum, sum_free=s_raw >= _CLIP_SUM_EPS)
        else:
            bc = b
        return bc, b, saved

    def vjp(self, gd, gz, gb, perspective_correct: bool, clip: bool):
        """Gradients on the corners' NDC x, y and view depth: three lists of three (m,) arrays."""
        fr, s = self.fr, self.s
        m = s.stop - s.start
        zeros = np.zeros(m)
        gx = [zeros.copy(), zeros.copy(), zeros.copy()]
        gy = [zeros.copy(), zeros.copy(), zeros.copy()]
        gzc = None
        qx, qy = self.qx, self.qy
        xs = (self.x0, self.x1, self.x2)
        ys = (self.y0, self.y1, self.y2)
        if gd is not None:
            g = np.where(fr._inside[s], -gd, gd)
            e = fr._edge[s]
            for k, (ia, ib) in enumerate(((0, 1), (0, 2), (1, 2))):  # the three edges
                sel = np.flatnonzero(e == k)
                if sel.size == 0:
                    continue
                ax, ay = xs[ia][sel], ys[ia][sel]
                dx, dy = xs[ib][sel] - ax, ys[ib][sel] - ay
                l2 = dx * dx + dy * dy
                rx, ry = qx[sel] - ax, qy[sel] - ay
                degenerate = l2 <= _EPS
                t = (rx * dx + ry * dy) / np.where(degenerate, 1.0, l2)
                t = np.where(degenerate, 1.0, np.clip(t, 0.0, 1.0))
                # proj - q = -(r - t d); dD/da = 2 (1 - t)(proj - q), dD/db = 2 t (proj - q)
                cx = -2.0 * (rx - t * dx) * g[sel]
                cy = -2.0 * (ry - t * dy) * g[sel]
                gx[ia][sel] += (1.0 - t) * cx
                gy[ia][sel] += (1.0 - t) * cy
                gx[ib][sel] += t * cx
                gy[ib][sel] += t * cy
        if gz is not None or gb is not None:
            bc, b, sv = self.bary(perspective_correct, clip)
            zc = (self.z0, self.z1, self.z2)
            G = [zeros.copy() for _ in range(3)] if gb is None else [
                np.array(gb[:, i], dtype=np.float64) for i in range(3)]
            gzc = [zeros.copy(), zeros.copy(), zeros.copy()]
            if gz is not None:
                for i in range(3):  # corners
                    G[i] += gz * zc[i]
                    gzc[i] += gz * bc[i]
            if clip:
                w, ssum = sv["w"], sv["ssum"]
                gsum = -(G[0] * w[0] + G[1] * w[1] + G[2] * w[2]) / ssum ** 2 * sv["sum_free"]
                G = [(b[i] >= 0.0) * (G[i] / ssum + gsum) for i in range(3)]
            b0 = sv["b0"]
            if perspective_correct:
                top, den, zz = sv["top"], sv["den"], sv["zz"]
                gden = -(G[0] * top[0] + G[1] * top[1] + G[2] * top[2]) / den ** 2 * sv["den_free"]
                gt = [G[i] / den + gden for i in range(3)]
                gzc[0] += gt[1] * b0[1] * zc[2] + gt[2] * b0[2] * zc[1]
                gzc[1] += gt[0] * b0[0] * zc[2] + gt[2] * b0[2] * zc[0]
                gzc[2] += gt[0] * b0[0] * zc[1] + gt[1] * b0[1] * zc[0]
                G = [gt[i] * zz[i] for i in range(3)]
            area = sv["area"]
            g0, g1, g2 = (Gi / area for Gi in G)
            garea = -(G[0] * b0[0] + G[1] * b0[1] + G[2] * b0[2]) / area
            x0, y0, x1, y1, x2, y2 = self.x0, self.y0, self.x1, self.y1, self.x2, self.y2
            # e0 = EF(q; p1, p2), e1 = EF(q; p2, p0), e2 = EF(q; p0, p1), area = EF(p2; p0, p1)
            gx[0] += g1 * (y2 - qy) + g2 * (qy - y1) + garea * (y2 - y1)
            gy[0] += g1 * (qx - x2) + g2 * (x1 - qx) + garea * (x1 - x2)
            gx[1] += g0 * (qy - y2) + g2 * (y0 - qy) + garea * (y0 - y2)
            gy[1] += g0 * (x2 - qx) + g2 * (qx - x0) + garea * (x2 - x0)
            gx[2] += g0 * (y1 - qy) + g1 * (qy - y0) + garea * (y1 - y0)
            gy[2] += g0 * (qx - x1) + g1 * (x0 - qx) + garea * (x0 - x1)
        return gx, gy, gzc


# ------------------------------------------------------------------------------------------
# Rasterizer
# ------------------------------------------------------------------------------------------


def _check_mesh(mesh) -> Mesh:
    if not isinstance(mesh, Mesh):
        raise TypeError(f"mesh: expected a geofit Mesh, got {type(mesh)!r}")
    return mesh


def _check_cameras(cameras) -> CamerasBase:
    if not isinstance(cameras, CamerasBase):
        raise TypeError(f"cameras: expected a geofit camera batch, got {type(cameras)!r}")
    return cameras


def _check_settings(settings) -> SoftRasterizationSettings:
    if settings is None:
        return SoftRasterizationSettings()
    if not isinstance(settings, SoftRasterizationSettings):
        raise TypeError(f"raster_settings: expected SoftRasterizationSettings, got "
                        f"{type(settings)!r}")
    return settings


def _pixel_centres(H: int, W: int):
    S = min(H, W)
    px = (W - 1 - 2 * np.arange(W, dtype=np.float64)) / S
    py = (H - 1 - 2 * np.arange(H, dtype=np.float64)) / S
    return px, py


def _seg_sqdist(qx, qy, ax, ay, dx, dy, inv_l2, degenerate):
    """Squared distance from q to segment a + t d (PyTorch3D's PointLineDistanceForward).

    ``inv_l2 = 1 / |d|^2`` (0 for a degenerate segment) and ``degenerate`` (0/1): a degenerate
    segment (``|d|^2 <= 1e-8``) gives the distance to its second end ``a + d`` (t = 1).
    """
    rx = qx - ax
    ry = qy - ay
    t = np.clip((rx * dx + ry * dy) * inv_l2 + degenerate, 0.0, 1.0)
    ex = rx - t * dx
    ey = ry - t * dy
    return ex * ex + ey * ey


_TEMP_FLOATS_PER_PAIR = 24  # float64 temporaries alive per candidate pair (rough count)


def _rasterize_view(x, y, z, faces, H, W, px, py, blur, K, perspective_correct, clip, cull,
                    zclip, max_pairs):
    """Kept entries of one view: (face, pixel, signed dist, edge, inside) and its stats."""
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
        return empty, stats
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
    fids, i_lo, j_lo, nx, counts = fids[nz], i_lo[nz], j_lo[nz], nx[nz], counts[nz]
    if fids.size == 0:
        return empty, stats
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
    parts = []
    cum = np.cumsum(counts)
    start = 0
    while start < len(fids):  # chunks of faces (bounded memory)
        base = int(cum[start - 1]) if start else 0
        stop = max(int(np.searchsorted(cum, base + max_pairs, side="right")), start + 1)
        cc = counts[start:stop]
        n_pairs = int(cc.sum())
        stats["peak_pairs"] = max(stats["peak_pairs"], n_pairs)
        loc = np.repeat(np.arange(start, stop), cc)  # position in fids
        off = np.arange(n_pairs, dtype=np.int64) - np.repeat(np.cumsum(cc) - cc, cc)
        nxl = nx[loc]
        col = i_lo[loc] + off % nxl
        row = j_lo[loc] + off // nxl
        del off, nxl
        qx = px[col]
        qy = py[row]
        # stage 1: signed distances to the three edge lines; a pair whose pixel lies beyond
        # sqrt(blur) outside one of them is farther than sqrt(blur) from the triangle
        sl = [a[loc] * qx + b[loc] * qy + c[loc] for a, b, c in lines]
        s_min = np.minimum(np.minimum(sl[0], sl[1]), sl[2])
        live = np.flatnonzero(s_min > cut)
        loc, col, row, qx, qy, s_min = (v[live] for v in (loc, col, row, qx, qy, s_min))
        sl = [v[live] for v in sl]
        # stage 2: exact squared distance to the triangle (the nearest of the three segments,
        # PyTorch3D's order e01, e02, e12 on ties). Inside a triangle the nearest segment point
        # is the foot on the nearest edge line, so there it is (min_i s_i)^2 (faces with a
        # degenerate edge, whose distance PyTorch3D takes to an end point, excepted).
        inside = s_min > 0.0
        gen = np.flatnonzero(~inside | degface[loc])
        fast = np.flatnonzero(inside & ~degface[loc])
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
            lg = loc[gen]
            d = [_seg_sqdist(qx[gen], qy[gen], ax[lg], ay[lg], dx[lg], dy[lg], il[lg], dg[lg])
                 for ax, ay, dx, dy, il, dg in segs]
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
        parts.append((fids[loc[sel]], row[sel] * W + col[sel],
                      np.where(inside[sel], -dist[sel], dist[sel]), edge[sel], inside[sel]))
        start = stop
    f, pix, sd, edge, inside = (np.concatenate(c) for c in zip(*parts))
    n = len(f)
    if n:
        cnt = np.bincount(pix, minlength=H * W)
        stats["max_faces_per_pixel"] = int(cnt.max())
        over = cnt > K
        stats["truncated_pixels"] = int(np.count_nonzero(over))
        if stats["truncated_pixels"]:
            f, pix, sd, edge, inside = _truncate(f, pix, sd, edge, inside, over[pix], x, y, z,
                                                 faces, px, py, W, K, perspective_correct,
                                                 clip)
    return (f, pix, sd, edge, inside), stats


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
    tmp = SoftFragments(1, (len(py), W), K, np.zeros(len(sel), np.int64), pix[sel], f[sel],
                        sd[sel], np.array([0, len(sel)]), {}, edge[sel], inside[sel],
                        {"faces": faces, "x": x[None], "y": y[None], "z": z[None], "px": px,
                         "py": py, "perspective_correct": perspective_correct, "clip": clip})
    drop = sel[tmp.k >= K]
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

    def one(n):
        with np.errstate(invalid="ignore", divide="ignore"):
            return _rasterize_view(x[n], y[n], zview[n], faces, H, W, px, py, s.blur_radius, K,
                                   persp, clip, s.cull_backfaces, zclip, int(s.max_pairs))

    results = _map_views(one, N, threads)
    cols = [r[0] for r in results]
    counts = [len(c[0]) for c in cols]
    f, pix, sd, edge, inside = (np.concatenate(c) for c in zip(*cols))
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
           "zclip": zclip, "blur_radius": s.blur_radius, "n_threads": threads}
    return SoftFragments(N, (H, W), K, view, pix, f, sd, offsets, stats, edge, inside, ctx)


# ------------------------------------------------------------------------------------------
# Silhouette blend
# ------------------------------------------------------------------------------------------


def _check_fragments(fragments) -> SoftFragments:
    if not isinstance(fragments, SoftFragments):
        raise TypeError(f"fragments: expected SoftFragments, got {type(fragments)!r}")
    return fragments


def _sigmoid_terms(fr: SoftFragments, sigma: float):
    """``p = sigmoid(-d / sigma)`` and ``log(1 - p)`` per entry, cached on the fragments.

    With ``e = exp(-d / sigma)`` (exponent capped at 700): ``p = e / (1 + e)`` and
    ``log(1 - p) = -log1p(e)``, finite for every distance (a cap only changes ``log(1 - p)``
    below -700, where ``1 - S`` underflows to 0 either way).
    """
    cache = fr.__dict__.setdefault("_sigmoid_cache", {})
    if sigma not in cache:
        e = np.exp(np.minimum(fr.dist * (-1.0 / sigma), 700.0))
        cache.clear()
        cache[sigma] = (e / (1.0 + e), -np.log1p(e))
    return cache[sigma]


def _log_one_minus_p(dist: np.ndarray, sigma: float) -> np.ndarray:
    """log(1 - sigmoid(-d / sigma)) = log sigmoid(d / sigma), finite for every d."""
    return -np.log1p(np.exp(np.minimum(dist * (-1.0 / sigma), 700.0)))


def sigmoid_alpha_blend(fragments: SoftFragments, sigma: float = 1e-4) -> np.ndarray:
    """Soft silhouettes ``S = 1 - prod_k (1 - sigmoid(-d_k / sigma))`` (PyTorch3D's op).

    Parameters
    ----------
    fragments : SoftFragments
    sigma : float
        Falloff width in squared NDC units (> 0).

    Returns
    -------
    alpha : (N, H, W) float64
        0 where no face was kept. The product is evaluated as ``exp(sum log sigmoid(d/sigma))``,
        which is finite for every distance.
    """
    fr = _check_fragments(fragments)
    sigma = check_positive(sigma, "sigma")
    H, W = fr.image_size
    tot = fr.n_views * H * W
    logq = np.bincount(fr.global_pixel, _sigmoid_terms(fr, sigma)[1], tot)
    return (-np.expm1(logq)).reshape(fr.n_views, H, W)


def sigmoid_alpha_blend_vjp(fragments: SoftFragments, grad_alpha, sigma: float = 1e-4,
                            alpha=None) -> np.ndarray:
    """dL/d dists from dL/d alpha for :func:`sigmoid_alpha_blend`.

    ``dS/dd_k = -(p_k / sigma) (1 - S)``: exact, no division by ``1 - p_k`` (PyTorch3D's
    backward uses the same identity).

    Parameters
    ----------
    fragments : SoftFragments
    grad_alpha : (N, H, W) float64
    sigma : float
    alpha : (N, H, W) float64, optional
        The forward result (recomputed if omitted).

    Returns
    -------
    grad_dists : (m,) float64
    """
    fr = _check_fragments(fragments)
    sigma = check_positive(sigma, "sigma")
    H, W = fr.image_size
    g = as_array(grad_alpha, "grad_alpha", (fr.n_views, H, W)).reshape(-1)
    if alpha is None:
        alpha = sigmoid_alpha_blend(fr, sigma)
    gp = fr.global_pixel
    coef = g * (1.0 - np.asarray(alpha).reshape(-1)) * (-1.0 / sigma)   # per pixel
    return coef[gp] * _sigmoid_terms(fr, sigma)[0]


class SoftSilhouetteShader:
    """PyTorch3D's ``SoftSilhouetteShader``: RGBA with RGB = 1 and A the soft silhouette.

    Parameters
    ----------
    blend_params : BlendParams, optional
        Only ``sigma`` is used (default 1e-4).
    """

    def __init__(self, blend_params: BlendParams | None = None):
        self.blend_params = _check_blend(blend_params)

    def __call__(self, fragments: SoftFragments) -> np.ndarray:
        """(N, H, W, 4) float64 images."""
        fr = _check_fragments(fragments)
        a = sigmoid_alpha_blend(fr, self.blend_params.sigma)
        out = np.ones(a.shape + (4,))
        out[..., 3] = a
        return out


def _check_blend(blend_params) -> BlendParams:
    if blend_params is None:
        return BlendParams()
    if not isinstance(blend_params, BlendParams):
        raise TypeError(f"blend_params: expected a BlendParams, got {type(blend_params)!r}")
    check_positive(blend_params.sigma, "blend_params.sigma")
    check_positive(blend_params.gamma, "blend_params.gamma")
    as_array(blend_params.background_color, "blend_params.background_color", (3,))
    return blend_params


# ------------------------------------------------------------------------------------------
# Phong shading of vertex colours
# ------------------------------------------------------------------------------------------


def _dot3(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _normalize3(x):
    """x / max(|x|, 1e-6) for a vector given as three (m,) components; also |x| and the divisor."""
    nrm = np.sqrt(_dot3(x, x))
    c = np.maximum(nrm, _NORM_EPS)
    inv = 1.0 / c
    return [xi * inv for xi in x], nrm, c


def _normalize3_vjp(g, y, nrm, c):
    """Backward of y = x / max(|x|, eps) (the clamp passes no gradient to |x|)."""
    proj = np.where(nrm > _NORM_EPS, _dot3(y, g), 0.0)
    inv = 1.0 / c
    return [(g[i] - y[i] * proj) * inv for i in range(3)]


def _vertex_normals(verts: np.ndarray, faces: np.ndarray):
    """PyTorch3D's vertex normals (component arrays) and what their vjp needs."""
    V = len(verts)
    X = [np.ascontiguousarray(verts[:, c]) for c in range(3)]
    f0, f1, f2 = (np.ascontiguousarray(faces[:, i]) for i in range(3))
    a = [X[c][f1] - X[c][f0] for c in range(3)]
    b = [X[c][f2] - X[c][f0] for c in range(3)]
    cr = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    m = [np.bincount(f0, cr[c], V) + np.bincount(f1, cr[c], V) + np.bincount(f2, cr[c], V)
         for c in range(3)]
    n, nrm, cl = _normalize3(m)
    return n, (a, b, nrm, cl, f0, f1, f2)


def _vertex_normals_vjp(g_n, n, saved, V):
    a, b, nrm, cl, f0, f1, f2 = saved
    g_m = _normalize3_vjp(g_n, n, nrm, cl)
    g_c = [g_m[c][f0] + g_m[c][f1] + g_m[c][f2] for c in range(3)]
    # cross = a x b: d/da = b x g, d/db = g x a
    g_a = [b[1] * g_c[2] - b[2] * g_c[1], b[2] * g_c[0] - b[0] * g_c[2],
           b[0] * g_c[1] - b[1] * g_c[0]]
    g_b = [g_c[1] * a[2] - g_c[2] * a[1], g_c[2] * a[0] - g_c[0] * a[2],
           g_c[0] * a[1] - g_c[1] * a[0]]
    out = np.empty((V, 3))
    for c in range(3):  # coordinates
        out[:, c] = (np.bincount(f1, g_a[c], V) + np.bincount(f2, g_b[c], V)
                     - np.bincount(f0, g_a[c] + g_b[c], V))
    return out


def _per_view(param: np.ndarray, n_views: int, name: str) -> np.ndarray:
    p = np.asarray(param, dtype=np.float64)
    if p.shape[0] not in (1, n_views):
        raise ValueError(f"{name}: expected 1 or {n_views} entries (one per view), got "
                         f"{p.shape[0]}")
    return np.broadcast_to(p, (n_views,) + p.shape[1:])


def _entry_param(p: np.ndarray, view: np.ndarray):
    """Per-entry values of a per-view parameter (N,) or (N, 3): scalars when all views agree."""
    if p.ndim == 1:
        return float(p[0]) if np.all(p == p[0]) else p[view]
    if np.all(p == p[0]):
        return [float(v) for v in p[0]]
    return [np.ascontiguousarray(p[view, c]) for c in range(p.shape[1])]


def _interp(b, cols, i):
    """sum_j b_j cols[c][i_j] for each component c."""
    return [b[0] * col[i[0]] + b[1] * col[i[1]] + b[2] * col[i[2]] for col in cols]


def _scatter(b, g, i, V):
    """(V, 3): sum over entries of b_j g[c] onto vertex i_j (the transpose of _interp)."""
    out = np.empty((V, len(g)))
    for c in range(len(g)):  # components
        out[:, c] = (np.bincount(i[0], b[0] * g[c], V) + np.bincount(i[1], b[1] * g[c], V)
                     + np.bincount(i[2], b[2] * g[c], V))
    return out


_CHUNK = 65536  # entries per shading chunk (cache-sized arrays)


def _chunks(n: int, size: int = _CHUNK) -> list:
    return [slice(a, min(a + size, n)) for a in range(0, n, size)]


@dataclass(eq=False)
class PhongColors:
    """Per-entry Phong colours of :func:`phong_vertex_colors` and what their vjp needs.

    Attributes
    ----------
    entries : (k,) int64
        The fragment entries shaded (all of them unless a subset was asked for).
    colors : (k, 3) float64
        ``(Ma La + Md D) texel + Ms S`` per shaded entry.
    shade : (k, 3) float64
        ``Ma La + Md D``: the factor multiplying the interpolated vertex colour.
    specular : (k, 3) float64
        ``Ms S``.
    """

    entries: np.ndarray
    colors: np.ndarray
    shade: np.ndarray
    specular: np.ndarray
    _saved: dict = field(default_factory=dict, repr=False)

    @property
    def cos(self) -> np.ndarray:
        """(k,) float64 ``n . l`` (cosine between the shading normal and the light) per entry."""
        parts = [c["cos"] for c in self._saved["chunk_saved"]]
        return np.concatenate(parts) if parts else np.zeros(0)

    def vjp(self, grad_colors) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Backward of the shading.

        Parameters
        ----------
        grad_colors : (k, 3) float64
            dL/d ``colors``.

        Returns
        -------
        grad_verts : (V, 3) float64
            Through the interpolated world positions and the vertex normals (not through the
            barycentrics: see ``grad_bary``).
        grad_vertex_colors : (V, 3) float64
        grad_bary : (k, 3) float64
            dL/d barycentrics of the shaded entries (for :meth:`SoftFragments.vjp`).
        """
        s = self._saved
        k = len(self.entries)
        g = as_array(grad_colors, "grad_colors", (k, 3))
        V = s["n_verts"]
        g_bary = np.empty((k, 3))

        def one(ci):
            sl = s["chunks"][ci]
            gP, gN, gT, gb, cs = _phong_chunk_vjp(s["chunk_saved"][ci], g[sl], self.shade[sl],
                                                  s)
            g_bary[sl] = gb
            b, i = cs["b"], cs["i"]
            return _scatter(b, gP, i, V), _scatter(b, gN, i, V), _scatter(b, gT, i, V)

        parts = _map_views(one, len(s["chunks"]), s["n_threads"])
        gv = np.zeros((V, 3))
        gn = np.zeros((V, 3))
        gcol = np.zeros((V, 3))
        for a, b, c in parts:  # chunks
            gv += a
            gn += b
            gcol += c
        gv += _vertex_normals_vjp([np.ascontiguousarray(gn[:, c]) for c in range(3)], s["vn"],
                                  s["vn_saved"], V)
        return gv, gcol, g_bary


def _phong_chunk(b, i, v, s):
    """Phong colours of one chunk of entries (barycentrics b, vertex ids i, views v)."""
    P = _interp(b, s["verts"], i)
    Nrm = _interp(b, s["vn"], i)
    tex = _interp(b, s["vcol"], i)
    nn, *n_norm = _normalize3(Nrm)
    if s["loc"] is not None:
        lp = _entry_param(s["loc"], v)
        Lraw = [lp[c] - P[c] for c in range(3)]
    elif s["direction"] is not None:
        dp = _entry_param(s["direction"], v)
        Lraw = [np.broadcast_to(np.asarray(dp[c], np.float64), P[0].shape) for c in range(3)]
    else:
        Lraw = [np.zeros_like(P[0]) for _ in range(3)]
    ln, *l_norm = _normalize3(Lraw)
    cos = _dot3(nn, ln)
    cp = _entry_param(s["centres"], v)
    vd, *v_norm = _normalize3([cp[c] - P[c] for c in range(3)])
    r = [2.0 * cos * nn[c] - ln[c] for c in range(3)]
    alpha = np.where(cos > 0.0, np.maximum(_dot3(vd, r), 0.0), 0.0)
    sh = _entry_param(s["shininess"], v)
    pw = np.power(alpha, sh)
    Ld, Ls = _entry_param(s["Ld"], v), _entry_param(s["Ls"], v)
    La, Ma, Md, Ms = (_entry_param(s[k], v) for k in ("La", "Ma", "Md", "Ms"))
    relu = np.maximum(cos, 0.0)
    n = len(cos)
    shade = np.empty((n, 3))
    spec = np.empty((n, 3))
    colors = np.empty((n, 3))
    for c in range(3):  # colour channels
        shade[:, c] = Ma[c] * La[c] + Md[c] * (Ld[c] * relu)
        spec[:, c] = Ms[c] * (Ls[c] * pw)
        colors[:, c] = shade[:, c] * tex[c] + spec[:, c]
    saved = {"b": b, "i": i, "Md": Md, "Ms": Ms, "Ld": Ld, "Ls": Ls, "tex": tex, "cos": cos,
             "alpha": alpha, "shininess": sh, "nn": nn, "l": ln, "v": vd, "r": r,
             "l_norm": l_norm, "v_norm": v_norm, "n_norm": n_norm}
    return colors, shade, spec, saved


def _phong_chunk_vjp(cs, g, shade, s):
    """Gradients on the interpolated position, normal and texel, and on the barycentrics."""
    g = [np.ascontiguousarray(g[:, c]) for c in range(3)]
    i = cs["i"]
    g_tex = [g[c] * shade[:, c] for c in range(3)]
    vcol = s["vcol"]
    g_bary = [g_tex[0] * vcol[0][i[j]] + g_tex[1] * vcol[1][i[j]] + g_tex[2] * vcol[2][i[j]]
              for j in range(3)]
    Md, Ld, Ms, Ls = cs["Md"], cs["Ld"], cs["Ms"], cs["Ls"]
    tex, cos = cs["tex"], cs["cos"]
    # diffuse = Ld max(0, cos): d colour_c / d cos = Md_c Ld_c texel_c [cos > 0]
    g_cos = (g[0] * (Md[0] * Ld[0]) * tex[0] + g[1] * (Md[1] * Ld[1]) * tex[1]
             + g[2] * (Md[2] * Ld[2]) * tex[2]) * (cos > 0.0)
    # specular = Ls alpha^sh with alpha = max(r . v, 0) [cos > 0]
    a, sh = cs["alpha"], cs["shininess"]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        da = np.where(a > 0.0, sh * np.power(a, sh - 1.0), 0.0)
    g_a = (g[0] * (Ms[0] * Ls[0]) + g[1] * (Ms[1] * Ls[1]) + g[2] * (Ms[2] * Ls[2])) * da
    nn, ln, vd, r = cs["nn"], cs["l"], cs["v"], cs["r"]
    g_r = [g_a * vd[c] for c in range(3)]
    g_v = [g_a * r[c] for c in range(3)]
    # r = 2 cos nn - l with cos = nn . l
    g_cos = g_cos + 2.0 * _dot3(g_r, nn)
    g_nn = [2.0 * cos * g_r[c] + g_cos * ln[c] for c in range(3)]
    g_l = [g_cos * nn[c] - g_r[c] for c in range(3)]
    gv_raw = _normalize3_vjp(g_v, vd, *cs["v_norm"])
    g_P = [-x for x in gv_raw]
    if s["loc"] is not None:  # l = normalize(location - P)
        gl_raw = _normalize3_vjp(g_l, ln, *cs["l_norm"])
        g_P = [g_P[c] - gl_raw[c] for c in range(3)]
    g_N = _normalize3_vjp(g_nn, nn, *cs["n_norm"])
    # P = sum b_j V[i_j], N = sum b_j n[i_j]
    Vc, Nc = s["verts"], s["vn"]
    for j in range(3):  # corners
        g_bary[j] = g_bary[j] + (g_P[0] * Vc[0][i[j]] + g_P[1] * Vc[1][i[j]]
                                 + g_P[2] * Vc[2][i[j]] + g_N[0] * Nc[0][i[j]]
                                 + g_N[1] * Nc[1][i[j]] + g_N[2] * Nc[2][i[j]])
    return g_P, g_N, g_tex, np.stack(g_bary, 1), cs


def _light_params(lights, n_views):
    from ..lighting import AmbientLights, DirectionalLights, PointLights

    if not isinstance(lights, (PointLights, DirectionalLights, AmbientLights)):
        raise TypeError(f"lights: expected PointLights, DirectionalLights or AmbientLights, got "
                        f"{type(lights)!r}")
    amb = _per_view(lights.ambient_color, n_views, "lights.ambient_color")
    if isinstance(lights, AmbientLights):
        zero = np.zeros((n_views, 3))
        return amb, zero, zero, None, None
    dif = _per_view(lights.diffuse_color, n_views, "lights.diffuse_color")
    spe = _per_view(lights.specular_color, n_views, "lights.specular_color")
    if isinstance(lights, PointLights):
        return amb, dif, spe, _per_view(lights.location, n_views, "lights.location"), None
    return amb, dif, spe, None, _per_view(lights.direction, n_views, "lights.direction")


def phong_vertex_colors(fragments: SoftFragments, mesh: Mesh, vertex_colors, lights, cameras,
                        materials, entries=None) -> PhongColors:
    """Per-entry Phong colours of a mesh with per-vertex colours (PyTorch3D's ``phong_shading``).

    For each fragment entry with (clipped) barycentrics ``b``: world point ``P = sum b_i v_i``,
    normal ``N = sum b_i n_i`` (``n`` PyTorch3D's area-weighted vertex normals), texel
    ``t = sum b_i c_i``; then ``colour = (Ma La + Md Ld max(0, n.l)) t + Ms Ls max(0, r.v)^s
    [n.l > 0]`` with ``n = N/|N|``, ``l`` towards the light, ``v`` towards the camera and
    ``r = 2 (n.l) n - l`` (normalisations with eps 1e-6). No attenuation or shadows.

    Parameters
    ----------
    fragments : SoftFragments
        From :func:`rasterize_soft` of ``mesh``.
    mesh : Mesh
        The rasterized mesh (``V`` vertices).
    vertex_colors : (V, 3) float64
        Per-vertex RGB.
    lights : PointLights, DirectionalLights or AmbientLights
        1 or N lights.
    cameras : camera batch
        The N cameras (their centres give the view directions).
    materials : Materials
        1 or N materials.
    entries : (k,) int64, optional
        Shade only these fragment entries (default: all).

    Returns
    -------
    PhongColors
        Computed in cache-sized chunks on the fragments' thread count.
    """
    fr = _check_fragments(fragments)
    mesh = _check_mesh(mesh)
    cameras = _check_cameras(cameras)
    V = mesh.n_verts
    vcol = as_array(vertex_colors, "vertex_colors", (V, 3))
    if fr._ctx.get("n_verts") != V:
        raise ValueError(f"fragments: rasterized from a mesh with {fr._ctx.get('n_verts')} "
                         f"vertices, mesh has {V}")
    N = fr.n_views
    if len(cameras) not in (1, N):
        raise ValueError(f"cameras: expected 1 or {N} cameras, got {len(cameras)}")
    if entries is None:
        entries = np.arange(len(fr))
    else:
        entries = as_array(entries, "entries", (None,), np.int64)
        if entries.size and (entries.min() < 0 or entries.max() >= len(fr)):
            raise ValueError(f"entries: expected indices in [0, {len(fr)}), got range "
                             f"[{entries.min()}, {entries.max()}]")
    amb, dif, spe, loc, direction = _light_params(lights, N)
    vn, vn_saved = _vertex_normals(mesh.verts, mesh.faces)
    s = {"n_verts": V, "verts": [np.ascontiguousarray(mesh.verts[:, c]) for c in range(3)],
         "vn": vn, "vn_saved": vn_saved,
         "vcol": [np.ascontiguousarray(vcol[:, c]) for c in range(3)],
         "loc": loc, "direction": direction, "La": amb, "Ld": dif, "Ls": spe,
         "Ma": _per_view(materials.ambient_color, N, "materials.ambient_color"),
         "Md": _per_view(materials.diffuse_color, N, "materials.diffuse_color"),
         "Ms": _per_view(materials.specular_color, N, "materials.specular_color"),
         "shininess": _per_view(materials.shininess, N, "materials.shininess"),
         "centres": _per_view(cameras.get_camera_center(), N, "cameras"),
         "n_threads": fr._ctx.get("n_threads", 1)}
    k = len(entries)
    chunks = _chunks(k)
    colors = np.empty((k, 3))
    shade = np.empty((k, 3))
    spec = np.empty((k, 3))
    faces = mesh.faces
    bary = fr.bary

    def one(ci):
        e = entries[chunks[ci]]
        tri = faces[fr.face[e]]
        i = [np.ascontiguousarray(tri[:, j]) for j in range(3)]
        bb = bary[e]
        b = [np.ascontiguousarray(bb[:, j]) for j in range(3)]
        c, sh, sp, saved = _phong_chunk(b, i, fr.view[e], s)
        colors[chunks[ci]], shade[chunks[ci]], spec[chunks[ci]] = c, sh, sp
        return saved

    s["chunk_saved"] = _map_views(one, len(chunks), s["n_threads"])
    s["chunks"] = chunks
    return PhongColors(entries, colors, shade, spec, s)


# ------------------------------------------------------------------------------------------
# Softmax RGB blend
# ------------------------------------------------------------------------------------------


@dataclass(eq=False)
class SoftBlend:
    """Result of :func:`softmax_rgb_blend_soft` with what its vjp needs.

    Attributes
    ----------
    images : (N, H, W, 4) float64
        RGB and alpha.
    weights : (m,) float64
        ``w_k / (sum_j w_j + delta)``: the weight of each entry's colour in its pixel.
    background_weight : (N * H * W,) float64
        ``delta / (sum_j w_j + delta)`` per pixel.
    """

    images: np.ndarray
    weights: np.ndarray
    background_weight: np.ndarray
    _saved: dict = field(default_factory=dict, repr=False)

    def vjp(self, grad_images) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Backward of the blend.

        Parameters
        ----------
        grad_images : (N, H, W, 4) float64

        Returns
        -------
        grad_colors : (m, 3) float64
        grad_dists : (m,) float64
        grad_zbuf : (m,) float64
        """
        s = self._saved
        fr = s["fragments"]
        shape = self.images.shape
        g = as_array(grad_images, "grad_images", shape).reshape(-1, 4)
        gp = fr.global_pixel
        out = self.images.reshape(-1, 4)
        D = s["D"]
        inv_D = 1.0 / D
        g_num = [g[:, c] * inv_D for c in range(3)]           # per pixel
        g_D = -(g[:, 0] * out[:, 0] + g[:, 1] * out[:, 1] + g[:, 2] * out[:, 2]) * inv_D
        w = s["w"]
        cols = s["colors"]
        gn_e = [gn[gp] for gn in g_num]                        # per entry
        g_col = np.empty((len(w), 3))
        for c in range(3):  # colour channels
            g_col[:, c] = w * gn_e[c]
        g_w = gn_e[0] * cols[:, 0] + gn_e[1] * cols[:, 1] + gn_e[2] * cols[:, 2] + g_D[gp]
        bg = s["bg"]
        g_delta = g_num[0] * bg[0] + g_num[1] * bg[1] + g_num[2] * bg[2] + g_D
        p = s["p"]
        gamma = s["gamma"]
        g_p = g_w * s["E"]
        gww = g_w * w
        g_zinv = gww / gamma
        G = len(D)
        g_zm = -np.bincount(gp, gww, G) / gamma
        g_zm += np.where(s["delta_free"], -g_delta * s["delta"] / gamma, 0.0)
        # zm = max(z_inv) (one entry per pixel holds it), clamped at 1e-10
        first = s["first"]
        g_zinv[first] += np.where(s["zm_free"], g_zm, 0.0)[gp[first]]
        g_zbuf = -g_zinv / s["zrange"]
        sigma = s["sigma"]
        # p = sigmoid(-d / sigma); alpha = 1 - prod(1 - p): dA/dd_k = -(p_k / sigma)(1 - A)
        g_d = (g_p * (1.0 - p) + g[gp, 3] * (1.0 - out[gp, 3])) * (-p / sigma)
        return g_col, g_d, g_zbuf


def _softmax_weights(fr: SoftFragments, bp: BlendParams, znear, zfar) -> dict:
    """The colour-independent part of softmax_rgb_blend: weights, normaliser, alpha."""
    H, W = fr.image_size
    G = fr.n_views * H * W
    gp = fr.global_pixel
    zn = np.broadcast_to(np.asarray(znear, np.float64).reshape(-1), (fr.n_views,))[fr.view]
    zf = np.broadcast_to(np.asarray(zfar, np.float64).reshape(-1), (fr.n_views,))[fr.view]
    sigma, gamma = float(bp.sigma), float(bp.gamma)
    p, log1mp = _sigmoid_terms(fr, sigma)
    zrange = zf - zn
    zinv = (zf - fr.depth) / zrange
    zmax = np.full(G, -np.inf)
    np.maximum.at(zmax, gp, zinv)
    # the entry holding each pixel's maximum (torch.max sends the gradient to one of them)
    cand = np.flatnonzero(zinv == zmax[gp])
    _, first_idx = np.unique(gp[cand], return_index=True)
    first = cand[first_idx]
    zm = np.maximum(zmax, _BLEND_EPS)
    zm_free = zmax > _BLEND_EPS
    E = np.exp((zinv - zm[gp]) / gamma)
    w = p * E
    delta_raw = np.exp((_BLEND_EPS - zm) / gamma)
    delta = np.maximum(delta_raw, _BLEND_EPS)
    delta_free = delta_raw > _BLEND_EPS
    D = np.bincount(gp, w, G) + delta
    alpha = -np.expm1(np.bincount(gp, log1mp, G))
    return {"D": D, "w": w, "p": p, "E": E, "gamma": gamma, "sigma": sigma, "delta": delta,
            "delta_free": delta_free, "first": first, "zm_free": zm_free, "zrange": zrange,
            "alpha": alpha}


def softmax_rgb_blend_soft(colors, fragments: SoftFragments,
                           blend_params: BlendParams | None = None, znear=1.0,
                           zfar=100.0) -> SoftBlend:
    """PyTorch3D's ``softmax_rgb_blend`` over the sparse entries, in float64.

    With ``p_k = sigmoid(-d_k / sigma)``, ``z_k = (zfar - zbuf_k) / (zfar - znear)``,
    ``zm = max(max_k z_k, 1e-10)``, ``w_k = p_k exp((z_k - zm) / gamma)`` and
    ``delta = max(exp((1e-10 - zm) / gamma), 1e-10)``::

        RGB = (sum_k w_k c_k + delta bg) / (sum_k w_k + delta),   A = 1 - prod_k (1 - p_k).

    Parameters
    ----------
    colors : (m, 3) float64
        Colour of each entry.
    fragments : SoftFragments
    blend_params : BlendParams, optional
    znear, zfar : float or (N,) float64
        The cameras' clipping planes (from the camera in PyTorch3D's shader).

    Returns
    -------
    SoftBlend
    """
    fr = _check_fragments(fragments)
    bp = _check_blend(blend_params)
    m = len(fr)
    col = as_array(colors, "colors", (m, 3))
    pre = _softmax_weights(fr, bp, znear, zfar)
    H, W = fr.image_size
    G = fr.n_views * H * W
    gp = fr.global_pixel
    w, D, delta = pre["w"], pre["D"], pre["delta"]
    bg = np.asarray(bp.background_color, np.float64)
    out = np.empty((G, 4))
    for c in range(3):  # colour channels
        out[:, c] = (np.bincount(gp, w * col[:, c], G) + delta * bg[c]) / D
    out[:, 3] = pre["alpha"]
    saved = dict(pre, fragments=fr, colors=col, bg=bg)
    return SoftBlend(out.reshape(fr.n_views, H, W, 4), w / D[gp], delta / D, saved)


# ------------------------------------------------------------------------------------------
# Renderers
# ------------------------------------------------------------------------------------------


class SoftGrads(NamedTuple):
    """Gradients of a scalar loss with respect to the inputs of a soft render.

    Attributes
    ----------
    verts : (V, 3) float64
    colors : (V, 3) float64 or None
        Per-vertex colours (Phong renders only).
    """

    verts: np.ndarray
    colors: np.ndarray | None


@dataclass(eq=False)
class SoftRender:
    """Images of a soft render and the means to differentiate them.

    Attributes
    ----------
    images : (N, H, W, 4) float64
        RGBA (RGB = 1 for silhouettes).
    fragments : SoftFragments
    """

    images: np.ndarray
    fragments: SoftFragments
    _kind: str = "silhouette"
    _saved: dict = field(default_factory=dict, repr=False)

    @property
    def silhouettes(self) -> np.ndarray:
        """(N, H, W) float64 alpha channel."""
        return self.images[..., 3]

    def vjp(self, grad_images) -> SoftGrads:
        """Gradient of ``L`` from ``dL/d images``.

        Parameters
        ----------
        grad_images : (N, H, W, 4) or (N, H, W) float64
            dL/d images; an ``(N, H, W)`` array is the gradient on the alpha channel only.

        Returns
        -------
        SoftGrads
        """
        shape = self.images.shape
        g = np.asarray(grad_images, dtype=np.float64)
        if g.shape == shape[:3]:
            g4 = np.zeros(shape)
            g4[..., 3] = g
            g = g4
        g = as_array(g, "grad_images", shape)
        fr = self.fragments
        if self._kind == "silhouette":
            sigma = self._saved["sigma"]
            gd = sigmoid_alpha_blend_vjp(fr, g[..., 3], sigma, self.images[..., 3])
            return SoftGrads(fr.vjp(grad_dists=gd), None)
        blend: SoftBlend = self._saved["blend"]
        shading: PhongColors = self._saved["shading"]
        g_col, g_d, g_z = blend.vjp(g)
        gv, gcol, gb = shading.vjp(g_col[shading.entries])
        gbary = np.zeros((len(fr), 3))
        gbary[shading.entries] = gb
        gv = gv + fr.vjp(grad_dists=g_d, grad_zbuf=g_z, grad_bary=gbary)
        return SoftGrads(gv, gcol)

    def color_operator(self) -> tuple[list, np.ndarray]:
        """The render's RGB as an affine map of the vertex colours (geometry held fixed).

        ``rgb[..., c].ravel() == A[c] @ vertex_colors[:, c] + b[..., c].ravel()`` exactly (up to
        rounding), because the blend weights and the shading do not depend on the colours.

        Returns
        -------
        A : list of 3 scipy.sparse.csr_matrix, each (N * H * W, V)
        b : (N, H, W, 3) float64
            The specular and background part.

        Raises
        ------
        ValueError
            For a silhouette render.
        """
        if self._kind != "phong":
            raise ValueError("color_operator: only a SoftPhongRenderer render has colours")
        fr = self.fragments
        blend: SoftBlend = self._saved["blend"]
        shading: PhongColors = self._saved["shading"]
        V = fr._ctx["n_verts"]
        H, W = fr.image_size
        G = fr.n_views * H * W
        e = shading.entries
        gp = fr.global_pixel[e]
        tri = fr._ctx["faces"][fr.face[e]]
        rows = np.repeat(gp, 3)
        cols = tri.ravel()
        wts = blend.weights[e]
        bary = fr.bary[e]
        mats = []
        for c in range(3):  # colour channels
            data = (wts[:, None] * shading.shade[:, c:c + 1] * bary).ravel()
            mats.append(sp.csr_matrix((data, (rows, cols)), shape=(G, V)))
        bg = np.asarray(self._saved["bg"], np.float64)
        b = np.stack([np.bincount(gp, wts * shading.specular[:, c], G) for c in range(3)], 1)
        b += blend.background_weight[:, None] * bg[None, :]
        return mats, b.reshape(fr.n_views, H, W, 3)


class SoftSilhouetteRenderer:
    """Soft rasterizer + :class:`SoftSilhouetteShader` (the tutorial's ``renderer_silhouette``).

    Parameters
    ----------
    cameras : camera batch
        ``N`` cameras (can be overridden per call).
    raster_settings : SoftRasterizationSettings, optional
    blend_params : BlendParams, optional
        ``sigma`` (default 1e-4).

    Examples
    --------
    >>> from geofit import FoVPerspectiveCameras, ico_sphere, look_at_view_transform
    >>> R, T = look_at_view_transform(2.7, 0.0, [0.0, 90.0])
    >>> r = SoftSilhouetteRenderer(FoVPerspectiveCameras(R=R, T=T),
    ...                            SoftRasterizationSettings.tutorial(32))
    >>> out = r(ico_sphere(2))
    >>> out.images.shape, out.vjp(out.silhouettes).verts.shape
    ((2, 32, 32, 4), (162, 3))
    """

    def __init__(self, cameras=None, raster_settings: SoftRasterizationSettings | None = None,
                 blend_params: BlendParams | None = None):
        self.cameras = cameras
        self.raster_settings = _check_settings(raster_settings)
        self.blend_params = _check_blend(blend_params)

    def __call__(self, mesh: Mesh, cameras=None) -> SoftRender:
        cameras = _check_cameras(cameras if cameras is not None else self.cameras)
        fr = rasterize_soft(mesh, cameras, self.raster_settings)
        sigma = float(self.blend_params.sigma)
        a = sigmoid_alpha_blend(fr, sigma)
        images = np.ones(a.shape + (4,))
        images[..., 3] = a
        return SoftRender(images, fr, "silhouette", {"sigma": sigma})


class SoftPhongRenderer:
    """Soft rasterizer + Phong shading of vertex colours + softmax blend (``SoftPhongShader``).

    Parameters
    ----------
    cameras : camera batch
        ``N`` cameras (can be overridden per call).
    lights : PointLights, DirectionalLights or AmbientLights, optional
        Default ``PointLights()`` (location (0, 1, 0)).
    materials : Materials, optional
        Default ``Materials()``.
    raster_settings : SoftRasterizationSettings, optional
    blend_params : BlendParams, optional

    Notes
    -----
    ``znear`` and ``zfar`` of the blend come from the cameras (1 and 100 for cameras without
    them), as PyTorch3D's ``SoftPhongShader``. Entries whose softmax factor
    ``exp((z_k - zm) / gamma)`` is below 1e-20 (faces far behind the nearest one of their
    pixel; about half of them for a closed mesh) are not shaded: their colour would move the
    pixel by less than 1e-20 of its nearest face's share (1e-16 relative in the worst case of a
    nearest face barely inside the blur radius). Their distances and depths still enter the
    alpha channel and the blend's normaliser exactly.

    Examples
    --------
    >>> import numpy as np
    >>> from geofit import FoVPerspectiveCameras, ico_sphere, look_at_view_transform
    >>> R, T = look_at_view_transform(2.7, 0.0, 0.0)
    >>> r = SoftPhongRenderer(FoVPerspectiveCameras(R=R, T=T),
    ...                       raster_settings=SoftRasterizationSettings.tutorial(16))
    >>> out = r(ico_sphere(2), np.full((162, 3), 0.5))
    >>> g = out.vjp(np.ones(out.images.shape))
    >>> out.images.shape, g.verts.shape, g.colors.shape
    ((1, 16, 16, 4), (162, 3), (162, 3))
    """

    def __init__(self, cameras=None, lights=None, materials=None,
                 raster_settings: SoftRasterizationSettings | None = None,
                 blend_params: BlendParams | None = None):
        from ..lighting import PointLights
        from ..materials import Materials

        self.cameras = cameras
        self.lights = lights if lights is not None else PointLights()
        self.materials = materials if materials is not None else Materials()
        self.raster_settings = _check_settings(raster_settings)
        self.blend_params = _check_blend(blend_params)

    def __call__(self, mesh: Mesh, vertex_colors, cameras=None, lights=None) -> SoftRender:
        cameras = _check_cameras(cameras if cameras is not None else self.cameras)
        lights = lights if lights is not None else self.lights
        fr = rasterize_soft(mesh, cameras, self.raster_settings)
        znear = getattr(cameras, "znear", 1.0)
        zfar = getattr(cameras, "zfar", 100.0)
        # faces far behind the nearest one of their pixel get a softmax weight below
        # _NEGLIGIBLE of its weight: their colour is not computed (it would change the pixel by
        # less than that relative amount)
        E = _softmax_weights(fr, self.blend_params, znear, zfar)["E"]
        active = np.flatnonzero(E >= _NEGLIGIBLE)
        shading = phong_vertex_colors(fr, mesh, vertex_colors, lights, cameras, self.materials,
                                      entries=active)
        colors = np.zeros((len(fr), 3))
        colors[active] = shading.colors
        blend = softmax_rgb_blend_soft(colors, fr, self.blend_params, znear, zfar)
        return SoftRender(blend.images, fr, "phong",
                          {"blend": blend, "shading": shading,
                           "bg": self.blend_params.background_color})
