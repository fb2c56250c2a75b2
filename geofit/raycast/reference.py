"""Brute-force float64 ray/triangle intersection in numpy: the reference :class:`RayCaster`
is tested against. Every ray is tested against every face (in chunks), so it is O(r * m):
use it on small inputs only."""
from __future__ import annotations

import numpy as np

from .._validate import as_faces, as_points, check_positive
from .embree import RayHits, _check_rays, _empty_hits

__all__ = ["intersect_rays_triangles"]


def intersect_rays_triangles(origins, directions, verts, faces, *, tnear=0.0, tfar=np.inf,
                             chunk_pairs: int = 2_000_000) -> RayHits:
    """First hit of each ray against a triangle mesh, by testing every ray against every face.

    Parameters
    ----------
    origins : (r, 3) float64
        Ray origins.
    directions : (r, 3) float64
        Ray directions (any non-zero length; ``t`` is in units of their length).
    verts : (V, 3) float64
        Mesh vertices.
    faces : (m, 3) int64
        Triangles indexing ``verts``.
    tnear, tfar : float or (r,) float64, optional
        Accepted interval of ``t`` (default ``[0, inf]``).
    chunk_pairs : int, optional
        Ray-face pairs evaluated per chunk (bounds memory).

    Returns
    -------
    RayHits
        As :meth:`RayCaster.cast` with ``mesh_id`` 0 on a hit: the smallest ``t`` in
        ``[tnear, tfar]`` over the faces the ray meets. Ties (a ray through a shared edge or
        vertex) go to the lowest face index.

    Raises
    ------
    ValueError
        On bad shapes, non-finite values, zero-length directions, out-of-range face indices,
        or ``tfar < tnear``.

    Notes
    -----
    Moller-Trumbore (1997) in float64 with closed edges: a ray meets a face when the
    barycentrics satisfy ``u >= 0, v >= 0, u + v <= 1`` and the determinant is non-zero (rays
    parallel to a face's plane never hit it).

    Examples
    --------
    >>> hits = intersect_rays_triangles([[0.2, 0.2, 1.0]], [[0, 0, -1.0]],
    ...                                 [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    >>> hits.t, hits.face_id, hits.bary
    (array([1.]), array([0]), array([[0.6, 0.2, 0.2]]))
    """
    o, d, tn, tf = _check_rays(origins, directions, tnear, tfar)
    r = len(o)
    V = as_points(verts, "verts")
    F = as_faces(faces, "faces", len(V))
    chunk_pairs = int(check_positive(chunk_pairs, "chunk_pairs"))
    out = _empty_hits(r)
    m = len(F)
    if r == 0 or m == 0:
        return out
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1 = B - A
    e2 = C - A
    step = max(1, chunk_pairs // m)
    for a in range(0, r, step):  # loop over chunks of rays
        oc, dc = o[a:a + step], d[a:a + step]
        n = len(oc)
        pvec = np.cross(dc[:, None, :], e2[None, :, :])            # (n, m, 3)
        det = np.einsum("fk,nfk->nf", e1, pvec)
        ok = det != 0
        inv = np.divide(1.0, np.where(ok, det, 1.0))
        tvec = oc[:, None, :] - A[None, :, :]
        u = np.einsum("nfk,nfk->nf", tvec, pvec) * inv
        qvec = np.cross(tvec, e1[None, :, :])                       # (n, m, 3)
        v = np.einsum("nk,nfk->nf", dc, qvec) * inv
        t = np.einsum("fk,nfk->nf", e2, qvec) * inv
        valid = (ok & (u >= 0) & (v >= 0) & (u + v <= 1)
                 & (t >= tn[a:a + n, None]) & (t <= tf[a:a + n, None]))
        t = np.where(valid, t, np.inf)
        best = np.argmin(t, axis=1)
        rows = np.arange(n)
        tb = t[rows, best]
        hit = np.isfinite(tb)
        idx = a + np.flatnonzero(hit)
        bu, bv = u[rows, best][hit], v[rows, best][hit]
        out.t[idx] = tb[hit]
        out.face_id[idx] = best[hit]
        out.mesh_id[idx] = 0
        out.bary[idx] = np.stack([1.0 - bu - bv, bu, bv], axis=1)
    return out
