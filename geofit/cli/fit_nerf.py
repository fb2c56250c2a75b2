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
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ._common import (
    add_capture_arg,
    add_output_args,
    add_view_args,
    capture_views,
    cow_views,
    save_gif,
    save_png,
)

__all__ = ["register", "run"]


def run(args: argparse.Namespace) -> int:
    from ..cameras import FoVPerspectiveCameras, look_at_view_transform
    from ..fit.nerf import fit_nerf, render_nerf

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    train, test = capture_views(args.capture) if args.capture else cow_views(args)
    overrides = {}
    for key in ("lr", "n_hidden_neurons", "n_harmonic_functions", "n_iter"):
        v = getattr(args, key)
        if v is not None:
            overrides[key] = v
    if args.threads is not None:
        overrides["n_threads"] = args.threads
    recipe = args.recipe
    if args.preset is not None:  # the former option
        recipe = "default" if args.preset == "scene" else "tutorial"
    res = fit_nerf(train, recipe=recipe, held_out=test, time_budget=args.time,
                   early_stopping=args.early_stopping, seed=args.seed, verbose=not args.quiet,
                   progress=not args.no_progress, **overrides)
    summary = res.summary()
    summary["history"] = res.history.to_dict()
    (out / "nerf_summary.json").write_text(json.dumps(summary, indent=1) + "\n",
                                           encoding="utf-8")
    np.savez_compressed(out / "nerf_field.npz", **res.field.params,
                        config=json.dumps(asdict(res.config)))
    if res.images is not None:
        save_png(out / "nerf_heldout.png", [test.images, res.images[..., :3]])
    if args.frames > 0:
        azim = np.linspace(-180.0, 180.0, args.frames, endpoint=False) + 180.0
        R, T = look_at_view_transform(2.7, 10.0, azim)
        frames = render_nerf(res.field, FoVPerspectiveCameras(R=R, T=T), args.image_size,
                             n_pts_per_ray=res.config.n_pts_per_ray,
                             min_depth=res.config.min_depth, max_depth=res.config.max_depth,
                             occupancy=res.occupancy)
        save_gif(out / "nerf_rotation.gif", frames[..., :3])
    psnr = "n/a" if res.psnr is None else f"{res.psnr:.2f} dB"
    print(f"geofit fit-nerf: {res.status} ({res.message}); {res.n_params} parameters, "
          f"{res.samples_per_ray:.1f} samples/ray, {res.n_iterations} steps in "
          f"{res.seconds:.1f} s (wall {res.wall_seconds:.1f} s); held-out PSNR {psnr}; "
          f"wrote {out}")
    return 0 if res.ok else 1


def register(subparsers) -> None:
    """Add the ``fit-nerf`` sub-command."""
    p = subparsers.add_parser(
        "fit-nerf", help="fit a neural radiance field to renders of the cow (tutorial 6)",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
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
    add_output_args(p)
    p.set_defaults(func=run)
