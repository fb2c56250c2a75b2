"""The per-level problem of :func:`geofit.fit.volume.fit_volume`: grids, rays, the sparse
sampling operator and the emission-absorption objective with its analytic gradient.

:class:`_Objective` holds one level: the free voxels (inside the hull, not pruned), the rays and
the contiguous sample ranges that can meet them (empty-space skipping, early termination), the
sparse trilinear operator from free voxels to samples (built once per level), and
``evaluate(x) -> (value, grad, terms)`` for the flat parameter vector ``x`` of density and
colour logits. The chain rule is composed in plain sight: Huber losses on the pixels, the
raymarcher's vector-Jacobian product, the transposed sampling operator, the sigmoids.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy import ndimage

from .._threads import get_num_threads, parallel_map
from ..cameras import CamerasBase
from ..loss.robust import huber, huber_residual
from ..render.volume.raymarching import exclusive_product as _exclusive_product
from ..render.volume.raymarching import sequential_sum as _sequential_sum
from ..render.volume.raymarching import shifted_cumprod as _shifted_cumprod
from ..render.volume.raymarching import suffix_from as _suffix_from
from ..render.volume.raymarching import suffix_products as _suffix_products
from ..render.volume.raymarching import through_transmittance as _through_transmittance
from ..render.volume.raysampling import NDCMultinomialRaysampler
from ..render.volume.skipping import cell_table as _cell_table
from ..render.volume.skipping import range_layout as _range_layout
from ..render.volume.skipping import range_operator as _range_operator
from ..render.volume.skipping import ray_voxel_affine as _ray_pixel_affine
from ..render.volume.skipping import sample_ranges as _sample_ranges
from ..structures.volume import Volume

_EPS = 1e-10          # PyTorch3D's EA eps
_LOGIT_CLIP = 1e-6    # opacities/colours are kept in [clip, 1 - clip] when converted to logits




def _sigmoid(x: np.ndarray) -> np.ndarray:
    """``1 / (1 + exp(-x))`` for ``x >= 0``, ``exp(x) / (1 + exp(x))`` below (no overflow)."""
    e = np.exp(-np.abs(x))
    q = 1.0 + e
    out = np.divide(e, q)
    np.divide(1.0, q, out=out, where=x >= 0)
    return out


def _logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(p, _LOGIT_CLIP, 1.0 - _LOGIT_CLIP)
    return np.log(p) - np.log1p(-p)


def _elementwise(fn, a: np.ndarray) -> np.ndarray:
    """``fn(a)`` (float64) for an elementwise ``fn``, in slabs on the pool (the same values)."""
    flat = a.reshape(-1)
    out = np.empty(flat.size)
    cuts = np.linspace(0, flat.size, 2 * get_num_threads() + 1).astype(np.int64)

    def slab(k):
        out[cuts[k]:cuts[k + 1]] = fn(flat[cuts[k]:cuts[k + 1]])
    parallel_map(slab, range(len(cuts) - 1))
    return out.reshape(a.shape)


def _downsample(a: np.ndarray, f: int) -> np.ndarray:
    """Block mean over f x f pixels of (N, H, W, ...)."""
    if f == 1:
        return a
    N, H, W = a.shape[:3]
    return a.reshape(N, H // f, f, W // f, f, *a.shape[3:]).mean(axis=(2, 4))


class _Grid:
    """The placement of one level's grid (a Volume without values)."""

    def __init__(self, size, voxel_size: float, translation: np.ndarray):
        self.size = tuple(int(s) for s in size)
        self.voxel_size = float(voxel_size)
        self.translation = np.asarray(translation, dtype=np.float64)
        size_xyz = np.array(self.size[::-1], dtype=np.float64)
        self.scale = 0.5 * (size_xyz - 1.0) * self.voxel_size
        self.n = int(np.prod(self.size))

    def local(self, P: np.ndarray) -> np.ndarray:
        return (P + self.translation) / self.scale

    def volume(self, densities, features=None) -> Volume:
        return Volume(densities, features, self.voxel_size, -0.0 + self.translation)

    def centres(self, flat: np.ndarray | None = None) -> np.ndarray:
        """World centres ``(n, 3)`` of all voxels, or of the voxels ``flat`` (flat indices):
        the values of :meth:`Volume.get_coord_grid`, computed only where asked."""
        if flat is None:
            flat = np.arange(self.n)
        D, H, W = self.size
        z, rem = np.divmod(flat, H * W)
        y, x = np.divmod(rem, W)
        P = np.stack([np.linspace(-1.0, 1.0, W)[x], np.linspace(-1.0, 1.0, H)[y],
                      np.linspace(-1.0, 1.0, D)[z]], axis=1)
        return P * self.scale - self.translation


def _ray_box(o: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Slab test: parameter interval [t0, t1] of o + t d inside the box (t0 > t1: miss)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        ta = (lo - o) * inv
        tb = (hi - o) * inv
    tmin = np.where(np.isnan(ta), -np.inf, np.minimum(ta, tb))
    tmax = np.where(np.isnan(ta), np.inf, np.maximum(ta, tb))
    # a zero direction component: inside the slab or not at all
    flat_ok = np.where(d == 0.0, (o >= lo) & (o <= hi), True)
    t0 = tmin.max(axis=1)
    t1 = tmax.min(axis=1)
    t1 = np.where(flat_ok.all(axis=1), t1, -np.inf)
    return t0, t1


class _Objective:
    """One level: rays, kept sample ranges, the sparse operator and the loss.

    Parameters are ``[log-density of the free density voxels, colour logits (3 per column)]``;
    the columns are the voxels read by at least one kept sample.
    """

    def __init__(self, grid: _Grid, origins, directions, lengths, rgb, sil, dens_grid,
                 allowed, *, termination: float | None, n_pixels: int, huber_scale: float,
                 chunk_samples: int = 1 << 19, dtype=np.float64, smoothness=(0.0, 0.0)):
        self.grid = grid
        self.clock = None  # the fit's Clock: its deadline is checked inside evaluate
        self.dtype = np.dtype(dtype)
        self.smoothness = (float(smoothness[0]), float(smoothness[1]))
        self.n_pts = n = len(lengths)
        self.huber_scale = huber_scale
        self.n_pixels = n_pixels
        self.n_rays_total = len(origins)
        l0 = float(lengths[0])
        dl = float(lengths[-1] - lengths[0]) / (n - 1)
        # 1. candidate samples: those inside the box of the allowed voxels (+ one voxel)
        zz, yy, xx = np.nonzero(allowed)
        n_r = len(origins)
        A, B = np.empty((n_r, 3)), np.empty((n_r, 3))
        k_range = (np.zeros(n_r, np.int64), np.full(n_r, -1, np.int64))
        lo = hi = None
        if zz.size:
            lo = np.array([xx.min(), yy.min(), zz.min()], dtype=np.float64) - 1.0
            hi = np.array([xx.max(), yy.max(), zz.max()], dtype=np.float64) + 1.0
        cuts = np.linspace(0, n_r, 2 * get_num_threads() + 1).astype(np.int64)

        def rays_part(i):  # each ray on its own: parts of the rays on the pool
            sl = slice(cuts[i], cuts[i + 1])
            A[sl], B[sl] = _ray_pixel_affine(origins[sl], directions[sl], l0, dl, grid.size,
                                             grid.scale, grid.translation)
            if lo is not None:
                t0, t1 = _ray_box(A[sl], B[sl], lo, hi)   # in units of samples
                k_range[0][sl] = np.clip(np.ceil(t0 - 1e-9), 0, n)
                k_range[1][sl] = np.clip(np.floor(t1 + 1e-9), -1, n - 1)
        parallel_map(rays_part, range(len(cuts) - 1))
        # 2. contiguous ranges: first sample reading an allowed voxel .. last one still visible
        if termination is None and allowed.all():
            # dense grid: the samples inside the box are exactly those that read a voxel
            first = np.where(k_range[1] >= k_range[0], k_range[0], -1)
            last = np.where(k_range[1] >= k_range[0], k_range[1], -1)
        else:
            cell_any = _cell_table(allowed, "any")
            cell_min = None
            if termination is not None:
                cell_min = _cell_table(np.where(allowed, dens_grid, 0.0), "min")
            first, last = _sample_ranges(A, B, n, grid.size, cell_any, cell_min=cell_min,
                                         termination=termination, k_range=k_range,
                                         chunk_samples=2 * chunk_samples)
        lay = _range_layout(first, last, chunk_samples)
        self.layout = lay
        self.ray_ids = lay.ray_ids
        self.n_samples = int(lay.count.sum())
        # 3. the sparse operator over the voxels the kept samples read
        self.W, self.columns = _range_operator(A, B, lay, grid.size, dtype=self.dtype,
                                               all_columns=bool(termination is None
                                                                and allowed.all()))
        # free densities: columns that are allowed; the others are fixed empty
        self.free_idx = np.flatnonzero(allowed.reshape(-1)[self.columns])
        self.n_free_density = int(self.free_idx.size)
        self.n_columns = int(self.columns.size)
        # targets of the kept rays, and the constant loss of the others (rendered as 0)
        self.rgb = rgb[self.ray_ids].astype(self.dtype)
        self.sil = sil[self.ray_ids].astype(self.dtype)
        miss = np.ones(len(origins), bool)
        miss[self.ray_ids] = False
        miss_c = huber(0.0 * rgb[miss], rgb[miss], huber_scale)[0]
        miss_s = huber(0.0 * sil[miss], sil[miss], huber_scale)[0]
        self.const_colour = float(miss_c.sum())
        self.const_sil = float(miss_s.sum())
        self._miss = (np.flatnonzero(miss), miss_c.mean(axis=1) + miss_s)
        # (1 + eps)^first: the factor of the skipped empty samples in front of each ray
        self.lead = ((1.0 + _EPS) ** lay.first).astype(self.dtype)
        # float32: 1 + eps rounds to 1 and every leading factor is 1 (the march skips them)
        self._unit_eps = bool(self.dtype.type(1.0 + _EPS) == 1.0 and np.all(self.lead == 1.0))
        self._blocks = None
        self._chunk_W = None
        self._buffers: dict = {}  # the sampled values and their gradients, reused
        self._last = None  # (x, each kept ray's loss) of the last evaluation
        # smoothness: squared differences between face-neighbouring free voxels
        self.D_density, self.D_colour = parallel_map(
            lambda flat: _difference_operator(flat, grid.size),
            [self.columns[self.free_idx], self.columns])

    @property
    def n_params(self) -> int:
        return self.n_free_density + 3 * self.n_columns

    # ---- parameters <-> grids ---------------------------------------------------------------

    def pack(self, ld_grid: np.ndarray, lc_grid: np.ndarray) -> np.ndarray:
        """Flat parameter vector from logit grids (D*H*W,) and (3, D*H*W)."""
        cols = self.columns
        return np.concatenate([ld_grid[cols[self.free_idx]], lc_grid[:, cols].reshape(-1)])

    def unpack_into(self, x: np.ndarray, ld_grid: np.ndarray, lc_grid: np.ndarray) -> None:
        cols = self.columns
        nd = self.n_free_density
        ld_grid[cols[self.free_idx]] = x[:nd]
        lc_grid[:, cols] = x[nd:].reshape(3, -1)

    # ---- objective ---------------------------------------------------------------------------

    def _values(self, x: np.ndarray):
        """Voxel values, channel-major ``(4, n_columns)``: density, then RGB (the sigmoids of
        the four channels run on the pool)."""
        nd = self.n_free_density
        X = np.zeros((4, self.n_columns), dtype=self.dtype)
        lc = x[nd:].reshape(3, -1)
        sc = np.empty(lc.shape)

        def channel(ch):
            if ch == 0:
                v = _sigmoid(x[:nd])
                X[0, self.free_idx] = v
                return v
            sc[ch - 1] = _sigmoid(lc[ch - 1])
            X[ch] = sc[ch - 1]
            return None
        sd = parallel_map(channel, range(4))[0]
        return X, sd, sc

    def _split(self):
        """Row blocks of W at chunk boundaries, one per thread, transposed (built once; views
        of W's arrays): ``(r0, r1, W[r0:r1].T)``."""
        if self._blocks is None:
            n_t = get_num_threads()
            chunks = self.layout.chunks
            if n_t < 2 or len(chunks) < 2:
                self._blocks = [(0, self.layout.n_rows, _transposed(self.W))]
            else:
                starts = np.array([row for row, a, b, K in chunks])
                nnz_at = self.W.indptr[starts]  # nonzeros before each chunk
                targets = self.W.nnz * np.arange(1, n_t) / n_t
                cuts = np.unique(np.clip(np.searchsorted(nnz_at, targets), 1, len(chunks) - 1))
                rows = [0, *starts[cuts].tolist(), self.layout.n_rows]
                self._blocks = [(r0, r1, _transposed(_row_block(self.W, r0, r1)))
                                for r0, r1 in zip(rows, rows[1:])]
        return self._blocks

    def _march_chunk(self, k: int, Y, G, per_ray: np.ndarray | None = None):
        """The loss sums (colour, silhouette) of ray chunk ``k``; writes its sample gradients
        into G (if given).

        ``Y`` and ``G`` are channel-major ``(4, n_rows)`` (density, RGB), so each chunk's
        channels are contiguous ``(rays, K)`` arrays. The sums over a ray's samples are
        sequential (cumulative sums and products), in the same order as a strided einsum.
        With ``per_ray`` (n_kept,), each kept ray's colour mean plus silhouette loss is stored
        there (for per-view diagnostics).
        """
        s = self.huber_scale
        n_col = 3.0 * self.n_pixels
        n_sil = float(self.n_pixels)
        unit = self._unit_eps
        row, a, b, K = self.layout.chunks[k]
        r = b - a
        rays = slice(a, b)
        d = Y[0, row:row + r * K].reshape(r, K)
        f = Y[1:, row:row + r * K].reshape(3, r, K)
        c = (1.0 + _EPS) - d
        # with 1 + eps == 1 in the working precision, c is 1 - d and the leading factor 1:
        # the transmittances are then the prefix products of 1 - d
        P = _shifted_cumprod(c, 1)
        T = P if unit else P * self.lead[rays, None]
        w = d * T
        rgb = _sequential_sum(w * f).T  # (r, 3), each summed from the first sample on
        if unit:
            op = 1.0 - P[:, -1] * c[:, -1]
        else:
            op = 1.0 - np.prod(1.0 - d, axis=1)
        hc, gc = huber_residual(rgb - self.rgb[rays], s)
        hs, gs = huber_residual(op - self.sil[rays], s)
        sums = float(hc.sum(dtype=np.float64)), float(hs.sum(dtype=np.float64))
        if per_ray is not None:
            per_ray[rays] = hc.mean(axis=1, dtype=np.float64) + hs
        if G is None:
            return sums
        g_rgb = gc / n_col
        g_op = gs / n_sil
        h = f[0] * g_rgb[:, 0, None]
        h += f[1] * g_rgb[:, 1, None]
        h += f[2] * g_rgb[:, 2, None]
        S = _suffix_from(w * h, 1)
        through = _through_transmittance(S, c, d, h if unit else h * self.lead[rays, None],
                                         1)
        if unit:  # prod_{j != k} c_j: the prefix products P times the suffix products
            ex = _suffix_products(c)
            ex *= P
        else:
            ex = _exclusive_product(1.0 - d)
        ex *= g_op[:, None]
        g0 = G[0, row:row + r * K].reshape(r, K)
        np.multiply(T, h, out=g0)
        g0 -= through
        g0 += ex
        gf = G[1:, row:row + r * K].reshape(3, r, K)
        for ch in range(3):  # colour channels
            np.multiply(w, g_rgb[:, ch, None], out=gf[ch])
        return sums

    def ray_losses(self, x: np.ndarray) -> np.ndarray:
        """(n_rays,) colour (mean over RGB) plus silhouette Huber loss of every ray (the last
        evaluation's when it was at ``x``: the fit asks at its final point)."""
        if self._last is not None and np.array_equal(self._last[0], x):
            kept = self._last[1]
        else:
            X, _, _ = self._values(x)
            kept = np.zeros(len(self.ray_ids))
            self._sweep(X, None, kept)
        out = np.empty(self.n_rays_total)
        out[self.ray_ids] = kept
        out[self._miss[0]] = self._miss[1]
        return out

    def _buffer(self, name: str) -> np.ndarray:
        """A (4, n_rows) work array kept from one evaluation to the next (fresh arrays of this
        size, 107 MB each at 128^3, cost page faults every time: ~0.05 s of system time)."""
        if name not in self._buffers:
            self._buffers[name] = np.empty((4, self.layout.n_rows), dtype=self.dtype)
        return self._buffers[name]

    def _sweep(self, X: np.ndarray, G: np.ndarray | None, per_ray=None, extra=None):
        """Sample the values ``X (4, n_columns)`` along every kept ray and march: the loss sums
        (colour, silhouette) and (G given) the sample gradients in ``G (4, n_rows)``.

        One task per ray chunk on the pool: its rows of W times each channel (per row the
        same sums as the whole product), then its march while they are in the cache. The
        chunks' sums are added in chunk order within the parts of :meth:`_parts`, then the
        parts' (the order that fixes the value's rounding). ``extra()``, if given, runs as
        one more task after the chunks (filling the pool's tail); returns the sums and its
        result.
        """
        chunks = self.layout.chunks
        if self._chunk_W is None:  # views of W's rows, one per chunk
            self._chunk_W = [_row_block(self.W, row, row + (b - a) * K)
                             for row, a, b, K in chunks]
        Y = self._buffer("Y")

        def chunk(k):
            if k is None:
                return extra()
            row, a, b, K = chunks[k]
            Wk = self._chunk_W[k]
            for ch in range(4):  # channels
                Y[ch, row:row + (b - a) * K] = Wk @ X[ch]
            return self._march_chunk(k, Y, G, per_ray)
        sums = parallel_map(chunk, [*range(len(chunks)), *([None] if extra else [])])
        extra_result = sums.pop() if extra else None
        part_sums = []
        for lo, hi in self._parts():  # parts of the chunks
            col_sum = sil_sum = 0.0
            for c_k, s_k in sums[lo:hi]:  # chunks, in order
                col_sum += c_k
                sil_sum += s_k
            part_sums.append((col_sum, sil_sum))
        return part_sums, extra_result

    def _parts(self) -> list:
        """Ranges of ray chunks whose loss sums are added first (then the parts' sums, in this
        order: the parts, one per row block, fix the value's rounding)."""
        nch = len(self.layout.chunks)
        bounds = np.linspace(0, nch, len(self._split()) + 1).astype(int).tolist()
        return list(zip(bounds, bounds[1:]))

    def evaluate(self, x: np.ndarray, *, want_grad: bool = True):
        """Loss (colour + silhouette Huber means) and its gradient with respect to ``x``.

        Sparse products and ray chunks run on geofit's threads (numpy and scipy release the GIL).
        Values and sample gradients are channel-major: one sparse matrix-vector product per
        channel (scipy's single-vector kernels are faster than its multi-vector ones, with the
        same sums in the same order).
        """
        if self.clock is not None:  # a time budget holds inside long evaluations
            self.clock.check()
        X, sd, sc = self._values(x)
        blocks = self._split()
        G = self._buffer("G") if want_grad else None
        per_ray = np.empty(len(self.ray_ids))
        lam_d, lam_c = self.smoothness
        smooth = lam_d > 0 or lam_c > 0
        # the prior runs on the pool beside the ray chunks
        sums, prior = self._sweep(X, G, per_ray, extra=(
            lambda: self._smoothness(sd, sc, want_grad)) if smooth else None)
        self._remember(x, per_ray)
        if self.clock is not None:
            self.clock.check()
        n_col = 3.0 * self.n_pixels
        loss_c = (self.const_colour + sum(v[0] for v in sums)) / n_col
        loss_s = (self.const_sil + sum(v[1] for v in sums)) / float(self.n_pixels)
        terms = {"colour": loss_c, "silhouette": loss_s}
        if smooth:
            terms["smoothness"], s_sd, s_sc = prior
        if not want_grad:
            return sum(terms.values()), terms

        def bwd(task):  # the transposed products of the row blocks, one per thread
            r0, r1, Wt = task
            return np.stack([Wt @ G[ch, r0:r1] for ch in range(4)])
        Zs = parallel_map(bwd, blocks)
        value = sum(terms.values())
        Z = Zs[0] if len(Zs) == 1 else sum(Zs[1:], Zs[0])
        nd = self.n_free_density
        grad = np.empty_like(x)
        gc = grad[nd:].reshape(3, -1)

        def chain(ch):  # through the sigmoids, one channel per task
            if ch == 0:
                g = Z[0, self.free_idx].astype(np.float64)
                if smooth:
                    g = g + s_sd
                grad[:nd] = g * sd * (1.0 - sd)
            else:
                g = Z[ch].astype(np.float64)
                if smooth:
                    g = g + s_sc[ch - 1]
                v = sc[ch - 1]
                gc[ch - 1] = g * v * (1.0 - v)
        parallel_map(chain, range(4))
        return value, grad, terms

    def _remember(self, x: np.ndarray, per_ray: np.ndarray) -> None:
        """Keep a copy of ``x`` (in a reused array) and its rays' losses for :meth:`ray_losses`."""
        if self._last is None or self._last[0].shape != x.shape:
            self._last = (np.array(x, dtype=np.float64), per_ray)
        else:
            np.copyto(self._last[0], x)
            self._last = (self._last[0], per_ray)

    def _smoothness(self, sd: np.ndarray, sc: np.ndarray, want_grad: bool):
        """The prior's value and (``want_grad``) its gradients with respect to the density
        and colour values ``sd`` (n_free,) and ``sc`` (3, n_columns)."""
        lam_d, lam_c = self.smoothness
        dd = self.D_density @ sd
        dc = self.D_colour @ sc.T
        e_d = max(dd.size, 1)
        e_c = max(dc.size, 1)
        value = lam_d * float(dd @ dd) / e_d + lam_c * float(np.sum(dc * dc)) / e_c
        if not want_grad:
            return value, None, None
        return (value, (2.0 * lam_d / e_d) * (self.D_density.T @ dd),
                (2.0 * lam_c / e_c) * (self.D_colour.T @ dc).T)


def _sharing(cls, data: np.ndarray, indices: np.ndarray, indptr: np.ndarray, shape):
    """``cls((data, indices, indptr), shape)`` on these very arrays: scipy's constructor
    copies arrays that are views of less than half their base (its ``prune``), which the row
    blocks below are (the chunks' views of W: 400 MB copied per level at 128^3)."""
    m = cls(shape, dtype=data.dtype)
    m.data, m.indices, m.indptr = data, indices, indptr
    return m


def _row_block(W: sp.csr_matrix, r0: int, r1: int) -> sp.csr_matrix:
    """Rows ``r0:r1`` of a csr matrix as a view of its data and indices (``W[r0:r1]`` copies
    them); its products are ``W[r0:r1]``'s, entry for entry."""
    p0, p1 = int(W.indptr[r0]), int(W.indptr[r1])
    return _sharing(sp.csr_matrix, W.data[p0:p1], W.indices[p0:p1],
                    W.indptr[r0:r1 + 1] - W.indptr[r0], (r1 - r0, W.shape[1]))


def _transposed(B: sp.csr_matrix) -> sp.csc_matrix:
    """``B.T`` sharing B's arrays (``B.T`` copies them when they are a small view)."""
    return _sharing(sp.csc_matrix, B.data, B.indices, B.indptr, B.shape[::-1])


def _difference_operator(flat: np.ndarray, size) -> sp.csr_matrix:
    """(E, n) forward differences between the voxels ``flat`` (sorted) that are face neighbours.

    Row ``e`` of the result is ``+1`` at voxel ``i`` and ``-1`` at its neighbour ``j`` along x, y
    or z, for every pair of listed voxels.
    """
    D, H, W = size
    n = len(flat)
    lookup = np.full(D * H * W, -1, np.int64)
    lookup[flat] = np.arange(n)
    z, rem = np.divmod(flat, H * W)
    y, x = np.divmod(rem, W)
    rows_i, rows_j = [], []
    for coord, extent, off in ((x, W, 1), (y, H, W), (z, D, H * W)):  # axes
        ok = coord + 1 < extent
        j = np.full(n, -1, np.int64)
        j[ok] = lookup[flat[ok] + off]
        keep = np.flatnonzero(j >= 0)
        rows_i.append(keep)
        rows_j.append(j[keep])
    e = sum(len(k) for k in rows_i)
    idx = np.int32 if max(n, 2 * e) < 2 ** 31 - 1 else np.int64
    ij = np.empty((e, 2), idx)  # row e: +1 at i, -1 at j > i (sorted, no duplicates)
    ij[:, 0] = np.concatenate(rows_i)
    ij[:, 1] = np.concatenate(rows_j)
    data = np.empty((e, 2))
    data[:, 0] = 1.0
    data[:, 1] = -1.0
    return sp.csr_matrix((data.reshape(-1), ij.reshape(-1), np.arange(0, 2 * e + 1, 2,
                                                                      dtype=idx)), shape=(e, n))


def _resample(values: np.ndarray, coarse: _Grid, fine: _Grid) -> np.ndarray:
    """Trilinear resampling (zero padding) of coarse values ``(..., D, H, W)`` at fine centres."""
    # fine voxel centres in coarse voxel-index coordinates, per axis (the grids are separable)
    axes = []
    for ax in range(3):  # z, y, x
        nf, nc = fine.size[ax], coarse.size[ax]
        t = 2 - ax
        world = np.linspace(-1.0, 1.0, nf) * fine.scale[t] - fine.translation[t]
        axes.append(((world + coarse.translation[t]) / coarse.scale[t] + 1.0) * 0.5 * (nc - 1))
    zz, yy, xx = np.meshgrid(*axes, indexing="ij")
    coords = np.stack([zz, yy, xx])
    lead = values.shape[:-3]
    flat = values.reshape((-1,) + coarse.size)
    out = np.empty((len(flat),) + fine.size)
    # channels x slabs of z on the pool (map_coordinates releases the GIL; each output voxel
    # is computed on its own, so the slabs change nothing)
    n_slabs = max(1, min(fine.size[0], 2 * get_num_threads()))
    cuts = np.linspace(0, fine.size[0], n_slabs + 1).astype(int)

    def slab(task):
        ch, z0, z1 = task
        out[ch, z0:z1] = ndimage.map_coordinates(flat[ch], coords[:, z0:z1], order=1,
                                                 mode="grid-constant", cval=0.0)
    parallel_map(slab, [(ch, z0, z1) for ch in range(len(flat))  # channels
                        for z0, z1 in zip(cuts[:-1], cuts[1:]) if z1 > z0])
    return out.reshape(lead + fine.size)


def _rays(cameras: CamerasBase, R_h: int, R_w: int, n_pts: int, min_depth: float,
          max_depth: float):
    """Origins and directions ``(N R_h R_w, 3)`` of the tutorial's raysampler, and its sample
    lengths ``(n_pts,)`` (the same for every ray: the sampler is asked for two samples only,
    since its ``(N, H, W, n_pts)`` lengths would be one array per ray of the same values)."""
    sampler = NDCMultinomialRaysampler(image_width=R_w, image_height=R_h, n_pts_per_ray=2,
                                       min_depth=min_depth, max_depth=max_depth)
    b = sampler(cameras)
    return (b.origins.reshape(-1, 3), b.directions.reshape(-1, 3),
            np.linspace(min_depth, max_depth, n_pts))
