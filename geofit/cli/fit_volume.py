"""``geofit fit-volume``: fit a voxel volume to renders of the cow by raymarching (tutorial 5).

Renders the tutorial's training views of the cow with geofit (40 azimuths at elevation 0, 128 px,
black background, silhouettes) and held-out views between them (elevations 0 and 20), fits a
grid of densities and colours with :func:`geofit.fit.volume.fit_volume` (geofit's reduced model
with L-BFGS by default, ``--recipe tutorial`` for PyTorch3D's dense Adam recipe), and writes into
``--out``:

* ``volume_summary.json`` -- status, active voxels, samples per ray, held-out PSNR and IoU,
  times, the per-level statistics and the history;
* ``volume.npz`` -- ``densities (D, H, W)``, ``features (3, D, H, W)``, ``voxel_size``,
  ``volume_translation`` (PyTorch3D's ``Volumes`` conventions);
* ``volume_heldout.png`` -- held-out targets above the renders;
* ``volume_rotation.gif`` -- a rotating render (``--frames`` views around the cow).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from ._common import (add_capture_arg, add_command, add_quiet_arg, add_view_args, capture_views,
                      cow_views, finish, options, out_dir, save_png, save_rotation, write_json)

__all__ = ["register", "run"]


def _ints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}")


def run(args: argparse.Namespace) -> int:
    """Run the sub-command; returns the exit code."""
    from ..fit.volume import VolumeFitOptions, fit_volume, render_volume, volume_metrics

    out = out_dir(args)
    t0 = time.perf_counter()
    train, test = capture_views(args.capture) if args.capture else cow_views(args)
    t_data = time.perf_counter() - t0
    kw = options(args, {"levels": "levels", "iters": "iterations", "smoothness": "smoothness"})
    opts = VolumeFitOptions(method=args.method, volume_size=args.size, n_iter=args.steps,
                            precision=args.precision, **kw)
    res = fit_volume(train, recipe=args.recipe, options=opts, time_budget=args.time,
                     progress=not args.no_progress)
    m = volume_metrics(res.volume, test.images, test.silhouettes, test.cameras)
    summary = res.summary()
    summary.update({"dataset": train.name, "views": len(train),
                    "image_size": args.image_size, "data_seconds": t_data,
                    "held_out": {"psnr": m.psnr, "iou": m.iou,
                                 "psnr_per_view": m.psnr_per_view, "iou_per_view":
                                 m.iou_per_view, "azim": test.azim, "elev": test.elev}})
    summary["history"] = res.history.to_dict()
    write_json(out / "volume_summary.json", summary)
    vol = res.volume
    np.savez_compressed(out / "volume.npz", densities=vol.densities, features=vol.features,
                        voxel_size=vol.voxel_size, volume_translation=vol.volume_translation)
    save_png(out / "volume_heldout.png", [test.images, m.images[..., :3]])
    save_rotation(out / "volume_rotation.gif",
                  lambda cameras: render_volume(vol, cameras, args.image_size), args.frames,
                  elev=15.0)
    return finish("fit-volume", res, f"{res.n_active_voxels} active voxels of {vol.n_voxels}, "
                  f"{res.samples_per_ray:.1f} samples/ray of {res.n_pts_per_ray}, "
                  f"{res.n_iterations} iterations in {res.seconds:.1f} s; held-out PSNR "
                  f"{m.psnr:.2f} dB, IoU {m.iou:.4f}", out)


def register(subparsers) -> None:
    """Add the ``fit-volume`` sub-command."""
    from ..fit.volume import FIT_VOLUME_METHODS, RECIPES

    p = add_command(subparsers, "fit-volume",
                    "fit a voxel volume to renders of the cow by raymarching (tutorial 5)",
                    __doc__, run)
    p.add_argument("--recipe", choices=tuple(RECIPES), default="default",
                   help="geofit's reduced model (default) or the tutorial's dense Adam recipe")
    p.add_argument("--method", choices=FIT_VOLUME_METHODS, default=None,
                   help="solver of the default recipe: L-BFGS (default), nlopt L-BFGS, Adam")
    p.add_argument("--size", type=int, default=128, help="final grid size (default 128)")
    p.add_argument("--levels", type=_ints, default=None,
                   help="coarse-to-fine grid sizes, e.g. 32,64,128 (default: halving to 32)")
    p.add_argument("--iters", type=_ints, default=None,
                   help="iterations per level, e.g. 150,100,50 (default: the method's)")
    p.add_argument("--steps", type=int, default=300,
                   help="Adam steps of the tutorial recipe (default 300)")
    p.add_argument("--smoothness", type=float, default=None,
                   help="weight of the smoothness prior (default: fit_volume's)")
    p.add_argument("--time", type=float, default=None, help="solver time budget in seconds")
    p.add_argument("--precision", choices=("float32", "float64"), default="float32",
                   help="arithmetic of the ray marching (default float32)")
    add_capture_arg(p)
    add_view_args(p)
    add_quiet_arg(p)
