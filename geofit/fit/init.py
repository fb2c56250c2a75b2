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

import math
from dataclasses import dataclass

import numpy as np

from .._validate import as_array, check_positive
from ..ops import topology
from ..ops.topology import face_components
from ..shapes import ico_sphere
from ..structures import Mesh
from ..structures.visual_hull import carve_hull, close_unsupported_handles

__all__ = ["INITS", "InitialMesh", "MAX_ENTRIES_PER_PIXEL", "MAX_FACES", "VisualHullMesh",
           "decimate", "initial_mesh", "max_edge_length", "mesh_from_occupancy",
           "shortest_edge", "visual_hull_mesh"]

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


#: The longest remeshing edge of the multi-view fit: 1/15 of the bounding-box diagonal.
_MIN_EDGES_ACROSS = 15


def max_edge_length(mesh: Mesh) -> float:
    """The longest edge the default multi-view fit remeshes to: 1/15 of the bounding-box
    diagonal (low resolution images would otherwise leave a small object a handful of faces)."""
    v = mesh.verts
    return float(np.linalg.norm(v.max(axis=0) - v.min(axis=0))) / _MIN_EDGES_ACROSS


#: The remeshing keeps at most about this many faces at full image size (``/ factor**2`` at
#: a level downsampled by ``factor``).
MAX_FACES = 4000
#: ... and at most about this many soft-rasterizer entries ((pixel, face) pairs within the blur
#: radius) per pixel of a view: the evaluation's time is proportional to the entries. The cow's
#: fit has about 5.5, a box or the double-walled open cylinder 8.5-10.7 at 4000 faces
#: (measured at 128 px, tutorial blur). 6 leaves every surface of at most 12 770 square
#: pixels as it was at 128 px (the face cap binds first; the cow and fandisk, whose hulls are
#: 13 062 and 12 772, fit bit for bit as with 7.45): of the 11 shapes of benchmarks/fit_views.py
#: only the open cylinder changes (held-out IoU 0.9717 -> 0.9747, F@0.01 0.727 -> 0.729); a
#: procedural box 0.9817 / 0.385 -> 0.9800 / 0.448 and 98 -> 84 CPU s (7.45 before; measured,
#: benchmarks/results/fit_views_session9_thin.md).
MAX_ENTRIES_PER_PIXEL = 6.0
# entries per face beyond its own area: about _BAND r e + pi r^2 for edges e and blur radius r
# (pixels): a face's blur band, foreshortened (fitted on the cow, box and open cylinder, 20
# views of 128 px, at their face counts: within 5 % of the measured entries; the remesher
# can leave more faces than a / (0.433 e^2), e.g. 3262 for 2516 on a box's hull)
_BAND = 2.78


def shortest_edge(area: float, pixel_size: float, factor: int, image_size,
                  blur_radius: float) -> float:
    """The shortest remeshing edge (world units) of a silhouette level: the face count stays
    under :data:`MAX_FACES` ``/ factor**2`` and the soft rasterizer's expected entries per view
    under :data:`MAX_ENTRIES_PER_PIXEL` per pixel, so an evaluation's time stays bounded
    whatever the object's surface area.

    The expected entries of one view, in pixels of the level (``p = pixel_size * factor``
    world units, surface area ``a = area / p**2``, ``n = a / (0.433 e**2)`` faces of edge
    ``e``, blur radius ``r = sqrt(blur_radius) min(H, W) / 2``): ``a / 2`` (the mean projected
    area of a closed surface's faces) plus ``n (2.78 r e + pi r**2)`` (each face's blur band);
    the bound is a quadratic in ``1 / e``.

    Parameters
    ----------
    area : float
        Surface area of the mesh (world units squared).
    pixel_size : float
        World size of a full-resolution pixel at the object.
    factor : int
        The level's downsampling factor.
    image_size : (2,) int
        The level's ``(H, W)``.
    blur_radius : float
        The soft rasterizer's blur radius (squared NDC units).

    Returns
    -------
    float
        World units (0 for an empty surface).
    """
    H, W = (int(v) for v in image_size)
    faces = math.sqrt(float(area) * factor * factor / (0.433 * MAX_FACES))
    p = float(pixel_size) * factor
    a = float(area) / (p * p)
    r = math.sqrt(float(blur_radius)) * min(H, W) / 2.0
    if a <= 0 or r <= 0:
        return faces
    extra = MAX_ENTRIES_PER_PIXEL * H * W / a - 0.5  # entries per unit area beyond a / 2
    if extra <= 0:  # even the faces' own area is over the bound: the face cap decides
        return faces
    c2, c1 = math.pi * r * r / 0.433, _BAND * r / 0.433  # c2 u^2 + c1 u <= extra, u = 1 / e
    u = (-c1 + math.sqrt(c1 * c1 + 4.0 * c2 * extra)) / (2.0 * c2)
    return max(faces, p / u)


@dataclass
class VisualHullMesh:
    """A mesh of the visual hull and how it was carved (:func:`visual_hull_mesh`).

    Attributes
    ----------
    mesh : Mesh
        Closed where the hull is, with the hull's genus and parts.
    voxel_size : float
        Spacing of the carving grid (world units).
    pixel_size : float
        World size of a pixel at the hull's centre.
    n_faces_marching_cubes : int
        Faces before decimation.
    n_filled : int
        Grid nodes filled by ``close_handles`` (0 without it).
    n_closed_pixels : float
        Silhouette pixels (all views) that ``close_px`` filled before carving (0 without it).
    n_vote_kept : int
        Carving-grid nodes the vote (``margins``) kept that one view alone would have carved.
    depth_px : float
        The hull field's largest value at the grid's nodes (pixels): how far inside every
        silhouette the hull's deepest node projects, about half the hull's largest
        thickness. Below half a grid step (``voxel_size / pixel_size``) the hull is thinner
        than a grid step everywhere (a zero-thickness sheet, whose hull some view sees
        edge-on as a line of a pixel or two): marching cubes cannot resolve it and the mesh
        is a few fragments.
    genus_before, genus_after : int or None
        Genus of the marching-cubes surface without and with the nodes ``close_handles``
        would fill (None when it found none); they were filled only if ``genus_after <
        genus_before``.
    """

    mesh: Mesh
    voxel_size: float
    pixel_size: float
    n_faces_marching_cubes: int
    n_filled: int = 0
    n_closed_pixels: float = 0.0
    n_vote_kept: int = 0
    depth_px: float = float("inf")
    genus_before: int | None = None
    genus_after: int | None = None


def _check_margins(margins, name: str = "margins") -> tuple:
    """``margins`` of the carving vote (:func:`geofit.structures.visual_hull.hull_field`) as a
    tuple of floats: non-empty, finite, >= 0 and non-increasing; else ValueError naming
    ``name``."""
    try:
        m = tuple(float(x) for x in margins)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a sequence of numbers (pixels), got "
                         f"{margins!r}") from None
    if not m or not all(np.isfinite(m)) or min(m) < 0 or any(
            b > a for a, b in zip(m, m[1:])):
        raise ValueError(f"{name}: expected finite numbers >= 0, non-increasing, at least "
                         f"one, got {margins!r}")
    return m


def visual_hull_mesh(silhouettes, cameras, *, edge_px: float = 4.0, shrink_px: float = 0.0,
                     threshold: float = 0.5, voxel_px: float = 1.5, refine: int = 1,
                     close_handles: float = 0.0, upsample: int = 1,
                     close_px: float = 0.0, margins=(0.0,), vote_depth: float = 0.0,
                     check=None, fill_px: float = 0.0, grey_px: float = 0.0,
                     grey_level: float = 0.05, per_part: bool = False) -> VisualHullMesh:
    """A coarse mesh of the visual hull of silhouettes (tutorial 4's default start).

    The hull's signed-distance field (:func:`geofit.structures.visual_hull.carve_hull`: carved on
    a coarse grid over the region every camera sees, then on a grid of 1.5 pixels over the
    occupied box), scikit-image's marching cubes at its zero level, and :func:`decimate`
    (Open3D's quadric error) to faces of edge ``edge_px`` pixels (at most
    :func:`max_edge_length`). The carving level is the silhouettes' ``threshold`` (optionally
    moved ``shrink_px`` pixels inwards): the tutorial's soft silhouettes exceed 0.5 up to about
    a pixel outside the object's outline (faces blend), so the 0.5 hull is inflated by that
    much; the fit, which matches the same soft model, recovers it. Shrinking the carving level
    instead (half a pixel) cut the thin limbs of the "woody" test shape into 13 parts (held-out
    IoU 0.35 against 0.89 unshrunk, measured), so the default does not. The hull keeps the
    genus and the parts the silhouettes show (a hole seen through in some view stays open); it
    is larger than the object where no view sees a concavity.

    Parameters
    ----------
    silhouettes : (N, H, W) float64
        The silhouettes and their ``N`` cameras, as in
        :func:`geofit.structures.visual_hull.carve_hull`.
    cameras : CamerasBase
    edge_px : float
        Edge length of the decimated mesh, in pixels at the hull's centre (> 0).
    shrink_px : float
        Carve the ``threshold`` outline this many pixels inwards.
    threshold : float
        Silhouette level of the outline, in (0, 1).
    voxel_px : float
        Carving grid spacing in pixels (default 1.5). A part thinner than about a grid step
        can fall between the nodes and vanish; 0.5 keeps parts down to about a pixel (27 times
        the nodes of the default).
    refine : int
        Subdivide the grid this many times per axis in the band around the surface only
        (:func:`geofit.structures.visual_hull.carve_hull`); 3 gives 0.5 px near the surface at
        a fraction of ``voxel_px=0.5``'s cost.
    close_handles : float
        Fill narrow tunnels no silhouette sees through, bridging gaps of up to this many
        pixels on either side of a node
        (:func:`geofit.structures.visual_hull.close_unsupported_handles`; 0 or False: none,
        True: 1 pixel). The filling is kept only if it lowers the genus of the hull's surface
        (filling a crevice can close a loop around it and add a handle): ``genus_before``
        and ``genus_after`` say what it gave, ``n_filled`` how many nodes were filled (0 when
        it was not kept).
    per_part : bool
        Decimate each connected part of the hull on its own, to its area's share of the faces
        but at least 48 (a part the carving cut off, a leg, keeps a shape; the quadric
        decimation of the whole collapses small parts). False: the whole at once.
    upsample : int
        Carve at sub-pixel outlines: the soft silhouettes interpolated on a grid ``upsample``
        times finer (:func:`geofit.structures.visual_hull.signed_distance_images`).
    close_px : float
        Close each thresholded silhouette with a disk of this radius (pixels) first: pinholes
        and slits narrower than ``2 close_px`` carve nothing.
    fill_px : float
        Fill each thresholded silhouette's pinholes first: background regions not reaching
        the image's border of at most this many pixels
        (:func:`geofit.structures.visual_hull.signed_distance_images`); the outline stays.
    grey_px, grey_level : float
        Keep the grey cores of the soft silhouettes: pixels above ``grey_level`` (default
        0.05) and more than ``grey_px`` pixels (0: none) from every pixel at or below it
        count as inside (:func:`geofit.structures.visual_hull.signed_distance_images`).
    margins : sequence of float
        The carving vote (:func:`geofit.structures.visual_hull.hull_field`; pixels,
        non-increasing): ``(0,)`` carves what any one view puts outside its silhouette;
        ``(1, 0)`` only what one view puts more than a pixel outside or two views outside, so
        a pinhole or seam at most 2 pixels wide in one view carves no tunnel.
    vote_depth : float
        The vote only fills, and only where its hull is deeper than this many pixels
        (:func:`geofit.structures.visual_hull.carve_hull`): tunnels are filled, the outline
        keeps the plain hull's. 0: the vote as it is. Needs ``refine=1``.
    check : callable, optional
        Called between the carving's views and steps (a fit passes its clock's
        :meth:`~geofit.fit.Clock.check`, which raises :class:`~geofit.fit.TimeUp` once its
        time budget is used up).

    Returns
    -------
    VisualHullMesh

    Raises
    ------
    ValueError
        If the silhouettes are not (N, H, W) with N cameras, ``edge_px`` <= 0, ``threshold``
        is outside (0, 1), ``margins`` is not a non-increasing sequence of numbers >= 0, or
        the hull is empty.
    """
    sil = as_array(silhouettes, "silhouettes", (len(cameras), None, None))
    edge_px = check_positive(edge_px, "edge_px")
    if not 0.0 < float(threshold) < 1.0:
        raise ValueError(f"threshold: expected a number in (0, 1), got {threshold!r}")
    voxel_px = check_positive(voxel_px, "voxel_px")
    for name, val in (("refine", refine), ("upsample", upsample)):
        if not isinstance(val, (int, np.integer)) or isinstance(val, bool) or val < 1:
            raise ValueError(f"{name}: expected an integer >= 1, got {val!r}")
    close_px = check_positive(close_px, "close_px", strict=False)
    fill_px = check_positive(fill_px, "fill_px", strict=False)
    grey_px = check_positive(grey_px, "grey_px", strict=False)
    close_handles = check_positive(float(close_handles) if isinstance(close_handles, bool)
                                   else close_handles, "close_handles", strict=False)
    if not isinstance(per_part, (bool, np.bool_)):
        raise TypeError(f"per_part: expected a bool, got {per_part!r}")
    if not 0.0 <= float(grey_level) < float(threshold):
        raise ValueError(f"grey_level: expected a number in [0, threshold = {threshold!r}), "
                         f"got {grey_level!r}")
    margins = _check_margins(margins)
    vote_depth = check_positive(vote_depth, "vote_depth", strict=False)
    if vote_depth > 0 and refine != 1:
        raise ValueError(f"vote_depth: the deep vote needs refine=1, got vote_depth "
                         f"{vote_depth!r} with refine {refine!r}")
    g = carve_hull(sil, cameras, threshold=float(threshold), shrink_px=float(shrink_px),
                   voxel_px=voxel_px, refine=int(refine), upsample=int(upsample),
                   close_px=close_px, margins=margins, vote_depth=vote_depth, check=check,
                   fill_px=fill_px, grey_px=grey_px, grey_level=grey_level)
    n_filled, genus = 0, None
    mc = None
    if close_handles:
        closed = close_unsupported_handles(g, radius_px=float(close_handles))
        if closed.n_filled:  # kept only if it lowers the genus (bridging a crevice can add one)
            plain = mesh_from_occupancy(g.field, g.origin, g.voxel_size, level=0.0)
            mc = mesh_from_occupancy(closed.grid.field, g.origin, g.voxel_size, level=0.0)
            genus = (topology(plain, self_intersections=False).genus,
                     topology(mc, self_intersections=False).genus)
            if genus[1] < genus[0]:
                g, n_filled = closed.grid, closed.n_filled
            else:
                mc = plain
    if check is not None:
        check()
    if mc is None:
        mc = mesh_from_occupancy(g.field, g.origin, g.voxel_size, level=0.0)
    le = min(edge_px * g.pixel_size, max_edge_length(mc))
    if per_part:
        mesh = _decimate_parts(mc, le)
    else:
        mesh = _decimate_to_edge(mc, le, 200)
    return VisualHullMesh(mesh, g.voxel_size, g.pixel_size, mc.n_faces, n_filled,
                          g.n_closed_pixels, g.n_vote_kept, float(g.field.max()),
                          genus_before=None if genus is None else genus[0],
                          genus_after=None if genus is None else genus[1])


#: The fewest faces :func:`visual_hull_mesh` decimates a part of the hull to (``per_part``).
_MIN_PART_FACES = 48


def _decimate_to_edge(mesh: Mesh, edge: float, min_faces: int) -> Mesh:
    """``mesh`` decimated to faces of about ``edge`` (equilateral: 0.433 edge^2 each), at
    least ``min_faces``; as it is when it has no more faces than that."""
    n = int(max(min_faces, float(mesh.face_areas.sum()) / (0.433 * edge * edge)))
    return decimate(mesh, n) if n < mesh.n_faces else mesh


def _decimate_parts(mc: Mesh, edge: float) -> Mesh:
    """Each connected part of ``mc`` decimated on its own to faces of about ``edge`` (its
    area's share, at least :data:`_MIN_PART_FACES`), so that a small part (a leg the carving
    cut off at an ankle thinner than the grid) keeps a shape instead of collapsing."""
    flab = face_components(mc.faces)
    n_parts = int(flab.max()) + 1 if len(flab) else 0
    if n_parts <= 1:
        return _decimate_to_edge(mc, edge, 200)
    V, F, off = [], [], 0
    for i in range(n_parts):  # parts (few; each one Open3D call)
        used, inv = np.unique(mc.faces[flab == i], return_inverse=True)
        part = _decimate_to_edge(Mesh(mc.verts[used], inv.reshape(-1, 3).astype(np.int64)),
                                 edge, _MIN_PART_FACES)
        if part.n_faces == 0:
            continue
        V.append(part.verts)
        F.append(part.faces + off)
        off += part.n_verts
    return Mesh(np.concatenate(V), np.concatenate(F))
