"""Uniform random points on triangle meshes (PyTorch3D's ``sample_points_from_meshes``).

A sample is a face drawn with probability proportional to its area and a barycentric point in it,
``p = w0 v_a + w1 v_b + w2 v_c`` with PyTorch3D's warping of two uniform numbers ``u, v``:
``w0 = 1 - sqrt(u)``, ``w1 = sqrt(u) (1 - v)``, ``w2 = sqrt(u) v``. Once the faces and weights are
drawn the samples are a *linear* function of the vertices, ``points = B @ verts`` with a sparse
``(n, V)`` matrix ``B`` holding three weights per row, so a loss on the samples reaches the
vertices through ``dL/dV = B.T @ dL/dP``. No gradient flows through the random choice of faces
(PyTorch3D does the same: ``multinomial`` is not differentiable).

Two entry points draw the same samples from the same seed:

* :func:`sample_points_from_meshes` returns what PyTorch3D's does: the points alone, or a tuple
  ``(points, normals)``, ``(points, textures)`` or ``(points, normals, textures)`` whose parts are
  also attributes (``out.points``, ``out.normals``, ``out.textures``);
* :func:`sample_points_with_jacobian` returns :class:`SampledPoints`, which adds the face of each
  sample, its barycentric weights and the sparse Jacobian ``B``: what fitting code needs.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from .._memory import check_count
from .._validate import as_rng
from ..structures.mesh import Mesh, Meshes, as_mesh

#: Bytes per sample of a sampling call: points, normals, barycentrics, face ids, the sparse
#: Jacobian (3 entries) and the random draws, about 25 float64 / int64 values.
_BYTES_PER_SAMPLE = 200

__all__ = [
    "PointsNormals",
    "PointsNormalsTextures",
    "PointsTextures",
    "SampledPoints",
    "barycentric_matrix",
    "sample_points_from_meshes",
    "sample_points_with_jacobian",
]


class SampledPoints(NamedTuple):
    """Random surface samples of one mesh and the linear map that produced them.

    Attributes
    ----------
    points : (n, 3) float64
        Sample positions, ``points == B @ mesh.verts``.
    normals : (n, 3) float64 or None
        Unit normal of the face each sample lies on (``return_normals=True``), else None.
    face_idx : (n,) int64
        Index into ``mesh.faces`` of the face each sample lies on.
    bary : (n, 3) float64
        Barycentric weights ``(w0, w1, w2)`` of each sample in its face (non-negative, sum 1):
        ``points[i] = sum_j bary[i, j] * mesh.verts[mesh.faces[face_idx[i], j]]``.
    B : scipy.sparse.csr_matrix, shape (n, V)
        The sampling Jacobian: row ``i`` holds ``bary[i]`` in the columns
        ``mesh.faces[face_idx[i]]``. ``d points / d verts``, so ``dL/dV = B.T @ dL/dP``.
    textures : (n, C) float64 or None
        Colour of each sample from ``mesh.sample_textures`` (``return_textures=True``), else None.
    """

    points: np.ndarray
    normals: np.ndarray | None
    face_idx: np.ndarray
    bary: np.ndarray
    B: sp.csr_matrix
    textures: np.ndarray | None = None


class PointsNormals(NamedTuple):
    """``(points, normals)``: PyTorch3D's return with ``return_normals=True``."""

    points: np.ndarray
    normals: np.ndarray


class PointsTextures(NamedTuple):
    """``(points, textures)``: PyTorch3D's return with ``return_textures=True``."""

    points: np.ndarray
    textures: np.ndarray


class PointsNormalsTextures(NamedTuple):
    """``(points, normals, textures)``: PyTorch3D's return with both flags."""

    points: np.ndarray
    normals: np.ndarray
    textures: np.ndarray


def barycentric_matrix(faces: np.ndarray, face_idx: np.ndarray, bary: np.ndarray,
                       n_verts: int) -> sp.csr_matrix:
    """The sparse ``(k, V)`` matrix mapping vertices to points given by faces and barycentrics.

    Parameters
    ----------
    faces : (F, 3) int64
        Triangles of the mesh.
    face_idx : (k,) int64
        Face of each point, in ``[0, F)``.
    bary : (k, 3) float64
        Barycentric weights of each point in its face.
    n_verts : int
        Number of vertices ``V`` (columns of the result).

    Returns
    -------
    scipy.sparse.csr_matrix, shape (k, V)
        Row ``i`` has ``bary[i, j]`` in column ``faces[face_idx[i], j]`` (j = 0, 1, 2), so
        ``B @ verts`` are the points and ``B.T @ g`` scatters per-point gradients to the vertices.
        A face that repeats a vertex gives a row with a repeated column; scipy sums duplicates
        in every product, so the map is still exact.
    """
    k = len(face_idx)
    return sp.csr_matrix(
        (np.ascontiguousarray(bary, dtype=np.float64).ravel(),
         np.ascontiguousarray(faces[face_idx]).ravel(),
         np.arange(0, 3 * k + 1, 3, dtype=np.int64)),
        shape=(k, int(n_verts)),
    )


def _sample_one(mesh: Mesh, n: int, rng: np.random.Generator, return_normals: bool,
                return_textures: bool, name: str) -> SampledPoints:
    if mesh.n_faces == 0:
        raise ValueError(f"{name}: the mesh has no faces to sample")
    if return_textures and mesh.textures is None:
        raise ValueError(f"{name}: return_textures=True but the mesh has no textures")
    verts = mesh.verts  # finite: a Mesh rejects NaN/inf vertices when it is built
    with np.errstate(over="ignore", invalid="ignore"):  # overflow is reported just below
        cdf = np.cumsum(mesh.face_areas)
    total = cdf[-1]
    if not np.isfinite(total):
        raise ValueError(f"{name}: the total surface area is not finite (coordinates overflow)")
    if not total > 0:
        raise ValueError(f"{name}: the total surface area is zero, nothing to sample")
    # Area-weighted face choice with replacement (inverse CDF; zero-area faces are never hit
    # because side='right' skips flat steps of the CDF).
    face_idx = np.searchsorted(cdf, rng.random(n) * total, side="right")
    np.minimum(face_idx, mesh.n_faces - 1, out=face_idx)
    face_idx = face_idx.astype(np.int64, copy=False)
    uv = rng.random((2, n))
    su = np.sqrt(uv[0])
    bary = np.empty((n, 3))
    bary[:, 0] = 1.0 - su
    bary[:, 1] = su * (1.0 - uv[1])
    bary[:, 2] = su * uv[1]
    B = barycentric_matrix(mesh.faces, face_idx, bary, mesh.n_verts)
    points = B @ verts
    normals = mesh.face_normals[face_idx] if return_normals else None
    textures = mesh.sample_textures(face_idx, bary) if return_textures else None
    return SampledPoints(points, normals, face_idx, bary, B, textures)


def sample_points_with_jacobian(mesh, num_samples: int = 10000, *, seed=None,
                              return_normals: bool = False,
                              return_textures: bool = False):
    """Samples of :func:`sample_points_from_meshes` with their faces, barycentrics and Jacobian.

    Parameters
    ----------
    mesh : Mesh or Meshes
        The surface(s) to sample.
    num_samples : int
        Number of points per mesh, >= 1.
    seed : int, numpy.random.Generator or None
        Randomness; the same seed gives the same samples. A batch draws its meshes one after
        the other from one generator.
    return_normals : bool
        Also return the unit normal of each sample's face.
    return_textures : bool
        Also return each sample's colour, ``mesh.sample_textures(face_idx, bary)`` (bilinear UV
        lookup for ``TexturesUV``, barycentric interpolation for ``TexturesVertex``): this is how
        PyTorch3D colours samples of the textured cow.

    Returns
    -------
    SampledPoints or list of SampledPoints
        For a ``Mesh``, one :class:`SampledPoints` (``points`` (n, 3), ``normals`` (n, 3) or
        None, ``face_idx`` (n,), ``bary`` (n, 3), ``B`` csr (n, V), ``textures`` (n, C) or None).
        For a ``Meshes`` batch, a list with one per mesh; ``face_idx`` and ``B`` then refer to
        that mesh's own faces and vertices (stack ``sp.block_diag([s.B for s in out])`` for the
        packed ``(N n, sum V)`` Jacobian).

    Raises
    ------
    ValueError
        If ``num_samples`` is not an integer >= 1, a mesh has no faces, zero or non-finite total
        area, or non-finite vertices (a :class:`Mesh` already rejects NaN/inf vertices when it is
        built), or ``return_textures`` is set on a mesh without textures.
    TypeError
        If ``mesh`` is not a Mesh or Meshes, or ``seed`` is not an int, Generator or None.

    Notes
    -----
    PyTorch3D's recipe (``sample_points_from_meshes`` in 0.7.9): faces from
    ``areas.multinomial(num_samples, replacement=True)``, then ``u, v ~ U[0, 1)``,
    ``w0 = 1 - sqrt(u)``, ``w1 = sqrt(u)(1 - v)``, ``w2 = sqrt(u) v``. The density is exactly
    uniform in area: the face is chosen proportionally to its area and the square-root warp makes
    the point uniform within the face. The torch random stream itself is not reproduced.
    Unlike PyTorch3D, an empty mesh inside a batch raises instead of returning zeros.
    :func:`sample_points_from_meshes` with the same arguments returns the same points.

    Examples
    --------
    >>> from geofit import ico_sphere
    >>> from geofit.ops import sample_points_with_jacobian
    >>> s = sample_points_with_jacobian(ico_sphere(2), 1000, seed=0, return_normals=True)
    >>> s.points.shape, s.B.shape
    ((1000, 3), (1000, 162))
    >>> bool(abs(s.points - s.B @ ico_sphere(2).verts).max() < 1e-15)
    True
    """
    n = check_count(num_samples, "num_samples", _BYTES_PER_SAMPLE)  # estimate before allocating
    rng = as_rng(seed)
    if not isinstance(mesh, (Mesh, Meshes)):
        mesh = as_mesh(mesh, "mesh")  # a trimesh or Open3D mesh
    if isinstance(mesh, Mesh):
        return _sample_one(mesh, n, rng, bool(return_normals), bool(return_textures), "mesh")
    if isinstance(mesh, Meshes):
        return [_sample_one(m, n, rng, bool(return_normals), bool(return_textures), f"mesh[{i}]")
                for i, m in enumerate(mesh)]  # loop over batch members
    raise TypeError(f"mesh: expected a Mesh or Meshes, got {type(mesh)!r}")


def sample_points_from_meshes(mesh, num_samples: int = 10000, *, seed=None,
                              return_normals: bool = False, return_textures: bool = False):
    """Sample points uniformly (by area) on a mesh or a batch: PyTorch3D's return values.

    Parameters
    ----------
    mesh, num_samples, seed, return_normals, return_textures
        As in :func:`sample_points_with_jacobian`; the same arguments give the same samples.

    Returns
    -------
    points : (n, 3) float64, or (N, n, 3) for a ``Meshes`` batch of N
        Alone when neither flag is set, as in PyTorch3D.
    PointsNormals, PointsTextures or PointsNormalsTextures
        With ``return_normals`` and/or ``return_textures``: the tuple PyTorch3D returns,
        ``(points, normals)``, ``(points, textures)`` or ``(points, normals, textures)``
        (normals (n, 3), textures (n, C); a leading N for a batch), also readable by name.

    Raises
    ------
    ValueError, TypeError
        As :func:`sample_points_with_jacobian`; also ValueError if the textures of a batch have
        different channel counts.

    See Also
    --------
    sample_points_with_jacobian : the same samples with faces, barycentrics and the sparse
        Jacobian ``B`` (``points == B @ verts``), for gradients.

    Notes
    -----
    A single :class:`Mesh` (which PyTorch3D does not have: its ``Meshes`` is always a batch) gives
    2-D arrays; a ``Meshes`` batch gives PyTorch3D's stacked (N, n, ...) arrays.

    Examples
    --------
    >>> from geofit import ico_sphere
    >>> from geofit.ops import sample_points_from_meshes
    >>> points = sample_points_from_meshes(ico_sphere(2), 1000, seed=0)
    >>> points.shape
    (1000, 3)
    >>> points, normals = sample_points_from_meshes(ico_sphere(2), 1000, seed=0,
    ...                                             return_normals=True)
    >>> normals.shape
    (1000, 3)
    """
    out = sample_points_with_jacobian(mesh, num_samples, seed=seed,
                                      return_normals=return_normals,
                                      return_textures=return_textures)
    if isinstance(out, list):  # a batch: stack as PyTorch3D's padded tensors
        points = np.stack([s.points for s in out])
        normals = np.stack([s.normals for s in out]) if return_normals else None
        textures = None
        if return_textures:
            channels = {s.textures.shape[1] for s in out}
            if len(channels) > 1:
                raise ValueError(f"mesh: the textures of the batch have different channel "
                                 f"counts {sorted(channels)}, cannot stack them")
            textures = np.stack([s.textures for s in out])
    else:
        points, normals, textures = out.points, out.normals, out.textures
    if return_normals and return_textures:
        return PointsNormalsTextures(points, normals, textures)
    if return_normals:
        return PointsNormals(points, normals)
    if return_textures:
        return PointsTextures(points, textures)
    return points
