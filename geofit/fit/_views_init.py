"""The data-driven start and the remeshing rounds of :func:`geofit.fit.fit_mesh_to_views`.

* :func:`initial_mesh` -- the fit's start: the visual hull
  (:func:`geofit.fit.init.visual_hull_mesh`, carved by :mod:`geofit.structures.visual_hull`),
  an ico-sphere or the given mesh; every length of the default fit is a number of pixels times
  the world size of a pixel at the object (:func:`geofit.structures.visual_hull.pixel_footprint`),
  so no setting depends on the object's scale or on the image size.
* :func:`remesh_to_length` -- :func:`geofit.ops.remesh` towards one edge length (split,
  collapse, flip; manifold in, manifold out).
* the remeshing's shortest and longest edges are :func:`geofit.fit.init.shortest_edge` and
  :func:`geofit.fit.init.max_edge_length`.

No gradient is defined here.
"""
from __future__ import annotations

import numpy as np

from ..shapes import ico_sphere
from ..structures import Mesh
from ..structures.visual_hull import pixel_footprint
from .history import TimeUp
from .init import max_edge_length, visual_hull_mesh

__all__ = ["initial_mesh", "remesh_to_length"]


def initial_mesh(plan, run) -> None:
    """The starting mesh of a :func:`~geofit.fit.fit_mesh_to_views` plan (``plan.init``; the
    visual hull is carved with the fit's clock running and its time budget checked between
    views), the world size of a pixel at its centre and the longest remeshing edge
    (``plan.init_info``), and a history note.

    When the time budget runs out while the hull is carved, the start is the tutorial's
    ico-sphere and ``run.stages`` gets an ``"init"`` stage with status ``"time_budget"``
    (the later stages then find no time left). When the hull is thinner than its carving grid
    everywhere (twice ``VisualHullMesh.depth_px`` below a grid step: a zero-thickness sheet), its
    mesh is a few fragments, and the ico-sphere enclosing them is the start instead
    (``init`` ``"sphere"``; the description says why)."""
    t0 = run.clock.elapsed()
    v = plan.views
    hull = None
    if plan.init_name == "hull":
        # the hull is decimated with Open3D, whose first import takes seconds under load
        # (16.8 s wall at load 28): paid here, before the carving checks the clock, not after
        # the deadline (a 45 s budget ended at 61.6 s); kept local: geofit's start-up
        import open3d  # noqa: F401
        fac = plan.levels[0][1] if plan.silhouette_method != "sgd" else 1
        try:
            hull = visual_hull_mesh(v.silhouettes, v.cameras, edge_px=plan.edge_px * fac,
                                    upsample=plan.hull_upsample,
                                    close_px=plan.hull_close_px, margins=plan.hull_margins,
                                    vote_depth=plan.hull_vote_depth,
                                    check=run.clock.check, fill_px=plan.hull_fill_px,
                                    grey_px=plan.hull_grey_px,
                                    close_handles=plan.hull_close_handles,
                                    per_part=plan.hull_per_part)
        except TimeUp:
            seconds = run.clock.elapsed() - t0
            plan.init, plan.init_name = ico_sphere(4), "sphere"
            run.stages.append({
                "name": "init", "method": "visual hull", "status": "time_budget",
                "seconds": seconds,
                "message": f"reached the time budget of {plan.time_budget:g} s while carving "
                           f"the visual hull ({seconds:.1f} s): the result is the unfitted "
                           "ico-sphere; give a larger time_budget"})
    flat = ""
    if hull is not None and 2.0 * hull.depth_px < hull.voxel_size / hull.pixel_size:
        # a hull thinner than a grid step everywhere (a sheet): its mesh is a few fragments
        # (the flat sheet of benchmarks/unseen_shapes.py: 27 vertices in 5 parts, held-out
        # IoU 0.003); the sphere enclosing them starts the fit instead (IoU 0.956, F 0.843)
        lo, hi = hull.mesh.verts.min(axis=0), hull.mesh.verts.max(axis=0)
        s = ico_sphere(4)
        plan.init = s.update_verts(0.5 * (lo + hi) + 0.5 * np.linalg.norm(hi - lo) * s.verts)
        plan.init_name = "sphere"
        flat = (f"; the visual hull is thinner than its carving grid everywhere (deepest node "
                f"{hull.depth_px:.2g} px inside, grid step "
                f"{hull.voxel_size / hull.pixel_size:.2g} px: a sheet), so the sphere "
                f"enclosing it starts the fit")
        hull = None
    if hull is not None:
        plan.init = hull.mesh
        info = {"voxel_size": hull.voxel_size, "pixel_size": hull.pixel_size,
                "n_faces_marching_cubes": hull.n_faces_marching_cubes,
                "n_closed_pixels": hull.n_closed_pixels, "n_vote_kept": hull.n_vote_kept,
                "n_filled": hull.n_filled, "genus_before": hull.genus_before,
                "genus_after": hull.genus_after}
        closed = (f"; {hull.n_closed_pixels:g} silhouette pixels of pinholes and slits "
                  f"closed" if plan.hull_close_px or plan.hull_fill_px or plan.hull_grey_px
                  else "")
        if plan.grey_filled:
            closed += (f"; {plan.grey_filled} grey target pixels covered "
                       f"(silhouette_grey_px)")
        handles = _handles_note(hull)
        if handles:
            closed += "; " + handles
        if hull.n_vote_kept:
            closed += (f"; {hull.n_vote_kept} grid nodes that one view alone would carve "
                       f"kept by the vote")
        desc = (f"the visual hull of the silhouettes ({plan.init.n_verts} vertices, marching "
                f"cubes on {info['voxel_size']:.3g} voxels, decimated{closed})")
    else:
        info = {"pixel_size": pixel_footprint(v.cameras, v.image_size,
                                              plan.init.verts.mean(axis=0))}
        desc = (f"ico-sphere ({plan.init.n_verts} vertices{flat})" if plan.init_name == "sphere"
                else f"the given mesh ({plan.init.n_verts} vertices)")
    plan.init_info = dict(info, description=desc, seconds=run.clock.elapsed() - t0,
                          max_edge=max_edge_length(plan.init))
    extra = {}
    if info.get("genus_before") is not None:  # what closing the unsupported handles removed
        extra = {"hull_genus": info["genus_before"], "hull_filled_nodes": info["n_filled"],
                 "hull_handles_closed": (info["genus_before"] - info["genus_after"]
                                         if info["n_filled"] else 0)}
    run.history.note(0, run.clock.elapsed(), f"initial mesh: {desc}", init=plan.init_name,
                     n_verts=plan.init.n_verts, **extra)


def _handles_note(hull) -> str:
    """What ``close_handles`` removed from the hull, in words ("" when it found nothing)."""
    if hull.genus_before is None:
        return ""
    if hull.n_filled:
        return (f"{hull.genus_before - hull.genus_after} handles no silhouette supports "
                f"closed (genus {hull.genus_before} -> {hull.genus_after}, {hull.n_filled} "
                f"grid nodes filled)")
    return (f"no handle closed (filling would give genus {hull.genus_before} -> "
            f"{hull.genus_after}: not applied)")


def remesh_to_length(mesh: Mesh, length: float, n_passes: int = 3) -> Mesh:
    """:func:`geofit.ops.remesh` towards the edge length ``length`` (manifold kept)."""
    from ..ops import remesh

    return remesh(mesh, float(length), n_passes=n_passes).mesh

