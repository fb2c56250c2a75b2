"""First hits and occlusion of many rays against a mesh or a batch of meshes (Embree).

:class:`RayCaster` builds one Embree scene (through ``embreex``) over every mesh of a batch,
casts all rays in one call per thread, and refines each hit in float64. Embree works in float32;
the three things that keep its answers accurate are (as in trimesh):

1. all geometry is centred and scaled into the box ``[-1, 1]^3`` before the scene is built, and
   the rays are transformed likewise;
2. each ray starts at the point of its line just before the scene's bounding sphere (never
   before ``tnear``), so a far-away camera does not cost float32 digits;
3. Embree only *chooses the triangle*: ``t`` and the barycentrics are then recomputed in float64
   by a Moller-Trumbore intersection with that triangle, in the caller's coordinates.
"""
from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np

from .._threads import get_num_threads, parallel_map
from .._validate import as_array, as_points
from ..structures import Meshes, as_meshes

__all__ = ["EmbreeScene", "RayCaster", "RayHits"]  # moller_trumbore: shared inside geofit

# Bounding-sphere radius of the normalised box [-1, 1]^3, with a margin.
_R = 1.75
_DEFAULT_PARALLEL_MIN = 50_000


def unit_box(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre ``(3,)`` and half the largest side of the bounding box of ``points (k, 3)``.

    The float32 scenes (Embree's, Open3D's) store ``(v - centre) / scale``, so every used
    coordinate lies in [-1, 1] and float32 keeps the same relative accuracy wherever the mesh
    sits; ray offsets and distances are scaled back by ``scale``. A single point gets scale 1.
    """
    lo, hi = points.min(axis=0), points.max(axis=0)
    half = 0.5 * float(np.max(hi - lo))
    return 0.5 * (lo + hi), (half if half > 0 else 1.0)


class RayHits(NamedTuple):
    """First intersection of each of ``r`` rays (see :meth:`RayCaster.cast`).

    Attributes
    ----------
    t : (r,) float64
        Ray parameter of the hit: the hit point is ``origins + t * directions`` (units of the
        given direction vectors, like PyTorch3D's ray lengths; the distance when directions are
        unit vectors). ``inf`` on a miss.
    face_id : (r,) int64
        Index of the hit triangle within its own mesh's ``faces``; -1 on a miss.
    mesh_id : (r,) int64
        Index of the hit mesh in the batch (0 for a single Mesh); -1 on a miss.
    bary : (r, 3) float64
        Barycentrics ``(w0, w1, w2)`` of the hit point in the hit triangle ``(v0, v1, v2)``:
        ``point = w0 v0 + w1 v1 + w2 v2``. Embree's ``(u, v)`` are ``w1, w2`` and
        ``w0 = 1 - u - v``. Zero on a miss.
    """

    t: np.ndarray
    face_id: np.ndarray
    mesh_id: np.ndarray
    bary: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(r,) bool: True where the ray hit something."""
        return self.face_id >= 0

    def points(self, origins, directions) -> np.ndarray:
        """(r, 3) float64 hit points ``origins + t * directions``; zero on a miss."""
        o = np.asarray(origins, dtype=np.float64)
        d = np.asarray(directions, dtype=np.float64)
        h = self.hit
        out = np.zeros(o.shape)
        out[h] = o[h] + self.t[h, None] * d[h]
        return out


def _empty_hits(r: int) -> RayHits:
    return RayHits(np.full(r, np.inf), np.full(r, -1, np.int64), np.full(r, -1, np.int64),
                   np.zeros((r, 3)))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def moller_trumbore(o, d, A, B, C):
    """Moller-Trumbore: float64 parameters of ray ``i`` against the plane of triangle ``i``.

    Parameters
    ----------
    o, d : (n, 3) float64
        Ray origins and directions.
    A, B, C : (n, 3) float64
        The corners of the triangle each ray is tested against.

    Returns
    -------
    t, u, v, det : (n,) float64
        The hit point ``o + t d = (1-u-v) A + u B + v C`` whenever ``det != 0`` (for
        ``det == 0`` the ray is parallel to the plane and t, u, v are 0). Whether the point is
        inside the triangle (``u, v >= 0, u + v <= 1``) is for the caller to test.
    """
    e1 = B - A
    e2 = C - A
    pvec = _cross(d, e2)
    det = _dot(e1, pvec)
    ok = det != 0
    inv = np.divide(1.0, np.where(ok, det, 1.0)) * ok
    tvec = o - A
    u = _dot(tvec, pvec) * inv
    qvec = _cross(tvec, e1)
    v = _dot(d, qvec) * inv
    t = _dot(e2, qvec) * inv
    return t, u, v, det


def _as_ray_limit(x, name: str, r: int) -> np.ndarray:
    """A scalar or (r,) array of ray parameters, as (r,) float64 (inf allowed)."""
    if np.ndim(x) == 0:
        try:
            x = np.full(r, float(x))
        except (TypeError, ValueError):
            raise ValueError(f"{name}: expected a number or an ({r},) array, got {x!r}") from None
    arr = as_array(x, name, (r,), finite=False)
    if np.any(np.isnan(arr)):
        raise ValueError(f"{name}: expected numbers, got NaN")
    return arr


def _check_rays(origins, directions, tnear, tfar):
    """Validated rays: ``o, d (r, 3)`` float64 (non-zero directions), ``tnear, tfar (r,)``."""
    o = as_points(origins, "origins")
    r = len(o)
    d = as_array(directions, "directions", (r, 3))
    L2 = _dot(d, d)
    if np.any(L2 == 0):
        raise ValueError(f"directions: expected non-zero vectors, got "
                         f"{int(np.count_nonzero(L2 == 0))} zero-length rows")
    tn = _as_ray_limit(tnear, "tnear", r)
    tf = _as_ray_limit(tfar, "tfar", r)
    if np.any(~np.isfinite(tn)) or np.any(tn < 0):
        raise ValueError("tnear: expected finite values >= 0")
    if np.any(tf < tn):
        raise ValueError("tfar: expected tfar >= tnear for every ray")
    return o, d, tn, tf


class EmbreeScene:
    """One Embree scene (``embreex``) over triangle meshes, in a normalised frame.

    The one place geofit builds Embree scenes: :class:`RayCaster` (any rays, float64 checks and
    refinement) and the mesh rasterizer (millions of structured pixel rays, generated in float32
    inside worker threads) both cast against it. Vertices are mapped into ``[-1, 1]^3`` by
    ``x' = (x - center) / scale`` (one map for all meshes, from the vertices the faces use), and
    rays given to :meth:`intersect` and :meth:`occluded` are in that frame, in float32.

    Parameters
    ----------
    meshes : sequence of (verts, faces)
        ``verts (V_i, 3) float64`` and ``faces (F_i, 3) int64`` of each mesh; meshes without
        faces get no Embree geometry. At least one face in all.
    robust : bool, optional
        Embree's robust (watertight) traversal, so that a ray through a shared edge hits one of
        its triangles (default True).

    Attributes
    ----------
    center : (3,) float64
        Centre of the bounding box of the used vertices.
    scale : float
        Half the longest side of that box (1 for a degenerate box).
    lo, hi : (3,) float64
        The box.
    geom_to_mesh : (G,) int64
        Index in ``meshes`` of each Embree geometry (the meshes with faces, in order).

    Notes
    -----
    embreex creates its device with ``rtcNewDevice(NULL)`` and exposes no configuration string,
    so the build threads of Embree's own (TBB) scheduler, used only while the scene is
    committed, cannot be set from Python: they follow the process's CPU affinity (measured:
    committing a scene on 2 allowed cores added one TBB worker thread, under ``taskset -c 0``
    none), not :func:`geofit.set_num_threads`. Queries run on the calling thread; callers split
    rays over geofit's pool (:func:`geofit.get_num_threads`).
    """

    def __init__(self, meshes, *, robust: bool = True):
        from embreex import mesh_construction, rtcore_scene  # kept local: start-up

        meshes = [(np.asarray(v, dtype=np.float64), np.asarray(f)) for v, f in meshes]
        used = [v[f.ravel()] for v, f in meshes if len(f)]
        if not used:
            raise ValueError("meshes: expected at least one face, got 0 faces")
        used = np.concatenate(used)
        self.lo, self.hi = used.min(axis=0), used.max(axis=0)
        self.center, self.scale = unit_box(used)
        scene = rtcore_scene.EmbreeScene(robust=bool(robust))
        geom_to_mesh = []
        for i, (v, f) in enumerate(meshes):  # loop over meshes
            if len(f) == 0:
                continue
            v32 = np.ascontiguousarray((v - self.center) / self.scale, dtype=np.float32)
            mesh_construction.TriangleMesh(scene, v32, np.ascontiguousarray(f, dtype=np.int32))
            geom_to_mesh.append(i)
        self.geom_to_mesh = np.asarray(geom_to_mesh, dtype=np.int64)
        # One tiny query commits the scene before any threads share it.
        scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))
        self._scene = scene

    def intersect(self, o: np.ndarray, d: np.ndarray, tfar: np.ndarray | None = None):
        """First hits of float32 rays ``o + t d`` (normalised frame), ``t <= tfar``.

        Parameters
        ----------
        o, d : (r, 3) float32
            Contiguous origins and directions in the normalised frame.
        tfar : (r,) float32, optional
            Largest ``t`` per ray (default unlimited).

        Returns
        -------
        geom, prim : (r,) int32
            Embree geometry (-1 on a miss; see ``geom_to_mesh``) and triangle within it.
        u, v, t : (r,) float32
            Embree's barycentrics of vertices 1 and 2 and the ray parameter of the hit.
        """
        if tfar is None:
            res = self._scene.run(o, d, output=1)
        else:
            res = self._scene.run(o, d, dists=tfar, output=1)
        return res["geomID"], res["primID"], res["u"], res["v"], res["tfar"]

    def occluded(self, o: np.ndarray, d: np.ndarray, tfar: np.ndarray) -> np.ndarray:
        """(r,) bool: whether float32 rays (normalised frame) hit anything with ``t <= tfar``."""
        res = self._scene.run(o, d, dists=tfar, query="OCCLUDED")
        return np.asarray(res) >= 0


class RayCaster:
    """One Embree scene over a mesh or a batch of meshes; first hits and occlusion for rays.

    Parameters
    ----------
    meshes : Mesh or Meshes or sequence of Mesh
        The geometry. Mesh ``i`` of the batch is reported as ``mesh_id == i``.
    n_threads : int, optional
        Threads used for large ray batches (default: :func:`geofit.get_num_threads`, read at
        each call: the CPUs available to this process unless overridden). The rays are split
        into ``n_threads`` contiguous chunks, each cast and refined on its own thread of
        geofit's shared pool (embreex releases the GIL); results do not depend on the thread
        count.
    parallel_min : int, optional
        Ray counts below this are cast in one call on the calling thread (default 50 000).
    robust : bool, optional
        Embree's robust (watertight) traversal mode, so that a ray through a shared edge hits
        one of its triangles (default True).

    Raises
    ------
    TypeError
        If ``meshes`` is not a Mesh, Meshes or sequence of Mesh.
    ValueError
        If the batch has no faces at all, or ``n_threads`` / ``parallel_min`` are invalid.

    Notes
    -----
    *Precision.* Embree stores vertices and rays in float32. All geometry is mapped into
    ``[-1, 1]^3`` (``x' = (x - center) / scale``, one map for the whole batch), each ray is
    advanced to just before the scene's bounding sphere, and every hit is refined in float64 by
    Moller-Trumbore against the triangle Embree chose, using the caller's float64 origins,
    directions and vertices. ``t`` is therefore exact to float64 rounding for that triangle.
    The choice of triangle is float32's: a ray within ~1e-7 (relative to the scene size) of a
    shared edge may be reported on either neighbour, and the refined barycentrics are then
    clipped to the triangle (they can fall outside it by that much). ``tfar`` is applied exactly
    to the refined ``t``; ``tnear`` is applied by Embree in float32.

    *Updates.* embreex has no vertex-update API: :meth:`update_verts` rebuilds the scene.
    Measured on the 2-core development machine (best of 5-9, other processes sharing the CPUs):
    4.3 ms for 5,120 faces and 75-225 ms for 100,000 faces; ``benchmarks/raycast.py`` records
    the current figures.

    *Threads.* Large batches are split into ``n_threads`` chunks on geofit's shared thread pool
    (:mod:`geofit._threads`); each chunk is one Embree call (which releases the GIL) and its own
    float64 refinement, so a batch of rays costs ``n_threads`` Embree calls, not one per ray.

    Examples
    --------
    >>> import numpy as np
    >>> from geofit import plane
    >>> rc = RayCaster(plane())
    >>> hits = rc.cast([[0.1, 0.2, 1.0]], [[0.0, 0.0, -2.0]])
    >>> hits.t, hits.mesh_id
    (array([0.5]), array([0]))
    """

    def __init__(self, meshes, *, n_threads: int | None = None,
                 parallel_min: int = _DEFAULT_PARALLEL_MIN, robust: bool = True):
        self._meshes = as_meshes(meshes)
        if n_threads is not None and (not isinstance(n_threads, (int, np.integer))
                                      or n_threads < 1):
            raise ValueError(f"n_threads: expected an integer >= 1, got {n_threads!r}")
        if not isinstance(parallel_min, (int, np.integer)) or parallel_min < 1:
            raise ValueError(f"parallel_min: expected an integer >= 1, got {parallel_min!r}")
        self._n_threads = None if n_threads is None else int(n_threads)
        self.parallel_min = int(parallel_min)
        self._robust = bool(robust)
        self._build()

    # ------------------------------------------------------------------ scene
    def _build(self) -> None:
        ms = self._meshes
        nf = ms.num_faces_per_mesh()
        if len(ms) == 0 or nf.sum() == 0:
            raise ValueError("meshes: expected at least one face in the batch, got 0 faces")
        self._verts_packed = ms.verts_packed()
        self._faces_packed = ms.faces_packed()
        self._face_first = ms.mesh_to_faces_packed_first_idx()
        self._embree = EmbreeScene([(m.verts, m.faces) for m in ms], robust=self._robust)
        self._center, self._scale = self._embree.center, self._embree.scale
        self._geom_to_mesh = self._embree.geom_to_mesh

    @property
    def n_threads(self) -> int:
        """Threads (and chunks) used for a large batch of rays."""
        return get_num_threads() if self._n_threads is None else self._n_threads

    @property
    def meshes(self) -> Meshes:
        """The batch the scene was built over (with the latest vertices)."""
        return self._meshes

    @property
    def n_meshes(self) -> int:
        return len(self._meshes)

    @property
    def n_faces(self) -> int:
        """Total number of triangles in the scene."""
        return len(self._faces_packed)

    def update_verts(self, verts) -> RayCaster:
        """Move the vertices (same faces) and rebuild the Embree scene in place.

        Parameters
        ----------
        verts : (V, 3) float64, or list of (V_i, 3) float64, or (sum V_i, 3) float64
            New positions: one array for a single mesh, a list with one array per mesh, or the
            packed array of the whole batch.

        Returns
        -------
        RayCaster
            ``self``, for chaining.

        Raises
        ------
        ValueError
            If the shapes do not match the batch.
        """
        ms = self._meshes
        if isinstance(verts, (list, tuple)):
            if len(verts) != len(ms):
                raise ValueError(f"verts: expected a list of {len(ms)} arrays, got {len(verts)}")
            new = Meshes([m.update_verts(as_array(v, f"verts[{i}]", (m.n_verts, 3)))
                          for i, (m, v) in enumerate(zip(ms, verts))])
        else:
            new = ms.update_packed(as_array(verts, "verts",
                                            (int(ms.num_verts_per_mesh().sum()), 3)))
        self._meshes = new
        self._build()
        return self

    def packed_face_id(self, hits: RayHits) -> np.ndarray:
        """(r,) int64 index of each hit face in ``meshes.faces_packed()``; -1 on a miss."""
        out = np.full(len(hits.face_id), -1, dtype=np.int64)
        h = hits.face_id >= 0
        out[h] = self._face_first[hits.mesh_id[h]] + hits.face_id[h]
        return out

    # ------------------------------------------------------------------ rays
    def _validate_rays(self, origins, directions, tnear, tfar):
        return _check_rays(origins, directions, tnear, tfar)

    def _prepare(self, o, d, tn, tf):
        """Rays in the normalised frame, advanced to the scene: float32 start, unit direction and
        far limit, an "empty window" mask, and (s0, L) to map Embree's parameter back:
        ``t = (s0 + t_embree) / L``."""
        s = self._scale
        os_ = (o - self._center) / s
        ds = d / s
        L = np.sqrt(_dot(ds, ds))  # |d| in normalised units per unit of t
        u = ds / L[:, None]
        tc = -_dot(os_, u)
        s0 = np.maximum(tn * L, tc - _R)  # no geometry before tc - R along the ray
        start = os_ + s0[:, None] * u
        with np.errstate(invalid="ignore"):  # inf - finite is fine; inf*0 cannot occur (L > 0)
            far = tf * L - s0
        empty = ~(far > 0)
        far = np.where(empty, 0.0, np.minimum(far, 1e37))
        return (np.ascontiguousarray(start, dtype=np.float32),
                np.ascontiguousarray(u, dtype=np.float32),
                np.ascontiguousarray(far, dtype=np.float32), empty, s0, L)

    def _cast_chunk(self, o, d, tn, tf) -> RayHits:
        r = len(o)
        out = _empty_hits(r)
        if r == 0:
            return out
        start, u, far, empty, s0, L = self._prepare(o, d, tn, tf)
        geom, prim, eu, ev, et = self._embree.intersect(start, u, far)
        geom = geom.astype(np.int64)
        h = np.flatnonzero((geom >= 0) & ~empty)
        if len(h) == 0:
            return out
        mesh = self._geom_to_mesh[geom[h]]
        face = prim[h].astype(np.int64)
        tri = self._faces_packed[self._face_first[mesh] + face]
        V = self._verts_packed
        t, bu, bv, det = moller_trumbore(o[h], d[h], V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]])
        # Parallel to the plane in float64 (det == 0): keep Embree's float32 answer.
        par = det == 0
        if np.any(par):
            hp = h[par]
            t[par] = (s0[hp] + et[hp].astype(np.float64)) / L[hp]
            bu[par] = eu[hp]
            bv[par] = ev[hp]
        keep = t <= tf[h]  # tfar applied exactly to the refined t
        h, mesh, face, t, bu, bv = h[keep], mesh[keep], face[keep], t[keep], bu[keep], bv[keep]
        w = np.stack([1.0 - bu - bv, bu, bv], axis=1)
        if np.any(w < 0):  # float32 chose a triangle that float64 misses by ~1e-7: clip to it
            w = np.maximum(w, 0.0)
            w /= w.sum(axis=1, keepdims=True)
        out.t[h] = t
        out.face_id[h] = face
        out.mesh_id[h] = mesh
        out.bary[h] = w
        return out

    def _occluded_chunk(self, o, d, tn, tf) -> np.ndarray:
        if len(o) == 0:
            return np.zeros(0, dtype=bool)
        start, u, far, empty, _, _ = self._prepare(o, d, tn, tf)
        return self._embree.occluded(start, u, far) & ~empty

    def _chunks(self, r: int) -> list[slice]:
        n = self.n_threads
        if r < self.parallel_min or n == 1:
            return [slice(0, r)]
        bounds = np.linspace(0, r, n + 1).astype(int)
        return [slice(a, b) for a, b in itertools.pairwise(bounds)]

    def _map(self, fn, o, d, tn, tf) -> list:
        return parallel_map(lambda p: fn(o[p], d[p], tn[p], tf[p]), self._chunks(len(o)),
                            self.n_threads)

    def cast(self, origins, directions, *, tnear=0.0, tfar=np.inf) -> RayHits:
        """First hit of each ray ``origins + t * directions`` with ``tnear <= t <= tfar``.

        Parameters
        ----------
        origins : (r, 3) float64
            Ray origins.
        directions : (r, 3) float64
            Ray directions, any non-zero length; ``t`` is measured in units of their length.
        tnear : float or (r,) float64, optional
            Smallest accepted ``t`` (>= 0, default 0).
        tfar : float or (r,) float64, optional
            Largest accepted ``t`` (default inf).

        Returns
        -------
        RayHits
            ``t (r,)`` (inf on a miss), ``face_id (r,)`` and ``mesh_id (r,)`` (-1 on a miss),
            ``bary (r, 3)`` (0 on a miss). ``r = 0`` gives empty arrays.

        Raises
        ------
        ValueError
            If shapes differ from (r, 3), values are not finite, a direction has zero length,
            ``tnear`` is negative or not finite, or ``tfar < tnear``.
        """
        o, d, tn, tf = self._validate_rays(origins, directions, tnear, tfar)
        parts = self._map(self._cast_chunk, o, d, tn, tf)
        if len(parts) == 1:
            return parts[0]
        return RayHits(*(np.concatenate([getattr(p, f) for p in parts])
                         for f in RayHits._fields))

    def occluded(self, origins, directions, tfar=np.inf, *, tnear=0.0) -> np.ndarray:
        """Whether anything lies on each ray segment ``tnear <= t <= tfar`` (shadow rays).

        Parameters
        ----------
        origins, directions : (r, 3) float64
            As in :meth:`cast`.
        tfar : float or (r,) float64, optional
            End of each segment (default inf), e.g. 1 with ``directions = light - origins``.
        tnear : float or (r,) float64, optional
            Start of each segment (default 0).

        Returns
        -------
        (r,) bool
            True if the segment hits any triangle. Decided by Embree in float32 (no float64
            refinement), so a hit within ~1e-7 (relative) of ``tfar`` may go either way.

        Raises
        ------
        ValueError
            As :meth:`cast`.
        """
        o, d, tn, tf = self._validate_rays(origins, directions, tnear, tfar)
        return np.concatenate(self._map(self._occluded_chunk, o, d, tn, tf))

    def __repr__(self) -> str:
        return f"RayCaster(n_meshes={self.n_meshes}, n_faces={self.n_faces})"
