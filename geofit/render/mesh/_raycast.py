"""Camera-ray casting for the mesh renderer: pixel rays generated and cast in float32 chunks.

:class:`geofit.raycast.RayCaster` is the general tool (any rays, float64 validation and
refinement of every ray). Rendering casts millions of *structured* rays (one per pixel, all
from one camera per view), so this module builds the rays itself, chunk by chunk inside worker
threads, in float32 in the scene's normalised frame, skips pixels outside the projected bounding
rectangle of the mesh, and refines only the hits in float64. The Embree scene is built the same
way as RayCaster's: vertices mapped into ``[-1, 1]^3`` and robust (watertight) traversal.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..._threads import get_num_threads, parallel_map
from ...raycast.embree import EmbreeScene, moller_trumbore

# Rays per task handed to a worker thread (a few tasks per thread balance the load).
_TASK_RAYS = 65_536


def n_threads_default() -> int:
    return get_num_threads()


class PixelHits(NamedTuple):
    """Compact camera-ray hits of one group of views (sorted by pixel)."""

    pixel: np.ndarray  # (k,) int64 flat index into (N, H, W)
    face: np.ndarray   # (k,) int64 face of the group's mesh
    bary: np.ndarray   # (k, 3) float64 perspective-correct barycentrics (w0, w1, w2)
    depth: np.ndarray  # (k,) float64 ray parameter = view depth


class ViewRays(NamedTuple):
    """Affine pixel-ray maps of one view in world coordinates.

    The ray through NDC ``(x, y)`` is ``o + x ox + y oy + t (d + x dx + y dy)`` with view depth
    ``t`` (directions have view-space z component 1).
    """

    o: np.ndarray
    ox: np.ndarray
    oy: np.ndarray
    d: np.ndarray
    dx: np.ndarray
    dy: np.ndarray


def view_rays(cameras) -> list[ViewRays]:
    """Affine ray maps of every camera, from the public ``unproject_points``.

    Unprojecting the NDC points (0, 0), (1, 0), (0, 1) at view depths 1 and 2 gives the map
    exactly (it is affine in x, y for both perspective and orthographic cameras).
    """
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    p1 = cameras.unproject_points(np.c_[xy, np.ones(3)], world_coordinates=True)
    p2 = cameras.unproject_points(np.c_[xy, np.full(3, 2.0)], world_coordinates=True)
    D = p2 - p1          # (N, 3, 3): directions at the three points
    O = p1 - D           # origins (view depth 0)
    out = []
    for n in range(len(D)):  # loop over views
        out.append(ViewRays(O[n, 0], O[n, 1] - O[n, 0], O[n, 2] - O[n, 0],
                            D[n, 0], D[n, 1] - D[n, 0], D[n, 2] - D[n, 0]))
    return out


def project(verts: np.ndarray, vr: ViewRays, perspective: bool) -> tuple[np.ndarray, np.ndarray]:
    """NDC ``xy (V, 2)`` and view depth ``z (V,)`` of world points, from a view's ray map.

    Solves ``P = o + x ox + y oy + z (d + x dx + y dy)``; for perspective cameras (``ox = oy =
    0``) this is linear in ``(x z, y z, z)``, for orthographic ones (``dx = dy = 0``) in
    ``(x, y, z)``. Points at depth 0 of a perspective camera get infinite x, y.
    """
    if perspective:
        M = np.stack([vr.dx, vr.dy, vr.d], axis=1)
        sol = np.linalg.solve(M, (verts - vr.o).T).T
        z = sol[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = sol[:, :2] / z[:, None]
    else:
        M = np.stack([vr.ox, vr.oy, vr.d], axis=1)
        sol = np.linalg.solve(M, (verts - vr.o).T).T
        xy, z = sol[:, :2], sol[:, 2]
    return xy, z


_TILE = 8


def coverage_mask(xy: np.ndarray, z: np.ndarray, faces: np.ndarray, H: int, W: int,
                  tnear: float) -> np.ndarray:
    """(H, W) bool: pixels whose centre may lie inside a projected face (conservative).

    Each face's projected bounding box, grown by one pixel, marks the 8x8 tiles it touches
    (a 2-D difference array summed twice, no loop over faces). When a face reaches view depth
    ``tnear`` or less its projection is unbounded and every pixel is kept.
    """
    zf = z[faces]
    if len(faces) == 0:
        return np.zeros((H, W), bool)
    if not np.all(zf.min(axis=1) > tnear):
        return np.ones((H, W), bool)
    S = min(H, W)
    # Continuous pixel coordinates: column i has x = (W - 1 - 2 i) / S.
    col = (W - 1 - xy[:, 0] * S) * 0.5
    row = (H - 1 - xy[:, 1] * S) * 0.5
    cf, rf = col[faces], row[faces]
    nty, ntx = -(-H // _TILE), -(-W // _TILE)
    c0 = np.clip(np.floor(cf.min(axis=1)) - 1, 0, W - 1).astype(np.int64) // _TILE
    c1 = np.clip(np.ceil(cf.max(axis=1)) + 1, 0, W - 1).astype(np.int64) // _TILE
    r0 = np.clip(np.floor(rf.min(axis=1)) - 1, 0, H - 1).astype(np.int64) // _TILE
    r1 = np.clip(np.ceil(rf.max(axis=1)) + 1, 0, H - 1).astype(np.int64) // _TILE
    # Faces entirely off-screen on one side clip to the border tile: drop them.
    inside = ((cf.max(axis=1) >= -1) & (cf.min(axis=1) <= W) & (rf.max(axis=1) >= -1)
              & (rf.min(axis=1) <= H))
    c0, c1, r0, r1 = c0[inside], c1[inside], r0[inside], r1[inside]
    n = (nty + 1) * (ntx + 1)
    idx = np.concatenate([r0 * (ntx + 1) + c0, r0 * (ntx + 1) + c1 + 1,
                          (r1 + 1) * (ntx + 1) + c0, (r1 + 1) * (ntx + 1) + c1 + 1])
    w = np.concatenate([np.ones(len(c0)), -np.ones(len(c0)), -np.ones(len(c0)),
                        np.ones(len(c0))])
    diff = np.bincount(idx, weights=w, minlength=n).reshape(nty + 1, ntx + 1)
    tiles = np.cumsum(np.cumsum(diff, axis=0), axis=1)[:nty, :ntx] > 0.5
    return np.repeat(np.repeat(tiles, _TILE, axis=0), _TILE, axis=1)[:H, :W]


def cast_pixels(scene: EmbreeScene, pixels: np.ndarray, rays: list[ViewRays], xs: np.ndarray,
                ys: np.ndarray, tnear: np.ndarray, n_threads: int,
                tnear_pixel: np.ndarray | None = None) -> PixelHits:
    """Cast the rays through the given pixel centres (float32, Embree's answer unrefined).

    Parameters
    ----------
    scene : EmbreeScene
    pixels : (r,) int64
        Sorted flat pixel indices into ``(N, H, W)``.
    rays : list of ViewRays
        Ray maps of every view of the batch.
    xs : (W,) float64, ys : (H,) float64
        NDC x of every column and y of every row.
    tnear : (N,) float64
        View depth at which each view's rays start (PyTorch3D's z clipping plane).
    n_threads : int
    tnear_pixel : (r,) float64, optional
        Per-ray start depth overriding ``tnear`` (to continue rays past a culled face).

    Returns
    -------
    PixelHits, sorted by pixel; ``depth`` is Embree's float32 value.
    """
    W, H = len(xs), len(ys)
    c, s = scene.center, scene.scale
    N = len(rays)
    # Per-view coefficients in the normalised frame (t, the view depth, is unchanged):
    # o' = (o - c) / s, d' = d / s; rows: o, ox, oy, d, dx, dy.
    coef = np.empty((N, 6, 3))
    for b, vr in enumerate(rays):  # loop over views
        coef[b] = [(vr.o - c) / s, vr.ox / s, vr.oy / s, vr.d / s, vr.dx / s, vr.dy / s]
    coef32 = coef.astype(np.float32)
    xs32 = xs.astype(np.float32)
    ys32 = ys.astype(np.float32)
    tn32 = tnear.astype(np.float32)
    tp32 = None if tnear_pixel is None else tnear_pixel.astype(np.float32)
    n_tasks = max(1, min(len(pixels) // _TASK_RAYS + 1, 8 * max(n_threads, 1)))
    bounds = np.linspace(0, len(pixels), n_tasks + 1).astype(np.int64)

    def run(k):
        a, b = bounds[k], bounds[k + 1]
        p = pixels[a:b]
        view, rem = np.divmod(p, H * W)
        row, col = np.divmod(rem, W)
        x = xs32[col][:, None]
        y = ys32[row][:, None]
        cf = coef32[view]
        tn = tn32[view] if tp32 is None else tp32[a:b]
        d = cf[:, 3] + x * cf[:, 4] + y * cf[:, 5]
        o = cf[:, 0] + x * cf[:, 1] + y * cf[:, 2] + tn[:, None] * d
        _, prim, u, v, t = scene.intersect(o, d)
        hit = np.flatnonzero(prim >= 0)
        return p[hit], prim[hit].astype(np.int64), u[hit], v[hit], t[hit] + tn[hit]

    if len(pixels) == 0:
        parts = []
    else:
        parts = parallel_map(run, range(n_tasks), n_threads)
    if not parts:
        return PixelHits(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)),
                         np.zeros(0))
    pix = np.concatenate([p[0] for p in parts])
    face = np.concatenate([p[1] for p in parts])
    u = np.concatenate([p[2] for p in parts]).astype(np.float64)
    v = np.concatenate([p[3] for p in parts]).astype(np.float64)
    t = np.concatenate([p[4] for p in parts]).astype(np.float64)
    bary = np.stack([1.0 - u - v, u, v], axis=1)
    return PixelHits(pix, face, bary, t)


def hit_rays(pixels: np.ndarray, rays: list[ViewRays], xs: np.ndarray, ys: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Float64 world origins, directions (view z = 1) and NDC xy of the rays of given pixels.

    Returns ``o (r, 3)``, ``d (r, 3)``, ``xy (r, 2)``.
    """
    W, H = len(xs), len(ys)
    view, rem = np.divmod(pixels, H * W)
    row, col = np.divmod(rem, W)
    coef = np.stack([np.stack(vr) for vr in rays])  # (N, 6, 3)
    x = xs[col][:, None]
    y = ys[row][:, None]
    cf = coef[view]
    o = cf[:, 0] + x * cf[:, 1] + y * cf[:, 2]
    d = cf[:, 3] + x * cf[:, 4] + y * cf[:, 5]
    return o, d, np.concatenate([x, y], axis=1)


def refine(o: np.ndarray, d: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray,
           bary: np.ndarray, t: np.ndarray, clip: bool = True
           ) -> tuple[np.ndarray, np.ndarray]:
    """Float64 Moller-Trumbore of ray ``i`` against triangle ``i``: exact ``t`` and barycentrics.

    Embree (float32) chose the triangle; where the float64 plane intersection is undefined
    (ray parallel to the plane) the float32 answers ``bary``, ``t`` are kept. Barycentrics that
    float64 puts slightly outside the triangle (the ray passes within float32 rounding of an
    edge) are clipped to it and renormalised.

    Returns ``bary (r, 3)``, ``t (r,)``. ``clip=False`` leaves the clipping to the caller
    (:func:`clip_bary` over all the rays: it renormalises every row when any is outside).
    """
    tt, u, v, det = moller_trumbore(o, d, A, B, C)
    ok = det != 0
    w = np.stack([1.0 - u - v, u, v], axis=1)
    w = np.where(ok[:, None], w, bary)
    tt = np.where(ok, tt, t)
    return (clip_bary(w) if clip else w), tt


def clip_bary(w: np.ndarray) -> np.ndarray:
    """``w (r, 3)``, or, when any barycentric is negative, all rows clipped at 0 and
    renormalised (:func:`refine`'s last step)."""
    if np.any(w < 0):
        w = np.maximum(w, 0.0)
        w /= w.sum(axis=1, keepdims=True)
    return w
