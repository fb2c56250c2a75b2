"""The data-driven start and the remeshing rounds of :func:`geofit.fit.fit_mesh_to_views`.

* :func:`initial_mesh` -- the fit's start: the visual hull
  (:func:`geofit.fit.init.visual_hull_mesh`, carved by :mod:`geofit.structures.visual_hull`),
  an ico-sphere or the given mesh; every length of the default fit is a number of pixels times
  the world size of a pixel at the object (:func:`geofit.structures.visual_hull.pixel_footprint`),
  so no setting depends on the object's scale or on the image size.
* :func:`remesh_to_length` -- :func:`geofit.ops.remesh` towards one edge length (split,
  collapse, flip; manifold in, manifold out).
* :func:`shortest_edge` -- the shortest remeshing edge that keeps one evaluation of the soft
  silhouettes bounded (faces, and the rasterizer's (pixel, face) entries).

No gradient is defined here.
"""
from __future__ import annotations

import math

from ..shapes import ico_sphere
from ..structures import Mesh
from ..structures.visual_hull import pixel_footprint
from .history import TimeUp
from .init import max_edge_length, visual_hull_mesh

__all__ = ["initial_mesh", "remesh_to_length", "shortest_edge"]

#: The remeshing keeps at most about this many faces at full image size (``/ factor**2`` at
#: a level downsampled by ``factor``).
MAX_FACES = 4000
#: ... and at most about this many soft-rasterizer entries ((pixel, face) pairs within the blur
#: radius) per pixel of a view: the evaluation's time is proportional to the entries. The cow's
#: fit has about 5.5, a box or the double-walled open cylinder 8.5-10.7 at 4000 faces
#: (measured at 128 px, tutorial blur); 7.45 leaves every shape of at most about 16 000
#: square pixels of surface at the default's 3 px edges.
MAX_ENTRIES_PER_PIXEL = 7.45
# entries per face beyond its own area: about _BAND r e + pi r^2 for edges e and blur radius r
# (pixels): a face's blur band, foreshortened (fitted on the cow, box and open cylinder, 20
# views of 128 px: within 5 % of the measured entries)
_BAND = 2.78


def initial_mesh(plan, run) -> None:
    """The starting mesh of a :func:`~geofit.fit.fit_mesh_to_views` plan (``plan.init``; the
    visual hull is carved with the fit's clock running and its time budget checked between
    views), the world size of a pixel at its centre and the longest remeshing edge
    (``plan.init_info``), and a history note.

    When the time budget runs out while the hull is carved, the start is the tutorial's
    ico-sphere and ``run.stages`` gets an ``"init"`` stage with status ``"time_budget"``
    (the later stages then find no time left)."""
    t0 = run.clock.elapsed()
    v = plan.views
    hull = None
    if plan.init_name == "hull":
        fac = plan.levels[0][1] if plan.silhouette_method != "sgd" else 1
        try:
            hull = visual_hull_mesh(v.silhouettes, v.cameras, edge_px=plan.edge_px * fac,
                                    upsample=plan.hull_upsample,
                                    close_px=plan.hull_close_px, margins=plan.hull_margins,
                                    vote_depth=plan.hull_vote_depth,
                                    check=run.clock.check)
        except TimeUp:
            seconds = run.clock.elapsed() - t0
            plan.init, plan.init_name = ico_sphere(4), "sphere"
            run.stages.append({
                "name": "init", "method": "visual hull", "status": "time_budget",
                "seconds": seconds,
                "message": f"reached the time budget of {plan.time_budget:g} s while carving "
                           f"the visual hull ({seconds:.1f} s): the result is the unfitted "
                           "ico-sphere; give a larger time_budget"})
    if hull is not None:
        plan.init = hull.mesh
        info = {"voxel_size": hull.voxel_size, "pixel_size": hull.pixel_size,
                "n_faces_marching_cubes": hull.n_faces_marching_cubes,
                "n_closed_pixels": hull.n_closed_pixels, "n_vote_kept": hull.n_vote_kept}
        closed = (f"; {hull.n_closed_pixels:g} silhouette pixels of pinholes and slits "
                  f"closed" if plan.hull_close_px else "")
        if hull.n_vote_kept:
            closed += (f"; {hull.n_vote_kept} grid nodes that one view alone would carve "
                       f"kept by the vote")
        desc = (f"the visual hull of the silhouettes ({plan.init.n_verts} vertices, marching "
                f"cubes on {info['voxel_size']:.3g} voxels, decimated{closed})")
    else:
        info = {"pixel_size": pixel_footprint(v.cameras, v.image_size,
                                              plan.init.verts.mean(axis=0))}
        desc = (f"ico-sphere ({plan.init.n_verts} vertices)" if plan.init_name == "sphere"
                else f"the given mesh ({plan.init.n_verts} vertices)")
    plan.init_info = dict(info, description=desc, seconds=run.clock.elapsed() - t0,
                          max_edge=max_edge_length(plan.init))
    run.history.note(0, run.clock.elapsed(), f"initial mesh: {desc}", init=plan.init_name,
                     n_verts=plan.init.n_verts)


def remesh_to_length(mesh: Mesh, length: float, n_passes: int = 3) -> Mesh:
    """:func:`geofit.ops.remesh` towards the edge length ``length`` (manifold kept)."""
    from ..ops import remesh

    return remesh(mesh, float(length), n_passes=n_passes).mesh


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
