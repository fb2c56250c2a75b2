"""Pieces shared by the sub-commands: parser set-up, the cow's renders or a capture as data,
option overrides and the files they write (JSON summaries, PNG grids, rotating GIFs).

A private module: the command line skips modules whose name starts with ``_`` when it looks for
``register(subparsers)``.
"""
from __future__ import annotations

import argparse
import json
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


def add_capture_arg(p: argparse.ArgumentParser) -> None:
    """The optional positional ``CAPTURE``: a capture folder to fit instead of the cow."""
    p.add_argument("capture", nargs="?", default=None, metavar="CAPTURE",
                   help="a capture folder (or its camera file) to fit instead of the cow's "
                        "renders: NeRF/Blender transforms.json, a COLMAP text model with "
                        "images/ and masks/, or OpenCV cameras.json (geofit.io.load_views). "
                        "Held out: transforms_test.json beside transforms_train.json, else "
                        "every 8th view. The scene should sit in the tutorial's box (3 units "
                        "around the origin, cameras about 2.7 away)")


def capture_views(path: str):
    """``(train, test)`` datasets of a capture folder (see :func:`add_capture_arg`);
    ``train.held_out`` is ``test``."""
    from ..io.views import _make_dataset, load_views

    folder = Path(path)
    if (folder / "transforms_train.json").is_file() and not (folder / "transforms.json").exists():
        train = load_views(folder / "transforms_train.json")
        test_file = folder / "transforms_test.json"
        train.held_out = load_views(test_file) if test_file.is_file() else train
        return train, train.held_out
    data = load_views(folder)
    n = len(data.cameras)
    if n < 2:
        raise ValueError(f"CAPTURE: {path} has {n} view; at least 2 are needed (every 8th "
                         "is held out)")
    held = np.arange(n) % 8 == 0
    name = data.name
    train, test = (_make_dataset(data.images[m], data.silhouettes[m], data.cameras[m], name)
                   for m in (~held, held))
    train.held_out = test
    return train, test


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


def add_quiet_arg(p: argparse.ArgumentParser) -> None:
    """``--quiet`` (no progress lines) and ``--no-progress`` (no progress bar)."""
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_command(subparsers, name: str, help: str, doc: str | None, func,
                input: tuple[str, str] | None = None) -> argparse.ArgumentParser:
    """A sub-command's parser with its ``--out`` folder option.

    ``help`` is its line in the command list, the module docstring ``doc`` (without its first
    paragraph, the title) its description, ``func(args)`` runs it; ``input = (name, help)``
    adds an optional positional input file (``None`` when not given).
    """
    p = subparsers.add_parser(name, help=help,
                              description=doc.split("\n\n", 1)[-1] if doc else None,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.set_defaults(func=func)
    if input is not None:
        p.add_argument(input[0], nargs="?", type=Path, default=None, help=input[1])
    p.add_argument("--out", default="out", help="output folder (default: out)")
    return p


def options(args: argparse.Namespace, names: dict[str, str]) -> dict:
    """``{keyword: getattr(args, attribute)}`` for each ``attribute: keyword`` of ``names``
    whose value was given (is not None): the options a sub-command passes on as overrides."""
    return {kw: getattr(args, a) for a, kw in names.items() if getattr(args, a) is not None}


def out_dir(args: argparse.Namespace) -> Path:
    """The ``--out`` folder, created if missing."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def wrote(*paths) -> int:
    """Print ``wrote PATH, PATH...``; the exit code 0."""
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def finish(command: str, res, details: str, out: Path) -> int:
    """Print ``geofit COMMAND: status (message); details; wrote OUT``; the exit code: 0 when
    the fit ``res`` succeeded, else 1."""
    print(f"geofit {command}: {res.status} ({res.message}); {details}; wrote {out}")
    return 0 if res.ok else 1


def write_json(path: Path, obj) -> None:
    """Write ``obj`` as indented JSON (numpy values and non-finite floats made plain)."""
    from ..fit.history import _json_safe

    from .._atomic import write_text

    write_text(path, json.dumps(_json_safe(obj), indent=1) + "\n")  # atomic, as batch's


def save_rotation(path: Path, render, n_frames: int, elev: float, azim0: float = 180.0) -> None:
    """Write a GIF of ``n_frames`` views around the origin (distance 2.7, elevation ``elev``,
    azimuths from ``azim0``); ``render(cameras)`` returns their ``(n, H, W, >=3)`` images."""
    if n_frames <= 0:
        return
    from ..cameras import FoVPerspectiveCameras, look_at_view_transform

    azim = np.linspace(0.0, 360.0, n_frames, endpoint=False) + azim0
    R, T = look_at_view_transform(2.7, elev, azim)
    save_gif(path, render(FoVPerspectiveCameras(R=R, T=T))[..., :3])
