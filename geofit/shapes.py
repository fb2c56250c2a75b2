"""Procedural shapes: ico-spheres (PyTorch3D's exact vertex and face order), tori, boxes, planes,
and test shapes of other topologies (double torus, open cylinder, thin plate, two spheres).

Every function returns a :class:`~geofit.structures.Mesh` in float64, deterministic, with
counter-clockwise faces seen from outside.
"""
from __future__ import annotations

import numpy as np

from ._memory import check_allocation

from .structures.mesh import Mesh, as_meshes

__all__ = ["ico_sphere", "subdivide", "torus", "box", "plane", "tetrahedron", "double_torus",
           "open_cylinder", "thin_plate", "two_spheres", "implicit_surface", "TEST_SHAPES"]

# PyTorch3D's level-0 icosahedron (pytorch3d/utils/ico_sphere.py): the rounded coordinates are
# kept as they are, so level 0 is not exactly on the unit sphere (|v| = 0.99998...).
_ICO_VERTS0 = np.array(
    [
        [-0.5257, 0.8507, 0.0], [0.5257, 0.8507, 0.0], [-0.5257, -0.8507, 0.0],
        [0.5257, -0.8507, 0.0], [0.0, -0.5257, 0.8507], [0.0, 0.5257, 0.8507],
        [0.0, -0.5257, -0.8507], [0.0, 0.5257, -0.8507], [0.8507, 0.0, -0.5257],
        [0.8507, 0.0, 0.5257], [-0.8507, 0.0, -0.5257], [-0.8507, 0.0, 0.5257],
    ]
)
_ICO_FACES0 = np.array(
    [
        [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
        [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
        [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
    ],
    dtype=np.int64,
)


def _check_level(level, name="level", hi=8) -> int:
    if not isinstance(level, (int, np.integer)) or isinstance(level, bool) or not 0 <= level <= hi:
        raise ValueError(f"{name}: expected an integer in [0, {hi}], got {level!r}")
    return int(level)


def subdivide(mesh: Mesh, feats: np.ndarray | None = None):
    """Midpoint subdivision: one new vertex per edge, four faces per face (PyTorch3D order).

    New vertices follow the old ones in the order of ``mesh.edges``; face ``f`` becomes faces
    ``f``, ``F + f``, ``2F + f`` and ``3F + f`` (corner 0, 1, 2 and middle triangles), exactly as
    ``pytorch3d.ops.SubdivideMeshes``. Orientation is preserved.

    Parameters
    ----------
    mesh : Mesh
        The mesh to refine (textures are dropped).
    feats : (V, C) float64, optional
        Per-vertex features to average onto the new vertices.

    Returns
    -------
    Mesh, or (Mesh, (V + E, C) float64) when ``feats`` is given.
    """
    topo = mesh.topology
    V = mesh.n_verts
    F = mesh.faces
    fe = topo.faces_to_edges + V  # new vertex ids, edge opposite corner 0, 1, 2
    f0 = np.stack([F[:, 0], fe[:, 2], fe[:, 1]], 1)
    f1 = np.stack([F[:, 1], fe[:, 0], fe[:, 2]], 1)
    f2 = np.stack([F[:, 2], fe[:, 1], fe[:, 0]], 1)
    faces = np.concatenate([f0, f1, f2, fe], 0)
    e = topo.edges
    verts = np.concatenate([mesh.verts, 0.5 * (mesh.verts[e[:, 0]] + mesh.verts[e[:, 1]])], 0)
    out = Mesh(verts, faces)
    if feats is None:
        return out
    feats = np.asarray(feats, dtype=np.float64)
    if feats.ndim != 2 or len(feats) != V:
        raise ValueError(f"feats: expected shape ({V}, C), got {feats.shape}")
    return out, np.concatenate([feats, 0.5 * (feats[e[:, 0]] + feats[e[:, 1]])], 0)


def ico_sphere(level: int = 0) -> Mesh:
    """A unit ico-sphere, PyTorch3D's ``ico_sphere`` vertex for vertex.

    Parameters
    ----------
    level : int
        Number of midpoint subdivisions of the icosahedron, 0 to 8. Level ``l`` has
        ``10 * 4**l + 2`` vertices and ``20 * 4**l`` faces (level 4: 2562 and 5120).

    Returns
    -------
    Mesh
        Vertices on the unit sphere (level 0 keeps PyTorch3D's rounded coordinates).

    Examples
    --------
    >>> from geofit import ico_sphere
    >>> m = ico_sphere(4)
    >>> m.n_verts, m.n_faces
    (2562, 5120)
    """
    level = _check_level(level)
    mesh = Mesh(_ICO_VERTS0, _ICO_FACES0)
    for _ in range(level):  # subdivision levels
        mesh = subdivide(mesh)
        v = mesh.verts / np.linalg.norm(mesh.verts, axis=1, keepdims=True)
        mesh = mesh.update_verts(v)
    return mesh


def torus(major_radius: float = 1.0, minor_radius: float = 0.35, n_major: int = 48,
          n_minor: int = 24) -> Mesh:
    """A torus around the y axis (genus 1, watertight).

    Parameters
    ----------
    major_radius : float
        Distance from the centre to the tube's centre line (> minor_radius).
    minor_radius : float
        Tube radius (> 0).
    n_major, n_minor : int
        Segments around the ring and around the tube (>= 3).

    Returns
    -------
    Mesh
        ``n_major * n_minor`` vertices and twice as many faces.
    """
    if not (np.isfinite(major_radius) and np.isfinite(minor_radius)
            and 0 < minor_radius < major_radius):
        raise ValueError("torus: expected 0 < minor_radius < major_radius, got "
                         f"{minor_radius!r} and {major_radius!r}")
    for name, n in (("n_major", n_major), ("n_minor", n_minor)):
        if not isinstance(n, (int, np.integer)) or n < 3:
            raise ValueError(f"{name}: expected an integer >= 3, got {n!r}")
    check_allocation(200 * int(n_major) * int(n_minor), "n_major and n_minor",  # ~25 values
                     f"a torus of {int(n_major) * int(n_minor):,} vertices")  # per vertex
    u = 2 * np.pi * np.arange(n_major) / n_major
    v = 2 * np.pi * np.arange(n_minor) / n_minor
    U, W = np.meshgrid(u, v, indexing="ij")
    r = major_radius + minor_radius * np.cos(W)
    verts = np.stack([r * np.cos(U), minor_radius * np.sin(W), r * np.sin(U)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    a = i * n_minor + j
    b = ((i + 1) % n_major) * n_minor + j
    c = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
    d = i * n_minor + (j + 1) % n_minor
    faces = np.concatenate([np.stack([a, d, b], -1).reshape(-1, 3),
                            np.stack([b, d, c], -1).reshape(-1, 3)])
    return Mesh(verts, faces)


def box(size=(1.0, 1.0, 1.0)) -> Mesh:
    """An axis-aligned box centred at the origin, 8 vertices and 12 outward-facing triangles."""
    s = np.broadcast_to(np.asarray(size, dtype=np.float64), (3,))
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ValueError(f"size: expected three finite numbers > 0, got {size!r}")
    c = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]) * s
    faces = np.array([
        [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
        [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],
    ])
    return Mesh(c, faces)


def plane(size: float = 2.0, n: int = 1, z: float = 0.0) -> Mesh:
    """A square in the plane ``Z = z``, ``n x n`` cells, normal +Z.

    Parameters
    ----------
    size : float
        Side length (> 0).
    n : int
        Cells per side (>= 1): ``(n + 1)**2`` vertices, ``2 n**2`` faces.
    z : float
        Height of the plane.
    """
    if not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n: expected an integer >= 1, got {n!r}")
    if not np.isfinite(size) or size <= 0:
        raise ValueError(f"size: expected a finite number > 0, got {size!r}")
    t = np.linspace(-size / 2, size / 2, n + 1)
    X, Y = np.meshgrid(t, t, indexing="ij")
    verts = np.stack([X, Y, np.full_like(X, z)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = i * (n + 1) + j
    b = (i + 1) * (n + 1) + j
    faces = np.concatenate([np.stack([a, b, b + 1], -1).reshape(-1, 3),
                            np.stack([a, b + 1, a + 1], -1).reshape(-1, 3)])
    return Mesh(verts, faces)


def tetrahedron() -> Mesh:
    """A regular tetrahedron inscribed in the unit sphere, outward faces."""
    v = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=np.float64) / np.sqrt(3)
    faces = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
    return Mesh(v, faces)


def implicit_surface(sdf, bounds: float = 1.0, resolution: int = 64) -> Mesh:
    """The zero level set of a vectorised signed distance function, by marching cubes.

    Parameters
    ----------
    sdf : callable
        ``sdf((N, 3) float64) -> (N,) float64``, negative inside.
    bounds : float
        The grid spans ``[-bounds, bounds]^3`` (the surface must lie strictly inside).
    resolution : int
        Grid points per axis (>= 8).

    Returns
    -------
    Mesh
        Outward-oriented faces (scikit-image's ``marching_cubes``), deterministic.
    """
    from skimage.measure import marching_cubes  # kept local: start-up

    if not isinstance(resolution, (int, np.integer)) or resolution < 8:
        raise ValueError(f"resolution: expected an integer >= 8, got {resolution!r}")
    t = np.linspace(-bounds, bounds, resolution)
    X = np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3)
    vol = np.asarray(sdf(X), dtype=np.float64).reshape(resolution, resolution, resolution)
    h = t[1] - t[0]
    verts, faces, _, _ = marching_cubes(vol, 0.0, spacing=(h, h, h))
    verts = verts - bounds
    faces = faces.astype(np.int64)
    mesh = Mesh(verts, faces)
    # orient outwards: positive signed volume
    v = verts[faces]
    if np.einsum("ij,ij->", v[:, 0], np.cross(v[:, 1], v[:, 2])) < 0:
        mesh = Mesh(verts, faces[:, ::-1].copy())
    return mesh


def _torus_sdf(P, center, R, r):
    q = P - center
    return np.hypot(np.hypot(q[:, 0], q[:, 2]) - R, q[:, 1]) - r


def double_torus(resolution: int = 72) -> Mesh:
    """A genus-2 surface: two overlapping tori (ring radius 0.45, tube 0.18) side by side.

    Marching cubes of the union of their signed distances on a ``resolution``-cube grid over
    ``[-1.25, 1.25]^3``; watertight, one part, genus 2.
    """
    def sdf(P):
        return np.minimum(_torus_sdf(P, np.array([-0.48, 0.0, 0.0]), 0.45, 0.18),
                          _torus_sdf(P, np.array([0.48, 0.0, 0.0]), 0.45, 0.18))

    return implicit_surface(sdf, 1.25, resolution)


def open_cylinder(radius: float = 0.5, height: float = 1.5, n_around: int = 48,
                  n_height: int = 36) -> Mesh:
    """A tube around the y axis, open at both ends (two boundary loops, genus 0).

    ``n_around * (n_height + 1)`` vertices; faces oriented outwards.
    """
    for name, n in (("n_around", n_around), ("n_height", n_height)):
        if not isinstance(n, (int, np.integer)) or n < 3:
            raise ValueError(f"{name}: expected an integer >= 3, got {n!r}")
    if not (np.isfinite(radius) and np.isfinite(height) and radius > 0 and height > 0):
        raise ValueError(f"open_cylinder: expected radius, height > 0, got {radius!r}, {height!r}")
    u = 2 * np.pi * np.arange(n_around) / n_around
    y = np.linspace(-height / 2, height / 2, n_height + 1)
    U, Y = np.meshgrid(u, y, indexing="ij")
    verts = np.stack([radius * np.cos(U), Y, radius * np.sin(U)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_around), np.arange(n_height), indexing="ij")
    a = i * (n_height + 1) + j
    b = ((i + 1) % n_around) * (n_height + 1) + j
    faces = np.concatenate([np.stack([a, a + 1, b], -1).reshape(-1, 3),
                            np.stack([b, a + 1, b + 1], -1).reshape(-1, 3)])
    return Mesh(verts, faces)


def thin_plate(thickness: float = 0.06, resolution: int = 96) -> Mesh:
    """A closed thin square plate (1.6 x 1.6 x ``thickness``, rounded rims), by marching cubes."""
    if not (np.isfinite(thickness) and 0 < thickness < 1):
        raise ValueError(f"thickness: expected a number in (0, 1), got {thickness!r}")
    half = np.array([0.8, thickness / 2, 0.8])
    rr = thickness / 2

    def sdf(P):
        q = np.abs(P) - (half - rr)
        return (np.linalg.norm(np.maximum(q, 0.0), axis=1)
                + np.minimum(q.max(axis=1), 0.0) - rr)

    return implicit_surface(sdf, 0.9, resolution)


def two_spheres(level: int = 3, radius: float = 0.45, gap: float = 0.2) -> Mesh:
    """Two separate ico-spheres on the x axis, ``gap`` apart (two parts, genus 0)."""
    s = ico_sphere(level)
    off = radius + gap / 2
    v = np.concatenate([s.verts * radius - [off, 0, 0], s.verts * radius + [off, 0, 0]])
    f = np.concatenate([s.faces, s.faces + s.n_verts])
    return Mesh(v, f)


#: The procedural test shapes, name -> generator (no arguments).
TEST_SHAPES = {
    "torus": lambda: torus(1.0, 0.35, 64, 32),
    "double_torus": double_torus,
    "open_cylinder": open_cylinder,
    "thin_plate": thin_plate,
    "two_spheres": two_spheres,
}
