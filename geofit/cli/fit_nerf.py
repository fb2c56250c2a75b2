"""``geofit fit-nerf``: fit a neural radiance field to renders of the cow (tutorial 6).

Renders the tutorial's 40 training views of the cow with geofit (black background, silhouettes,
cameras) and the held-out views between them, fits a NeRF with :func:`geofit.fit.nerf.fit_nerf`
(the scene-sized recipe by default, ``--recipe tutorial`` for the tutorial's network and recipe),
and writes into ``--out``:

* ``nerf_summary.json`` -- status, parameter count, samples per ray, held-out PSNR, times, the
  configuration and the history;
* ``nerf_field.npz`` -- the network's parameters (names as the tutorial's ``state_dict``) and its
  configuration;
* ``nerf_heldout.png`` -- held-out targets above the renders;
* ``nerf_rotation.gif`` -- a rotating render (``--frames`` views around the cow).
"""
from __future__ import annotations

import argparse
import json
from dataclasses import asdict, replace

import numpy as np

from ._common import (add_capture_arg, add_command, add_quiet_arg, add_view_args, capture_views,
                      cow_views, finish, options, out_dir, save_png, save_rotation, write_json)

__all__ = ["register", "run"]


def run(args: argparse.Namespace) -> int:
    from ..fit.nerf import RECIPES, fit_nerf, render_nerf

    out = out_dir(args)
    train, test = capture_views(args.capture) if args.capture else cow_views(args)
    overrides = options(args, {"lr": "lr", "n_hidden_neurons": "n_hidden_neurons",
                               "n_harmonic_functions": "n_harmonic_functions",
                               "n_iter": "n_iter", "threads": "n_threads"})
    recipe = args.recipe
    if args.preset is not None:  # the former option
        recipe = "default" if args.preset == "scene" else "tutorial"
    opts = replace(RECIPES[recipe], early_stopping=args.early_stopping, **overrides)
    res = fit_nerf(train, recipe=recipe, options=opts, evaluator=test, time_budget=args.time,
                   seed=args.seed, progress=not args.no_progress)
    summary = res.summary()
    summary["history"] = res.history.to_dict()
    write_json(out / "nerf_summary.json", summary)
    np.savez_compressed(out / "nerf_field.npz", **res.field.params,
                        config=json.dumps(asdict(res.config)))
    if res.images is not None:
        save_png(out / "nerf_heldout.png", [test.images, res.images[..., :3]])
    save_rotation(out / "nerf_rotation.gif", lambda cameras: render_nerf(
        res.field, cameras, args.image_size, n_pts_per_ray=res.config.n_pts_per_ray,
        min_depth=res.config.min_depth, max_depth=res.config.max_depth,
        occupancy=res.occupancy), args.frames, elev=10.0, azim0=0.0)
    psnr = "n/a" if res.psnr is None else f"{res.psnr:.2f} dB"
    return finish("fit-nerf", res, f"{res.n_params} parameters, {res.samples_per_ray:.1f} "
                  f"samples/ray, {res.n_iterations} steps in {res.seconds:.1f} s (wall "
                  f"{res.wall_seconds:.1f} s); held-out PSNR {psnr}", out)


def register(subparsers) -> None:
    """Add the ``fit-nerf`` sub-command."""
    p = add_command(subparsers, "fit-nerf",
                    "fit a neural radiance field to renders of the cow (tutorial 6)", __doc__, run)
    p.add_argument("--recipe", choices=("default", "tutorial"), default="default",
                   help="geofit's scene-sized recipe (default) or the tutorial's")
    p.add_argument("--preset", choices=("scene", "tutorial"), default=None,
                   help="deprecated spelling of --recipe (scene: default)")
    p.add_argument("--time", type=float, default=600.0,
                   help="solver time budget in seconds (default 600)")
    p.add_argument("--iters", dest="n_iter", type=int, default=None,
                   help="maximum Adam steps (default: the recipe's)")
    p.add_argument("--lr", type=float, default=None, help="learning rate (default: recipe)")
    p.add_argument("--width", dest="n_hidden_neurons", type=int, default=None,
                   help="hidden width (default: recipe)")
    p.add_argument("--frequencies", dest="n_harmonic_functions", type=int, default=None,
                   help="harmonic frequencies of the point embedding (default: recipe)")
    p.add_argument("--early-stopping", type=int, default=None,
                   help="stop when the held-out loss has not improved for this many checkpoints")
    add_capture_arg(p)
    add_view_args(p)
    p.add_argument("--threads", type=int, default=None, help="threads (default: up to 2)")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    add_quiet_arg(p)
