"""A texture that holds the images: a UV atlas and its texels from one sparse least squares.

* :func:`uv_atlas` -- charts and their packing by xatlas (``xatlas`` on the package index, the
  library Blender and many engines use), at a texel size given in pixels of the views.
* :func:`fit_texture` -- for fixed geometry the hard render
  (:class:`geofit.render.mesh.HardImageLoss`: Phong shading of the first face hit) is affine
  in the texels: a covered ray shows ``shade * texture(uv) + specular``, ``texture(uv)`` a
  bilinear lookup of four texels (PyTorch3D's ``TexturesUV`` sampling, ``align_corners=True``,
  border padding). Stacking every ray of every view gives one sparse operator ``A_c``
  (:func:`texel_operator`) per channel, each ray weighted by how reliably a fitted surface
  shows it the right texel (:func:`ray_reliability`: face-on rays, away from the mesh's
  outline, count most), and the texels minimise the quadratic
  :class:`TextureProblem`: the data term, a within-chart Laplacian (4-neighbours; texels of
  two charts are never linked, so nothing bleeds across a seam: :func:`texel_charts`,
  :func:`chart_laplacian`) that fills texels no view sees and damps the views' disagreement on
  an imperfect surface, and a weak prior (the vertex colours at each texel's surface point)
  for whole charts no view sees. One sparse LU (SuperLU), shared by the channels when their
  shading is the same (grey lights and materials); then four reweighted solves with Cauchy's
  robust loss (rays a fitted geometry gets wrong, e.g. a too-wide outline that sees the
  background, would otherwise pull the texels they hit to their colour); the texels are
  clipped to [0, 1].

The objective's gradient (:meth:`TextureProblem.__call__`) is tested against finite
differences; the solve is exact for it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.ndimage import distance_transform_edt

from .._threads import parallel_map
from .._validate import as_array, check_int, check_positive
from ..ops.topology import face_components
from ..render.mesh.image_term import HardImageLoss, affine_color_operator
from ..structures import Mesh, TexturesUV, as_mesh
from ..structures.visual_hull import pixel_footprint

__all__ = ["TexelCharts", "TextureProblem", "chart_laplacian", "fit_texture", "leave_views_out",
           "ray_reliability", "robust_scale", "texel_charts", "texel_operator", "texture_problem",
           "uv_atlas", "uv_charts"]


def uv_atlas(mesh: Mesh, texel_size: float, *, padding: int = 2,
             max_resolution: int = 2048) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """A UV atlas of ``mesh`` with texels of ``texel_size`` world units (xatlas).

    Parameters
    ----------
    mesh : Mesh
    texel_size : float
        World size of one texel (> 0).
    padding : int
        Texels between charts (>= 1; bilinear lookups near a chart's border read them).
    max_resolution : int
        The atlas is at most this many texels on a side (the texel size grows if needed).

    Returns
    -------
    faces_uvs : (F, 3) int64
        Per face corner, an index into ``verts_uvs`` (faces in the mesh's order).
    verts_uvs : (T, 2) float64
        UV coordinates in [0, 1] (u to the right, v up).
    size : (2,) int
        ``(H, W)`` of the texture image.
    """
    import xatlas  # imported when an atlas is built (a compiled extension)

    mesh = as_mesh(mesh, "mesh")
    h = check_positive(texel_size, "texel_size")
    atlas = xatlas.Atlas()
    atlas.add_mesh(mesh.verts.astype(np.float32), mesh.faces.astype(np.uint32))
    po = xatlas.PackOptions()
    po.padding = int(padding)
    po.bilinear = True
    po.texels_per_unit = float(1.0 / h)
    po.resolution = 0
    atlas.generate(pack_options=po)
    if max(atlas.width, atlas.height) > max_resolution:
        po.texels_per_unit = 0.0
        po.resolution = int(max_resolution)
        atlas = xatlas.Atlas()
        atlas.add_mesh(mesh.verts.astype(np.float32), mesh.faces.astype(np.uint32))
        atlas.generate(pack_options=po)
    _, idx, uvs = atlas[0]
    W, H = int(atlas.width), int(atlas.height)
    uv = uvs.astype(np.float64)
    # xatlas's uvs are divided by the atlas size with texel centres at half-integers; this
    # texture's sampling puts texel centres at u (W - 1) (align_corners=True): map them
    px = uv * [W, H] - 0.5
    uv = np.stack([px[:, 0] / (W - 1), 1.0 - px[:, 1] / (H - 1)], 1)
    return idx.astype(np.int64), uv, (H, W)


def _bilinear(uv: np.ndarray, size: tuple[int, int]):
    """(k, 4) texel ids and (k, 4) weights of the bilinear lookups at ``uv (k, 2)``
    (``align_corners=True``, border padding)."""
    H, W = size
    x = np.clip(uv[:, 0] * (W - 1), 0.0, W - 1)
    y = np.clip((1.0 - uv[:, 1]) * (H - 1), 0.0, H - 1)
    x0 = np.minimum(np.floor(x).astype(np.int64), max(W - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.int64), max(H - 2, 0))
    fx, fy = x - x0, y - y0
    x1, y1 = np.minimum(x0 + 1, W - 1), np.minimum(y0 + 1, H - 1)
    ids = np.stack([y0 * W + x0, y0 * W + x1, y1 * W + x0, y1 * W + x1], 1)
    w = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
    return ids, w


def texel_operator(loss, mesh: Mesh, faces_uvs, verts_uvs, size, hits=None):
    """``(A, y)``: the loss's residual as an affine map of the texels (geometry fixed).

    ``loss(mesh with TexturesUV(t)) = 1/(N H W) sum_c |A[c] t[..., c].ravel() - y[:, c]|^2``.

    Parameters
    ----------
    loss : HardImageLoss
    mesh : Mesh
    faces_uvs : (F, 3) int64
    verts_uvs : (T, 2) float64
    size : (2,) int
        ``(H, W)`` of the texture.
    hits : PixelRayHits, optional
        ``loss.pixel_hits(mesh)``, if already cast.

    Returns
    -------
    A : list of 3 scipy.sparse.csr_matrix, each (R, H W)
    y : (R, 3) float64
    """

    h = loss.shaded_hits(mesh, hits)
    uv = np.einsum("kj,kjd->kd", h.bary, verts_uvs[faces_uvs[h.face]])
    ids, w = _bilinear(uv, size)
    hit_of = np.repeat(np.arange(len(h.ray)), 4)
    return affine_color_operator(loss, h, hit_of, ids.ravel(), w.ravel(), size[0] * size[1])


def ray_reliability(loss, mesh: Mesh, hits=None, *, outline_weight: float = 0.03,
                    outline_px: float = 1.0) -> np.ndarray:
    """(R,) float64 weight of every ray of ``loss`` in the texels' data term, by how far an
    error of the geometry moves what the ray sees.

    A covered ray weighs ``|cos theta|`` (``theta`` between the ray and the normal of the face
    it hits): a surface off the true one by ``d`` shows the ray the true texture ``d tan
    theta`` away, so grazing rays carry the most misplaced colour. A covered ray within
    ``outline_px`` pixels of the mesh's own outline in its view (the distance to the nearest
    ray that misses) is further multiplied by ``outline_weight``: there a fitted outline that
    is off by a fraction of a pixel sees the background or the other side of the object.
    Rays that miss weigh 1 (they hold no texel).

    Parameters
    ----------
    loss : HardImageLoss
    mesh : Mesh
    hits : PixelRayHits, optional
        ``loss.pixel_hits(mesh)``, if already cast.
    outline_weight : float
        In [0, 1].
    outline_px : float
        Width of the outline band in pixels (>= 0).

    Returns
    -------
    (R,) float64
        In [0, 1]; ``R = N H W s^2`` rays in the loss's order.

    Raises
    ------
    ValueError
        If ``outline_weight`` is not in [0, 1] or ``outline_px`` is negative.
    """
    mesh = as_mesh(mesh, "mesh")
    w_out = check_positive(outline_weight, "outline_weight", strict=False)
    if w_out > 1.0:
        raise ValueError(f"outline_weight: expected a value in [0, 1], got {w_out}")
    band = check_positive(outline_px, "outline_px", strict=False) * loss.supersample
    h = loss.pixel_hits(mesh) if hits is None else hits
    N = len(loss.cameras)
    sH, sW = (k * loss.supersample for k in loss.image_size)
    n = mesh.face_normals[h.face]
    d = h.dirs / np.linalg.norm(h.dirs, axis=1, keepdims=True)
    w = np.ones(N * sH * sW)
    w[h.ray] = np.abs(np.einsum("kd,kd->k", n, d))
    covered = np.zeros(N * sH * sW, bool)
    covered[h.ray] = True
    dist = np.stack([distance_transform_edt(c) for c in covered.reshape(N, sH, sW)])  # views
    near = np.zeros(N * sH * sW, bool)
    near[h.ray] = dist.reshape(-1)[h.ray] <= band
    w[near] *= w_out
    return w


def _uv_pixels(faces_uvs, verts_uvs, size) -> np.ndarray:
    """(F, 3, 2) texel coordinates ``(x, y)`` of the face corners (texel centres at integers,
    ``align_corners=True``: ``x = u (W - 1)``, ``y = (1 - v)(H - 1)``)."""
    H, W = size
    uv = verts_uvs[faces_uvs]
    return np.stack([uv[..., 0] * (W - 1), (1.0 - uv[..., 1]) * (H - 1)], axis=-1)


def uv_charts(faces_uvs: np.ndarray) -> np.ndarray:
    """(F,) int64 chart of every face: faces that share a UV vertex are in one chart."""
    return face_components(faces_uvs)


@dataclass(frozen=True)
class TexelCharts:
    """Which chart of a UV atlas each texel belongs to, and where it lies on the surface.

    A texel is *read* by a face when a bilinear lookup at some point of the face's UV triangle
    gives it a non-zero weight (its centre lies less than one texel from the point along both
    axes); it then belongs to that face's chart.

    Attributes
    ----------
    chart : (H W,) int64
        The chart that reads each texel (row-major), -1 if no face reads it (free space).
    face : (H W,) int64
        The face of that chart nearest to the texel centre, -1 if none.
    bary : (H W, 3) float64
        Barycentrics of the point of ``face`` nearest to the texel centre (clamped; 0 where
        ``face`` is -1).
    n_shared : int
        Texels read by more than one chart: a lookup there would mix two charts (bleed). 0 for
        an atlas packed with bilinear padding.
    """

    chart: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    n_shared: int


def texel_charts(faces_uvs, verts_uvs, size) -> TexelCharts:
    """The chart and surface point of every texel of a ``(H, W)`` atlas (see
    :class:`TexelCharts`).

    Parameters
    ----------
    faces_uvs : (F, 3) int64
    verts_uvs : (T, 2) float64
    size : (2,) int
        ``(H, W)``.

    Returns
    -------
    TexelCharts

    Notes
    -----
    Exact: a texel centre ``q`` is read by a triangle when the open square of half-side one
    texel around ``q`` meets it, decided by the separating-axis test (the square's two axes
    and the triangle's three edge normals).
    """
    H, W = (int(s) for s in size)
    P = _uv_pixels(np.asarray(faces_uvs, np.int64), np.asarray(verts_uvs, np.float64), (H, W))
    lo, hi = P.min(axis=1), P.max(axis=1)
    # texel centres c with lo - 1 < c < hi + 1 (the square axes), clipped to the image
    x0 = np.clip(np.floor(lo[:, 0] - 1.0).astype(np.int64) + 1, 0, W)
    x1 = np.clip(np.ceil(hi[:, 0] + 1.0).astype(np.int64) - 1, -1, W - 1)
    y0 = np.clip(np.floor(lo[:, 1] - 1.0).astype(np.int64) + 1, 0, H)
    y1 = np.clip(np.ceil(hi[:, 1] + 1.0).astype(np.int64) - 1, -1, H - 1)
    nx, ny = np.maximum(x1 - x0 + 1, 0), np.maximum(y1 - y0 + 1, 0)
    cnt = nx * ny
    fid = np.repeat(np.arange(len(P)), cnt)
    local = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    q = np.stack([x0[fid] + local % nx[fid], y0[fid] + local // nx[fid]], 1).astype(np.float64)
    tri = P[fid]
    read = np.ones(len(fid), bool)
    for j in range(3):  # the triangle's edges: separated when the square lies beyond one
        a, b, c = tri[:, j], tri[:, (j + 1) % 3], tri[:, (j + 2) % 3]
        n = np.stack([a[:, 1] - b[:, 1], b[:, 0] - a[:, 0]], 1)
        n *= np.where(np.einsum("kd,kd->k", n, c - a) > 0, -1.0, 1.0)[:, None]  # outward
        read &= np.einsum("kd,kd->k", n, q - a) - np.abs(n).sum(1) < 0.0
    fid, q, tri = fid[read], q[read], tri[read]
    texel = q[:, 1].astype(np.int64) * W + q[:, 0].astype(np.int64)
    chart_of_face = uv_charts(faces_uvs)
    ch = chart_of_face[fid]
    pairs = np.unique(np.stack([texel, ch], 1), axis=0)
    n_charts = np.bincount(pairs[:, 0], minlength=H * W)
    # barycentrics of the texel centre; the face with the largest smallest one is the nearest
    e1, e2, d = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], q - tri[:, 0]
    den = e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1]
    den = np.where(np.abs(den) > 1e-300, den, 1e-300)
    b1 = (d[:, 0] * e2[:, 1] - e2[:, 0] * d[:, 1]) / den
    b2 = (e1[:, 0] * d[:, 1] - d[:, 0] * e1[:, 1]) / den
    bary = np.stack([1.0 - b1 - b2, b1, b2], 1)
    order = np.lexsort((-bary.min(axis=1), texel))
    first = order[np.unique(texel[order], return_index=True)[1]]
    chart = np.full(H * W, -1, np.int64)
    face = np.full(H * W, -1, np.int64)
    out_bary = np.zeros((H * W, 3))
    chart[texel[first]] = ch[first]
    face[texel[first]] = fid[first]
    b = np.clip(bary[first], 0.0, None)
    out_bary[texel[first]] = b / b.sum(axis=1, keepdims=True)
    return TexelCharts(chart, face, out_bary, int(np.count_nonzero(n_charts > 1)))


def chart_laplacian(chart: np.ndarray, size) -> sp.csr_matrix:
    """(H W, H W) graph Laplacian of the 4-neighbour texel pairs within one chart.

    Parameters
    ----------
    chart : (H W,) int64
        :attr:`TexelCharts.chart` (-1: free texels, coupled to nothing).
    size : (2,) int
        ``(H, W)``.

    Returns
    -------
    scipy.sparse.csr_matrix
        Symmetric, zero row sums, ``t^T L t = sum over linked pairs (t_i - t_j)^2``.
    """
    H, W = (int(s) for s in size)
    idx = np.arange(H * W).reshape(H, W)
    i = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
    j = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
    keep = (chart[i] == chart[j]) & (chart[i] >= 0)
    i, j = i[keep], j[keep]
    A = sp.coo_matrix((np.ones(len(i)), (i, j)), shape=(H * W, H * W))
    A = (A + A.T).tocsr()
    return (sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A).tocsr()


@dataclass
class TextureProblem:
    """The texels' objective, one channel at a time (the channels share the robust weights).

    ``E(t) = sum_i rho(|r_i(t)|) + sum_c s_c (lambda t_c^T L t_c + sum_k w_k (t_kc - p_kc)^2)``
    with ``r_i = (A_c t_c - y_c)_i`` the three-channel residual of ray ``i``, ``rho(r) = r^2``
    (least squares) or, with a ``robust_scale`` ``C``, Cauchy's ``rho(r) = C^2 log(1 + r^2 /
    C^2)``; ``s_c`` the mean diagonal of ``A_c^T A_c`` over the texels some ray sees (so
    ``lambda`` and ``w`` are relative to the weight of a seen texel), ``L`` the within-chart
    Laplacian (:func:`chart_laplacian`) and ``p`` the prior (e.g. vertex colours at the texels'
    surface points) weighted by ``w``. Its gradient is
    ``2 A_c^T (u * (A_c t_c - y_c)) + 2 s_c (lambda L t_c + w (t_c - p_c))`` with the ray
    weights ``u_i = rho'(|r_i|) / (2 |r_i|)`` (:meth:`ray_weights`: 1, or ``1 / (1 + |r_i|^2 /
    C^2)``). :meth:`solve` minimises the quadratic with the ray weights held fixed (exactly the
    least-squares minimum when they are 1); :meth:`solve_robust` iterates it (iteratively
    reweighted least squares, a majorise-minimise scheme: ``E`` never increases).

    Attributes
    ----------
    A : list of 3 scipy.sparse.csr_matrix, each (R, n)
    y : (R, 3) float64
    L : (n, n) scipy.sparse.csr_matrix
    smoothness : float
        ``lambda``.
    weights : (n,) float64
        ``w``.
    prior : (n, 3) float64
        ``p``.
    robust_scale : float or None
        ``C`` (None: least squares).
    """

    A: list
    y: np.ndarray
    L: sp.csr_matrix
    smoothness: float
    weights: np.ndarray
    prior: np.ndarray
    robust_scale: float | None = None

    def scale(self, c: int) -> float:
        """``s_c``; ValueError if no ray sees a texel."""
        d = np.asarray(self.A[c].multiply(self.A[c]).sum(axis=0)).ravel()
        if not np.any(d > 0):
            raise ValueError("images: no view sees the mesh (no texel is constrained)")
        return float(d[d > 0].mean())

    def residuals(self, t: np.ndarray) -> np.ndarray:
        """(R, 3) float64 residuals ``A_c t_c - y_c`` of texels ``t (n, 3)``."""
        return np.stack([self.A[c] @ t[:, c] - self.y[:, c] for c in range(3)], axis=1)

    def ray_weights(self, t: np.ndarray) -> np.ndarray:
        """(R,) float64 IRLS weights ``u`` at texels ``t (n, 3)`` (ones for least squares)."""
        r = self.residuals(t)
        if self.robust_scale is None:
            return np.ones(len(r))
        return 1.0 / (1.0 + np.einsum("rc,rc->r", r, r) / self.robust_scale ** 2)

    def __call__(self, t: np.ndarray) -> tuple[float, np.ndarray]:
        """``(E(t), dE/dt)`` for texels ``t (n, 3)``."""
        r = self.residuals(t)
        r2 = np.einsum("rc,rc->r", r, r)
        if self.robust_scale is None:
            value, u = float(r2.sum()), np.ones(len(r))
        else:
            C2 = self.robust_scale ** 2
            value, u = float(C2 * np.log1p(r2 / C2).sum()), 1.0 / (1.0 + r2 / C2)
        grad = np.empty_like(t)
        for c in range(3):  # channels
            s, tc = self.scale(c), t[:, c]
            Lt, dp = self.L @ tc, tc - self.prior[:, c]
            value += s * (self.smoothness * (tc @ Lt) + self.weights @ (dp * dp))
            grad[:, c] = 2.0 * (self.A[c].T @ (u * r[:, c]) + s * (self.smoothness * Lt
                                                                   + self.weights * dp))
        return float(value), grad

    def solve(self, ray_weights=None) -> np.ndarray:
        """(n, 3) float64 minimiser of the quadratic with ray weights ``u`` (R,) held fixed
        (default 1: the least-squares minimum); one sparse LU per distinct channel
        operator."""
        n = self.L.shape[0]
        out = np.empty((n, 3))
        U = None if ray_weights is None else sp.diags(np.asarray(ray_weights, np.float64))
        solve = None
        for c in range(3):  # colour channels
            if solve is None or not np.array_equal(self.A[c].data, self.A[c - 1].data):
                s = self.scale(c)
                UA = self.A[c] if U is None else (U @ self.A[c]).tocsr()
                lhs = ((self.A[c].T @ UA) + (s * self.smoothness) * self.L
                       + sp.diags(s * self.weights)).tocsc()
                solve = spla.factorized(lhs)  # shared by channels of equal shading
            uy = self.y[:, c] if ray_weights is None else ray_weights * self.y[:, c]
            out[:, c] = solve(self.A[c].T @ uy + s * self.weights * self.prior[:, c])
        return out

    def solve_robust(self, rounds: int, t=None) -> np.ndarray:
        """(n, 3) float64 texels after ``rounds`` reweighted solves from ``t`` (default: the
        least-squares minimum), each with the ray weights of the previous texels."""
        t = self.solve() if t is None else t
        for _ in range(rounds):  # IRLS rounds
            t = self.solve(self.ray_weights(t))
        return t


def texture_problem(loss, mesh: Mesh, faces_uvs, verts_uvs, size, *, smoothness: float = 1e-2,
                    prior=None, prior_weight: float = 1e-3, ray_weights=None,
                    hits=None) -> tuple[TextureProblem, TexelCharts]:
    """The texels' objective (:class:`TextureProblem`) for ``mesh`` under ``loss``.

    Parameters
    ----------
    loss : HardImageLoss
    mesh : Mesh
    faces_uvs, verts_uvs, size
        The atlas (:func:`uv_atlas`).
    smoothness : float
        ``lambda``.
    prior : (V, 3) float64, optional
        Vertex colours that texels no view sees fall back to (weight ``prior_weight``);
        without it every texel is pulled to grey (0.5) with weight 1e-9 only.
    prior_weight : float
        ``w`` of the texels a chart reads; free texels (read by no face) get 1e-9 and the
        prior's mean.
    ray_weights : (R,) float64, optional
        Non-negative weight of every ray's squared residual (e.g. :func:`ray_reliability`):
        the rows of ``A_c`` and ``y`` are scaled by its square root. Default 1.
    hits : PixelRayHits, optional
        ``loss.pixel_hits(mesh)``, if already cast.

    Returns
    -------
    problem : TextureProblem
    charts : TexelCharts

    Raises
    ------
    ValueError
        If ``smoothness`` or ``prior_weight`` is not positive, ``prior`` is not ``(V, 3)`` or
        ``ray_weights`` is not ``(R,)``, finite and non-negative.
    """
    smoothness = check_positive(smoothness, "smoothness")
    A, y = texel_operator(loss, mesh, faces_uvs, verts_uvs, size, hits)
    if ray_weights is not None:
        u = as_array(ray_weights, "ray_weights", (y.shape[0],))
        if np.any(u < 0):
            raise ValueError("ray_weights: expected non-negative weights, got a negative one")
        r = sp.diags(np.sqrt(u))
        A, y = [(r @ a).tocsr() for a in A], y * np.sqrt(u)[:, None]
    charts = texel_charts(faces_uvs, verts_uvs, size)
    n = size[0] * size[1]
    used = charts.face >= 0
    p = np.empty((n, 3))
    w = np.full(n, 1e-9)
    if prior is not None:
        pv = np.clip(as_array(prior, "prior", (mesh.n_verts, 3)), 0.0, 1.0)
        p[used] = np.einsum("kj,kjc->kc", charts.bary[used], pv[mesh.faces[charts.face[used]]])
        p[~used] = pv.mean(axis=0)
        w[used] = check_positive(prior_weight, "prior_weight")
    else:
        p[:] = 0.5
    L = chart_laplacian(charts.chart, size)
    return TextureProblem(A, y, L, float(smoothness), w, p), charts


def robust_scale(problem: TextureProblem, t: np.ndarray, k: float) -> float:
    """Cauchy's ``C``: ``k`` robust standard deviations (1.4826 times the median) of the
    residual norms of the rays that hit the mesh at texels ``t (n, 3)``, at least 1e-3."""
    hit = np.diff(problem.A[0].indptr) > 0
    if not np.any(hit):
        raise ValueError("images: no view sees the mesh (no texel is constrained)")
    r = np.linalg.norm(problem.residuals(t)[hit], axis=1)
    return max(float(k) * 1.4826 * float(np.median(r)), 1e-3)


def leave_views_out(problem: TextureProblem, n_views: int, n_folds: int,
                    ray_weights=None) -> float:
    """Squared error of texels solved without each fold of views, on that fold's rays.

    The rays are ordered view by view (``R = n_views`` blocks of equal size, as
    :func:`texel_operator` makes them); view ``v`` is in fold ``v % n_folds``. For each fold
    the texels minimise the quadratic of :meth:`TextureProblem.solve` with the ray weights
    ``ray_weights`` (default 1) and the fold's rays at weight 0; the fold's error is the plain
    ``sum over its rays and channels of (A_c t_c - y_c)^2`` (its views' render error).

    Parameters
    ----------
    problem : TextureProblem
    n_views : int
    n_folds : int
        2 to ``n_views``.
    ray_weights : (R,) float64, optional

    Returns
    -------
    float
        The summed error over the folds.

    Raises
    ------
    ValueError
        If ``n_folds`` is not in ``[2, n_views]`` or the rays do not split into ``n_views``
        equal blocks.
    """
    n_views = check_int(n_views, "n_views")
    n_folds = check_int(n_folds, "n_folds", 2)
    R = problem.A[0].shape[0]
    if n_folds > n_views:
        raise ValueError(f"n_folds: expected at most n_views = {n_views}, got {n_folds}")
    if R % n_views:
        raise ValueError(f"problem: expected its {R} rays in {n_views} equal blocks (views)")
    fold = (np.arange(R) // (R // n_views)) % n_folds
    u = np.ones(R) if ray_weights is None else np.asarray(ray_weights, np.float64)

    def error(k):  # fold k's render error (SuperLU releases the GIL: folds run in parallel)
        r = problem.residuals(problem.solve(np.where(fold == k, 0.0, u)))[fold == k]
        return float(np.einsum("rc,rc->", r, r))

    total = 0.0
    for e in parallel_map(error, range(n_folds)):  # summed in fold order
        total += e
    return total


def fit_texture(mesh, cameras, images, *, lights=None, materials=None, masks=None,
                background=(1.0, 1.0, 1.0), texel_px: float = 1.0, smoothness: float = 1e-2,
                prior=None, prior_weight: float = 1e-5, outline_weight: float | None = 0.03,
                robust: float | None = 2.0, robust_rounds: int = 4, check_folds: int = 4,
                supersample: int = 1, max_resolution: int = 2048) -> TexturesUV:
    """A UV texture for ``mesh`` from images, by sparse (robust) least squares.

    Parameters
    ----------
    mesh : Mesh
        The geometry (held fixed).
    cameras : CamerasBase
        ``N`` cameras.
    images : (N, H, W, 3) float64
        The views (a fourth channel is ignored).
    lights, materials, masks, background, supersample
        As :class:`geofit.render.mesh.HardImageLoss` (the lights the images were shot with;
        ``AmbientLights()`` for unlit colour).
    texel_px : float
        Texel size in pixels of the views at the object's centre (the median over the views
        of a pixel's footprint there): the atlas holds about as many texels as the views have
        pixels on the surface. Default 1; on the cow's 20 views of 128 px, 0.5 gained 0.2 dB
        of held-out PSNR for 3.5 times the time on the true surface and lost 0.4 dB on a
        fitted one.
    smoothness : float
        ``lambda`` of :class:`TextureProblem`: weight of the within-chart texel Laplacian,
        relative to the mean data weight of a seen texel (fills texels no view sees, damps
        the disagreement of views on an imperfect surface).
    prior : (V, 3) float64, optional
        Vertex colours for texels no view sees (see :func:`texture_problem`).
    prior_weight : float
        Weight of the prior, relative to a seen texel's data weight (default 1e-5: on a
        fitted surface the blurred vertex colours pulled seen texels too; 1e-3 cost the cow
        0.1-0.3 dB).
    outline_weight : float or None
        Rays weighted by :func:`ray_reliability` (``|cos theta|`` to the face hit, times
        ``outline_weight`` within one pixel of the mesh's outline in the ray's view), so that
        the views that see a surface face-on and away from its outline decide its texels;
        None: every ray weighs 1. On the default fit's geometry (see Notes) this with
        ``check_folds=4`` raised the cow's held-out PSNR 27.12 -> 27.45 dB.
    robust : float or None
        Cauchy's scale ``C`` of the data term (:class:`TextureProblem`) in robust standard
        deviations (1.4826 times the median) of the rays' residuals after the least-squares
        solve (at least 1e-3); None: least squares. Rays the geometry gets wrong (a fitted
        outline a pixel too wide sees the background; a surface off the true one sees the
        wrong texel) disagree with the other views; least squares pulls the texels they hit
        towards them (on the outline, towards the background: a pale rim that held-out views
        see inside the object). Default 2 (see Notes).
    robust_rounds : int
        Reweighted solves after the least-squares one (:meth:`TextureProblem.solve_robust`).
    check_folds : int
        With ``robust``: the robust texels are kept only if they predict views left out of
        the solve no worse than least squares does (:func:`leave_views_out`, this many folds
        of views, the robust weights of the full solve held; 0: no check). On an exact
        geometry Cauchy's scale (a multiple of the median residual, there ~0) drops the rays
        that carry the texture's sharp detail (the true cow: 34.1 dB least squares, 29.0
        robust); the check keeps least squares there. Default 4: with 2 folds each solve
        sees half the views and the check kept least squares where the robust texels
        predicted the held-out views better (cow 27.12 against 27.29 dB).
    max_resolution : int
        Largest side of the texture image.

    Returns
    -------
    TexturesUV
        Texels clipped to [0, 1].

    Raises
    ------
    ValueError
        If the images do not match the cameras, ``texel_px``, ``smoothness`` or ``robust`` is
        not positive, ``robust_rounds`` is negative, ``outline_weight`` is not in [0, 1], or
        no view sees the mesh.

    Notes
    -----
    Held-out PSNR on the default fit's geometry of ``benchmarks/fit_views.py --shapes`` (20
    views of 128 px, 16 held-out; benchmarks/results/fit_views_texture.md): least squares
    scored 0.9-1.6 dB below the vertex colours on five shapes (fandisk 26.29 against 27.22,
    torus 29.83 against 31.37), because the rays of the fitted outline (a pixel too wide) see
    the background and paint pale rims; the default is at or above least squares on all 11
    shapes and above the vertex colours on 9 (fandisk 27.34, torus 31.64; the ogre and the
    thin plate 0.03-0.04 dB below them). On the exact geometry the check keeps least squares
    (the cow: 34.08 dB; the robust texels alone 28.97).

    Where the cow's held-out error lies (default fit, 16 held-out views, texture before the
    ray weights: 27.12 dB): 60 % on the 889 outline pixels where the fit's coverage differs
    from the truth's (612 covered too wide, 277 missed; without them 31.1 dB), 3 % on
    interior pixels that read a chart's border texels, the rest inside. On the true surface
    the same solve gives 34.1 dB; a texture solved on the held-out views themselves, on the
    fitted surface, 28.7 dB (texel_px 0.5: 28.8): what any texture on that geometry can
    reach. With the ray weights: cow 27.45 dB, teapot 30.45 -> 30.50, fandisk 26.95 -> 27.23,
    true cow 34.14 -> 34.13.

    The same split on the session-11 default fit (hull_close_handles, 27.15 dB, summed squared
    error 506 over the 16 views; 28 dB is 415): 334 on the 945 pixels whose coverage differs
    from the truth's (635 too wide, 310 missed; 88 % of them within one pixel of the true
    outline), 172 on pixels both cover. The texture solved on the held-out views themselves
    (least squares, no ray weights) scores 28.42 dB on that geometry and still leaves 301 on the
    mismatched pixels: no texture reaches 28 dB there; the outline must. Measured, none changes
    that: ``smoothness`` 3e-3 / 3e-2 / 0.1 / 0.3 (27.04 / 27.21 / 27.15 / 26.85 dB),
    ``texel_px`` 0.7 (27.10), the outline band 2 px (27.08), ``|cos theta|**2`` ray weights
    (cow 27.23 but fandisk 27.23 -> 27.08), down-weighting rays beside depth discontinuities
    (27.17); the robust texels (fold check off) 26.58.
    """
    mesh = as_mesh(mesh, "mesh")
    loss = HardImageLoss(cameras, images, lights=lights, materials=materials, masks=masks,
                         background=background, supersample=supersample, edges=False)
    texel_px = check_positive(texel_px, "texel_px")
    lam = check_positive(smoothness, "smoothness")
    hits = loss.pixel_hits(mesh)
    u = None if outline_weight is None else ray_reliability(loss, mesh, hits,
                                                            outline_weight=outline_weight)
    k = None if robust is None else check_positive(robust, "robust")
    rounds = check_int(robust_rounds, "robust_rounds", 0)
    folds = check_int(check_folds, "check_folds", 0)
    px = pixel_footprint(cameras, loss.image_size, mesh.verts.mean(axis=0))
    faces_uvs, verts_uvs, size = uv_atlas(mesh, texel_px * px, max_resolution=max_resolution)
    problem, _ = texture_problem(loss, mesh, faces_uvs, verts_uvs, size, smoothness=lam,
                                 prior=prior, prior_weight=prior_weight, ray_weights=u,
                                 hits=hits)
    t = problem.solve()
    if k is not None and rounds:
        problem.robust_scale = robust_scale(problem, t, k)
        t_rob = problem.solve_robust(rounds, t)
        n = len(cameras)
        folds = min(folds, n) if n >= 2 else 0
        if not folds or (leave_views_out(problem, n, folds, problem.ray_weights(t_rob))
                         <= leave_views_out(problem, n, folds)):
            t = t_rob
    maps = np.clip(t.reshape(size[0], size[1], 3), 0.0, 1.0)
    return TexturesUV(maps, faces_uvs, verts_uvs)

