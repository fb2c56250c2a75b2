"""Exact nearest neighbours for far queries: witness-pruned block search over a Morton octree.

Why a KD-tree is slow on far queries: to prove that a query's nearest point is the nearest, an
exact tree search opens every node whose box is closer than that point. When the query is far
from a surface that faces it (a dolphin point against the side of a sphere 2 units away, or near
the centre of a surrounding sphere), the points in a shell one leaf box thick around the nearest
distance cover a wide patch of the surface, because a box tilted against the surface reaches
towards the query by a fraction of its size times the distance. At 1M points a side that made
scipy's search 15 times slower on clouds 2 units apart than on overlapping clouds, whatever the
starting bound (a per-query bound equal to the true distance saved 25%: the work is the proof,
not the finding).

The search here proves nearness per *block* of queries instead, with a *witness*: for a block
(a box with centre ``q0`` and half extents ``h``, some consecutive queries in Z-order) and any
point ``w`` of the cloud, a point ``p`` can be the nearest of some query ``q`` of the block only
if ``|q - p| <= |q - w|`` for that ``q``, which expands (``q = q0 + d``, ``|d_i| <= h_i``) to::

    |p - q0|^2 <= |w - q0|^2 + 2 sum_i h_i |p_i - w_i|

a test that looks at the point's position *along* the surface, not at its distance from the
query, so a far flat front is cut to a patch about the block's size. The same inequality over a
cell's bounding box (its distance to ``q0``, the largest ``|p_i - w_i|``) prunes whole cells of
a Morton octree of the cloud, level by level; the witness of each block is the best cell
representative seen so far, and blocks are split as the cells shrink (1024 queries at the top,
down to 32: blocks of 4 took 5 times as long at 1M points, with more cell pairs to test).
What survives is checked point by point and the exact squared distances of each query to its
block's candidates are compared (the same float64 formula as everywhere). A block
whose witness is already near (within a few block diagonals) is handed back to the KD-tree,
which is fast there, and so is a block that keeps more than ``_CROWD`` cells at a level or
``_HEAVY`` candidate points (near the centre of a surrounding sphere, where every exact search
has much to look at and the KD-tree's compiled loop is faster than numpy's passes).

Exactness: no point that ties with or beats the witness for some query of the block is pruned
(every test keeps a relative margin of 1e-9 for rounding, and the block half-extents are rounded
up), so each query's candidates contain all its nearest points; among equal distances the point
first in the cloud's Z-order wins (the KD-tree's own rule for the blocks handed back to it), and
the chunks of queries are fixed, so the result does not depend on the number of threads.
"""
from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np

from .._threads import parallel_map

__all__ = ["MORTON_BITS", "WitnessSearch", "far_share", "leaf_level", "morton_codes",
           "morton_frame"]

MORTON_BITS = 21  # bits per axis: 63-bit codes
_MASKS = ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
          (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249))
_LEAF = 8  # mean points per finest cell
_K_TOP = 1024  # queries per block at the top level, divided by 4 per level ...
_K_MIN = 32  # ... down to this
_NEAR = 2.0  # a block whose witness is within _NEAR block diagonals goes to the KD-tree
_CHUNK = 1 << 15  # queries per work item (memory: pairs and candidates of one chunk)
_COMBOS = 1 << 21  # (query, candidate) distances computed at once
_FRAMED = 3  # finest levels with oriented boxes
_CROWD = 64  # cells kept by a block at one level above which it goes to the KD-tree
_HEAVY = 256  # candidates of a block above which its queries go to the KD-tree
_SLACK = 1e-9  # relative margin of every pruning test (rounding)


def morton_frame(points: np.ndarray) -> tuple[np.ndarray, float]:
    """``(lo, scale)``: the corner of the bounding cube of (n, 3) ``points`` and the factor that
    maps its side to ``2**21 - 1`` (0 for a single point)."""
    lo = points.min(axis=0)
    span = float((points.max(axis=0) - lo).max())
    return lo, ((2 ** MORTON_BITS - 1) / span if span > 0 else 0.0)


def morton_codes(points: np.ndarray, frame: tuple[np.ndarray, float] | None = None) -> np.ndarray:
    """(n,) uint64 Z-order codes of (n, 3) ``points``: 21 bits per axis over their bounding cube,
    or over the cube ``frame`` of another cloud (:func:`morton_frame`; points outside it are
    clamped to its faces)."""
    lo, scale = morton_frame(points) if frame is None else frame
    t = np.clip((points - lo) * scale, 0.0, 2 ** MORTON_BITS - 1)
    q = t.astype(np.uint64)
    code = np.zeros(len(points), np.uint64)
    for axis in range(3):  # the three coordinates: spread 21 bits to every third bit
        v = q[:, axis]
        for shift, mask in _MASKS:
            v = (v | (v << np.uint64(shift))) & np.uint64(mask)
        code |= v << np.uint64(axis)
    return code


def far_share(codes: np.ndarray, frame: tuple[np.ndarray, float], q: np.ndarray,
              level: int) -> float:
    """Share of the queries ``q`` (k, 3) that are far from the cloud whose sorted codes are
    ``codes`` (in ``frame``): their octree cell at ``level`` holds none of its points, or they
    lie outside its cube by more than one such cell. No tree needed."""
    if len(q) == 0:
        return 0.0
    lo, scale = frame
    side = float(2 ** (MORTON_BITS - level))  # a cell's side, in code units
    t = (q - lo) * scale
    outside = ((t < -side) | (t > 2 ** MORTON_BITS - 1 + side)).any(axis=1)
    shift = np.uint64(3 * (MORTON_BITS - level))
    keys = codes >> shift
    qk = morton_codes(q, frame) >> shift
    pos = np.minimum(np.searchsorted(keys, qk), len(keys) - 1)
    return float(np.mean(outside | (keys[pos] != qk)))


def _segments(ids: np.ndarray) -> np.ndarray:
    """Start of each run of equal values in ``ids`` (non-empty)."""
    return np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])


def _ranges(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenation of ``arange(s, s + c)`` for each start ``s`` and count ``c``."""
    off = np.cumsum(counts) - counts
    return np.repeat(starts - off, counts) + np.arange(int(counts.sum()))


def leaf_level(codes: np.ndarray) -> int:
    """The coarsest octree level whose cells hold at most ``_LEAF`` points on average (codes
    ascending): the finest level of :class:`WitnessSearch`."""
    n = len(codes)
    for level in range(1, MORTON_BITS + 1):  # octree levels, coarse to fine
        key = codes >> np.uint64(3 * (MORTON_BITS - level))
        if n <= _LEAF * (1 + np.count_nonzero(key[1:] != key[:-1])):
            return level
    return MORTON_BITS


class _Level:
    """The non-empty cells of one octree level: point ranges, boxes, a representative point,
    and the range of their children in the next level."""

    def __init__(self, points: np.ndarray, key: np.ndarray):
        self.start = _segments(key)
        self.end = np.r_[self.start[1:], len(points)]
        self.lo = np.minimum.reduceat(points, self.start, axis=0)
        self.hi = np.maximum.reduceat(points, self.start, axis=0)
        self.rep = self.start + (self.end - self.start) // 2  # a point in the cell's middle
        self.child_start = self.child_end = None
        self.framed = None

    def allow_frames(self) -> None:
        """Give this level oriented boxes, computed per cell when first visited (:meth:`frames`):
        far queries visit a small part of the cloud."""
        nc = len(self.start)
        self.framed = np.zeros(nc, bool)
        self.frame = np.zeros((nc, 3, 3))
        self.mid = np.zeros((nc, 3))
        self.half = np.zeros((nc, 3))
        self._lock = threading.Lock()

    def frames(self, points: np.ndarray, cells: np.ndarray) -> None:
        """Oriented boxes of ``cells`` not yet done: the principal axes ``frame`` (3, 3), the
        box centre ``mid`` and half extents ``half`` along them. Any orthonormal frame bounds a
        cell; the principal one fits a flat patch, whatever its tilt."""
        with self._lock:  # the chunks' threads share the level
            new = ~self.framed[cells]
            if not new.any():
                return
            todo = np.unique(cells[new])
            cnt = self.end[todo] - self.start[todo]
            p = points[_ranges(self.start[todo], cnt)]
            st = np.cumsum(cnt) - cnt
            cell = np.repeat(np.arange(len(todo)), cnt)
            mean = np.add.reduceat(p, st, axis=0) / cnt[:, None]
            d = p - mean[cell]
            cov = np.empty((len(todo), 3, 3))
            for i in range(3):  # the six second moments
                for j in range(i, 3):
                    cov[:, i, j] = cov[:, j, i] = np.add.reduceat(d[:, i] * d[:, j], st)
            _, frame = np.linalg.eigh(cov)
            u = np.einsum("nij,ni->nj", frame[cell], d)
            ulo = np.minimum.reduceat(u, st, axis=0)
            uhi = np.maximum.reduceat(u, st, axis=0)
            self.frame[todo] = frame
            self.mid[todo] = mean + np.einsum("cij,cj->ci", frame, 0.5 * (ulo + uhi))
            # rounded up: the projections above are rounded by a few ulps of the cell's size
            size = np.abs(self.hi[todo] - self.lo[todo]).max(axis=1, keepdims=True)
            self.half[todo] = 0.5 * (uhi - ulo) * (1.0 + 1e-9) + 1e-12 * size + 1e-300
            self.framed[todo] = True


class WitnessSearch:
    """Exact nearest neighbours in a fixed cloud sorted in Z-order (see the module notes).

    Parameters
    ----------
    points : (n, 3) float64
        The cloud, sorted by ``codes``.
    codes : (n,) uint64
        Its Z-order codes (:func:`morton_codes`), ascending.
    """

    def __init__(self, points: np.ndarray, codes: np.ndarray):
        self.points = points
        self.levels = [_Level(points, codes >> np.uint64(3 * (MORTON_BITS - level)))
                       for level in range(1, leaf_level(codes) + 1)]
        for lv in self.levels[-_FRAMED:]:
            lv.allow_frames()
        for a, b in zip(self.levels[:-1], self.levels[1:]):
            a.child_start = np.searchsorted(b.start, a.start)
            a.child_end = np.r_[a.child_start[1:], len(b.start)]

    def nearest(self, q: np.ndarray, kd: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """(k,) int64 index of the nearest point of each query of (k, 3) ``q`` (in Z-order).

        ``kd(rows)`` must return the exact nearest point of ``q[rows]`` (the KD-tree); it is
        called once, for the queries whose block turned out near the cloud.
        """
        chunks = [(s, min(s + _CHUNK, len(q))) for s in range(0, len(q), _CHUNK)]
        out = parallel_map(lambda c: self._chunk(q[c[0]:c[1]]), chunks)
        idx = np.concatenate(out) if out else np.zeros(0, np.int64)
        near = np.flatnonzero(idx < 0)
        if len(near):
            idx[near] = kd(near)
        return idx

    def _chunk(self, q: np.ndarray) -> np.ndarray:
        """Nearest index of each query of one chunk, -1 where the block was near (KD-tree)."""
        P = self.points
        nq = len(q)
        top = self.levels[0]
        k = _K_TOP
        q0, h = _blocks(q, k)
        nb = len(q0)
        pb = np.repeat(np.arange(nb), len(top.start))
        pc = np.tile(np.arange(len(top.start)), nb)
        w = np.zeros(nb, np.int64)
        d2w = np.full(nb, np.inf)
        far = np.ones(nb, bool)
        for li, lv in enumerate(self.levels):
            if li:  # split the blocks, expand the kept cells to their children
                k_new = max(_K_MIN, k // 4)
                if k_new < k:
                    pb, pc, q0, h, w, far = _split(q, k, k_new, pb, pc, w, far)
                    dv = P[w] - q0
                    d2w = np.einsum("ij,ij->i", dv, dv)
                    k = k_new
                prev = self.levels[li - 1]
                nch = prev.child_end[pc] - prev.child_start[pc]
                pc = _ranges(prev.child_start[pc], nch)
                pb = np.repeat(pb, nch)
            if len(pb) == 0:
                break
            # witness: the nearest representative of the block's cells so far
            qb = q0[pb]
            rep = lv.rep[pc]
            dv = P[rep] - qb
            d2 = np.einsum("ij,ij->i", dv, dv)
            s = _segments(pb)
            best = np.minimum.reduceat(d2, s)
            blk = pb[s]
            better = best < d2w[blk]
            first = _first_min(d2, best, s)
            w[blk[better]] = rep[first[better]]
            d2w[blk[better]] = best[better]
            # a block with a near witness goes to the KD-tree
            diag2 = 4.0 * np.einsum("ij,ij->i", h, h) * (_K_MIN / k)  # ~ the final blocks'
            near = far & (d2w <= _NEAR * _NEAR * diag2)
            far &= ~near
            if near.any():
                sel = far[pb]
                pb, pc, qb = pb[sel], pc[sel], qb[sel]
            # prune cells: |p - q0|^2 <= |w - q0|^2 + 2 sum h_i |p_i - w_i| for no p of the cell
            lo, hi = lv.lo[pc], lv.hi[pc]
            if lv.framed is None:  # the axis-aligned box
                gap = np.maximum(np.maximum(lo - qb, qb - hi), 0.0)
            else:  # the oriented box: nearer the points of a tilted patch (measured: enough)
                lv.frames(P, pc)
                v = np.einsum("nij,ni->nj", lv.frame[pc], qb - lv.mid[pc])
                gap = np.maximum(np.abs(v) - lv.half[pc], 0.0)
            wb = P[w[pb]]
            lat = 2.0 * np.einsum("ij,ij->i", h[pb],
                                  np.maximum(np.abs(lo - wb), np.abs(hi - wb)))
            keep = np.einsum("ij,ij->i", gap, gap) <= (d2w[pb] + lat) * (1.0 + _SLACK)
            pb, pc = pb[keep], pc[keep]
            # a block that keeps many cells is almost equally far from a wide part of the
            # cloud (near the centre of a surrounding sphere): the KD-tree is faster there
            crowded = np.bincount(pb, minlength=len(far)) > _CROWD
            if crowded.any():
                far &= ~crowded
                keep = far[pb]
                pb, pc = pb[keep], pc[keep]
        out = np.full(nq, -1, np.int64)
        if len(pb):
            self._leaves(q, k, pb, pc, q0, h, w, d2w, out)
        return out

    def _leaves(self, q, k, pb, pc, q0, h, w, d2w, out) -> None:
        """Point-level test of the kept finest cells, then exact distances per query."""
        P = self.points
        lv = self.levels[-1]
        cnt = lv.end[pc] - lv.start[pc]
        cb = np.repeat(pb, cnt)
        cj = _ranges(lv.start[pc], cnt)
        dv = P[cj] - q0[cb]
        lat = 2.0 * np.einsum("ij,ij->i", h[cb], np.abs(P[cj] - P[w[cb]]))
        keep = np.einsum("ij,ij->i", dv, dv) <= (d2w[cb] + lat) * (1.0 + _SLACK)
        cb, cj = cb[keep], cj[keep]
        nb = len(q0)
        ncand = np.bincount(cb, minlength=nb)
        cstart = np.cumsum(ncand) - ncand
        ncand[ncand > _HEAVY] = 0  # many near-equidistant candidates: the KD-tree is faster
        rows = np.flatnonzero(ncand[np.arange(len(q)) // k] > 0)  # queries of far blocks
        per = ncand[rows // k]
        total = np.cumsum(per)
        for a, b in _batches(total, _COMBOS):  # bounded (query, candidate) batches
            r, n_r = rows[a:b], per[a:b]
            j = cj[_ranges(cstart[r // k], n_r)]
            dv = np.repeat(q[r], n_r, axis=0) - P[j]
            d = np.einsum("ij,ij->i", dv, dv)
            s = np.cumsum(n_r) - n_r
            out[r] = j[_first_min(d, np.minimum.reduceat(d, s), s)]


def _blocks(q: np.ndarray, k: int):
    """Centres and half extents (rounded up) of the blocks of ``k`` consecutive queries."""
    st = np.arange(0, len(q), k)
    lo = np.minimum.reduceat(q, st, axis=0)
    hi = np.maximum.reduceat(q, st, axis=0)
    q0 = 0.5 * (lo + hi)
    h = np.maximum(hi - q0, q0 - lo) * (1.0 + 1e-12)
    return q0, h


def _split(q, k, k_new, pb, pc, w, far):
    """Blocks of ``k`` queries split into blocks of ``k_new``: each child inherits its parent's
    cells, witness and status (the witness distance is recomputed from the child's centre)."""
    r = k // k_new
    q0, h = _blocks(q, k_new)
    nb_new = len(q0)
    parent = np.arange(nb_new) // r
    w, far = w[parent], far[parent]
    if len(pb):
        s = _segments(pb)
        blk = pb[s]
        m = np.diff(np.r_[s, len(pb)])  # cells per parent block
        nch = np.minimum((blk + 1) * r, nb_new) - blk * r  # children per parent block
        tot = m * nch
        t = _ranges(np.zeros(len(s), np.int64), tot)  # position within the parent's new run
        mm = np.repeat(m, tot)
        pb = np.repeat(blk * r, tot) + t // mm
        pc = pc[np.repeat(s, tot) + t % mm]
    return pb, pc, q0, h, w, far


def _first_min(d: np.ndarray, best: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Index of the first entry equal to its segment's minimum ``best``, per segment ``s``."""
    counts = np.diff(np.r_[s, len(d)])
    pos = np.flatnonzero(d == np.repeat(best, counts))
    return pos[np.searchsorted(pos, s)]


def _batches(total: np.ndarray, budget: int):
    """Consecutive (a, b) row ranges whose cumulative ``total`` grows by about ``budget``."""
    a = 0
    n = len(total)
    while a < n:
        base = total[a - 1] if a else 0
        b = int(np.searchsorted(total, base + budget, side="right"))
        b = max(b, a + 1)
        yield a, b
        a = b
