"""Point-cloud targets of :func:`geofit.fit.fit_mesh`: the cloud, its normals, a first mesh.

``fit_mesh(P)`` with ``P`` a point cloud (a ``(k, 3)`` array, a geofit ``PointCloud`` or a
one-cloud ``Pointclouds``, a trimesh or Open3D point cloud) fits a mesh to the points:

* :class:`CloudTarget` holds the points in the fit's frame with a KD-tree (scipy ``cKDTree``,
  built once) and *unoriented* PCA normals (Open3D ``estimate_normals``, 12 neighbours); the
  distance of a point ``x`` to the cloud's surface is its distance to the tangent disk of radius
  ``rho`` (twice the points' spacing) around its nearest point ``y``:
  ``d^2 = r_n^2 + max(0, r_t - rho)^2`` with ``r_n = (x - y) . n_y`` and ``r_t`` the length of
  the tangential part of ``x - y``. Inside the cloud it is the point-to-plane distance (as in
  ICP), which, unlike the distance to the nearest point, does not grow with the spacing; past
  the cloud's boundary it grows, so surface that extends beyond the points (in their plane,
  where the plane distance is zero) is pulled back.
* :func:`orient_normals` orients the normals consistently (Hoppe et al. 1992: propagation along
  a minimum spanning tree of the k-nearest-neighbour graph; scipy's ``minimum_spanning_tree``
  and ``breadth_first_order``, the signs composed by pointer doubling, no loop over points).
* :func:`mesh_from_points` is the first mesh: screened Poisson reconstruction (Open3D,
  Kazhdan and Hoppe 2013) from the oriented normals, the surface it puts over the scan's
  holes removed (so open surfaces stay open, closed ones closed), then quadric decimation
  (:func:`geofit.fit.init.decimate`). It has the genus, boundaries and parts the points show.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .._foreign import foreign_kind
from .._threads import get_num_threads
from .._validate import as_points, as_rng
from ..structures import Mesh, PointCloud, Pointclouds, as_pointcloud
from ..ops import remesh
from ..ops.topology import face_components
from .init import decimate

__all__ = ["BoundaryPlacement", "CloudTarget", "EvidenceTrim", "as_cloud_points",
           "boundary_distance",
           "close_small_loops", "is_cloud", "mesh_from_points", "orient_normals",
           "place_boundary", "trim_to_evidence"]

#: Fewest points a target cloud may have.
MIN_POINTS = 20


def is_cloud(target) -> bool:
    """Whether ``target`` is a point cloud (not a mesh) for :func:`geofit.fit.fit_mesh`."""
    if isinstance(target, (PointCloud, Pointclouds)):
        return True
    if foreign_kind(target) in ("trimesh.PointCloud", "open3d.PointCloud"):
        return True
    return isinstance(target, np.ndarray) and target.ndim == 2


def as_cloud_points(target, name: str = "target") -> np.ndarray:
    """``(k, 3) float64`` points of a point-cloud target (see :func:`is_cloud`).

    Raises
    ------
    ValueError
        If the cloud is not ``(k, 3)``, has NaN or inf coordinates, fewer than
        :data:`MIN_POINTS` points, or a batch holds more than one cloud.
    """
    if isinstance(target, Pointclouds):
        if len(target) != 1:
            raise ValueError(f"{name}: expected one point cloud, got a batch of {len(target)}")
        target = target[0]
    if not isinstance(target, np.ndarray):
        target = as_pointcloud(target, name).points
    P = as_points(target, name)
    if len(P) < MIN_POINTS:
        raise ValueError(f"{name}: expected a point cloud of at least {MIN_POINTS} points, "
                         f"got {len(P)}")
    if not float(np.abs(P - P.mean(0)).max()) > 0:
        raise ValueError(f"{name}: all points coincide")
    return P


def orient_normals(points: np.ndarray, normals: np.ndarray, k: int = 10) -> np.ndarray:
    """Consistently oriented normals: propagation along a minimum spanning tree.

    Parameters
    ----------
    points : (k, 3) float64
        The cloud.
    normals : (k, 3) float64
        Unit normals of either sign.
    k : int
        Neighbours per point in the graph.

    Returns
    -------
    (k, 3) float64
        ``normals`` with some rows negated. The graph's edges weigh ``(1.1 - |n_i . n_j|)
        |p_i - p_j|`` (short edges between nearly parallel normals first, which keeps the
        propagation from jumping across a thin part); each connected part of the graph is
        rooted at its point of largest x, whose normal is made to point towards +x (outwards
        on a closed surface). Sign of a point = product of the relative signs
        ``sign(n_i . n_parent)`` along its tree path, computed by pointer doubling.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components
    from scipy.sparse.csgraph import minimum_spanning_tree
    from scipy.spatial import cKDTree

    n = len(points)
    k = min(k, n - 1)
    dist, idx = cKDTree(points).query(points, k + 1)
    i = np.repeat(np.arange(n), k)
    j = idx[:, 1:].ravel()
    d = dist[:, 1:].ravel()
    cos = np.abs(np.einsum("ij,ij->i", normals[i], normals[j]))
    w = (1.1 - cos) * d + 1e-12
    G = coo_matrix((w, (i, j)), shape=(n, n)).tocsr()
    G = G.maximum(G.T)
    T = minimum_spanning_tree(G)
    T = T + T.T
    n_parts, label = connected_components(T, directed=False)
    # one root per part: its point of largest x
    order = np.lexsort((-points[:, 0], label))
    first = np.r_[True, label[order][1:] != label[order][:-1]]
    roots = order[first]
    parent = np.full(n, -1, dtype=np.int64)
    for r in roots:  # one BFS per connected part (a handful), vectorised inside scipy
        _, pred = breadth_first_order(T, int(r), directed=False, return_predecessors=True)
        sel = pred >= 0
        parent[sel] = pred[sel]
    rel = np.ones(n)
    has = parent >= 0
    rel[has] = np.sign(np.einsum("ij,ij->i", normals[has], normals[parent[has]])) + 0.0
    rel[rel == 0] = 1.0
    root_sign = np.where(normals[roots, 0] < 0, -1.0, 1.0)
    rel[roots] = root_sign
    # pointer doubling: sign[i] = product of rel along the path from i to its root
    sign, up = rel.copy(), parent.copy()
    while (up >= 0).any():
        a = up >= 0
        sign[a] *= sign[up[a]]
        nxt = np.full(n, -1, dtype=np.int64)
        nxt[a] = up[up[a]]
        up = nxt
    return normals * sign[:, None]


def _unit_normals(pcd) -> np.ndarray:
    """(k, 3) float64 normals of an Open3D point cloud, a non-finite or zero one as +z."""
    nrm = np.array(pcd.normals, dtype=np.float64)
    bad = ~np.isfinite(nrm).all(1) | (np.linalg.norm(nrm, axis=1) < 0.5)
    nrm[bad] = [0.0, 0.0, 1.0]
    return nrm


class CloudTarget:
    """A fixed target point cloud: KD-tree, unoriented normals, spacing (built once).

    Parameters
    ----------
    points : (k, 3) float64
        The cloud (the fit's frame).

    Attributes
    ----------
    points, normals : (k, 3) float64
        Points and unit PCA normals (12 neighbours; sign arbitrary).
    spacing : float
        Median distance of a point to its nearest other point.
    rho : float
        Radius of the tangent disks (``2 * spacing``).
    reach : float or None
        With a value (a watertight fit of a scan with holes), a point farther than ``reach``
        from every point of the cloud is where the scan has no evidence: its distance and
        gradient are 0 (the smoothness of the large-steps parameterisation alone shapes the
        surface there). None (the default): every point is pulled to the cloud's surface, so
        surface past the cloud's boundary is pulled back.
    """

    def __init__(self, points: np.ndarray, *, reach: float | None = None):
        import open3d as o3d
        from scipy.spatial import cKDTree

        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self.tree = cKDTree(self.points)
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.points))
        pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(12))
        self.normals = _unit_normals(pcd)
        self.spacing = float(np.median(self.tree.query(self.points, 2)[0][:, 1]))
        self.rho = 2.0 * self.spacing
        self.reach = reach

    @cached_property
    def local_spacing(self) -> np.ndarray:
        """(k,) float64 spacing of the cloud around each point: its distance to its 10th
        nearest other point, scaled so that the median is :attr:`spacing` (where the sampling
        is twice as sparse, it is twice as large)."""
        r = self.tree.query(self.points, min(11, len(self.points)))[0][:, -1]
        return r * (self.spacing / max(float(np.median(r)), 1e-300))

    def _residuals(self, X: np.ndarray):
        """Normal residual ``r_n`` (n,), tangential part ``t`` (n, 3), its excess over ``rho``
        ``e = max(0, |t| - rho)`` (n,), and the nearest points' normals (n, 3)."""
        dist, idx = self.tree.query(X, workers=get_num_threads())
        d = X - self.points[idx]
        n = self.normals[idx]
        rn = np.einsum("ij,ij->i", d, n)
        t = d - rn[:, None] * n
        e = np.maximum(np.linalg.norm(t, axis=1) - self.rho, 0.0)
        if self.reach is not None:  # no evidence there: no residual
            out = dist > self.reach
            rn[out] = 0.0
            e[out] = 0.0
        return rn, t, e, n

    def distances(self, X: np.ndarray) -> np.ndarray:
        """(n,) distances of ``X`` to the cloud's surface: ``sqrt(r_n^2 + e^2)``."""
        rn, _, e, _ = self._residuals(X)
        return np.sqrt(rn * rn + e * e)

    def loss(self, X: np.ndarray) -> tuple[float, np.ndarray]:
        """``mean_i (r_n,i^2 + e_i^2)`` and its (n, 3) gradient
        ``2 (r_n n + e t / |t|) / n``.

        Which point is nearest is piecewise constant and carries no gradient.
        """
        rn, t, e, n = self._residuals(X)
        value = float(np.mean(rn * rn + e * e))
        tl = np.linalg.norm(t, axis=1)
        s = np.divide(e, tl, out=np.zeros_like(e), where=e > 0)
        return value, (2.0 / len(X)) * (rn[:, None] * n + s[:, None] * t)

    def subsample(self, n: int, rng) -> np.ndarray:
        """(min(n, k), 3) points drawn without replacement."""
        if n >= len(self.points):
            return self.points
        return self.points[np.sort(as_rng(rng).choice(len(self.points), n, replace=False))]


def _past_the_points(V: np.ndarray, F: np.ndarray, cloud: CloudTarget,
                     reach: float) -> np.ndarray:
    """(V,) bool: the vertices of a Poisson reconstruction that span a hole of the scan.

    The vertices farther than ``reach`` from every point form connected regions (through the
    edges of ``F``). Poisson surface can be far from the points in two ways: over a hole it
    continues *past* the points, in their tangent plane (the offset from the nearest point
    lies in that point's tangent plane), while over a part thinner than the octree's cells
    (a fin, a tail) it is *displaced* from the points along their normal, a surface the fit
    pulls back onto them. A region is removed when most of its vertices are past the points
    (their offset from the nearest point more than 30 degrees off that point's normal: the
    median sine of the angle is over 1/2). Measured at depth 6 on 20,000-point scans
    (50,000 for the clean dolphin and suzanne): the median sine is 0.57-1.0 over the regions
    that span the holes of one-sided scans and open shapes (ogre's smallest 0.57, torus 0.99,
    open cylinder 1.0), 0.33-0.43 around the dolphin's fins (clean and noisy), 0.06-0.31 on
    suzanne and the teapot; the former rule (every vertex farther than ``reach``) opened 2-4
    holes in clean, closed scans.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    dist, j = cloud.tree.query(V)
    far = dist > reach
    if not far.any():
        return far
    off = V - cloud.points[j]
    nrm = cloud.normals[j]
    tang = np.linalg.norm(off - np.einsum("ij,ij->i", off, nrm)[:, None] * nrm, axis=1)
    past = far & (tang > 0.5 * dist)  # offset more than 30 degrees off the point's normal
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    E = E[far[E[:, 0]] & far[E[:, 1]]]
    G = coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(len(V), len(V)))
    _, lab = connected_components(G, directed=False)
    n_far = np.bincount(lab[far], minlength=len(V))
    n_past = np.bincount(lab[past], minlength=len(V))
    return far & (2 * n_past[lab] > n_far[lab])


#: Neighbours of the normals of the Poisson start's points, among the at most ``n_max``
#: points it uses (so their neighbourhood has the same size whatever the scan's density; on
#: a scan of at most ``n_max`` points, the fit's own normals). Measured as the share of
#: normals oriented against the true surface's (5 subsamples each): the fit's 12-neighbour
#: normals of all 100,000 points of the fandisk (noise 0.005) gave 355-5,393 of 20,000 and
#: starts of genus 1-20 for the genus-0 shape, 12 neighbours of the subsample starts of genus
#: 0 (one of genus 2). 20 neighbours did better on dense scans (0-7; Suzanne at 50,000 points
#: 159-452 against 216-2,451) but join the two sides of the dolphin's fins at 20,000 points
#: (a genus-2 start).
START_NORMAL_K = 12

#: Threads of the Poisson start's reconstruction. Open3D's multi-threaded solve gives a
#: different start in every process (Suzanne, 50,000 points, noise 0.002: three processes,
#: three different starts, and fits whose F@0.01 spread 0.981-0.988); on one thread the start
#: is the same in every process, at the same cost at depth 6 (1.1-1.3 CPU s with or without).
POISSON_THREADS = 1


def mesh_from_points(cloud: CloudTarget, *, n_faces: int = 2000, depth: int = 6,
                     n_max: int = 20_000, seed=0, trim: bool = True) -> Mesh:
    """A first mesh of a point cloud: screened Poisson, trimmed, decimated (Open3D).

    Parameters
    ----------
    cloud : CloudTarget
        The points (at most ``n_max`` of them are used, with their own normals from
        :data:`START_NORMAL_K` neighbours, oriented by :func:`orient_normals`).
    n_faces : int
        Face budget of the decimated mesh (the closed loops' fans included, unless a second
        decimation to fit them leaves loops again).
    depth : int
        Octree depth of the Poisson reconstruction.
    n_max : int
        Points used at most.
    seed : int or numpy.random.Generator
        Which points when there are more than ``n_max``.
    trim : bool
        Remove the surface that spans the scan's holes (:func:`_past_the_points`, with a
        reach of 3 point spacings and 2 octree cells; False: the closed reconstruction, in a
        cube 1.5 times the points' bounding box).

    Returns
    -------
    Mesh
        The reconstruction (trimmed), cleaned and decimated, its boundary loops of at most
        :data:`SMALL_LOOP_EDGES` edges closed (:func:`close_small_loops`).

    Raises
    ------
    ValueError
        If the reconstruction is empty.
    """
    import open3d as o3d

    rng = as_rng(seed)
    P = cloud.points
    sel = (np.arange(len(P)) if len(P) <= n_max
           else np.sort(rng.choice(len(P), n_max, replace=False)))
    P = P[sel]
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    # normals of the points used, from their own START_NORMAL_K neighbours (see there)
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(START_NORMAL_K))
    pcd.normals = o3d.utility.Vector3dVector(orient_normals(P, _unit_normals(pcd)))
    # closed: a reconstruction cube 1.5x the points' box (Open3D's 1.1 clips the surface that
    # closes a one-sided scan, leaving a boundary where the box cuts it)
    m, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
        pcd, depth=int(depth), scale=1.1 if trim else 1.5, n_threads=POISSON_THREADS)
    if len(m.vertices) and trim:
        cell = 2.0 * float(np.abs(P - P.mean(0)).max()) / 2 ** depth
        reach = max(3.0 * cloud.spacing, 2.0 * cell)
        mv, mf = np.asarray(m.vertices), np.asarray(m.triangles)
        hole = _past_the_points(mv, mf, cloud, reach)
        topo = Mesh(mv, mf.astype(np.int64)).topology
        if np.any(~hole[topo.edges[topo.boundary_edges]]):
            # the cube cut surface that is not over a hole (Poisson's surface around a thin
            # part at the points' extremes, the dolphin's tail): the closed reconstruction
            m, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
                pcd, depth=int(depth), scale=1.5, n_threads=POISSON_THREADS)
            mv, mf = np.asarray(m.vertices), np.asarray(m.triangles)
            hole = _past_the_points(mv, mf, cloud, reach)
        m.remove_vertices_by_mask(hole)
    if len(m.triangles) == 0:
        raise ValueError("target: the Poisson reconstruction of the point cloud is empty")
    mesh = Mesh(np.asarray(m.vertices, dtype=np.float64),
                np.asarray(m.triangles, dtype=np.int64))
    out = close_small_loops(decimate(mesh, n_faces))
    if out.n_faces > n_faces:  # the fans' faces inside the budget (a scan's point count)
        out = close_small_loops(decimate(mesh, max(4, 2 * n_faces - out.n_faces)))
    return out


#: Boundary loops of at most this many edges in the Poisson start are closed
#: (:func:`close_small_loops`).
SMALL_LOOP_EDGES = 6


def _boundary_half_edges(mesh: Mesh) -> np.ndarray:
    """(b, 3) int64: each boundary edge ``(p, q, f)`` as its face ``f`` runs it (``p -> q``)."""
    F, topo = mesh.faces, mesh.topology
    H = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])  # directed half-edges
    # their undirected edges (faces_to_edges[:, k] is the edge opposite corner k)
    on = topo.faces_to_edges[:, [2, 0, 1]].T.ravel()
    b = topo.edge_face_counts[on] == 1
    return np.c_[H[b], np.tile(np.arange(mesh.n_faces), 3)[b]]


def close_small_loops(mesh: Mesh, max_edges: int = SMALL_LOOP_EDGES) -> Mesh:
    """The mesh with its boundary loops of at most ``max_edges`` edges closed by a fan.

    The decimation's clean-up (Open3D's ``remove_non_manifold_edges``) can leave a hole of a
    few edges in a closed Poisson start (the clean dolphin at 20,000 points: one 4-edge loop);
    a hole of the scan is far larger than that at the start's resolution, and the surface
    over a real gap is removed at the end anyway (:func:`trim_to_evidence`). Each small loop
    gets a vertex at its centroid and one face per boundary edge, oriented as the faces beside
    it (Open3D's ``fill_holes`` joined two corners of that loop that an existing edge already
    joined: a non-manifold edge).

    Parameters
    ----------
    mesh : Mesh
    max_edges : int
        Largest loop closed.

    Returns
    -------
    Mesh
        ``mesh`` itself when it has no such loop.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    F = mesh.faces
    B = _boundary_half_edges(mesh)[:, :2]  # boundary half-edges, as their faces run them
    if len(B) == 0:
        return mesh
    n = mesh.n_verts
    G = coo_matrix((np.ones(len(B)), (B[:, 0], B[:, 1])), shape=(n, n))
    loop = connected_components(G, directed=False)[1][B[:, 0]]
    small = np.bincount(loop, minlength=n)[loop] <= max_edges
    if not small.any():
        return mesh
    B = B[small]
    _, li = np.unique(loop[small], return_inverse=True)
    centroid = np.zeros((li.max() + 1, 3))
    np.add.at(centroid, li, mesh.verts[B[:, 0]])
    centroid /= np.bincount(li)[:, None]
    return Mesh(np.r_[mesh.verts, centroid], np.r_[F, np.c_[B[:, 1], B[:, 0], n + li]])


#: Barycentric sample points of a face for :func:`trim_to_evidence`: its corners, edge
#: midpoints and centroid.
_FACE_SAMPLES = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0], [0, 0.5, 0.5],
                          [0.5, 0, 0.5], [1 / 3, 1 / 3, 1 / 3]])


@dataclass(frozen=True)
class EvidenceTrim:
    """What :func:`trim_to_evidence` removed.

    Attributes
    ----------
    mesh : Mesh
        The trimmed mesh (the input itself when nothing was removed).
    n_removed : int
        Faces removed (holes and the islands they left).
    n_holes : int
        Hole regions found (connected patches of removed faces holding a seed face).
    n_islands : int
        Small parts the holes cut off, removed with them.
    gap : float
        Gap factor of the seeds (``sqrt(log2 n) + 1``, ``n`` the cloud's points).
    """

    mesh: Mesh
    n_removed: int
    n_holes: int
    n_islands: int
    gap: float

    def describe(self) -> str:
        """One line for a fit's history."""
        return (f"removed {self.n_removed} faces where the scan has no point: {self.n_holes} "
                f"hole region(s) with a face farther than {self.gap:.2g} local spacings + 3 "
                f"noise from every point (faces beside them farther than 3 (spacing + noise) "
                f"at their centroid), {self.n_islands} island(s) they cut off")


def trim_to_evidence(mesh: Mesh, cloud: CloudTarget, noise: float, *,
                     min_island: float = 0.01) -> EvidenceTrim:
    """The mesh without the surface it has where the scan has a hole.

    A uniformly sampled surface has chance gaps: the chance that a disk of radius ``R`` holds
    none of ``n`` samples is ``2^-(R / s)^2`` (``s`` the median spacing), so its largest empty
    disk has a radius of about ``s sqrt(log2 n)`` (3.8 spacings for 20,000 points). A face is
    removed only where the gap is larger than that (Canny-style hysteresis):

    * **seeds**: faces whose 7 sample points (corners, edge midpoints, centroid) are all
      farther than ``(sqrt(log2 n) + 1) s_f + 3 noise`` from every point of the cloud, with
      ``s_f`` the local spacing near the face (:attr:`CloudTarget.local_spacing` of the point
      nearest its centroid);
    * **hole regions**: the edge-connected patches of faces whose centroid is farther than
      ``3 (s_f + noise)`` from every point that hold a seed (so a face whose centroid is off
      the points somewhere on a well-sampled surface, a large face at a crease, is never cut
      out on its own);
    * **islands**: parts of the trimmed mesh that were part of a larger part before and have
      fewer than ``min_island`` of its faces (what the holes cut off, not a surface).

    On a closed, well-sampled scan there is no seed, and nothing is removed.

    Parameters
    ----------
    mesh : Mesh
        A fitted mesh (the cloud's frame).
    cloud : CloudTarget
        The scan.
    noise : float
        The scan's noise level (same frame; see :func:`geofit.fit._scan_report.scan_report`).
    min_island : float
        Smallest part a hole may leave, as a fraction of the faces of the part it was cut from.

    Returns
    -------
    EvidenceTrim
        The trimmed mesh (``mesh`` itself when nothing is removed, or when everything would
        be) and what was removed.
    """
    n = len(cloud.points)
    gap = float(np.sqrt(np.log2(max(n, 2)))) + 1.0
    T = mesh.verts[mesh.faces]
    S = np.einsum("sk,mkd->msd", _FACE_SAMPLES, T).reshape(-1, 3)
    dist, near = cloud.tree.query(S)
    dist = dist.reshape(-1, len(_FACE_SAMPLES))
    s_f = cloud.local_spacing[near.reshape(dist.shape)[:, -1]]
    seed = dist.min(1) > gap * s_f + 3.0 * noise
    keep = np.ones(mesh.n_faces, dtype=bool)
    n_holes = n_islands = 0
    if seed.any():
        cand = dist[:, -1] > 3.0 * (s_f + noise)
        cand |= seed
        lab = face_components(mesh.topology.faces_to_edges, cand)
        holes = np.unique(lab[seed])
        keep = ~np.isin(lab, holes)
        n_holes = len(holes)
        # the parts the holes cut off
        before = face_components(mesh.faces)
        after = face_components(mesh.faces, keep)
        size_before = np.bincount(before)
        lab_k, size_k = np.unique(after[keep], return_counts=True)
        src = np.zeros(len(lab_k), dtype=np.int64)
        src[np.searchsorted(lab_k, after[keep])] = before[keep]
        small = lab_k[size_k < min_island * size_before[src]]
        n_islands = len(small)
        keep &= ~np.isin(after, small)
    n_removed = int((~keep).sum())
    if n_removed == 0 or n_removed == mesh.n_faces:
        return EvidenceTrim(mesh, 0, 0, 0, gap)
    F = mesh.faces[keep]
    used = np.unique(F)
    remap = np.full(mesh.n_verts, -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return EvidenceTrim(Mesh(mesh.verts[used], remap[F]), n_removed, n_holes, n_islands, gap)



@dataclass(frozen=True)
class BoundaryPlacement:
    """What :func:`place_boundary` did.

    Attributes
    ----------
    mesh : Mesh
        The mesh with its boundary placed (the input itself when it has no boundary).
    distance : float
        Distance of the placed boundary from the nearest point (:func:`boundary_distance`:
        2.5 spacings on a clean scan, fewer measured spacings where the scan is noisy).
    n_split : int
        Boundary edges split so that the boundary can follow the points.
    n_boundary : int
        Boundary vertices placed.
    shift : float
        Median signed move of the boundary vertices (> 0: outwards, past the points).
    """

    mesh: Mesh
    distance: float
    n_split: int
    n_boundary: int
    shift: float

    def describe(self) -> str:
        """One line for a fit's history."""
        return (f"placed the boundary ({self.n_boundary} vertices, {self.n_split} edges split) "
                f"at {self.distance:.3g} from the nearest point (2.5 clean spacings, the noise's "
                f"overshoot removed): "
                f"median move {self.shift:+.3g}")


#: :func:`boundary_distance`'s table: the scan's noise over its spacing, ``sigma / s`` ...
RIM_NOISE = np.array([0.0, 0.235, 0.414, 0.559, 0.684, 0.796, 0.910, 1.093, 1.270, 1.435, 1.741])
#: ... and the distance from the nearest point, in spacings ``s``, at which a boundary lies
#: where :data:`RIM_CLEAN` clean spacings put it on the same scan without noise
#: (``python benchmarks/scans_rim_offset.py --clean 2.5``).
RIM_DISTANCE = np.array([2.5, 2.346, 2.056, 1.860, 1.727, 1.589, 1.554, 1.413, 1.365, 1.337,
                         1.273])
#: Distance of a clean scan's boundary from its last points, in spacings. Measured on the
#: one-sided 20,000-point scans of ``benchmarks/_scans.py`` at noise 0.005 (session 9, where
#: the boundary at 2 measured spacings took the torus's F@0.01 from 0.997 to 0.9994 and lost
#: nowhere; measured at ``sigma / s = 0.4-0.6`` the measured spacing ``s`` is 1.2-1.34 clean
#: spacings, so that placement is 2.4-2.7 clean spacings).
RIM_CLEAN = 2.5


def boundary_distance(spacing: float, noise: float) -> float:
    """How far past the nearest point a fit's boundary goes where the scan ends.

    On a clean scan the boundary lies :data:`RIM_CLEAN` ``s`` (2.5 spacings; ``s`` the
    spacing, :class:`CloudTarget`) from the nearest point: the evidence of a surface reaches
    about that far (the tangent disks' radius ``rho = 2 s``, and a little more). With noise
    ``sigma`` (isotropic, as the scan report estimates it along the normals) the same rule
    would move the boundary outwards, for two reasons: the outermost noisy points already
    overshoot the rim (tangential noise), and the measured spacing ``s`` (the median distance
    to the nearest *noisy* point) grows with the noise. Both are those of a straight rim: a
    uniform (Poisson) sampling of a half-plane at the scan's clean spacing ``s0``, each point
    moved by ``N(0, sigma^2)`` in all three axes, a boundary vertex on the mean surface placed
    where its nearest point is ``T`` away. :data:`RIM_DISTANCE` is the ``T`` (in units of the
    noisy ``s``) that puts the boundary where ``2.5 s0`` puts it without noise, as a function
    of ``sigma / s`` (:data:`RIM_NOISE`; simulated, 10,000 points a seed, 3 seeds, +-0.05 at
    most: benchmarks/scans_rim_offset.py). At ``sigma = s0`` (``sigma / s = 0.68``) it is
    ``1.73 s`` (``2.53 s0``), where ``2.5 s`` (``3.66 s0``) would put the boundary more than
    a clean spacing past the clean placement; past the table the last value holds.
    Interpolated linearly.

    Parameters
    ----------
    spacing : float
        The cloud's spacing (:attr:`CloudTarget.spacing`).
    noise : float
        The scan's noise level (same frame; see
        :func:`geofit.fit._scan_report.scan_report`).

    Returns
    -------
    float
        The distance (same frame).
    """
    return float(spacing * np.interp(noise / spacing, RIM_NOISE, RIM_DISTANCE))


def place_boundary(mesh: Mesh, cloud: CloudTarget, noise: float = 0.0, *,
                   n_iter: int = 4) -> BoundaryPlacement:
    """The mesh with its boundary on the boundary of the cloud's surface.

    The cloud's surface (:class:`CloudTarget`) is the union of the tangent disks of radius
    ``rho`` (two spacings) around its points: where a scan ends, at a real rim or where the
    surface turned away from the scanner, the evidence of a surface reaches ``rho`` past the
    last points of a clean scan, and the fitted mesh a little more (``T`` =
    :func:`boundary_distance`: 2.5 spacings clean, less on a noisy scan, where the last points
    already overshoot the rim). The fit alone leaves its boundary anywhere within a few
    spacings of that line: its data term is flat within ``rho`` of the points and its
    smoothness shortens the boundary, and a boundary edge many spacings long cuts
    across the points' outline as a chord. Here

    1. the boundary edges longer than ``2 rho`` are split (:func:`geofit.ops.remesh`, splits
       only, up to twice), so the boundary can follow the points' outline;
    2. each boundary vertex moves in its tangent plane, along the outward normal of the
       boundary (away from its faces), to where its nearest point is ``T`` away (a few
       fixed-point steps ``t += T - d(v + t b)``, the move kept within ``[-h / 2, 2 T]``
       with ``h`` the vertex's shortest edge, so no face turns over).

    Measured on the 20,000-point scans of ``benchmarks/_scans.py`` (noise 0.005, 1 % strays;
    benchmarks/results/fit_mesh_scans_session9): one-sided, F@0.01 where the scan has
    evidence, the torus 0.9968-0.9975 -> 0.9992-0.9995 (Poisson at the same size 0.999; its
    missed true surface lay 1.2-2.4 clean spacings past the last points, where the fit's
    boundary stopped short), the teapot 0.9796 -> 0.9827, fandisk, Suzanne, ogre and the open
    cylinder's real rims within 0.0005 (0.9987 -> 0.9982, Poisson 0.997), the invented area
    down on all six; seen from all sides, the open cylinder's rims 0.9984-0.9989 -> 0.9977-0.9979
    (Poisson 0.990), at noise 0.01 0.9961 -> 0.9932-0.9938 (Poisson 0.993: the noisy last
    points already lie past the rim). With the distance from :func:`boundary_distance`
    (session 10, the same scans; the fits before the placement kept, only the placement
    changed) against ``2 s``: the open cylinder at noise 0.01 0.9931 -> 0.9951, one-sided
    the torus 0.9994 -> 0.9993, the open cylinder 0.9984 -> 0.9983, fandisk 0.9919 -> 0.9920,
    Suzanne 0.9768 -> 0.9766, teapot 0.9811 -> 0.9809, ogre 0.9535 -> 0.9541; the open
    cylinder's clean scans (more than ``2 s`` now) 0.9991 -> 0.9980 (noise 0), 0.9998 ->
    0.9996 (50,000 points at noise 0.002); Poisson at the same size lower in every cell.
    A boundary at ``2 s0`` (the table of ``--clean 2``) wins on the real rims but loses the
    one-sided torus (0.9984 against Poisson's 0.9990): the torus's true surface continues past
    its last points, the cylinder's ends at them, and the points do not tell the two apart.

    Parameters
    ----------
    mesh : Mesh
        A fitted mesh (the cloud's frame), edge-manifold and consistently oriented.
    cloud : CloudTarget
        The scan.
    noise : float
        The scan's noise level (same frame; 0: a clean scan, ``T`` = 2.5 spacings).
    n_iter : int
        Fixed-point steps of the moves.

    Returns
    -------
    BoundaryPlacement
        The mesh and what was done.
    """

    rho, T = cloud.rho, boundary_distance(cloud.spacing, noise)
    B = _boundary_half_edges(mesh)
    if len(B) == 0:
        return BoundaryPlacement(mesh, T, 0, 0, 0.0)
    # only the boundary edges are split: an edge's target is its endpoints' mean, and every
    # vertex off the boundary asks for more than any edge's length
    lv = np.full(mesh.n_verts, 10.0 * float(mesh.edge_lengths.max()))
    lv[B[:, :2].ravel()] = 1.5 * rho  # split above 4/3 of it
    r = remesh(mesh, lv, n_passes=2, collapse=False, flip=False)
    mesh = r.mesh
    B = _boundary_half_edges(mesh)
    V = mesh.verts
    # outward normal of each boundary edge (its face on its left), |pq| long, summed per vertex
    out = np.cross(V[B[:, 1]] - V[B[:, 0]], mesh.face_normals[B[:, 2]])
    b = np.zeros_like(V)
    np.add.at(b, B[:, 0], out)
    np.add.at(b, B[:, 1], out)
    vb = np.unique(B[:, :2])
    n = mesh.verts_normals[vb]
    d = b[vb] - np.einsum("ij,ij->i", b[vb], n)[:, None] * n  # in the tangent plane
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    E, le = mesh.edges, mesh.edge_lengths
    h = np.full(mesh.n_verts, np.inf)
    np.minimum.at(h, E[:, 0], le)
    np.minimum.at(h, E[:, 1], le)
    lo = -0.5 * h[vb]
    t = np.zeros(len(vb))
    for _ in range(n_iter):
        dist = cloud.tree.query(V[vb] + t[:, None] * d, workers=get_num_threads())[0]
        t = np.clip(t + T - dist, lo, 2.0 * T)
    V = V.copy()
    V[vb] += t[:, None] * d
    return BoundaryPlacement(mesh.update_verts(V), T, r.n_split, len(vb), float(np.median(t)))
