"""``geofit fit-views [CAPTURE]``: fit a mesh and its colours to multi-view images with
geofit.fit_mesh_to_views' defaults (tutorial 4).

Without CAPTURE, the fit_textured_mesh tutorial's renders of the default textured mesh (the cow
when the tutorial data is found, else the procedural stand-in) with its held-out views. The fit
is ``fit_mesh_to_views(dataset)`` exactly as in Python (its default: the visual hull of the
silhouettes refined by L-BFGS with remeshing, colours by one least-squares solve), with only the
options given here passed on.

Writes into ``--out``: ``fit_views.obj`` (the fitted surface), ``fit_views_colors.npz`` (verts,
faces, vertex colours), ``fit_views.json`` (status, timings, held-out IoU / PSNR, chamfer-L2 and
F-score against the true mesh when known), ``fit_views_history.json`` and ``fit_views.png``
(held-out targets above the fitted mesh's renders). Prints the held-out metrics last.
"""
from __future__ import annotations

import argparse

from .._atomic import atomic_write
from ._common import (FIT_OPTIONS, add_views_fit_command, metric_line, out_dir,
                      run_views_fit, save_png, timing_line, write_json)

__all__ = ["API", "register", "run"]

#: The function this sub-command runs (its docstring gives the options' help).
API = ("fit/views.py", "fit_mesh_to_views")


def run(args: argparse.Namespace) -> int:
    """Run the sub-command; returns the exit code."""
    import numpy as np

    from ..fit import fit_mesh_to_views
    from ..fit.views import ViewsEvaluator
    from ..io import save_obj

    run_ = run_views_fit(args, 4, fit_mesh_to_views)
    ds, held, fit = run_.train, run_.test, run_.result
    ev = ViewsEvaluator(held, ds.mesh)
    colors = fit.colors if fit.colors is not None else np.full((fit.mesh.n_verts, 3), 0.7)
    # the result as it is (its UV texture by default), the vertex colours without one
    metrics = ev(fit.mesh) if fit.mesh.textures is not None else ev(fit.mesh, colors)

    dest = out_dir(args)
    save_obj(dest / "fit_views.obj", fit.mesh)
    atomic_write(dest / "fit_views_colors.npz", lambda p: np.savez_compressed(
        p, verts=fit.mesh.verts, faces=fit.mesh.faces, colors=colors))
    fit.history.to_json(dest / "fit_views_history.json")
    summary = {**run_.summary(history=False), "stages": fit.stages, "heldout_metrics": metrics}
    write_json(dest / "fit_views.json", summary)
    k = min(4, len(held))
    save_png(dest / "fit_views.png", [held.images[:k], fit.render(held, n_views=k)])
    for s in fit.stages:
        print(f"{s['name']} ({s['method']}): {s['status']} in {s['seconds']:.1f} s - "
              f"{s['message']}")
    print(f"wrote {dest / 'fit_views.obj'}, fit_views.json, fit_views.png")
    print(f"geofit fit-views: {fit.status} ({fit.message}); {fit.mesh.n_verts} vertices")
    print(f"geofit fit-views: {timing_line(fit)}")
    print(f"geofit fit-views: held-out metrics: {metric_line(metrics)}")
    return 0 if fit.ok else 1


def register(subparsers) -> None:
    """Add the ``fit-views`` sub-command."""
    add_views_fit_command(subparsers, "fit-views", __doc__, run, API, FIT_OPTIONS, frames=False)
