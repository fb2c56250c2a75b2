"""Empty-space skipping for volume rendering and fitting: contiguous sample ranges per ray and
the sparse trilinear operator over the samples kept.

Shared by :class:`~geofit.render.volume.renderer.VolumeRenderer` and geofit's volume fit (the
names here are public within geofit; the package API, ``__all__``, stays empty). Sample ``k`` of
ray ``i`` sits at continuous voxel coordinates ``A[i] + k B[i]`` (:func:`ray_voxel_affine`, x, y,
z order); a cell table (:func:`cell_table`) says per trilinear cell whether it reads a marked
voxel (and a lower bound of its densities); :func:`sample_ranges` gives each ray's first and last
useful sample; :func:`range_layout` sorts and chunks the kept rays (:class:`RangeLayout`), and
:func:`range_operator` builds the ``(rows, voxels)`` csr matrix of trilinear weights.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from ..._threads import parallel_map

__all__: list[str] = []


_PAD = 2  # cell tables are padded by two cells on each side (see cell_table)


def cell_table(voxels: np.ndarray, reduce: str) -> np.ndarray:
    """Per trilinear cell, a reduction over its 8 corner voxels (zero padding outside).

    The cell with lowest corner ``(z, y, x)`` (each from -2 to size + 1) sits at index
    ``(z + 2, y + 2, x + 2)`` of the ``(D + 4, H + 4, W + 4)`` result. ``reduce`` is "any" (bool
    input: does the cell read a marked voxel) or "min" (float input: the smallest corner value,
    a lower bound of every trilinear sample in the cell).
    """
    D, H, W = voxels.shape
    pad = np.zeros((D + 4, H + 4, W + 4), dtype=voxels.dtype)
    pad[2:D + 2, 2:H + 2, 2:W + 2] = voxels
    out = pad.copy()
    # the cell at index i has corners at voxel-pad indices i and i + 1 along each axis
    for ax in range(3):
        sh = np.zeros_like(out)
        sl_dst = [slice(None)] * 3
        sl_src = [slice(None)] * 3
        sl_dst[ax] = slice(0, out.shape[ax] - 1)
        sl_src[ax] = slice(1, out.shape[ax])
        if reduce == "any":
            sh[tuple(sl_dst)] = out[tuple(sl_src)]
            out = out | sh
        else:
            sh[tuple(sl_dst)] = out[tuple(sl_src)]
            out = np.minimum(out, sh)
    return out


def ray_voxel_affine(origins, directions, l0: float, dl: float, grid_size, scale, translation):
    """Continuous voxel coordinates of sample k of each ray: ``A + k B`` (x, y, z order)."""
    half = 0.5 * (np.array(grid_size[::-1], dtype=np.float64) - 1.0)
    A = ((origins + l0 * directions + translation) / scale + 1.0) * half
    B = (dl * directions / scale) * half
    return A, B


def _cells_of(pix: np.ndarray, grid_size) -> np.ndarray:
    """Flat index into a :func:`cell_table` of the cell of continuous voxel coordinates."""
    return _flat_cells(lambda ax: np.array(pix[..., ax], dtype=np.float64), grid_size)


def _cells_affine(A: np.ndarray, B: np.ndarray, t: np.ndarray, grid_size) -> np.ndarray:
    """``_cells_of(A[:, None] + t[..., None] * B[:, None])`` for rays ``A, B (r, 3)`` at sample
    parameters ``t (r, K)``: the same cells without the ``(r, K, 3)`` coordinates."""
    def coordinate(ax):
        p = t * B[:, ax, None]
        p += A[:, ax, None]
        return p
    return _flat_cells(coordinate, grid_size)


def _flat_cells(coordinate, grid_size) -> np.ndarray:
    """The cells' flat indices from ``coordinate(ax)``, a new float64 array of the continuous
    voxel coordinate along axis ``ax`` (0: x), worked on in place axis by axis (the index is
    summed in float64: integers, exact far beyond any grid's size)."""
    D, H, W = grid_size
    hi = (W + 1.0, H + 1.0, D + 1.0)
    acc = None
    for ax, stride in ((2, 0), (1, H + 4), (0, W + 4)):  # z, y, x
        p = coordinate(ax)
        np.clip(p, -2.0, hi[ax], out=p)
        np.floor(p, out=p)
        p += 2.0
        if acc is None:
            acc = p
        else:
            acc *= stride
            acc += p
    return acc.astype(np.int64)


def _pix_corners(pix: np.ndarray, grid_size):
    """Trilinear corners of continuous voxel coordinates (k, 3): flat (k, 8), weights, valid."""
    D, H, W = grid_size
    size = np.array([W, H, D])
    pix = np.clip(pix, -1.0, size.astype(np.float64))
    b = np.floor(pix)
    frac = pix - b
    b = b.astype(np.int64)
    g = 1.0 - frac
    wx = np.stack([g[:, 0], frac[:, 0]], axis=1)
    wyx = (np.stack([g[:, 1], frac[:, 1]], axis=1)[:, :, None] * wx[:, None, :]).reshape(-1, 4)
    w = (np.stack([g[:, 2], frac[:, 2]], axis=1)[:, :, None] * wyx[:, None, :]).reshape(-1, 8)
    offs = np.array([0, 1, W, W + 1, H * W, H * W + 1, H * W + W, H * W + W + 1])
    flat = ((b[:, 2] * H + b[:, 1]) * W + b[:, 0])[:, None] + offs[None, :]
    valid = w != 0.0
    edge = np.flatnonzero(np.any((b < 0) | (b > size - 2), axis=1))
    if edge.size:  # corners outside the grid: zero padding
        be = b[edge]
        ix = be[:, 0, None] + np.array([0, 1])
        iy = be[:, 1, None] + np.array([0, 1])
        iz = be[:, 2, None] + np.array([0, 1])
        vx = (ix >= 0) & (ix < W)
        vy = (iy >= 0) & (iy < H)
        vz = (iz >= 0) & (iz < D)
        ve = (vz[:, :, None, None] & vy[:, None, :, None] & vx[:, None, None, :]).reshape(-1, 8)
        valid[edge] &= ve
        ixc, iyc, izc = np.clip(ix, 0, W - 1), np.clip(iy, 0, H - 1), np.clip(iz, 0, D - 1)
        flat[edge] = ((izc[:, :, None, None] * H + iyc[:, None, :, None]) * W
                      + ixc[:, None, None, :]).reshape(-1, 8)
    return flat, w, valid


def _chunk_bounds(sorted_counts: np.ndarray, chunk_samples: int) -> list:
    """Split rays sorted by increasing count into runs of at most ~chunk_samples padded samples."""
    bounds = []
    a, n = 0, len(sorted_counts)
    while a < n:  # chunks
        r = max(1, chunk_samples // max(int(sorted_counts[a]), 1))
        b = min(n, a + r)
        while b > a + 1 and (b - a) * int(sorted_counts[b - 1]) > chunk_samples:
            b = a + max(1, (b - a) // 2)
        bounds.append((a, b))
        a = b
    return bounds


def sample_ranges(A, B, n_pts: int, grid_size, cell_any: np.ndarray, *,
                   cell_min: np.ndarray | None = None, termination: float | None = None,
                   k_range=None, lengths: np.ndarray | None = None,
                   chunk_samples: int = 1 << 20):
    """First and last sample of each ray whose cell reads a marked voxel (-1: none).

    Sample ``k`` of ray ``i`` sits at continuous voxel coordinates ``A[i] + t B[i]`` with
    ``t = k``, or ``t = lengths[i, k]`` when ``lengths (r, n_pts)`` is given.

    With ``cell_min`` and ``termination``, the last sample is also capped where the
    transmittance computed from the cell lower bounds (an upper bound of the true
    transmittance) falls below ``termination``. ``k_range`` = (k_lo, k_hi) restricts the samples
    examined (e.g. to a box).
    """
    n_rays = len(A)
    first = np.full(n_rays, -1, np.int64)
    last = np.full(n_rays, -1, np.int64)
    if k_range is None:
        k_lo = np.zeros(n_rays, np.int64)
        k_hi = np.full(n_rays, n_pts - 1, np.int64)
    else:
        k_lo, k_hi = k_range
    cand = np.flatnonzero(k_hi >= k_lo)
    if cand.size == 0:
        return first, last
    span = k_hi[cand] - k_lo[cand] + 1
    srt = np.argsort(span, kind="stable")
    order, span = cand[srt], span[srt]
    any_flat = cell_any.reshape(-1)
    min_flat = None if cell_min is None else cell_min.reshape(-1)

    def ranges(bounds):  # one chunk of rays (independent of the others: run on the pool)
        a, b = bounds
        ids = order[a:b]
        K = int(span[b - 1])
        kk = k_lo[ids, None] + np.arange(K)[None, :]
        inr = kk <= k_hi[ids, None]
        if lengths is None:
            t = kk.astype(np.float64)
        else:
            t = lengths[ids[:, None], np.minimum(kk, n_pts - 1)]
        cells = _cells_affine(A[ids], B[ids], t, grid_size)
        act = any_flat[cells] & inr
        has = act.any(axis=1)
        if not has.any():
            return None
        f = np.argmax(act, axis=1)
        lst = K - 1 - np.argmax(act[:, ::-1], axis=1)
        if min_flat is not None and termination is not None:
            dens = np.where(act, np.clip(min_flat[cells], 0.0, 1.0), 0.0)
            T = np.cumprod(1.0 - dens, axis=1)
            below = T < termination
            stop = np.where(below.any(axis=1), np.argmax(below, axis=1), K - 1)
            lst = np.minimum(lst, np.maximum(stop, f))
        return ids[has], f[has], lst[has]

    for res in parallel_map(ranges, _chunk_bounds(span, chunk_samples)):  # chunks of rays
        if res is not None:
            ids, f, lst = res
            first[ids] = k_lo[ids] + f
            last[ids] = k_lo[ids] + lst
    return first, last


class RangeLayout(NamedTuple):
    """Rays sorted by sample count, in chunks padded to their longest ray."""

    ray_ids: np.ndarray   # (r,) rays with at least one sample, by increasing count
    first: np.ndarray     # (r,) first sample index
    count: np.ndarray     # (r,) samples marched
    chunks: list          # [(row, a, b, K)]: rays ray_ids[a:b], rows row .. row + (b-a) K
    n_rows: int


def range_layout(first: np.ndarray, last: np.ndarray, chunk_samples: int) -> RangeLayout:
    kept = np.flatnonzero(first >= 0)
    count = last[kept] - first[kept] + 1
    order = np.argsort(count, kind="stable")
    ray_ids, count = kept[order], count[order]
    chunks = []
    row = 0
    for a, b in _chunk_bounds(count, chunk_samples):  # chunks of rays
        K = int(count[b - 1])
        chunks.append((row, a, b, K))
        row += (b - a) * K
    return RangeLayout(ray_ids, first[ray_ids], count, chunks, row)


def _range_samples(A, B, layout: RangeLayout, a: int, b: int, lengths=None):
    """Continuous voxel coordinates (s, 3), local ray (s,) and offset (s,) of rays a:b."""
    cnt = layout.count[a:b]
    start = np.cumsum(cnt) - cnt
    local = np.repeat(np.arange(b - a), cnt)
    j = np.arange(int(cnt.sum())) - np.repeat(start, cnt)
    ids = layout.ray_ids[a:b][local]
    k = layout.first[a:b][local] + j
    t = k.astype(np.float64) if lengths is None else lengths[ids, k]
    return A[ids] + t[:, None] * B[ids], local, j


def range_operator(A, B, layout: RangeLayout, grid_size, *, lengths=None,
                    chunk_samples: int = 1 << 18, all_columns: bool = False,
                    dtype=np.float64):
    """The trilinear operator of a range layout over the voxels its samples read.

    With ``all_columns`` the columns are all the voxels of the grid and every sample row holds
    8 entries (explicit zeros for corners outside the grid), which skips the bookkeeping of
    the sparse case (for dense grids).

    Returns
    -------
    W : (layout.n_rows, m) csr_matrix
        Row ``row + i K + j`` holds the weights of sample ``j`` of ray ``i`` of the chunk at
        ``row`` (padding rows are empty).
    columns : (m,) int64
        Flat indices of the voxels read by at least one sample (sorted).
    """
    D, H, W = grid_size
    n_vox = D * H * W
    if all_columns:
        return _dense_range_operator(A, B, layout, grid_size, lengths, chunk_samples, dtype)
    # pass 1: which cells are read -> which voxels are read (the 8 corners of every cell);
    # chunks on the pool, their sample positions kept for pass 2
    def read_cells(chunk):
        row, a, b, K = chunk
        pix, local, j = _range_samples(A, B, layout, a, b, lengths)
        return pix, row + local * K + j, _cells_of(pix, grid_size)

    samples = parallel_map(read_cells, layout.chunks)
    cells = np.zeros((D + 4) * (H + 4) * (W + 4), bool)
    for _, _, c in samples:  # chunks of rays
        cells[c] = True
    cells = cells.reshape(D + 4, H + 4, W + 4)
    read = np.zeros((D, H, W), bool)
    for dz in (0, 1):  # voxel v is corner (dz, dy, dx) of the cell with lowest corner v - d
        for dy in (0, 1):
            for dx in (0, 1):
                read |= cells[2 - dz:D + 2 - dz, 2 - dy:H + 2 - dy, 2 - dx:W + 2 - dx]
    columns = np.flatnonzero(read)
    idx = np.int32 if max(layout.n_rows, n_vox) < 2 ** 31 - 1 else np.int64
    lookup = np.full(n_vox, -1, idx)
    lookup[columns] = np.arange(columns.size, dtype=idx)

    # pass 2: the entries, chunk by chunk on the pool
    def entries(k):
        pix, rows, _ = samples[k]
        samples[k] = None
        out = []
        for s0 in range(0, len(rows), chunk_samples):  # sub-chunks of samples
            sl = slice(s0, s0 + chunk_samples)
            flat, w, valid = _pix_corners(pix[sl], grid_size)
            col = lookup[flat]
            valid &= col >= 0
            out.append((rows[sl], valid.sum(axis=1), w[valid].astype(dtype), col[valid]))
        return out

    pieces = [sub for part in parallel_map(entries, range(len(samples)))  # chunks of rays
              for sub in part]  # sub-chunks, in row order
    sizes = [len(dat) for _, _, dat, _ in pieces]
    offsets = np.concatenate([[0], np.cumsum(sizes, dtype=np.int64)])
    if offsets[-1] >= 2 ** 31 - 1:
        idx = np.int64
    counts = np.zeros(layout.n_rows, np.uint8)  # entries per row (<= 8)
    data = np.empty(int(offsets[-1]), dtype)
    ind = np.empty(int(offsets[-1]), idx)

    def place(k):  # each piece into its slice of data and indices (the pool copies)
        rows, cnt, dat, col = pieces[k]
        counts[rows] = cnt
        data[offsets[k]:offsets[k + 1]] = dat
        ind[offsets[k]:offsets[k + 1]] = col
        pieces[k] = None
    parallel_map(place, range(len(pieces)))
    indptr = np.zeros(layout.n_rows + 1, idx)
    np.cumsum(counts, out=indptr[1:], dtype=idx)
    Wm = sp.csr_matrix((data, ind, indptr), shape=(layout.n_rows, columns.size))
    return Wm, columns


def _dense_range_operator(A, B, layout: RangeLayout, grid_size, lengths, chunk_samples, dtype):
    """:func:`range_operator` over all voxels: 8 entries per sample row, no compression."""
    D, H, W = grid_size
    n_vox = D * H * W
    idx = np.int32 if max(8 * layout.n_rows, n_vox) < 2 ** 31 - 1 else np.int64
    n_s = int(layout.count.sum())
    indices = np.empty(8 * n_s, idx)
    data = np.empty(8 * n_s, dtype)
    counts = np.zeros(layout.n_rows, np.int64)
    pos = 0
    for row, a, b, K in layout.chunks:  # chunks of rays
        pix, local, j = _range_samples(A, B, layout, a, b, lengths)
        rows = row + local * K + j
        counts[rows] = 8
        for s0 in range(0, len(rows), chunk_samples):  # sub-chunks of samples
            sl = slice(s0, s0 + chunk_samples)
            flat, w, valid = _pix_corners(pix[sl], grid_size)
            m = flat.shape[0] * 8
            indices[pos:pos + m] = flat.ravel()
            data[pos:pos + m] = np.where(valid, w, 0.0).ravel()
            pos += m
    indptr = np.zeros(layout.n_rows + 1, np.int64)
    np.cumsum(counts, out=indptr[1:])
    Wm = sp.csr_matrix((data, indices, indptr.astype(idx)), shape=(layout.n_rows, n_vox))
    return Wm, np.arange(n_vox)
