"""``geofit fit-volume [CAPTURE]``: fit a voxel volume to multi-view images with
geofit.fit_volume's defaults (tutorial 5).

Without CAPTURE, the tutorial's renders of the cow (40 azimuths at elevation 0, 128 px, black
background, silhouettes) and held-out views between them (elevations 0 and 20). The fit is
``fit_volume(dataset)`` exactly as in Python, with only the options given here passed on.
Writes into ``--out``:

* ``volume_summary.json`` -- status, active voxels, samples per ray, held-out PSNR and IoU,
  times, the per-level statistics and the history;
* ``volume.npz`` -- ``densities (D, H, W)``, ``features (3, D, H, W)``, ``voxel_size``,
  ``volume_translation`` (PyTorch3D's ``Volumes`` conventions);
* ``volume_heldout.png`` -- held-out targets above the renders;
* ``volume_rotation.gif`` -- a rotating render (``--frames`` views around the scene).

Prints the held-out metrics last.
"""
from __future__ import annotations

import argparse

from .._atomic import atomic_write
from ._common import (FIT_OPTIONS, add_views_fit_command, finish, out_dir, run_views_fit,
                      save_png, save_rotation, write_json)

__all__ = ["API", "register", "run"]

#: The function this sub-command runs (its docstring gives the options' help).
API = ("fit/volume.py", "fit_volume")


def run(args: argparse.Namespace) -> int:
    """Run the sub-command; returns the exit code."""
    import numpy as np

    from ..fit import fit_volume
    from ..fit.volume import render_volume, volume_metrics

    run_ = run_views_fit(args, 5, fit_volume)
    train, test, res = run_.train, run_.test, run_.result
    m = volume_metrics(res.volume, test.images, test.silhouettes, test.cameras)
    out = out_dir(args)
    write_json(out / "volume_summary.json", {**run_.summary(), "held_out": {
        "psnr": m.psnr, "iou": m.iou, "psnr_per_view": m.psnr_per_view,
        "iou_per_view": m.iou_per_view}})
    vol = res.volume
    atomic_write(out / "volume.npz", lambda p: np.savez_compressed(
        p, densities=vol.densities, features=vol.features, voxel_size=vol.voxel_size,
        volume_translation=vol.volume_translation))
    save_png(out / "volume_heldout.png", [test.images, m.images[..., :3]])
    save_rotation(out / "volume_rotation.gif",
                  lambda cameras: render_volume(vol, cameras, train.image_size[0]), args.frames,
                  elev=15.0)
    print(f"{res.n_active_voxels} active voxels of {vol.n_voxels}, {res.samples_per_ray:.1f} "
          f"samples/ray of {res.n_pts_per_ray}, {res.n_iterations} iterations in "
          f"{res.seconds:.1f} s")
    return finish("fit-volume", res, {"held-out PSNR (dB)": m.psnr, "held-out IoU": m.iou},
                  out)


def register(subparsers) -> None:
    """Add the ``fit-volume`` sub-command."""
    add_views_fit_command(subparsers, "fit-volume", __doc__, run, API, FIT_OPTIONS)
