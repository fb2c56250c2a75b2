"""``geofit fit-nerf [CAPTURE]``: fit a neural radiance field to multi-view images with
geofit.fit_nerf's defaults (tutorial 6).

Without CAPTURE, the tutorial's 40 renders of the cow (black background, silhouettes, cameras)
and held-out views between them. The fit is ``fit_nerf(dataset)`` exactly as in Python (the
scene-sized recipe), with only the options given here passed on. Writes into ``--out``:

* ``nerf_summary.json`` -- status, parameter count, samples per ray, held-out PSNR, times, the
  configuration and the history;
* ``nerf_field.npz`` -- the network's parameters (names as the tutorial's ``state_dict``) and its
  configuration;
* ``nerf_heldout.png`` -- held-out targets above the renders;
* ``nerf_rotation.gif`` -- a rotating render (``--frames`` views around the scene).

Prints the held-out PSNR last.
"""
from __future__ import annotations

import argparse

from .._atomic import atomic_write
from ._common import (FIT_OPTIONS, add_views_fit_command, finish, out_dir, run_views_fit,
                      save_png, save_rotation, write_json)

__all__ = ["API", "register", "run"]

#: The function this sub-command runs (its docstring gives the options' help).
API = ("fit/nerf.py", "fit_nerf")


def run(args: argparse.Namespace) -> int:
    """Run the sub-command; returns the exit code."""
    import json
    from dataclasses import asdict

    import numpy as np

    from ..fit import fit_nerf

    run_ = run_views_fit(args, 6, fit_nerf)
    train, test, res = run_.train, run_.test, run_.result
    out = out_dir(args)
    summary = run_.summary()
    write_json(out / "nerf_summary.json", summary)
    config = json.dumps(asdict(res.config))
    atomic_write(out / "nerf_field.npz",
                 lambda p: np.savez_compressed(p, **res.field.params, config=config))
    images, held_psnr = res.images, res.psnr
    if images is None:  # the time budget left the fit's final held-out render out
        from ..metrics import psnr

        images = res.render(test.cameras, test.image_size)
        held_psnr = float(psnr(np.clip(images[..., :3], 0.0, 1.0), test.images))
        summary["held_out_psnr_after_the_fit"] = held_psnr
        write_json(out / "nerf_summary.json", summary)
    save_png(out / "nerf_heldout.png", [test.images, images[..., :3]])
    save_rotation(out / "nerf_rotation.gif", lambda cameras: res.render(
        cameras, train.image_size[0]), args.frames, elev=10.0, azim0=0.0)
    print(f"{res.n_params} parameters, {res.samples_per_ray:.1f} samples/ray, "
          f"{res.n_iterations} steps in {res.seconds:.1f} s (wall {res.wall_seconds:.1f} s)")
    return finish("fit-nerf", res, {"held-out PSNR (dB)": held_psnr}, out)


def register(subparsers) -> None:
    """Add the ``fit-nerf`` sub-command."""
    add_views_fit_command(subparsers, "fit-nerf", __doc__, run, API, FIT_OPTIONS)
