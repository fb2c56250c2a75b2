"""``geofit fit-views``: fit a mesh and its vertex colours to multi-view images (tutorial 4).

Renders the fit_textured_mesh tutorial's dataset of the default textured mesh (the cow when the
tutorial data is found, else the procedural stand-in): ``--views`` views with soft silhouettes and
RGB, plus ``--heldout`` held-out views; deforms an ico-sphere to the silhouettes, then fits vertex
colours (and, with ``--textured lbfgs``, positions). geofit's default: L-BFGS over all views in the
large-steps parameterisation, coarse-to-fine (half resolution and one subdivision level less
first), colours by one least-squares solve. ``--recipe tutorial`` runs the tutorial's SGD recipe
instead, ``--recipe contour`` the hard silhouette's contour gradients with Adam.

Writes into ``--out``: ``fit_views.obj`` (the fitted surface), ``fit_views_colors.npz`` (verts,
faces, vertex colours), ``fit_views.json`` (status, timings, held-out IoU / PSNR, chamfer-L2 and
F-score against the true mesh), ``fit_views_history.json`` and ``fit_views.png`` (held-out
targets above the fitted mesh's renders).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from .._validate import check_int as _int
from ._common import (add_capture_arg, add_command, capture_views, out_dir, save_png,
                      write_json)

__all__ = ["register", "run"]


def run(args: argparse.Namespace) -> int:
    """Run the sub-command; returns the exit code."""
    from ..datasets import tutorial_views
    from ..fit.views import dataset_lights
    from ..fit.views import ViewsEvaluator, fit_mesh_to_views
    from ..io import save_obj
    from ..render import MeshRasterizer, MeshRenderer, RasterizationSettings, SoftPhongShader
    from ..shapes import ico_sphere
    from ..structures import Mesh, TexturesVertex

    _int(args.views, "--views")
    _int(args.image_size, "--image-size", 8)
    _int(args.heldout, "--heldout")
    _int(args.init_level, "--init-level", 0)
    t0 = time.perf_counter()
    if args.capture:
        ds, _ = capture_views(args.capture)   # ds.held_out: the held-out views
        H, W = ds.image_size
        args.views, args.heldout, args.image_size = len(ds), len(ds.held_out), H
        args.no_coarse_to_fine = args.no_coarse_to_fine or bool(H % 2 or W % 2)
    else:
        ds = tutorial_views(4, num_views=args.views, image_size=args.image_size,
                            num_held_out=args.heldout)
    t_data = time.perf_counter() - t0
    levels = None
    init_level = args.init_level
    stochastic = args.recipe == "tutorial" if args.method is None else args.method == "sgd"
    if not args.no_coarse_to_fine and not stochastic and args.image_size % 2 == 0 \
            and init_level >= 1:
        levels = [(0, 2), (1, 1)]
        init_level -= 1
    kw = {"recipe": args.recipe, "silhouette_method": args.method,
          "textured_method": args.textured, "silhouette_iters": args.silhouette_iters,
          "textured_iters": args.textured_iters, "silhouette_time": args.time,
          "large_steps": None if stochastic else args.large_steps, "levels": levels,
          "seed": args.seed}
    fit = fit_mesh_to_views(ds, init=ico_sphere(init_level), progress=not args.no_progress,
                            **kw)
    ev = ViewsEvaluator(ds.held_out, ds.mesh, n_samples=20000)
    colors = fit.colors if fit.colors is not None else np.full((fit.mesh.n_verts, 3), 0.7)
    metrics = ev(fit.mesh, colors)

    dest = out_dir(args)
    save_obj(dest / "fit_views.obj", Mesh(fit.mesh.verts, fit.mesh.faces))
    np.savez_compressed(dest / "fit_views_colors.npz", verts=fit.mesh.verts,
                        faces=fit.mesh.faces, colors=colors)
    fit.history.to_json(dest / "fit_views_history.json")
    summary = {"object": ds.name, "settings": {**{k: v for k, v in kw.items()},
                                               "views": args.views, "image_size": args.image_size,
                                               "heldout": args.heldout,
                                               "init_level": args.init_level},
               **fit.summary(), "stages": fit.stages, "heldout": metrics,
               "dataset_seconds": t_data}
    write_json(dest / "fit_views.json", summary)
    h = ds.held_out
    k = min(4, len(h))
    cams = h.cameras[np.arange(k)]
    ras = MeshRasterizer(cams, RasterizationSettings(image_size=h.image_size))
    tm = Mesh(fit.mesh.verts, fit.mesh.faces, TexturesVertex(np.clip(colors, 0, 1)))
    lights = dataset_lights(h)   # a capture's: the tutorial's point light
    pred = np.asarray(MeshRenderer(ras, SoftPhongShader(cameras=cams, lights=lights))(tm)
                      [..., :3], np.float64)
    save_png(dest / "fit_views.png", [h.images[:k], pred])
    print(f"object: {ds.name}; {args.views} views of {args.image_size} px, "
          f"{args.heldout} held-out views (dataset rendered in {t_data:.1f} s)")
    for s in fit.stages:
        print(f"{s['name']} ({s['method']}): {s['status']} in {s['seconds']:.1f} s - "
              f"{s['message']}")
    line = f"held-out IoU {metrics['iou']:.4f}"
    if "psnr" in metrics and fit.colors is not None:
        line += f", PSNR {metrics['psnr']:.2f} dB"
    if "chamfer_l2" in metrics:  # with a true mesh (not for a capture)
        line += (f"; chamfer-L2 {metrics['chamfer_l2']:.3g}, F-score@0.01 "
                 f"{metrics['fscore@0.01']:.3f}")
    print(line)
    print(f"wrote {dest / 'fit_views.obj'}, fit_views.json, fit_views.png")
    return 0 if fit.ok else 1


def register(subparsers) -> None:
    """Add the ``fit-views`` sub-command."""
    from ..fit.views import RECIPES, SILHOUETTE_METHODS, TEXTURED_METHODS

    p = add_command(subparsers, "fit-views",
                    "fit a mesh and its colours to multi-view images (PyTorch3D's "
                    "fit_textured_mesh)", __doc__, run)
    add_capture_arg(p)
    p.add_argument("--views", type=int, default=20, help="training views (default 20)")
    p.add_argument("--image-size", type=int, default=128, help="image size (default 128)")
    p.add_argument("--heldout", type=int, default=16, help="held-out views (default 16)")
    p.add_argument("--recipe", choices=tuple(RECIPES), default="default",
                   help="named settings (default: L-BFGS silhouettes, least-squares colours; "
                        "tutorial: the tutorial's SGD; contour: contour gradients with Adam)")
    p.add_argument("--method", choices=SILHOUETTE_METHODS + ("none",), default=None,
                   help="override the recipe's silhouette-stage method")
    p.add_argument("--textured", choices=TEXTURED_METHODS, default=None,
                   help="override the recipe's textured-stage method")
    p.add_argument("--silhouette-iters", type=int, default=200,
                   help="silhouette iterations (default 200; the tutorial uses 2000 SGD steps)")
    p.add_argument("--textured-iters", type=int, default=50, help="textured iterations")
    p.add_argument("--time", type=float, default=None,
                   help="time budget of the silhouette stage in seconds")
    p.add_argument("--large-steps", type=float, default=10.0,
                   help="lambda of the large-steps parameterisation (default 10)")
    p.add_argument("--no-coarse-to-fine", action="store_true",
                   help="one level at full resolution")
    p.add_argument("--init-level", type=int, default=4,
                   help="ico-sphere level of the final mesh (default 4)")
    p.add_argument("--seed", type=int, default=0, help="random views of the SGD recipe")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
