"""Initial meshes from the data: the target's own topology at a coarse resolution.

A deformed sphere cannot take genus >= 1, open boundaries or several parts. The fits therefore
start from a shape that already has the data's topology:

* a target **mesh** (tutorial 1): the target itself, decimated with Open3D's quadric error
  simplification (``TriangleMesh.simplify_quadric_decimation``, Garland and Heckbert 1997),
  which keeps holes, boundaries and parts, then cleaned (duplicated and degenerate faces,
  non-manifold edges removed);
* an **occupancy grid** (tutorial 4's visual hull, or a voxel fit): scikit-image's
  ``marching_cubes`` at the occupancy threshold, then the same decimation;
* ``"sphere"``: the tutorial's ico-sphere, kept for parity with PyTorch3D.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array
from ..shapes import ico_sphere
from ..structures import Mesh

__all__ = ["INITS", "InitialMesh", "decimate", "initial_mesh", "mesh_from_occupancy",
           "visual_hull_mesh"]

#: Initialisations :func:`initial_mesh` accepts.
INITS = ("auto", "sphere", "target")


@dataclass
class InitialMesh:
    """An initial mesh and how it was made.

    Attributes
    ----------
    mesh : Mesh
        The starting mesh, in the frame of the data it was made from.
    name : str
        ``"sphere"``, ``"target"`` (decimated target), ``"occupancy"`` or ``"user"``.
    description : str
        One line for the fit's message and history.
    """

    mesh: Mesh
    name: str
    description: str


def _to_open3d(verts, faces):
    import open3d as o3d

    return o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.array(verts, dtype=np.float64)),
        o3d.utility.Vector3iVector(np.array(faces, dtype=np.int32)))


def _clean(m) -> Mesh:
    m.remove_duplicated_vertices()
    m.remove_degenerate_triangles()
    m.remove_duplicated_triangles()
    m.remove_non_manifold_edges()
    m.remove_unreferenced_vertices()
    return Mesh(np.asarray(m.vertices, dtype=np.float64),
                np.asarray(m.triangles, dtype=np.int64))


def decimate(mesh: Mesh, n_faces: int) -> Mesh:
    """Quadric-error decimation to at most ``n_faces`` faces, cleaned (Open3D).

    Parameters
    ----------
    mesh : Mesh
        Any triangle mesh.
    n_faces : int
        Target face count (>= 4). A mesh with fewer faces is only cleaned.

    Returns
    -------
    Mesh
        Duplicated vertices merged; degenerate and duplicated faces, non-manifold edges and
        unreferenced vertices removed. Holes, boundaries and separate parts are kept.
    """
    if not isinstance(n_faces, (int, np.integer)) or isinstance(n_faces, bool) or n_faces < 4:
        raise ValueError(f"n_faces: expected an integer >= 4, got {n_faces!r}")
    m = _to_open3d(mesh.verts, mesh.faces)
    if mesh.n_faces > n_faces:
        m = m.simplify_quadric_decimation(int(n_faces))
    return _clean(m)


def mesh_from_occupancy(occupancy: np.ndarray, origin, voxel_size: float, *,
                        level: float = 0.5, n_faces: int | None = None) -> Mesh:
    """The ``level`` iso-surface of an occupancy grid (marching cubes), optionally decimated.

    Parameters
    ----------
    occupancy : (D, H, W) float64
        Occupancy (or density) on a regular grid; sample ``[i, j, k]`` sits at
        ``origin + voxel_size * (i, j, k)`` (x along the first axis).
    origin : (3,) float64
        Position of sample ``[0, 0, 0]``.
    voxel_size : float
        Grid spacing.
    level : float
        Iso-value.
    n_faces : int, optional
        Decimate to this many faces (:func:`decimate`).

    Returns
    -------
    Mesh
        Faces oriented outwards (towards lower occupancy).

    Raises
    ------
    ValueError
        If the grid is not 3-D, or ``level`` is not crossed by the grid.
    """
    from skimage.measure import marching_cubes

    occ = np.asarray(occupancy, dtype=np.float64)
    if occ.ndim != 3 or min(occ.shape) < 2:
        raise ValueError(f"occupancy: expected a (D, H, W) grid with sides >= 2, got {occ.shape}")
    if not occ.min() < level < occ.max():
        raise ValueError(f"level: the grid's values [{occ.min():g}, {occ.max():g}] do not cross "
                         f"{level!r}")
    # pad so that surfaces touching the grid's sides are closed
    occ = np.pad(occ, 1, constant_values=min(occ.min(), level - 1.0))
    h = float(voxel_size)
    verts, faces, _, _ = marching_cubes(occ, level, spacing=(h, h, h))
    verts = verts - h + np.asarray(origin, dtype=np.float64)
    faces = faces.astype(np.int64)
    v = verts[faces]
    if np.einsum("ij,ij->", v[:, 0], np.cross(v[:, 1], v[:, 2])) < 0:
        faces = faces[:, ::-1].copy()
    mesh = Mesh(verts, faces)
    return decimate(mesh, n_faces) if n_faces is not None else _clean(
        _to_open3d(mesh.verts, mesh.faces))


def initial_mesh(init, target: Mesh | None = None, *, n_faces: int = 2000,
                 sphere_level: int = 2) -> InitialMesh:
    """The starting mesh of a fit, from ``init`` and the data.

    Parameters
    ----------
    init : {"auto", "sphere", "target"}, int or Mesh
        ``"auto"``: the decimated target when there is one, else the ico-sphere.
        ``"target"``: the target decimated to ``n_faces`` faces (:func:`decimate`), keeping its
        genus, boundaries and parts. ``"sphere"``: ``ico_sphere(sphere_level)``. An int: that
        ico-sphere level. A Mesh: used as given.
    target : Mesh, optional
        The data's surface (normalised frame).
    n_faces : int
        Face budget of the decimated target.
    sphere_level : int
        Ico-sphere level for ``"sphere"``.

    Returns
    -------
    InitialMesh
    """
    if isinstance(init, Mesh):
        return InitialMesh(init, "user", f"the given mesh ({init.n_verts} vertices)")
    if isinstance(init, (int, np.integer)) and not isinstance(init, bool):
        m = ico_sphere(int(init))
        return InitialMesh(m, "sphere", f"ico-sphere level {int(init)} ({m.n_verts} vertices)")
    if not isinstance(init, str) or init not in INITS:
        raise ValueError(f"init: expected one of {INITS}, an ico-sphere level or a Mesh, "
                         f"got {init!r}")
    if init == "auto":
        init = "target" if target is not None else "sphere"
    if init == "sphere":
        m = ico_sphere(sphere_level)
        return InitialMesh(m, "sphere", f"ico-sphere level {sphere_level} ({m.n_verts} vertices)")
    if target is None:
        raise ValueError("init: 'target' needs a target mesh")
    m = decimate(target, n_faces)
    return InitialMesh(m, "target", f"the target decimated to {m.n_faces} faces "
                                    f"({m.n_verts} vertices, quadric error, Open3D)")


def visual_hull_mesh(silhouettes, cameras, *, extent: float = 1.5, resolution: int = 96,
                     n_faces: int | None = 2000) -> Mesh:
    """A coarse mesh of the visual hull of silhouettes (tutorial 4's initialisation).

    Each silhouette, thresholded at 0.5, becomes a signed distance in pixels (positive inside,
    scipy's Euclidean distance transform). Every node of a ``resolution``-cube grid spanning
    ``[-extent, extent]^3`` is projected into every view (``cameras.transform_points_screen``)
    and reads the signed distance there (bilinear; far outside beyond the image); the minimum
    over the views is positive exactly inside the visual hull, and, being a smooth field, its
    zero level set is located to a fraction of a voxel by marching cubes (not the
    conservative, dilated carving of :func:`geofit.fit.volume.visual_hull`, which must never cut
    into the object). Marching cubes (scikit-image) and :func:`decimate` then give the mesh. The
    hull has the genus and parts the silhouettes show (a hole seen through in some view stays
    open); it is larger than the object where no view sees a concavity.

    Parameters
    ----------
    silhouettes : (N, H, W) float64
        Silhouettes in [0, 1].
    cameras : CamerasBase
        The ``N`` cameras.
    extent : float
        Half-size of the grid (world units, centred at the origin).
    resolution : int
        Grid nodes per side (>= 8).
    n_faces : int or None
        Decimate to this many faces (None: keep the marching-cubes mesh).

    Returns
    -------
    Mesh

    Raises
    ------
    ValueError
        If ``resolution`` < 8, the silhouettes are not (N, H, W) with N cameras, or the hull is
        empty or fills the whole grid.
    """
    from scipy.ndimage import distance_transform_edt, map_coordinates

    if not isinstance(resolution, (int, np.integer)) or resolution < 8:
        raise ValueError(f"resolution: expected an integer >= 8, got {resolution!r}")
    sil = as_array(silhouettes, "silhouettes", (len(cameras), None, None))
    N, H, W = sil.shape
    t = np.linspace(-float(extent), float(extent), int(resolution))
    P = np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3)  # x, y, z order
    occ = np.full(len(P), np.inf)
    for i in range(N):  # views (each one vectorised call over all grid nodes)
        inside = sil[i] > 0.5
        sd = np.where(inside, distance_transform_edt(inside) - 0.5,
                      0.5 - distance_transform_edt(~inside))
        xy = cameras[i].transform_points_screen(P, (H, W))[0]
        val = map_coordinates(sd, [xy[:, 1] - 0.5, xy[:, 0] - 0.5], order=1,
                              cval=-float(H + W))
        np.minimum(occ, val, out=occ)
    occ = occ.reshape((int(resolution),) * 3)
    if not (occ > 0).any() or (occ > 0).all():
        raise ValueError("silhouettes: the visual hull is empty or fills the whole grid; check "
                         "the cameras and extent")
    vs = t[1] - t[0]
    return mesh_from_occupancy(occ, (t[0],) * 3, vs, level=0.0, n_faces=n_faces)
