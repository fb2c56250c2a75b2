"""Pieces shared by the sub-commands that fit the cow's renders (``fit-volume``, ``fit-nerf``).

A private module: the command line skips modules whose name starts with ``_`` when it looks for
``register(subparsers)``.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def cow_views(args: argparse.Namespace):
    """The tutorial's training renders of the cow and held-out views between them.

    ``args.views`` training views of ``args.image_size`` pixels; held out: up to 8 azimuths
    half-way between them (:func:`geofit.datasets.held_out_views`). Returns ``(train, test)``;
    ``train.held_out`` is ``test``.
    """
    from ..datasets import held_out_views, tutorial_views

    train = tutorial_views(5, num_views=args.views, image_size=args.image_size, num_held_out=0)
    train.held_out = held_out_views(num_views=args.views, image_size=args.image_size,
                                    n_azimuths=min(8, max(1, args.views - 1)))
    return train, train.held_out


def save_png(path: Path, rows: list) -> None:
    """Write rows of (n, H, W, 3) images in [0, 1] as one PNG grid (row by row)."""
    from PIL import Image

    grid = np.concatenate([np.concatenate(list(r), axis=1) for r in rows], axis=0)
    Image.fromarray((np.clip(grid, 0, 1) * 255).round().astype(np.uint8)).save(path)


def save_gif(path: Path, frames: np.ndarray, ms: int = 80) -> None:
    """Write (n, H, W, 3) frames in [0, 1] as a looping GIF, ``ms`` milliseconds per frame."""
    from PIL import Image

    ims = [Image.fromarray((np.clip(f, 0, 1) * 255).round().astype(np.uint8)) for f in frames]
    ims[0].save(path, save_all=True, append_images=ims[1:], duration=ms, loop=0)


def add_view_args(p: argparse.ArgumentParser) -> None:
    """``--views``, ``--image-size`` (the training renders) and ``--frames`` (the rotation)."""
    p.add_argument("--views", type=int, default=40, help="training views (default 40)")
    p.add_argument("--image-size", type=int, default=128, help="image size (default 128)")
    p.add_argument("--frames", type=int, default=24,
                   help="frames of the rotating render (0: none; default 24)")


def add_output_args(p: argparse.ArgumentParser) -> None:
    """``--quiet``, ``--no-progress`` and ``--out``."""
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--out", default="out", help="output folder (default: out)")
