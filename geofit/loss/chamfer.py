"""Chamfer distance between point clouds with analytic gradients (PyTorch3D's ``chamfer_distance``).

For every point of ``x`` the nearest point of ``y`` is found (and vice versa) by an exact
search (a KD-tree, Open3D's or scipy's, and for far queries a witness-pruned block search, see
below); the distances are then recomputed in float64 from
the coordinate differences, so values and gradients are exact for the neighbours found. The choice
of neighbour is piecewise constant: no gradient flows through it (as in PyTorch3D, whose
``knn_points`` indices are constants), and the gradient is exact wherever the nearest neighbours
are unique.

Gradients (squared distances, ``point_reduction="mean"``, one direction): with ``j = nn(i)``,
``d/dx_i mean_i |x_i - y_j|^2 = 2 (x_i - y_j) / n_x`` and ``-2 (x_i - y_j) / n_x`` is scattered onto
``y_j`` (``np.bincount``); the other direction is the mirror image. The two directions are
**summed** (PyTorch3D's convention): one point at (0, 0) against one at (3, 0) gives 18.

Search backends (``backend=``): ``"open3d"`` is Open3D's ``core.nns.NearestNeighborSearch``
(``knn_index`` + ``knn_search`` with k = 1 on float64 tensors, on all cores); ``"pykdtree"`` is
pykdtree's ``KDTree`` (float64; its OpenMP-parallel queries are held to one thread, which was
faster under load); ``"scipy"`` is
scipy's ``cKDTree(balanced_tree=False, compact_nodes=False)``, whose queries of fewer than 4096
points run on one thread (scipy starts its worker threads on every call, which costs more than it
saves there: 0.15 ms against 2 ms for 500 points). From 20 000 points the tree is built over the
points sorted along a Z-order curve and the queries are searched in that order too
(:func:`morton_order`; the answers are mapped back), which saves cache misses: at 1M points a
side on overlapping clouds it took Open3D's search from 62 s to 24 s and scipy's from 54 s to
29 s, sorting included (load about 15). Every path is
exact (tests compare them with brute force, and ``benchmarks/chamfer.py`` checks that every
method returns scipy's distances); only scipy has the L1 metric of ``norm=1``. On the deform
tutorial's clouds (5000 samples of the dolphin and of the fitted sphere, one thread, CPU time
under load ~14) pykdtree built a tree in 0.40-0.53 ms and queried 5000 points in 2.1-2.6 ms,
scipy's unbalanced tree 0.78-0.81 ms and 4.1-6.6 ms (leaf sizes 4 to 32 and the balanced or
compact variants were not faster; Open3D's build and query 5.7 ms); with the sphere still
around the dolphin (the tutorial's start) 31-35 ms against 55 ms per query. Over the
tutorial's 2000 steps this took chamfer_distance from 15.6 to 10.2 CPU ms per step, with the
same neighbours (the fitted vertices came out bit-identical).

Far queries: an exact KD-tree, Open3D's included, slows down when the two clouds are apart. To
prove a nearest point it opens every node whose box is closer than that point, and when a
surface faces the query from afar (a dolphin point 2 units from a sphere's side, or near the
centre of a surrounding sphere) a box tilted against the surface reaches towards the query by a
fraction of its size times the distance: a wide patch of the surface must be opened. At 1M points
a side scipy's search took 38 s on the clouds 2 units apart against 2.5 s overlapping (one
direction, load ~4), and a per-query bound equal to the true distance saved only 25% at 100k
(the work is the proof, not the finding). ``"auto"`` therefore proves nearness per block of
queries with a witness point instead (:mod:`geofit.loss._chamfer_search`: the bisector test
``|p - q0|^2 <= |w - q0|^2 + 2 sum_i h_i |p_i - w_i|`` over a Morton octree of the cloud, with
oriented boxes at its finest levels), which cuts a far front to a patch about the block's size
and stays exact (every pruning test keeps a margin for rounding; ties go to the point first in
Z-order).

``"auto"``, the default: below 20 000 points a side pykdtree's tree (Open3D's tensor set-up
dominates there, and pykdtree is twice as fast as scipy's; ``norm=1`` takes scipy's). From 20 000, a Z-order
sample of 2048 queries is located in the cloud's octree; if 5% or more of them lie in empty
cells of about 64 finest cells (the queries are far), the witness search runs, handing the
blocks it finds near, or with too many candidates, to a KD-tree (Open3D's when they are 20 000
or more and at least 10% of the queries, scipy's otherwise); else scipy's tree answers all
queries (as fast as Open3D's there: 2.4-2.5 s per direction at 1M points, load ~19). Measured
end to end by ``benchmarks/chamfer.py`` (``tables.default_ratios`` of
``benchmarks/results/chamfer.json``; 2 shared cores, so read the ratios, and the CPU-time
ratios, rather than seconds): at 1M points a side two samplings of the dolphin took 9.1 s, the
sphere moved 3 units clear of it 16.3 s (1.79 times; CPU time 1.82 times; before: more than 150
s) and the tutorial's start (the dolphin inside the sphere) more than 150 s (median of 3 runs,
load about 22; at 100k: 0.61 s, 1.5 s and 8.0 s). The tutorial's start stays slow: a dolphin
point near the sphere's centre is almost equally far from a large part of the sphere, so any
exact search must look at it (the witness search hands those blocks to the KD-tree).
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from pykdtree.kdtree import KDTree as PyKDTree
from scipy.spatial import cKDTree

from .._threads import in_worker, one_openmp_thread, parallel_map
from .._foreign import foreign_kind
from .._validate import as_array, as_points, check_choice
from ..structures.pointcloud import PointCloud, as_pointcloud
from ._chamfer_search import WitnessSearch, far_share, leaf_level, morton_codes, morton_frame

__all__ = ["ChamferResult", "ChamferTarget", "chamfer_distance", "morton_order"]

_BATCH_REDUCTIONS = ("mean", "sum", None)
_POINT_REDUCTIONS = ("mean", "sum", "max")
_COS_EPS = 1e-6  # PyTorch3D's cosine_similarity eps in chamfer_distance
_PARALLEL_QUERY = 4096  # query sizes from which cKDTree runs on all cores (measured break-even)
_BACKENDS = ("auto", "open3d", "pykdtree", "scipy")
_OPEN3D_FROM = 20_000  # "auto": points a side from which Open3D's search is used (measured)
_MORTON_FROM = 20_000  # clouds and queries from this size are searched in Z-order (measured)
_WITNESS_FROM = 20_000  # "auto": clouds and queries from which far queries take the witness search
_SAMPLE = 2048  # "auto": queries sampled (in Z-order) to tell far clouds from near ones ...
_FAR_LEVELS = 2  # ... a sample is far when its octree cell this many levels above the finest
_FAR_SHARE = 0.05  # ... is empty, and from this share of far samples the witness search is used
_FALLBACK_SHARE = 0.1  # queries handed back by the witness search, from this share of all of
# them, take the KD-tree picked for their number (Open3D's from 20k: the tutorial's start hands
# back most queries, the hard ones); fewer take scipy's, quick to build (apart: about 1%)


@dataclass(frozen=True, eq=False)
class ChamferResult:
    """Chamfer distance, its normal term, and their gradients; unpacks as PyTorch3D's 2-tuple.

    ``loss, loss_normals = chamfer_distance(x, y)`` works as in PyTorch3D (iteration, ``len``
    and indexing see only ``(loss, loss_normals)``); the analytic gradients, which PyTorch3D
    leaves to autograd, are attributes.

    Attributes
    ----------
    loss : float or (N,) float64
        The distance term (an (N,) array when ``batch_reduction=None``).
    loss_normals : float, (N,) float64 or None
        The normal term ``1 - |cos|`` (or ``1 - cos``), None without normals.
    grad_x, grad_y : float64 arrays shaped like ``x`` and ``y``
        Gradients of ``loss`` (of ``loss.sum()`` when ``batch_reduction=None``). Padding entries
        (beyond ``x_lengths`` / ``y_lengths``) get 0.
    grad_x_normals, grad_y_normals : float64 arrays shaped like the normals, or None
        Gradients of ``loss_normals`` with respect to the normals (it does not depend on the
        positions except through the piecewise-constant neighbour choice).
    """

    loss: float | np.ndarray
    loss_normals: float | np.ndarray | None
    grad_x: np.ndarray
    grad_y: np.ndarray
    grad_x_normals: np.ndarray | None = None
    grad_y_normals: np.ndarray | None = None

    def __iter__(self) -> Iterator:
        """``(loss, loss_normals)``, PyTorch3D's return value."""
        return iter((self.loss, self.loss_normals))

    def __len__(self) -> int:
        return 2

    def __getitem__(self, i):
        return (self.loss, self.loss_normals)[i]


def morton_order(points: np.ndarray) -> np.ndarray:
    """(n,) int64 permutation that sorts ``points`` (n, 3) along a Z-order (Morton) curve.

    Points close in space get close positions, so a KD-tree built over sorted points, queried by
    sorted queries, reads memory in order: measured in ``benchmarks/chamfer.py`` (``*_morton``
    rows). 21 bits per axis over the points' bounding cube.
    """
    return np.argsort(morton_codes(points), kind="stable").astype(np.int64, copy=False)


class _NearestIndex:
    """Exact nearest neighbours in a fixed cloud: Open3D's ``core.nns`` or scipy's cKDTree.

    The search structure is built on the first query (one per backend actually used) and reused;
    ``backend`` is ``"open3d"``, ``"scipy"`` or ``"auto"`` (see :meth:`_pick`). From
    ``_MORTON_FROM`` points the tree is built over the points in Z-order and the queries are
    searched in Z-order too (the answers are mapped back): the same exact neighbours, read with
    far fewer cache misses. With ``"auto"`` and the L2 norm, from ``_WITNESS_FROM`` points and
    queries, far queries take the witness search (:meth:`_search_far_aware`), built once per
    cloud like the trees.
    """

    def __init__(self, points: np.ndarray, backend: str):
        self.points = points
        self.backend = backend
        self._scipy = None
        self._pykdtree = None
        self._open3d = None
        self._order = None
        self._codes = None
        self._tree_points = points
        if len(points) >= _MORTON_FROM:
            self._frame = morton_frame(points)
            codes = morton_codes(points, self._frame)
            self._order = np.argsort(codes, kind="stable").astype(np.int64, copy=False)
            self._codes = codes[self._order]
            self._tree_points = np.ascontiguousarray(points[self._order])
        self._witness = None
        self._far_level = None

    def _pick(self, n_queries: int, norm: int) -> str:
        if norm == 1:  # only scipy has L1 (chamfer_distance refuses the others with it)
            return "scipy"
        if self.backend != "auto":
            return self.backend
        # Measured in benchmarks/chamfer.py: Open3D from _OPEN3D_FROM points, where it is
        # faster on far clouds; below, pykdtree (Open3D's tensor set-up dominates there, and
        # pykdtree builds and queries 5000 points in half scipy's CPU time: see the module notes).
        return "open3d" if min(len(self.points), n_queries) >= _OPEN3D_FROM else "pykdtree"

    def nearest(self, q: np.ndarray, norm: int, q_order: np.ndarray | None = None) -> np.ndarray:
        """(k,) int64 index of the nearest point (L2, or L1 for ``norm=1``) of each query."""
        if q_order is None and len(q) >= _MORTON_FROM:
            q_order = morton_order(q)
        qs = q if q_order is None else np.ascontiguousarray(q[q_order])
        if (self.backend == "auto" and norm == 2 and self._codes is not None
                and q_order is not None and min(len(q), len(self.points)) >= _WITNESS_FROM):
            idx = self._search_far_aware(qs, norm)
        else:
            idx = self._search(qs, norm)
        if self._order is not None:
            idx = self._order[idx]
        if q_order is not None:
            out = np.empty_like(idx)
            out[q_order] = idx
            idx = out
        return idx

    def _search_far_aware(self, q: np.ndarray, norm: int) -> np.ndarray:
        """``"auto"`` from ``_WITNESS_FROM`` points: scipy's tree for queries near the cloud,
        the witness search for far ones.

        A Z-order sample of ``_SAMPLE`` queries is located in the cloud's octree (its sorted
        Z-order codes: no tree); if at least ``_FAR_SHARE`` of them fall in empty cells
        ``_FAR_LEVELS`` levels above the finest (cells of 4 x 4 x 4 finest ones, about 8 points
        each), all queries take :class:`~geofit.loss._chamfer_search.WitnessSearch`, which hands
        the blocks it finds near, or with too many candidates, to the KD-tree picked for their
        number (:meth:`_pick`); otherwise all take scipy's tree (on overlapping clouds at 1M
        points a side it took 2.4-2.5 s per direction, as Open3D's, load ~19).
        """
        sample = q[:: max(1, len(q) // _SAMPLE)]
        if self._far_level is None:
            self._far_level = max(1, leaf_level(self._codes) - _FAR_LEVELS)
        level = self._far_level
        if far_share(self._codes, self._frame, sample, level) < _FAR_SHARE:
            return self._search(q, norm, "scipy")
        if self._witness is None:
            self._witness = WitnessSearch(self._tree_points, self._codes)
        return self._witness.nearest(q, lambda rows: self._search(
            q[rows], norm, None if len(rows) >= _FALLBACK_SHARE * len(q) else "scipy"))

    def _search(self, q: np.ndarray, norm: int, backend: str | None = None) -> np.ndarray:
        """Indices into ``self._tree_points`` of the nearest point of each query (with
        ``backend``, or the one :meth:`_pick` takes)."""
        if (backend or self._pick(len(q), norm)) == "open3d":
            import open3d as o3d  # kept local: start-up

            if self._open3d is None:
                self._open3d = o3d.core.nns.NearestNeighborSearch(
                    o3d.core.Tensor(self._tree_points))
                self._open3d.knn_index()
            idx, _ = self._open3d.knn_search(o3d.core.Tensor(np.ascontiguousarray(q)), 1)
            return idx.numpy()[:, 0].astype(np.int64, copy=False)
        if (backend or self._pick(len(q), norm)) == "pykdtree":
            if self._pykdtree is None:
                # leaves of 24 points: 4% less CPU than the default 16 on the tutorial's clouds,
                # at its start and end alike (12 to 32 measured; 32 as 24)
                self._pykdtree = PyKDTree(np.ascontiguousarray(self._tree_points), leafsize=24)
            # One OpenMP thread: chamfer_distance runs its two directions on geofit's pool, and
            # OpenMP teams spin at their barriers: under load ~15, 5000 queries took 4.5 CPU ms
            # on one thread and 8.2 on two (wall 17 and 33 ms; 100 000 queries: 0.96 and 1.2 s)
            with one_openmp_thread():
                _, idx = self._pykdtree.query(np.ascontiguousarray(q), k=1, sqr_dists=True)
            return idx.astype(np.int64)
        if self._scipy is None:
            # Unbalanced, non-compact trees build faster and query as fast (benchmarks/chamfer)
            self._scipy = cKDTree(self._tree_points, balanced_tree=False, compact_nodes=False)
        # Threads pay off only for large queries (scipy starts them on every call).
        _, idx = self._scipy.query(
            q, k=1, p=norm,
            workers=-1 if len(q) >= _PARALLEL_QUERY and not in_worker() else 1)
        return np.asarray(idx, dtype=np.int64)


def _nearest(index: _NearestIndex, q: np.ndarray, norm: int, q_order=None):
    """Nearest index point of each query: (idx (k,), d (k,), dd/dq (k, 3)) with d in float64."""
    idx = index.nearest(q, norm, q_order)
    diff = q - index.points[idx]
    if norm == 2:
        d = np.einsum("ij,ij->i", diff, diff)
        dd = 2.0 * diff
    else:
        d = np.abs(diff).sum(axis=1)
        dd = np.sign(diff)  # torch: d|t|/dt = sign(t), 0 at 0
    return idx, d, dd


def _scatter(idx: np.ndarray, vals: np.ndarray, n: int) -> np.ndarray:
    """Sum rows of (k, C) ``vals`` into an (n, C) array at rows ``idx``."""
    out = np.empty((n, vals.shape[1]))
    for c in range(vals.shape[1]):  # the coordinates
        out[:, c] = np.bincount(idx, vals[:, c], n)
    return out


def _cos_and_grads(a: np.ndarray, b: np.ndarray):
    """torch.cosine_similarity(a, b, eps=1e-6) per row and its exact gradients.

    ``cos = (a / max(|a|, eps)) . (b / max(|b|, eps))``; for ``|a| > eps``,
    ``d cos / d a = b / (m_a m_b) - cos a / |a|^2``; below eps only the first term.
    """
    sa = np.einsum("ij,ij->i", a, a)
    sb = np.einsum("ij,ij->i", b, b)
    e2 = _COS_EPS * _COS_EPS
    ma = np.maximum(sa, e2)
    mb = np.maximum(sb, e2)
    inv = 1.0 / np.sqrt(ma * mb)
    cos = np.einsum("ij,ij->i", a, b) * inv
    ca = np.where(sa > e2, cos / ma, 0.0)
    cb = np.where(sb > e2, cos / mb, 0.0)
    ga = b * inv[:, None] - a * ca[:, None]
    gb = a * inv[:, None] - b * cb[:, None]
    return cos, ga, gb


class _Direction(NamedTuple):
    """One direction (p -> q) of one batch member, before reduction."""

    d: np.ndarray  # (k,) distance of each p to its nearest q
    idx: np.ndarray  # (k,) index of that q
    dd: np.ndarray  # (k, 3) d d / d p
    nterm: np.ndarray | None  # (k,) normal term 1 - |cos| (or 1 - cos)
    dn_p: np.ndarray | None  # (k, 3) d nterm / d p_normal
    dn_q: np.ndarray | None  # (k, 3) d nterm / d q_normal[idx]


def _direction(p, q, index_q, norm, p_normals, q_normals, abs_cosine,
               p_order=None) -> _Direction:
    if len(p) == 0 or len(q) == 0:  # nothing to match: this direction contributes 0
        z = np.zeros(len(p))
        zz = np.zeros((len(p), 3))
        with_n = p_normals is not None
        return _Direction(z, np.zeros(len(p), np.int64), zz, z if with_n else None,
                          zz if with_n else None, zz if with_n else None)
    idx, d, dd = _nearest(index_q, p, norm, p_order)
    if p_normals is None:
        return _Direction(d, idx, dd, None, None, None)
    cos, ga, gb = _cos_and_grads(p_normals, q_normals[idx])
    if abs_cosine:
        s = np.sign(cos)
        nterm = 1.0 - np.abs(cos)
    else:
        s = np.ones_like(cos)
        nterm = 1.0 - cos
    return _Direction(d, idx, dd, nterm, -s[:, None] * ga, -s[:, None] * gb)


class _Reduced(NamedTuple):
    """One reduced direction p -> q: values and gradients (already times the member weight)."""

    value: float
    value_n: float | None
    g_p: np.ndarray  # (k, 3)
    g_q: np.ndarray  # (n_q, 3)
    gn_p: np.ndarray | None
    gn_q: np.ndarray | None


def _reduce_direction(dr: _Direction, point_reduction: str, w: float, n_q: int) -> _Reduced:
    """Reduce one direction over its points (mean, sum or max), times the member weight ``w``."""
    k = len(dr.d)
    if point_reduction == "max":
        if k == 0:
            return _Reduced(0.0, None, np.zeros((0, 3)), np.zeros((n_q, 3)), None, None)
        i = int(np.argmax(dr.d))
        coef = np.zeros(k)
        coef[i] = w
        value = w * dr.d[i]
    else:
        scale = w / max(k, 1) if point_reduction == "mean" else w
        coef = np.full(k, scale)
        value = scale * dr.d.sum()
    g_p = dr.dd * coef[:, None]
    g_q = -_scatter(dr.idx, g_p, n_q)
    if dr.nterm is None:
        return _Reduced(float(value), None, g_p, g_q, None, None)
    # the normal term has the same per-point weights (normals are never used with 'max')
    value_n = float(np.dot(coef, dr.nterm))
    gpn = dr.dn_p * coef[:, None]
    gqn = _scatter(dr.idx, dr.dn_q * coef[:, None], n_q)
    return _Reduced(float(value), value_n, g_p, g_q, gpn, gqn)


def _member(xb, yb, index_y, xnb, ynb, *, w, point_reduction, norm, single_directional,
            abs_cosine, backend):
    """Both directions of one batch member combined: (loss, loss_n, gx, gy, gxn, gyn)."""
    # x moves: its tree is rebuilt per call; its Z-order (if any) also orders the x -> y queries
    index_x = None if single_directional else _NearestIndex(xb, backend)
    x_order = None if index_x is None else index_x._order
    if single_directional:
        rx = _reduce_direction(_direction(xb, yb, index_y, norm, xnb, ynb, abs_cosine, x_order),
                               point_reduction, w, len(yb))
        return rx.value, rx.value_n, rx.g_p, rx.g_q, rx.gn_p, rx.gn_q
    jobs = [(xb, yb, index_y, xnb, ynb, x_order), (yb, xb, index_x, ynb, xnb, index_y._order)]

    def run(job):
        p, q, index_q, pn, qn, order = job
        return _reduce_direction(_direction(p, q, index_q, norm, pn, qn, abs_cosine, order),
                                 point_reduction, w, len(q))

    # The two directions (each: build the other cloud's tree, query it) on two threads of the
    # shared pool; the KD-trees release the GIL. From _PARALLEL_QUERY points this beats one
    # direction after the other with scipy starting its own threads per query (measured on the
    # deform tutorial's 5000 + 5000 samples, benchmarks/pytorch3d_port.py).
    if len(xb) + len(yb) >= _PARALLEL_QUERY:
        rx, ry = parallel_map(run, jobs)
    else:
        rx, ry = run(jobs[0]), run(jobs[1])
    if point_reduction == "max":
        # torch.maximum: the gradient goes to the larger term, split evenly on a tie
        sx, sy = (1.0, 0.0) if rx.value > ry.value else (0.0, 1.0) if ry.value > rx.value \
            else (0.5, 0.5)
        return (max(rx.value, ry.value), None, sx * rx.g_p + sy * ry.g_q,
                sx * rx.g_q + sy * ry.g_p, None, None)
    if rx.value_n is None:
        return rx.value + ry.value, None, rx.g_p + ry.g_q, rx.g_q + ry.g_p, None, None
    return (rx.value + ry.value, rx.value_n + ry.value_n, rx.g_p + ry.g_q, rx.g_q + ry.g_p,
            rx.gn_p + ry.gn_q, rx.gn_q + ry.gn_p)


def _cloud_points(a, name: str):
    """The points of a geofit, trimesh or Open3D point cloud; anything else unchanged."""
    if isinstance(a, PointCloud) or foreign_kind(a) in ("trimesh.PointCloud", "open3d.PointCloud"):
        return as_pointcloud(a, name).points
    return a


def _as_cloud(a, name: str):
    """(n, 3) or (N, n, 3) -> ((N, n, 3) float64, was_2d)."""
    a = _cloud_points(a, name)
    try:
        arr = np.asarray(a)
    except (TypeError, ValueError) as exc:  # ragged input
        raise ValueError(f"{name}: could not convert to an array ({exc})") from None
    if arr.ndim == 2:
        return as_array(arr, name, (None, 3))[None], True
    if arr.ndim != 3 or arr.shape[-1] != 3:
        raise ValueError(f"{name}: expected shape (n, 3) or (N, n, 3), got {arr.shape}")
    return as_array(arr, name, (None, None, 3)), False


def _as_lengths(lengths, name: str, N: int, P: int) -> np.ndarray:
    if lengths is None:
        return np.full(N, P, dtype=np.int64)
    arr = as_array(lengths, name, (N,), np.int64)
    if arr.size and (arr.min() < 0 or arr.max() > P):
        raise ValueError(f"{name}: expected lengths in [0, {P}], got range "
                         f"[{arr.min()}, {arr.max()}]")
    return arr


def _check_options(batch_reduction, point_reduction, norm, x_normals, y_normals, backend):
    check_choice(backend, "backend", _BACKENDS)
    if backend in ("open3d", "pykdtree") and norm == 1:
        raise ValueError(f"backend: {backend!r} has no L1 search, use norm=2 or "
                         "backend='scipy' (or 'auto')")
    check_choice(batch_reduction, "batch_reduction", _BATCH_REDUCTIONS)
    check_choice(point_reduction, "point_reduction", _POINT_REDUCTIONS)
    if isinstance(norm, bool) or norm not in (1, 2):
        raise ValueError(f"norm: expected 1 or 2, got {norm!r}")
    if point_reduction == "max" and (x_normals is not None or y_normals is not None):
        raise ValueError("x_normals/y_normals: normals must be None if point_reduction is 'max'")
    if (x_normals is None) != (y_normals is None):
        raise ValueError("x_normals/y_normals: give both normals or neither "
                         f"(got x_normals={'set' if x_normals is not None else None}, "
                         f"y_normals={'set' if y_normals is not None else None})")


def chamfer_distance(x, y, *, x_lengths=None, y_lengths=None, x_normals=None, y_normals=None,
                     weights=None, batch_reduction: str | None = "mean",
                     point_reduction: str = "mean", norm: int = 2,
                     single_directional: bool = False, abs_cosine: bool = True,
                     backend: str = "auto") -> ChamferResult:
    """Chamfer distance between two point clouds (or padded batches), PyTorch3D's semantics.

    Parameters
    ----------
    x : (n, 3) or (N, n, 3) float64
        First cloud, or a padded batch of clouds. A geofit, trimesh or Open3D point cloud
        object is taken as its (n, 3) points.
    y : (m, 3) or (N, m, 3) float64
        Second cloud(s); the batch size must match ``x`` (a 2-D input is a batch of one).
        Point cloud objects as for ``x``.
    x_lengths, y_lengths : (N,) int64, optional
        Number of valid points of each batch member (the rest is padding and is ignored; its
        gradient is 0). Default: all points.
    x_normals, y_normals : float64 arrays shaped like ``x`` and ``y``, optional
        Per-point normals; give both to get the normal term.
    weights : (N,) float64, optional
        Non-negative per-member weights multiplying each member's per-point terms. With
        ``batch_reduction="mean"`` the batch is divided by ``weights.sum()`` instead of N. All
        zeros gives a zero loss.
    batch_reduction : {"mean", "sum", None}
        How members are combined; None returns the (N,) per-member losses.
    point_reduction : {"mean", "sum", "max"}
        Per direction, the mean or sum of the nearest-neighbour distances over the valid points,
        or their max (then the two directions are combined with max: the symmetric Hausdorff
        distance, squared for ``norm=2``; normals not allowed).
    norm : {2, 1}
        2: squared Euclidean distances; 1: L1 distances (the neighbours are then L1-nearest).
    single_directional : bool
        Only the x -> y term.
    abs_cosine : bool
        Normal term ``1 - |cos|`` (orientation ignored) or ``1 - cos``.
    backend : {"auto", "open3d", "pykdtree", "scipy"}
        The exact nearest-neighbour search: Open3D's ``core.nns`` (knn), pykdtree's ``KDTree``
        or scipy's ``cKDTree``; ``"auto"`` takes pykdtree's tree below 20 000 points a side,
        and from there scipy's tree for queries near the other cloud and a witness-pruned
        block search for far ones, so that clouds far apart cost about as much as overlapping
        ones (see the module notes for the measured figures). ``norm=1`` needs scipy
        (``"auto"`` picks it). Every backend returns the exact nearest neighbours;
        values agree to rounding.

    Returns
    -------
    ChamferResult
        Unpacks as PyTorch3D's ``(loss, loss_normals)`` (``loss_normals`` None without
        normals) and carries ``grad_x``, ``grad_y``, ``grad_x_normals``, ``grad_y_normals``;
        the gradients have the shapes of the inputs (2-D in, 2-D out). With
        ``batch_reduction=None`` the gradients are those of ``loss.sum()`` (and
        ``loss_normals.sum()``).

    Raises
    ------
    ValueError
        On bad shapes, mismatched batch sizes, non-finite coordinates, lengths out of range,
        negative weights, an unknown reduction, norm or backend, ``backend="open3d"`` or
        ``"pykdtree"`` with ``norm=1``, normals with ``point_reduction="max"`` or only one of the two normals
        arrays.

    Notes
    -----
    Semantics of PyTorch3D 0.7.9's ``chamfer_distance``: the two directions are **summed** (one
    point at (0, 0) against one at (3, 0) gives 9 + 9 = 18), ``"mean"`` divides each member's
    sum by its length clamped at 1, and the normal term uses ``cosine_similarity`` with eps
    1e-6. A direction whose other cloud is empty contributes 0. Differences: PyTorch3D silently
    drops the normal term when only one normals tensor is given (this raises), and it does not
    offer ``point_reduction=None`` here (the per-point terms have no single gradient).
    When the maxima of the two directions tie under ``"max"``, the gradient is split evenly
    (``torch.maximum``'s convention).

    Examples
    --------
    >>> from geofit.loss import chamfer_distance
    >>> loss, loss_normals = chamfer_distance([[0.0, 0, 0]], [[3.0, 0, 0]])  # as PyTorch3D
    >>> loss, loss_normals
    (18.0, None)
    >>> r = chamfer_distance([[0.0, 0, 0]], [[3.0, 0, 0]])  # the gradients are attributes
    >>> r.loss, r.grad_x.tolist(), r.grad_y.tolist()
    (18.0, [[-12.0, 0.0, 0.0]], [[12.0, 0.0, 0.0]])
    """
    _check_options(batch_reduction, point_reduction, norm, x_normals, y_normals, backend)
    X, x2d = _as_cloud(x, "x")
    Y, y2d = _as_cloud(y, "y")
    N, P1, _ = X.shape
    if Y.shape[0] != N:
        raise ValueError(f"y: expected batch size {N} like x, got shape {Y.shape}")
    P2 = Y.shape[1]
    lx = _as_lengths(x_lengths, "x_lengths", N, P1)
    ly = _as_lengths(y_lengths, "y_lengths", N, P2)
    with_n = x_normals is not None
    if with_n:
        XN = as_array(x_normals, "x_normals", X.shape if not x2d else (P1, 3))
        YN = as_array(y_normals, "y_normals", Y.shape if not y2d else (P2, 3))
        XN = XN.reshape(X.shape)
        YN = YN.reshape(Y.shape)
    if weights is not None:
        w = as_array(weights, "weights", (N,))
        if np.any(w < 0):
            raise ValueError("weights: expected non-negative weights")
    else:
        w = np.ones(N)

    gx = np.zeros_like(X)
    gy = np.zeros_like(Y)
    gxn = np.zeros_like(X) if with_n else None
    gyn = np.zeros_like(Y) if with_n else None
    loss = np.zeros(N)
    loss_n = np.zeros(N) if with_n else None

    if weights is not None and w.sum() == 0.0:
        div = 1.0  # PyTorch3D returns zeros
        active = np.zeros(N, bool)
    else:
        div = (w.sum() if weights is not None else float(max(N, 1))) if batch_reduction == "mean" \
            else 1.0
        active = np.ones(N, bool)

    for b in range(N):  # loop over batch members
        if not active[b]:
            continue
        nx, ny = lx[b], ly[b]
        xb = X[b, :nx]
        yb = Y[b, :ny]
        out = _member(xb, yb, _NearestIndex(yb, backend),
                      XN[b, :nx] if with_n else None, YN[b, :ny] if with_n else None,
                      w=w[b] / div, point_reduction=point_reduction, norm=norm,
                      single_directional=single_directional, abs_cosine=abs_cosine,
                      backend=backend)
        loss[b] = out[0]
        gx[b, :nx] = out[2]
        gy[b, :ny] = out[3]
        if with_n:
            loss_n[b] = out[1]
            gxn[b, :nx] = out[4]
            gyn[b, :ny] = out[5]

    if batch_reduction is None:  # per-member values (div == 1)
        out_loss = loss
        out_n = loss_n
    else:
        out_loss = float(loss.sum())
        out_n = float(loss_n.sum()) if with_n else None
    if x2d:
        gx = gx[0]
        gxn = gxn[0] if with_n else None
    if y2d:
        gy = gy[0]
        gyn = gyn[0] if with_n else None
    return ChamferResult(out_loss, out_n, gx, gy, gxn, gyn)


class ChamferTarget:
    """A fixed target cloud whose KD-tree is built once, for repeated chamfer distances to it.

    Parameters
    ----------
    y : (m, 3) float64
        Target points (at least one); a geofit, trimesh or Open3D point cloud object is taken
        as its points.
    y_normals : (m, 3) float64, optional
        Target normals, for the normal term of :meth:`chamfer`.
    backend : {"auto", "open3d", "pykdtree", "scipy"}
        The nearest-neighbour search, as in :func:`chamfer_distance`.

    Notes
    -----
    The x -> y direction queries one tree over ``y``, built at the first query and reused
    (pykdtree's, scipy's or Open3D's, as ``backend`` picks for the sizes). The y -> x direction
    needs a tree over ``x``, which moves between calls, so it is rebuilt on every call (as PyTorch3D's
    ``knn_points`` does for both directions). Values equal ``chamfer_distance(x, y)`` with the
    same options.

    Examples
    --------
    >>> import numpy as np
    >>> from geofit.loss import ChamferTarget, chamfer_distance
    >>> rng = np.random.default_rng(0)
    >>> y = rng.normal(size=(500, 3)); x = rng.normal(size=(400, 3))
    >>> target = ChamferTarget(y)
    >>> value, grad = target.loss(x)
    >>> bool(np.isclose(value, chamfer_distance(x, y).loss))
    True
    """

    def __init__(self, y, *, y_normals=None, backend: str = "auto"):
        self.points = as_points(_cloud_points(y, "y"), "y", allow_empty=False)
        self.points.setflags(write=False)
        self.normals = None
        if y_normals is not None:
            self.normals = as_array(y_normals, "y_normals", (len(self.points), 3))
            self.normals.setflags(write=False)
        check_choice(backend, "backend", _BACKENDS)
        self.backend = backend
        self._index = _NearestIndex(self.points, self.backend)

    def __len__(self) -> int:
        return len(self.points)

    def __repr__(self) -> str:
        return (f"ChamferTarget(n_points={len(self.points)}, normals={self.normals is not None}, "
                f"backend={self.backend!r})")

    def chamfer(self, x, *, x_normals=None, point_reduction: str = "mean", norm: int = 2,
                single_directional: bool = False, abs_cosine: bool = True) -> ChamferResult:
        """Full result against the target: same semantics as :func:`chamfer_distance`.

        Parameters
        ----------
        x : (n, 3) float64
            Source points.
        x_normals : (n, 3) float64, optional
            Source normals (needs ``y_normals`` on the target).
        point_reduction, norm, single_directional, abs_cosine
            As in :func:`chamfer_distance` (batch reduction is moot for one cloud).

        Returns
        -------
        ChamferResult
            ``grad_x`` (n, 3) and ``grad_y`` (m, 3) (the latter for completeness: the target is
            usually fixed).
        """
        y_normals = self.normals if x_normals is not None else None
        if x_normals is not None and self.normals is None:
            raise ValueError("x_normals: the target was built without y_normals")
        _check_options("mean", point_reduction, norm, x_normals, y_normals, self.backend)
        xp = as_points(x, "x")
        xn = as_array(x_normals, "x_normals", (len(xp), 3)) if x_normals is not None else None
        out = _member(xp, self.points, self._index, xn, y_normals, w=1.0,
                      point_reduction=point_reduction, norm=norm,
                      single_directional=single_directional, abs_cosine=abs_cosine,
                      backend=self.backend)
        loss_n = None if out[1] is None else float(out[1])
        return ChamferResult(float(out[0]), loss_n, out[2], out[3], out[4], out[5])

    def loss(self, x, *, point_reduction: str = "mean", norm: int = 2,
             single_directional: bool = False):
        """Chamfer distance from ``x`` to the target and its gradient with respect to ``x``.

        Parameters
        ----------
        x : (n, 3) float64
            Source points (e.g. samples of a moving mesh).
        point_reduction : {"mean", "sum", "max"}
        norm : {2, 1}
        single_directional : bool
            As in :func:`chamfer_distance`.

        Returns
        -------
        value : float
            Equal to ``chamfer_distance(x, y, ...).loss``.
        grad_x : (n, 3) float64
        """
        r = self.chamfer(x, point_reduction=point_reduction, norm=norm,
                         single_directional=single_directional)
        return r.loss, r.grad_x
