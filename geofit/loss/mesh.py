"""Mesh regularisers with analytic gradients: edge length, normal consistency, Laplacian smoothing.

Each loss is ``value, grad = loss(mesh, ...)`` with ``value`` a float and ``grad`` the (V, 3)
float64 gradient with respect to ``mesh.verts`` (for a :class:`~geofit.structures.Meshes` batch,
the packed ``(sum V, 3)`` gradient of the batch mean). The definitions are PyTorch3D's
(``pytorch3d/loss/mesh_*.py``, v0.7.9), evaluated in float64.

Everything that depends only on the faces (edge scatter matrices, the face pairs of normal
consistency, the uniform Laplacian, the cotangent sparsity pattern) is computed once per
:class:`~geofit.structures.Topology` and cached, so a fitting loop that calls
``mesh.update_verts(v)`` thousands of times pays only for the per-vertex arithmetic.
"""
from __future__ import annotations

import threading

import numpy as np
import scipy.sparse as sp

from .._validate import check_choice, check_finite
from ..ops.laplacian import topology_cache, topology_cot_laplacian, topology_uniform_laplacian
from ..structures.mesh import Mesh, Meshes, Topology, as_mesh

__all__ = [
    "mesh_edge_loss",
    "mesh_laplacian_smoothing",
    "mesh_normal_consistency",
    "mesh_normal_variation",
    "normal_consistency_pairs",
]

_LAPLACIAN_METHODS = ("uniform", "cot", "cotcurv")


# The per-element arithmetic below works on vectors stored as three 1-D coordinate arrays
# ("structure of arrays"): contiguous 1-D operations are several times faster than column
# slices of (n, 3) arrays, and arrays of a few thousand floats stay below glibc's mmap threshold,
# which avoids a page fault storm on every call of a fitting loop.
def _coords(V: np.ndarray):
    """(n, 3) -> three contiguous (n,) coordinate arrays."""
    return [np.ascontiguousarray(c) for c in V.T]


def _cross(a, b):
    """Cross product of two vectors given as coordinate triples."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _batched(fn, mesh, name: str, *args):
    """Apply a single-mesh loss to a Mesh, or average it over a Meshes batch (PyTorch3D's /N)."""
    if not isinstance(mesh, (Mesh, Meshes)):
        mesh = as_mesh(mesh, name)  # a trimesh or Open3D mesh
    if isinstance(mesh, Mesh):
        return fn(mesh, *args)
    if isinstance(mesh, Meshes):
        n = len(mesh)
        if n == 0:
            return 0.0, np.zeros((0, 3))
        parts = [fn(m, *args) for m in mesh]  # loop over batch members
        value = sum(p[0] for p in parts) / n
        grad = np.concatenate([p[1] for p in parts], axis=0) / n
        return float(value), grad
    raise TypeError(f"{name}: expected a Mesh or Meshes, got {type(mesh)!r}")


# --------------------------------------------------------------------------- edge length
def _edge_ends(topology: Topology):
    """The two endpoint columns of ``topology.edges`` as contiguous arrays (cached)."""
    cache = topology_cache(topology)
    ends = cache.get("edge_ends")
    if ends is None:
        e = topology.edges
        ends = (np.ascontiguousarray(e[:, 0]), np.ascontiguousarray(e[:, 1]))
        cache["edge_ends"] = ends
    return ends


def _edge_loss_one(mesh: Mesh, t: float):
    e = mesh.edges
    E = len(e)
    if E == 0:
        return 0.0, np.zeros((mesh.n_verts, 3))
    nV = mesh.n_verts
    e0, e1 = _edge_ends(mesh.topology)
    X = _coords(mesh.verts)
    d = [x[e0] - x[e1] for x in X]
    length = np.sqrt(_dot(d, d))
    r = length - t
    value = float(np.dot(r, r) / E)
    # d/dv0 (|d| - t)^2 = 2 (|d| - t) d / |d|; the kink at |d| = 0 gets the zero subgradient.
    coef = np.divide(2.0 * r, length * E, out=np.zeros_like(r), where=length > 0)
    grad = np.empty((nV, 3))
    for k in range(3):  # the three coordinates
        g = d[k] * coef
        grad[:, k] = np.bincount(e0, g, nV) - np.bincount(e1, g, nV)
    return value, grad


def mesh_edge_loss(mesh, target_length: float = 0.0):
    """Mean squared deviation of the edge lengths from a target (PyTorch3D's ``mesh_edge_loss``).

    Parameters
    ----------
    mesh : Mesh or Meshes
        The mesh (or batch).
    target_length : float
        Resting edge length ``t``.

    Returns
    -------
    value : float
        ``mean_e (|v_a - v_b| - t)^2`` over the unique edges; a batch averages the per-mesh values.
        0 for a mesh without edges.
    grad : (V, 3) float64
        Gradient with respect to the vertices (packed (sum V, 3) for a batch). For ``t != 0`` the
        term of a zero-length edge has a kink; it contributes the zero subgradient.

    Notes
    -----
    PyTorch3D weights each term by ``1.0 / count.float()``, a float32 number even for float64
    vertices; this function uses the exact ``1 / E``, so the two differ by the relative factor
    ``fl32(1/E) E - 1`` (about 5e-8 for ico_sphere(2)).

    Examples
    --------
    >>> import numpy as np
    >>> from geofit import Mesh
    >>> from geofit.loss import mesh_edge_loss
    >>> tri = Mesh([[0, 0, 0], [2, 0, 0], [1, np.sqrt(3), 0]], [[0, 1, 2]])  # side 2
    >>> value, grad = mesh_edge_loss(tri, target_length=1.5)
    >>> round(value, 12)
    0.25
    """
    return _batched(_edge_loss_one, mesh, "mesh", check_finite(target_length, "target_length"))


# --------------------------------------------------------------------------- normal consistency
_NC_CHUNK = 8192  # pairs per block: bounds the workspace (~2 MB) whatever the mesh size


class _NormalPairs:
    """Per-topology data of normal consistency: one row per pair of faces sharing an edge.

    ``v0, v1`` are the edge's vertices (``v0 < v1``), ``a`` and ``b`` the vertices opposite the
    edge in the two faces.
    """

    def __init__(self, topology: Topology):
        faces = topology.faces
        fe = topology.faces_to_edges  # (F, 3): edge opposite corner k
        edge_of = fe.ravel()  # entry (f, k) -> edge
        opp_of = faces.ravel()  # entry (f, k) -> the vertex opposite that edge
        order = np.argsort(edge_of, kind="stable")
        edge_sorted = edge_of[order]
        E = len(topology.edges)
        count = np.bincount(edge_sorted, minlength=E)
        start = np.concatenate([[0], np.cumsum(count)[:-1]])
        # All pairs i < j within each edge's group of c entries (PyTorch3D's C++ enumeration,
        # pairs ordered by j then i): c (c - 1) / 2 pairs per edge.
        npairs = count * (count - 1) // 2
        P = int(npairs.sum())
        pe = np.repeat(np.arange(E), npairs)
        k = np.arange(P) - np.repeat(np.cumsum(npairs) - npairs, npairs)
        j = np.floor((1.0 + np.sqrt(1.0 + 8.0 * k)) / 2.0).astype(np.int64)
        # guard the float sqrt: enforce j (j - 1) / 2 <= k < j (j + 1) / 2
        j -= (j * (j - 1) // 2 > k)
        j += ((j + 1) * j // 2 <= k)
        i = k - j * (j - 1) // 2
        ent_i = order[start[pe] + i]
        ent_j = order[start[pe] + j]
        e = topology.edges[pe]
        self.n_pairs = P
        self.edge = pe
        self.v0 = e[:, 0].copy()
        self.v1 = e[:, 1].copy()
        self.a = opp_of[ent_i]
        self.b = opp_of[ent_j]
        self.face_i = ent_i // 3
        self.face_j = ent_j // 3
        # per block of _NC_CHUNK pairs, the scatter targets of the four gradient blocks
        self.scatter_idx = [np.concatenate([self.v1[s:s + _NC_CHUNK], self.v0[s:s + _NC_CHUNK],
                                            self.a[s:s + _NC_CHUNK], self.b[s:s + _NC_CHUNK]])
                            for s in range(0, P, _NC_CHUNK)]


def _normal_pairs(topology: Topology) -> _NormalPairs:
    cache = topology_cache(topology)
    pairs = cache.get("normal_pairs")
    if pairs is None:
        pairs = _NormalPairs(topology)
        cache["normal_pairs"] = pairs
    return pairs


def normal_consistency_pairs(mesh: Mesh):
    """The face pairs that normal consistency compares (cached per topology).

    Parameters
    ----------
    mesh : Mesh

    Returns
    -------
    dict of (P,) int64 arrays
        ``v0``, ``v1`` (the shared edge, ``v0 < v1``), ``a``, ``b`` (the opposite vertices),
        ``face_i``, ``face_j`` (the two faces), ``edge`` (index into ``mesh.edges``). Every edge
        with ``c`` incident faces contributes all ``c (c - 1) / 2`` pairs (non-manifold safe);
        boundary edges contribute none.
    """
    mesh = as_mesh(mesh, "mesh")  # a geofit, trimesh or Open3D mesh
    p = _normal_pairs(mesh.topology)
    return {k: getattr(p, k) for k in ("v0", "v1", "a", "b", "face_i", "face_j", "edge")}


_COS_EPS = 1e-8  # torch.cosine_similarity's default eps, used by PyTorch3D here


class _Workspace(threading.local):
    """Per-thread scratch buffers for the normal-consistency kernel.

    The kernel needs ~30 temporaries per pair block. Allocating and freeing them on every call
    makes glibc trim and regrow the heap, and the resulting page faults cost several times the
    arithmetic (measured 3x on ico_sphere(4) in a fresh process). Reusing fixed buffers with
    ``out=`` avoids that. Thread-local, so concurrent calls from threads never share buffers.
    """

    def __init__(self):
        self.buf = np.empty((33, _NC_CHUNK))
        self.w4 = np.empty(4 * _NC_CHUNK)


_WS = _Workspace()


def _cross_into(a, b, out, tmp):
    """out = a x b for coordinate triples, writing into the three arrays of ``out``."""
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        np.multiply(a[j], b[k], out=out[i])
        np.multiply(a[k], b[j], out=tmp)
        out[i] -= tmp


def _normal_consistency_one(mesh: Mesh):
    pairs = _normal_pairs(mesh.topology)
    P = pairs.n_pairs
    nV = mesh.n_verts
    if P == 0:
        return 0.0, np.zeros((nV, 3))
    X = _coords(mesh.verts)
    buf, w4 = _WS.buf, _WS.w4
    eps2 = _COS_EPS * _COS_EPS
    w = -1.0 / P  # dL/dcos for every pair
    acc = np.zeros((3, nV))
    cos_sum = 0.0
    for s in range(0, P, _NC_CHUNK):  # blocks of pairs (bounded scratch memory)
        e = min(s + _NC_CHUNK, P)
        n = e - s
        B = [buf[i, :n] for i in range(33)]
        x0, ed, p, q = B[0:3], B[3:6], B[6:9], B[9:12]
        n0, n1, g0, g1 = B[12:15], B[15:18], B[18:21], B[21:24]
        tmp, s0, s1, cos, c0, c1 = B[24], B[25], B[26], B[27], B[28], B[29]
        v0, v1, a, b = pairs.v0[s:e], pairs.v1[s:e], pairs.a[s:e], pairs.b[s:e]
        for k in range(3):  # the three coordinates
            np.take(X[k], v0, out=x0[k])
            np.take(X[k], v1, out=ed[k])
            ed[k] -= x0[k]  # v1 - v0
            np.take(X[k], a, out=p[k])
            p[k] -= x0[k]  # a - v0
            np.take(X[k], b, out=q[k])
            q[k] -= x0[k]  # b - v0
        _cross_into(ed, p, n0, tmp)  # n0 = (v1 - v0) x (a - v0)
        _cross_into(q, ed, n1, tmp)  # n1 = (b - v0) x (v1 - v0)
        # torch.cosine_similarity: cos = (n0 / max(|n0|, eps)) . (n1 / max(|n1|, eps))
        for out, u, v in ((s0, n0, n0), (s1, n1, n1), (cos, n0, n1)):
            np.multiply(u[0], v[0], out=out)
            for k in (1, 2):
                np.multiply(u[k], v[k], out=tmp)
                out += tmp
        np.maximum(s0, eps2, out=c0)  # m0^2
        np.maximum(s1, eps2, out=c1)  # m1^2
        np.multiply(c0, c1, out=tmp)
        np.sqrt(tmp, out=tmp)
        np.divide(1.0, tmp, out=tmp)  # 1 / (m0 m1)
        cos *= tmp
        cos_sum += float(cos.sum())
        # Exact derivative of that value: for |n0| > eps, d cos / d n0 = n1 / (m0 m1) - cos n0 / |n0|^2;
        # below eps the clamped norm is constant and only the first term remains.
        np.divide(cos, c0, out=c0)
        c0[s0 <= eps2] = 0.0
        np.divide(cos, c1, out=c1)
        c1[s1 <= eps2] = 0.0
        tmp *= w
        c0 *= w
        c1 *= w
        for k in range(3):
            np.multiply(n1[k], tmp, out=g0[k])  # dL/dn0
            np.multiply(n0[k], c0, out=cos)
            g0[k] -= cos
            np.multiply(n0[k], tmp, out=g1[k])  # dL/dn1
            np.multiply(n1[k], c1, out=cos)
            g1[k] -= cos
        # n0 = e x p: dL/dp = g0 x e, dL/de = p x g0;  n1 = q x e: dL/dq = e x g1, dL/de = g1 x q.
        dp, dq, de = n0, n1, x0  # reuse buffers (n0, n1, x0 are no longer needed)
        _cross_into(g0, ed, dp, tmp)
        _cross_into(ed, g1, dq, tmp)
        _cross_into(p, g0, de, tmp)
        _cross_into(g1, q, p, tmp)  # p is free now: holds g1 x q
        idx4 = pairs.scatter_idx[s // _NC_CHUNK]
        for k in range(3):
            de[k] += p[k]
            w4[:n] = de[k]  # onto v1
            np.add(de[k], dp[k], out=w4[n:2 * n])
            w4[n:2 * n] += dq[k]
            np.negative(w4[n:2 * n], out=w4[n:2 * n])  # onto v0
            w4[2 * n:3 * n] = dp[k]  # onto a
            w4[3 * n:4 * n] = dq[k]  # onto b
            acc[k] += np.bincount(idx4, w4[:4 * n], nV)
    value = float(P - cos_sum) / P
    return value, np.ascontiguousarray(acc.T)


def mesh_normal_consistency(mesh):
    """Mean ``1 - cos`` between the normals of faces sharing an edge (PyTorch3D's definition).

    Parameters
    ----------
    mesh : Mesh or Meshes
        The mesh (or batch).

    Returns
    -------
    value : float
        For every edge ``(v0, v1)`` and every pair of faces on it with opposite vertices ``a`` and
        ``b``: ``n0 = (v1 - v0) x (a - v0)``, ``n1 = (b - v0) x (v1 - v0)`` and the term
        ``1 - cos(n0, n1)``, with torch's ``cosine_similarity`` (each norm clamped at 1e-8). The
        mean over all pairs; 0 when there are none. A batch averages per mesh.
    grad : (V, 3) float64
        Gradient with respect to the vertices (packed for a batch).

    Notes
    -----
    The normals come from the edge geometry, not from the face winding, so the loss is the same
    for inconsistently oriented faces. An edge with ``c > 2`` faces (non-manifold) contributes
    all ``c (c - 1) / 2`` pairs, as PyTorch3D's ``mesh_normal_consistency_find_verts``. The pairs
    are computed once per topology. PyTorch3D weights by the float32 ``1 / count``; this
    function uses the exact ``1 / P`` (relative difference below 6e-8).

    Examples
    --------
    >>> from geofit import plane, box
    >>> from geofit.loss import mesh_normal_consistency
    >>> round(mesh_normal_consistency(plane(n=3))[0], 15)
    0.0
    """
    return _batched(_normal_consistency_one, mesh, "mesh")


# --------------------------------------------------------------------------- Laplacian smoothing
def _uniform_LT(topology: Topology) -> sp.csr_matrix:
    cache = topology_cache(topology)
    LT = cache.get("uniform_LT")
    if LT is None:
        LT = topology_uniform_laplacian(topology).T.tocsr()
        cache["uniform_LT"] = LT
    return LT


def _unit_rows(r: np.ndarray):
    """Row norms and r / |r| with 0 for zero rows (the zero subgradient at the kink)."""
    nr = np.sqrt(np.einsum("ij,ij->i", r, r))
    u = r * np.divide(1.0, nr, out=np.zeros_like(nr), where=nr > 0)[:, None]
    return nr, u


def _laplacian_one(mesh: Mesh, method: str):
    nV = mesh.n_verts
    if mesh.isempty():
        return 0.0, np.zeros((nV, 3))
    V = mesh.verts
    topo = mesh.topology
    if method == "uniform":
        L = topology_uniform_laplacian(topo)
        r = L @ V
        nr, u = _unit_rows(r)
        grad = _uniform_LT(topo) @ u
    else:
        L, inv_areas = topology_cot_laplacian(V, topo, 1e-12)
        LV = L @ V
        rowsum = np.asarray(L.sum(axis=1)).ravel()
        if method == "cot":
            # PyTorch3D: norm_w = 1 / rowsum where rowsum > 0, else rowsum kept as it is
            w = np.where(rowsum > 0, 1.0 / np.where(rowsum > 0, rowsum, 1.0), rowsum)
            r = LV * w[:, None] - V
            nr, u = _unit_rows(r)
            grad = L @ (u * w[:, None]) - u  # L symmetric: (diag(w) L - I)^T u
        else:  # cotcurv
            s = 0.25 * inv_areas
            r = (LV - rowsum[:, None] * V) * s[:, None]
            nr, u = _unit_rows(r)
            su = u * s[:, None]
            grad = L @ su - rowsum[:, None] * su
    value = float(nr.sum() / nV)
    return value, grad / nV


def mesh_laplacian_smoothing(mesh, method: str = "uniform"):
    """Laplacian smoothing loss, PyTorch3D's ``mesh_laplacian_smoothing`` in float64.

    Parameters
    ----------
    mesh : Mesh or Meshes
        The mesh (or batch).
    method : {"uniform", "cot", "cotcurv"}
        - ``"uniform"``: ``r_i = (L V)_i`` with ``L = D^-1 A - I`` (vector to the neighbour
          centroid);
        - ``"cot"``: ``r_i = (L V)_i / sum_j L_ij - v_i`` with the cotangent matrix of
          :func:`geofit.ops.cot_laplacian` (a row whose sum is <= 0 keeps that sum as its weight,
          as PyTorch3D does);
        - ``"cotcurv"``: ``r_i = ((L V)_i - sum_j L_ij v_i) / (4 A_i)`` with ``A_i`` the summed area
          of the faces around vertex i (units 1/length: the value depends on scale).

    Returns
    -------
    value : float
        ``mean_i |r_i|`` (the plain, unsquared Euclidean norm), averaged per mesh for a batch;
        0 for an empty mesh.
    grad : (V, 3) float64
        Gradient with ``L`` (and the cot row weights and areas) held constant, exactly as PyTorch3D
        builds them under ``no_grad``: ``M^T (r_i / |r_i|) / V`` for the linear map ``r = M V``.
        The cot variants rebuild ``L`` from the current vertices on every call. The norm has a
        kink where ``r_i = 0`` (e.g. a vertex at its neighbours' centroid); there the gradient
        takes the zero subgradient, never NaN.

    Raises
    ------
    ValueError
        For an unknown method.

    Examples
    --------
    >>> from geofit import ico_sphere
    >>> from geofit.loss import mesh_laplacian_smoothing
    >>> value, grad = mesh_laplacian_smoothing(ico_sphere(3), "uniform")
    >>> grad.shape
    (642, 3)
    """
    check_choice(method, "method", _LAPLACIAN_METHODS)
    return _batched(_laplacian_one, mesh, "mesh", method)


# --------------------------------------------------------------------------- normal variation
def _normal_tv_one(mesh: Mesh, eps: float):
    nV = mesh.n_verts
    pairs = _normal_pairs(mesh.topology)
    P = pairs.n_pairs
    if P == 0:
        return 0.0, np.zeros((nV, 3))
    V = mesh.verts
    x0 = V[pairs.v0]
    e, p, q = V[pairs.v1] - x0, V[pairs.a] - x0, V[pairs.b] - x0
    n0, n1 = np.cross(e, p), np.cross(q, e)  # as normal consistency: winding-free
    s0 = np.maximum(np.einsum("ij,ij->i", n0, n0), _COS_EPS ** 2)
    s1 = np.maximum(np.einsum("ij,ij->i", n1, n1), _COS_EPS ** 2)
    inv = 1.0 / np.sqrt(s0 * s1)
    cos = np.einsum("ij,ij->i", n0, n1) * inv
    r = np.sqrt(np.maximum(2.0 - 2.0 * cos, 0.0) + eps * eps)
    value = float(np.sum(r - eps) / P)
    dcos = -1.0 / (r * P)  # dL/dcos per pair
    # d cos / d n0 = n1 / (|n0| |n1|) - cos n0 / |n0|^2 (the clamped norm is constant below eps)
    c0 = np.where(s0 > _COS_EPS ** 2, cos / s0, 0.0)
    c1 = np.where(s1 > _COS_EPS ** 2, cos / s1, 0.0)
    g0 = dcos[:, None] * (n1 * inv[:, None] - n0 * c0[:, None])
    g1 = dcos[:, None] * (n0 * inv[:, None] - n1 * c1[:, None])
    # n0 = e x p: dL/dp = g0 x e, dL/de = p x g0;  n1 = q x e: dL/dq = e x g1, dL/de += g1 x q
    dp, dq = np.cross(g0, e), np.cross(e, g1)
    de = np.cross(p, g0) + np.cross(g1, q)
    grad = np.zeros((nV, 3))
    for k in range(3):  # coordinates (bincount scatters)
        grad[:, k] = (np.bincount(pairs.v1, de[:, k], nV) + np.bincount(pairs.a, dp[:, k], nV)
                      + np.bincount(pairs.b, dq[:, k], nV)
                      - np.bincount(pairs.v0, de[:, k] + dp[:, k] + dq[:, k], nV))
    return value, grad


def mesh_normal_variation(mesh, eps: float = 0.1):
    """Robust variation of the face normals across edges: flat stays flat, creases stay sharp.

    Parameters
    ----------
    mesh : Mesh or Meshes
        The mesh (or batch).
    eps : float
        Scale (> 0) of the Charbonnier penalty, in units of ``|n0 - n1|`` (about the bend angle
        in radians).

    Returns
    -------
    value : float
        For every pair of faces on an edge (the pairs of :func:`mesh_normal_consistency`) with
        unit normals ``n0, n1``: ``sqrt(|n0 - n1|^2 + eps^2) - eps``, where
        ``|n0 - n1|^2 = 2 - 2 cos``; the mean over the pairs (0 when there are none), averaged
        per mesh for a batch.
    grad : (V, 3) float64
        Gradient with respect to the vertices (packed for a batch).

    Notes
    -----
    Normal consistency (``1 - cos``) is quadratic in the bend angle ``t``, so spreading a crease
    of angle ``T`` over ``k`` edges costs about ``T^2 / (2 k)``: it pays to round every crease.
    This penalty is quadratic only below ``eps`` (small wiggles, ripples from remeshing, are
    penalised ``1 / eps`` times more strongly) and linear above it, so a crease costs about
    ``T`` however it is spread (a total variation of the normals): sharp edges are not rounded
    and flat faces are kept flat.

    Examples
    --------
    >>> from geofit import plane
    >>> from geofit.loss.mesh import mesh_normal_variation
    >>> round(mesh_normal_variation(plane(n=3))[0], 15)
    0.0
    """
    if not (isinstance(eps, (int, float, np.floating)) and np.isfinite(eps) and eps > 0):
        raise ValueError(f"eps: expected a finite number > 0, got {eps!r}")
    return _batched(_normal_tv_one, mesh, "mesh", float(eps))
