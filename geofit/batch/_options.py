"""The batch's tasks, their options and the checks of its paths, in the standard library only.

Shared with the command line, which builds its parser and checks the targets and the output
folder from here before numpy, Open3D or Dask are imported (a wrong path is answered at once).
"""
from __future__ import annotations

import errno
import os
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: Version 2: "ok" needs at least one step of the fit, failures carry their ``cause``.
RESULT_SCHEMA = "geofit-batch-result/2"
RESULT_FILE = "result.json"
PICTURE_FILE = "picture.png"

#: Suffixes of the mesh files a folder target expands to.
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")

#: Files whose presence makes a folder a multi-view capture (the layouts
#: ``geofit.io.load_views`` reads): the NeRF/Blender ``transforms.json`` (or its
#: ``transforms_train.json`` split), a COLMAP text model (also under ``sparse/0``), OpenCV
#: K/R/t per view in ``cameras.json``.
CAPTURE_MARKERS = ("transforms.json", "transforms_train.json", "cameras.txt",
                   "sparse/0/cameras.txt", "sparse/cameras.txt", "cameras.json")


def is_capture(path: Path) -> bool:
    """True for a folder holding a multi-view capture (one of :data:`CAPTURE_MARKERS`)."""
    path = Path(path)
    return path.is_dir() and any((path / m).is_file() for m in CAPTURE_MARKERS)


@dataclass(frozen=True)
class Option:
    """One setting of a task: its type, default and help (shared by :func:`fit_many` keyword
    arguments and the ``geofit batch`` flags). ``choices`` is a tuple, or a function returning
    it (called when a value is checked, so that listing a fit's recipes imports nothing before
    then)."""

    type: type
    default: Any
    help: str
    choices: tuple | Callable[[], tuple] | None = None

    def allowed(self) -> tuple | None:
        """The choices (resolved), or None."""
        return self.choices() if callable(self.choices) else self.choices


def _recipes(module: str) -> Callable[[], tuple]:
    """The recipe names of ``geofit.fit.<module>`` (its ``RECIPES``), read when called."""
    def names() -> tuple:
        import importlib

        return tuple(importlib.import_module(f"geofit.fit.{module}").RECIPES)

    return names


_SEED = Option(int, 0, "random seed of the fit")
_BUDGET = Option(float, None, "seconds of the fit's time budget per target")


def _recipe(module: str) -> Option:
    return Option(str, None, "the fit's named settings", _recipes(module))

#: Every task's options, with defaults. ``fit_many(..., **fit_kwargs)`` accepts exactly these.
#: The fit's own options are only ``time_budget``, ``seed`` and ``recipe``, passed on when
#: given: everything else is the fit's default (the one default of the API, the command line
#: and the notebooks). The others say what input is made (views rendered from a mesh target).
TASK_OPTIONS: dict[str, dict[str, Option]] = {
    "fit-mesh": {
        "recipe": _recipe("mesh"),
        "time_budget": _BUDGET,
        "seed": _SEED,
    },
    "render": {
        "views": Option(int, 4, "views per target"),
        "image_size": Option(int, 256, "pixels per side"),
        "dist": Option(float, 2.7, "camera distance (the mesh is normalised first)"),
        "elev": Option(float, 20.0, "camera elevation in degrees"),
    },
    "fit-views": {
        "views": Option(int, 20, "training views rendered from a mesh target"),
        "image_size": Option(int, 128, "image size of those views"),
        "heldout": Option(int, 8, "held-out views rendered from a mesh target"),
        "recipe": _recipe("views"),
        "time_budget": _BUDGET,
        "seed": _SEED,
    },
    "fit-volume": {
        "views": Option(int, 40, "training views rendered from a mesh target"),
        "image_size": Option(int, 128, "image size of those views"),
        "heldout": Option(int, 8, "held-out views rendered from a mesh target"),
        "recipe": _recipe("volume"),
        "time_budget": _BUDGET,
        "seed": _SEED,
    },
    "fit-nerf": {
        "views": Option(int, 40, "training views rendered from a mesh target"),
        "image_size": Option(int, 128, "image size of those views"),
        "heldout": Option(int, 8, "held-out views rendered from a mesh target"),
        "recipe": _recipe("nerf"),
        "time_budget": _BUDGET,
        "seed": _SEED,
    },
}

#: The tasks: ``fit-mesh`` and ``render`` take mesh files; ``fit-views``, ``fit-volume`` and
#: ``fit-nerf`` take capture folders (read by ``geofit.io.load_views``) or mesh files
#: (rendered into synthetic views first).
TASKS = tuple(TASK_OPTIONS)

#: Per task, the metric plotted as accuracy in ``summary.png`` and its label.
ACCURACY: dict[str, tuple[str, str]] = {
    "fit-mesh": ("fscore@0.01", "F-score@0.01 (normalised frame)"),
    "render": ("coverage", "share of pixels on the mesh"),
    "fit-views": ("iou", "held-out silhouette IoU"),
    "fit-volume": ("psnr", "held-out PSNR (dB)"),
    "fit-nerf": ("psnr", "held-out PSNR (dB)"),
}


# ------------------------------------------------------------------------------ paths
def check_input(path, name: str, *, folder: bool = False) -> Path:
    """``path`` as a Path when it is a readable file (or, with ``folder``, a readable folder).

    Raises
    ------
    FileNotFoundError
        When nothing is at ``path``.
    ValueError
        For a folder where a file is expected (or the reverse), or a path that cannot be read;
        the message names ``name``, the path and what was found.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{name}: {p} not found (no such file or folder)")
    if p.is_dir():
        if not folder:
            raise ValueError(f"{name}: expected a file, got the folder {p}")
        if not os.access(p, os.R_OK | os.X_OK):
            raise ValueError(f"{name}: the folder {p} cannot be read (permission denied)")
        return p
    if not p.is_file():
        raise ValueError(f"{name}: expected a regular file, got {p} (a device, FIFO or socket)")
    try:
        with open(p, "rb") as fh:
            fh.read(1)
    except OSError as exc:
        raise ValueError(f"{name}: {p} cannot be read ({exc.strerror or exc})") from None
    return p


def check_output_folder(path, name: str = "out") -> Path:
    """Create the output folder ``path`` if missing and prove it writable (a probe file is
    written and removed); returns it.

    Raises
    ------
    ValueError
        One line naming ``name``: the path is a file, or the folder cannot be created or
        written (read-only, permission denied, disk full).
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{name}: {out} is a file; expected a folder to write into")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"{name}: cannot create the folder {out} "
                         f"({exc.strerror or exc})") from None
    probe = out / f".geofit-write-check-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    try:
        with open(probe, "wb") as fh:
            fh.write(b"geofit")
    except OSError as exc:
        raise ValueError(f"{name}: the folder {out} is not writable "
                         f"({exc.strerror or exc})") from None
    finally:
        try:
            probe.unlink()
        except OSError:
            pass
    return out


#: errno values of a failure caused by the machine rather than by the target (a rerun retries
#: them by default): no space, quota, no memory, too many open files.
ENVIRONMENT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.ENOMEM, errno.EMFILE,
                                errno.ENFILE, errno.EFBIG})

#: Exception type names of a failure caused by the machine or the cluster: memory, a worker
#: killed or lost, the scheduler's connection closed, a timeout of the cluster.
ENVIRONMENT_ERRORS = frozenset({"MemoryError", "KilledWorker", "CommClosedError",
                                "FutureCancelledError", "CancelledError", "TimeoutError",
                                "WorkerLost", "ConnectionError", "BrokenPipeError"})


def environment_cause(exc: BaseException) -> bool:
    """True when ``exc`` (or an exception it was raised from) comes from the machine (disk
    full, out of memory, a killed worker; :data:`ENVIRONMENT_ERRNOS`,
    :data:`ENVIRONMENT_ERRORS`) rather than from the target's data or the fit."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if type(exc).__name__ in ENVIRONMENT_ERRORS:
            return True
        if isinstance(exc, OSError) and exc.errno in ENVIRONMENT_ERRNOS:
            return True
        exc = exc.__cause__ or exc.__context__
    return False
