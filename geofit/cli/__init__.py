"""The ``geofit`` command line.

Each workflow lives in its own module in this package and defines ``register(subparsers)``,
which adds one sub-command whose ``func(args) -> int`` runs it. ``main`` discovers them.

Imports of geofit's packages are made inside each sub-command's ``func``, not at module level,
on purpose: ``geofit --help`` and argument errors answer without importing Open3D, Embree,
matplotlib and the fits (docs/architecture.md: the command line's start-up is one of the two
reasons for a function-local import).
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every registered sub-command."""
    parser = argparse.ArgumentParser(
        prog="geofit",
        description="Fit and render 3D geometry on the CPU (PyTorch3D's tutorials in numpy).",
    )
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"geofit {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, RuntimeError) as exc:
        print(f"geofit {args.command}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
