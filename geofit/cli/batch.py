"""``geofit batch TASK TARGETS... --out DIR``: many targets, one Dask task each (this machine or a
Dask cluster).

TASK is fit-mesh, render, fit-views, fit-volume or fit-nerf. TARGETS are mesh files or folders (a
folder expands to its mesh files; for the multi-view tasks also to capture folders, and a mesh
file is rendered into synthetic views first). Each target writes ``DIR/<name>/result.json``
(status, message, metrics, seconds, parameter count, history, settings hash) and its outputs; the
batch writes ``DIR/summary.json``, ``summary.csv``, ``summary.png`` (accuracy against seconds, a
point per target) and ``index.html`` (each target's picture). A failing target is recorded and
the batch goes on. A target is ok when its fit made at least one step and ended well by its own
account; a fit whose time budget ran out before its first step is a failure. Running again with
the same DIR skips the targets already done with the same settings and input and redoes those
that failed because of the machine (disk full, memory, a killed worker); ``--retry-failed``
also recomputes the other failed ones, ``--force`` all. Each fit runs with its defaults (those
of ``geofit.fit_*`` and of the ``geofit fit-*`` commands): only the options given here are
passed on.

By default a Dask LocalCluster of ``--workers`` processes on 127.0.0.1 runs the targets and is
torn down afterwards; ``--scheduler tcp://HOST:PORT`` runs them on an existing Dask cluster
(``dask scheduler`` + ``dask worker``, dask-jobqueue, Kubernetes, SSH; DIR must be on a file
system every worker can write).
"""
from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["register", "run"]

EPILOG = """exit status:
  0  every target succeeded (or was already done)
  1  at least one target failed (see DIR/summary.csv and DIR/<name>/result.json), or an error
  2  bad command line
"""


def run(args: argparse.Namespace) -> int:
    """Run the sub-command; returns the exit code (0: all succeeded, 1: some failed)."""
    from ..batch import ACCURACY, TASK_OPTIONS, check_input, check_output_folder

    for t in args.targets:  # before Dask, numpy or Open3D load
        check_input(t, "TARGETS", folder=True)
    check_output_folder(args.out, "--out")
    from ..batch import fit_many

    opts = {k: getattr(args, k) for k in TASK_OPTIONS[args.task]}
    result = fit_many(args.targets, args.task, args.out, scheduler=args.scheduler,
                      n_workers=args.workers, threads_per_worker=args.threads_per_worker,
                      progress=not args.no_progress, force=args.force,
                      retry_failed=args.retry_failed, **opts)
    for r in result:
        acc = f"{r.accuracy:.4g}" if r.accuracy >= 0 else "-"
        note = " (reused)" if r.reused else ""
        print(f"{r.name}: {r.status}{note}, {ACCURACY[args.task][0]} {acc}, {r.seconds:.1f} s"
              + ("" if r.ok else f" - {r.message}"))
    where = (f"on {result.n_workers} worker(s) x {result.threads_per_worker} thread(s)"
             if result.n_workers else
             f"(nothing to compute: results of {result.n_result_workers} worker(s) reused)")
    for note in result.notes:
        print(f"note: {note}")
    print(f"{len(result)} targets: {result.n_ok} ok, {result.n_failed} failed, "
          f"{result.n_reused} reused; {result.seconds:.1f} s {where}; wrote "
          f"{Path(result.out) / 'index.html'}")
    return result.exit_code


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def register(subparsers) -> None:
    """Add the ``batch`` sub-command with one sub-command per task."""
    from ..batch import TASK_OPTIONS

    desc = __doc__.split("\n\n", 1)[1] if __doc__ else None
    p = subparsers.add_parser(
        "batch", help="fit or render many targets on Dask (this machine or a cluster)",
        description=desc, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    tasks = p.add_subparsers(dest="task", metavar="TASK", required=True)
    for task, options in TASK_OPTIONS.items():
        t = tasks.add_parser(task, help=f"run {task} on every target", description=desc,
                             epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
        t.add_argument("targets", nargs="+", type=Path, metavar="TARGETS",
                       help="mesh files or folders" + ("" if task in ("fit-mesh", "render")
                                                       else " (mesh files or capture folders)"))
        t.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
        t.add_argument("--workers", type=int, default=None, metavar="N",
                       help="worker processes of the local cluster (default: cores / threads)")
        t.add_argument("--threads-per-worker", type=int, default=None, metavar="T",
                       help="compute threads per target (default: cores / workers); "
                            "workers x threads may not exceed the cores")
        t.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="run on the Dask cluster of this scheduler (tcp://HOST:PORT) "
                            "instead of a local one")
        t.add_argument("--force", action="store_true",
                       help="recompute targets already done with the same settings")
        t.add_argument("--retry-failed", action="store_true",
                       help="recompute the targets that failed with the same settings")
        t.add_argument("--no-progress", action="store_true", help="no progress bar")
        g = t.add_argument_group(f"{task} options")
        for name, opt in options.items():
            default = "the fit's own" if opt.default is None else opt.default
            g.add_argument(_flag(name), dest=name, type=opt.type, default=None,
                           help=f"{opt.help} (default: {default})")
        t.set_defaults(func=run)
