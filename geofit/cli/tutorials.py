"""``geofit tutorials``: run the six workflows of PyTorch3D's tutorials and write one report.

Fit a mesh to a mesh, render textured meshes, render point clouds, fit a mesh to multi-view
images, fit a voxel volume and fit a neural radiance field, each with PyTorch3D's recipe (ported)
next to geofit's own method, on the default data (the tutorial files when ``GEOFIT_DATA`` or the
cache holds them, else procedural stand-ins). Writes into ``--out``: one folder per workflow
(rendered images, fitted meshes as OBJ, volumes and weights as npz, histories as JSON, charts)
and ``report.html`` (open it in a browser: no server needed), ``report.md`` and ``report.json``.

The default size is reduced to take a few minutes on two cores; ``--full`` runs the tutorials'
own sizes (much longer). Exit code 0 when every workflow ran, 1 when one failed (the report says
which and why).
"""
from __future__ import annotations

import argparse
import shlex
import time
from pathlib import Path

from ._common import check_out, module_constant

__all__ = ["register", "run"]


def _steps(text: str | None) -> list[str] | None:
    from ..tutorials import STEPS

    if text is None:
        return None
    names = [s.strip() for s in text.split(",") if s.strip()]
    unknown = [n for n in names if n not in STEPS]
    if unknown or not names:
        raise ValueError(f"--only: unknown step(s) {unknown or text!r}; expected a "
                         f"comma-separated subset of {','.join(STEPS)}")
    return names


def run(args: argparse.Namespace) -> int:
    """Run the sub-command; returns the exit code."""
    from ..tutorials import run_tutorials

    size = "full" if args.full else args.size
    if args.full and args.size not in ("default", "full"):
        raise ValueError(f"--full and --size {args.size} contradict each other")
    only = _steps(args.only)
    command = " ".join(["geofit", "tutorials", "--out", shlex.quote(str(args.out))]
                       + (["--full"] if args.full else [])
                       + ([f"--size {args.size}"] if args.size != "default" else [])
                       + ([f"--only {shlex.quote(args.only)}"] if args.only else [])
                       + ([f"--gallery {shlex.quote(str(args.gallery))}"] if args.gallery
                          else []))
    t0 = time.perf_counter()
    run_ = run_tutorials(args.out, size=size, only=only, progress=not args.no_progress,
                         seed=args.seed, command=command, gallery=args.gallery)
    for s in run_.steps:  # workflows
        print(f"{s.name:14s} {s.status if s.ok else s.status[:160]:>10s}  {s.seconds:7.1f} s")
    print(f"geofit tutorials: {sum(s.ok for s in run_.steps)} of {len(run_.steps)} workflows "
          f"ran in {time.perf_counter() - t0:.1f} s ({size} size)")
    print(f"geofit tutorials: wrote {run_.report['html']} and {run_.report['md']}")
    if args.gallery:
        files = run_.report["gallery"]
        mb = sum(p.stat().st_size for p in files) / 2 ** 20
        print(f"geofit tutorials: gallery of {len(files)} images ({mb:.2f} MB) in {args.gallery}")
    return 0 if run_.ok else 1


def register(subparsers) -> None:
    """Add the ``tutorials`` sub-command."""
    sizes = module_constant("tutorials/shared.py", "SIZES")

    p = subparsers.add_parser(
        "tutorials",
        help="run the six tutorial workflows end to end and write report.html / report.md",
        description=__doc__.split("\n\n", 1)[1].replace("``", "") if __doc__ else None,
    )
    p.add_argument("--out", type=Path, default=Path("out/tutorials"),
                   help="output folder (default: out/tutorials)")
    p.add_argument("--full", action="store_true",
                   help="the tutorials' full sizes (views, image sizes, iterations); slow")
    p.add_argument("--size", choices=sizes, default="default",
                   help="run size: tiny (for tests), default (a few minutes) or full "
                        "(same as --full)")
    p.add_argument("--only", default=None, metavar="STEP,...",
                   help="comma-separated steps to run (default: all six; see the report)")
    p.add_argument("--gallery", type=Path, default=None, metavar="DIR",
                   help="also copy the figures into DIR under stable names with a README.md "
                        "(e.g. docs/tutorials, for the project README)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice (default 0)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run, check=check_out)
