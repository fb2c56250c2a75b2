"""Mesh Laplacian matrices with PyTorch3D's exact definitions (``ops/laplacian_matrices.py``).

- :func:`uniform_laplacian`: ``L = D^-1 A - I`` (graph Laplacian of the edge graph, rows sum
  to zero), the matrix behind ``mesh_laplacian_smoothing(method="uniform")``.
- :func:`cot_laplacian`: the symmetric cotangent-weight matrix ``L_ij = cot a_ij + cot b_ij``
  (no diagonal) and the inverse of each vertex's incident face area.
- :func:`norm_laplacian`: ``L_ij = 1 / (|v_i - v_j| + eps)`` on the edges.

All are ``scipy.sparse.csr_matrix`` of shape ``(V, V)`` in float64. Sparsity patterns depend only
on the faces, so they are cached per :class:`~geofit.structures.Topology` (the object every mesh
made by ``update_verts`` shares); values that depend on the vertices are recomputed per call.
"""
from __future__ import annotations

import weakref

import numpy as np
import scipy.sparse as sp

from .._validate import as_array, as_faces, as_points, check_positive
from ..structures.mesh import Mesh, Meshes, Topology, as_mesh

# topology_uniform_laplacian / topology_cot_laplacian: public within geofit (geofit.loss uses
# them), not in the package API
__all__ = ["cot_laplacian", "norm_laplacian", "uniform_laplacian"]

# Per-topology caches (sparsity patterns, scatter matrices, normal-consistency pairs). Keyed by
# the Topology object itself, held weakly, so a cache entry lives exactly as long as the meshes
# that share that topology.
_TOPOLOGY_CACHE: weakref.WeakKeyDictionary[Topology, dict] = weakref.WeakKeyDictionary()


def topology_cache(topology: Topology) -> dict:
    """The per-topology cache dict (shared with :mod:`geofit.loss`)."""
    d = _TOPOLOGY_CACHE.get(topology)
    if d is None:
        d = {}
        _TOPOLOGY_CACHE[topology] = d
    return d


def _freeze(M: sp.csr_matrix) -> sp.csr_matrix:
    for a in (M.data, M.indices, M.indptr):
        a.setflags(write=False)
    return M


def topology_uniform_laplacian(topology: Topology) -> sp.csr_matrix:
    """:func:`uniform_laplacian` of a mesh's :class:`Topology` (no validation; cached on it).

    For callers inside geofit that already hold a topology (the Laplacian smoothing loss).
    Returns the shared, read-only ``(V, V)`` csr matrix.
    """
    cache = topology_cache(topology)
    L = cache.get("uniform_L")
    if L is None:
        A = topology.adjacency.tocsr()
        deg = np.diff(A.indptr).astype(np.float64)
        inv = np.divide(1.0, deg, out=np.zeros_like(deg), where=deg > 0)
        L = (sp.diags(inv) @ A - sp.identity(topology.n_verts, format="csr")).tocsr()
        L.sort_indices()
        L = _freeze(L)
        cache["uniform_L"] = L
    return L


def uniform_laplacian(mesh) -> sp.csr_matrix:
    """The uniform (graph) Laplacian ``L = D^-1 A - I`` of a mesh's edge graph.

    Parameters
    ----------
    mesh : Mesh or Meshes
        The mesh; for a batch the result is the block-diagonal packed ``(sum V, sum V)`` matrix.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (V, V)
        ``L[i, j] = 1 / deg(i)`` when ``(i, j)`` is an edge, ``L[i, i] = -1``, else 0, so
        ``(L @ verts)[i]`` is the vector from vertex i to the centroid of its neighbours and every
        row sums to 0 (an isolated vertex keeps only its ``-1``, as in PyTorch3D). The matrix
        depends only on the faces and is cached on the mesh's topology: it is shared and
        read-only (copy it before modifying).

    Examples
    --------
    >>> from geofit import ico_sphere
    >>> from geofit.ops import uniform_laplacian
    >>> L = uniform_laplacian(ico_sphere(1))
    >>> L.shape, bool(abs(L.sum(axis=1)).max() < 1e-15)
    ((42, 42), True)
    """
    if not isinstance(mesh, (Mesh, Meshes)):
        mesh = as_mesh(mesh, "mesh")  # a trimesh or Open3D mesh
    if isinstance(mesh, Mesh):
        return topology_uniform_laplacian(mesh.topology)
    if isinstance(mesh, Meshes):
        return sp.block_diag([topology_uniform_laplacian(m.topology) for m in mesh],
                             format="csr")
    raise TypeError(f"mesh: expected a Mesh or Meshes, got {type(mesh)!r}")


class _CotPattern:
    """Sparsity pattern of the cotangent Laplacian for fixed faces.

    ``pos`` maps each of the 6F directed contributions (face f, corner opposite the edge, both
    directions) to its slot in the CSR data array, so ``data = bincount(pos, weights)`` builds
    the matrix without sorting.
    """

    def __init__(self, faces: np.ndarray, n_verts: int):
        F = len(faces)
        V = int(n_verts)
        # PyTorch3D: L[v1, v2] = cot a, L[v2, v0] = cot b, L[v0, v1] = cot c, then L += L^T.
        ii = faces[:, [1, 2, 0]].T.ravel()  # corner-major: all cot a, then cot b, then cot c
        jj = faces[:, [2, 0, 1]].T.ravel()
        rows = np.concatenate([ii, jj])
        cols = np.concatenate([jj, ii])
        key = rows * max(V, 1) + cols
        uniq, pos = np.unique(key, return_inverse=True)
        self.n_verts = V
        self.n_faces = F
        pos = pos.astype(np.int64).ravel()
        # slots of the contributions, split per corner k and direction: cot[k] goes to
        # (ii, jj) entries pos[k*F:(k+1)*F] and to their transposes pos[3F + k*F: ...]
        self.pos = [np.ascontiguousarray(pos[k * F:(k + 1) * F]) for k in range(3)]
        self.pos_t = [np.ascontiguousarray(pos[3 * F + k * F:3 * F + (k + 1) * F]) for k in range(3)]
        self.faces_cols = tuple(np.ascontiguousarray(faces[:, k]) for k in range(3))
        self.indices = (uniq % max(V, 1)).astype(np.int32 if V < 2**31 else np.int64)
        urows = uniq // max(V, 1)
        self.indptr = np.searchsorted(urows, np.arange(V + 1)).astype(self.indices.dtype)
        self.nnz = len(uniq)

    def build(self, cot) -> sp.csr_matrix:
        """cot : three (F,) float64 arrays (cot a, cot b, cot c) -> symmetric csr (V, V)."""
        data = np.zeros(self.nnz)
        for k in range(3):  # the three corners
            data += np.bincount(self.pos[k], cot[k], self.nnz)
            data += np.bincount(self.pos_t[k], cot[k], self.nnz)
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n_verts, self.n_verts))


def _cot_pattern(faces: np.ndarray, n_verts: int, topology: Topology | None) -> _CotPattern:
    if topology is None:
        return _CotPattern(faces, n_verts)
    cache = topology_cache(topology)
    pat = cache.get("cot_pattern")
    if pat is None:
        pat = _CotPattern(topology.faces, topology.n_verts)
        cache["cot_pattern"] = pat
    return pat


def _cot_weights(verts: np.ndarray, faces_cols, eps: float):
    """PyTorch3D's cotangents (three (F,) arrays: cot a, cot b, cot c) and Heron areas (F,).

    ``faces_cols`` are the three contiguous corner columns of the faces. Coordinates are handled
    as separate 1-D arrays (faster than column slices of (F, 3) arrays).
    """
    f0, f1, f2 = faces_cols
    A2 = 0.0
    B2 = 0.0
    C2 = 0.0
    for x in verts.T:  # the three coordinates
        x = np.ascontiguousarray(x)
        x0, x1, x2 = x[f0], x[f1], x[f2]
        A2 = A2 + (x1 - x2) ** 2
        B2 = B2 + (x0 - x2) ** 2
        C2 = C2 + (x0 - x1) ** 2
    A = np.sqrt(A2)
    B = np.sqrt(B2)
    C = np.sqrt(C2)
    s = 0.5 * (A + B + C)
    area = np.sqrt(np.maximum(s * (s - A) * (s - B) * (s - C), eps))
    inv4 = 0.25 / area
    return ((B2 + C2 - A2) * inv4, (A2 + C2 - B2) * inv4, (A2 + B2 - C2) * inv4), area


def topology_cot_laplacian(verts, topology: Topology, eps: float = 1e-12):
    """:func:`cot_laplacian` of ``verts (V, 3) float64`` over a mesh's :class:`Topology`.

    No validation (callers inside geofit pass a mesh's own arrays); the sparsity pattern is
    cached on the topology. Returns ``(L csr (V, V), inv_areas (V,) float64)``.
    """
    return _cot_laplacian(verts, topology.faces, eps, topology)


def _cot_laplacian(verts, faces, eps, topology=None):
    """Unvalidated core: (L csr, inv_areas (V,))."""
    V = len(verts)
    pat = _cot_pattern(faces, V, topology)
    cot, area = _cot_weights(verts, pat.faces_cols, eps)
    L = pat.build(cot)
    tot = (np.bincount(pat.faces_cols[0], area, V) + np.bincount(pat.faces_cols[1], area, V)
           + np.bincount(pat.faces_cols[2], area, V))
    inv_areas = np.divide(1.0, tot, out=np.zeros_like(tot), where=tot > 0)
    return L, inv_areas


def cot_laplacian(verts, faces, eps: float = 1e-12):
    """The cotangent Laplacian and inverse vertex areas (PyTorch3D's ``cot_laplacian``).

    Parameters
    ----------
    verts : (V, 3) float64
        Vertex positions.
    faces : (F, 3) int64
        Triangles.
    eps : float
        Lower clamp of the squared Heron area ``s (s - A)(s - B)(s - C)`` (so a degenerate face
        has area ``sqrt(eps)``, never zero), > 0.

    Returns
    -------
    L : scipy.sparse.csr_matrix, shape (V, V)
        Symmetric, ``L[i, j] = cot a_ij + cot b_ij`` summed over the faces sharing edge (i, j),
        zero diagonal. Per face with side lengths ``A = |v1 - v2|``, ``B = |v0 - v2|``,
        ``C = |v0 - v1|``: ``cot a = (B^2 + C^2 - A^2) / (4 area)`` goes to ``L[v1, v2]``, cot b to
        ``L[v2, v0]``, cot c to ``L[v0, v1]``, then ``L += L^T``.
    inv_areas : (V,) float64
        ``1 / (sum of the areas of the faces containing vertex i)``, 0 for an isolated vertex
        (PyTorch3D returns this as a (V, 1) column).

    Raises
    ------
    ValueError
        On bad shapes, non-finite vertices, out-of-range indices or ``eps <= 0``.

    Examples
    --------
    >>> import numpy as np
    >>> from geofit.ops import cot_laplacian
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]])
    >>> L, inv_a = cot_laplacian(V, [[0, 1, 2]])
    >>> L.toarray().round(12)  # right angle at v0: cot 90 = 0 on edge (1, 2), cot 45 = 1 elsewhere
    array([[0., 1., 1.],
           [1., 0., 0.],
           [1., 0., 0.]])
    >>> inv_a  # each vertex touches the one face of area 1/2
    array([2., 2., 2.])
    """
    verts = as_points(verts, "verts")
    faces = as_faces(faces, "faces", len(verts))
    eps = check_positive(eps, "eps")
    return _cot_laplacian(verts, faces, eps)


def norm_laplacian(verts, edges, eps: float = 1e-12) -> sp.csr_matrix:
    """Inverse-edge-length weights ``L_ij = 1 / (|v_i - v_j| + eps)`` (PyTorch3D's ``norm_laplacian``).

    Parameters
    ----------
    verts : (V, 3) float64
        Vertex positions.
    edges : (E, 2) int64
        Unique undirected edges (e.g. ``mesh.edges``).
    eps : float
        Added to each length, > 0.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (V, V)
        Symmetric with zero diagonal (repeated edges add up, as in PyTorch3D).
    """
    verts = as_points(verts, "verts")
    edges = as_array(edges, "edges", (None, 2), np.int64)
    if edges.size and (edges.min() < 0 or edges.max() >= len(verts)):
        raise ValueError(f"edges: vertex indices must lie in [0, {len(verts) - 1}], "
                         f"got range [{edges.min()}, {edges.max()}]")
    eps = check_positive(eps, "eps")
    V = len(verts)
    w = 1.0 / (np.linalg.norm(verts[edges[:, 0]] - verts[edges[:, 1]], axis=1) + eps)
    L = sp.coo_matrix((np.r_[w, w], (np.r_[edges[:, 0], edges[:, 1]],
                                      np.r_[edges[:, 1], edges[:, 0]])), shape=(V, V))
    return L.tocsr()
