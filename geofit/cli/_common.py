"""Pieces shared by the sub-commands: parser set-up, argument checks, the cow's renders or a
capture as data, the fit's keywords and the files they write (JSON summaries, PNG grids,
rotating GIFs).

This module imports only the standard library at its top: the parser is built and the
arguments (input files, the output folder) are checked before numpy, Open3D or Embree load,
so a wrong path is answered at once. Everything heavy is imported inside the functions.

A private module: the command line skips modules whose name starts with ``_`` when it looks for
``register(subparsers)``.
"""
from __future__ import annotations

import argparse
import ast
import re
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

#: The package folder: API docstrings are read from its sources (with ``ast``, no import).
_PACKAGE = Path(__file__).resolve().parents[1]



#: The flags that choose the tutorial's views -> ``geofit.datasets.tutorial_views``' keywords
#: (passed on only when given: the tutorial's own counts and sizes otherwise).
VIEW_OPTIONS = {"views": "num_views", "image_size": "image_size", "heldout": "num_held_out"}


def tutorial_data(args: argparse.Namespace, tutorial: int):
    """The training views of ``CAPTURE`` (:func:`capture_views`) or, without one, the
    tutorial's renders of the cow (``geofit.datasets.tutorial_views(tutorial)`` with only the
    view flags given); ``train.held_out`` holds the held-out views. Returns ``(train, test)``.
    """
    if getattr(args, "capture", None):
        return capture_views(args.capture)
    from ..datasets import tutorial_views

    kw = {kw: getattr(args, a) for a, kw in VIEW_OPTIONS.items()
          if getattr(args, a, None) is not None}
    train = tutorial_views(tutorial, **kw)
    return train, train.held_out


def add_capture_arg(p: argparse.ArgumentParser) -> None:
    """The optional positional ``CAPTURE``: a capture folder to fit instead of the cow."""
    p.add_argument("capture", nargs="?", default=None, metavar="CAPTURE",
                   help="a capture folder (or its camera file) to fit instead of the cow's "
                        "renders: NeRF/Blender transforms.json or the NeRF-synthetic split "
                        "folder, nerfstudio, a COLMAP model with images/ and masks/, or OpenCV "
                        "cameras.json (geofit.io.load_views). Held out: the capture's test "
                        "views (NeRF-synthetic), else every 8th view. The scene should sit in "
                        "the tutorial's box (3 units around the origin, cameras about 2.7 away)")


def capture_views(path: str):
    """``(train, test)`` datasets of a capture folder (see :func:`add_capture_arg`);
    ``train.held_out`` is ``test``."""
    from ..io.views import load_views

    data = load_views(Path(path))
    if data.held_out is not None:  # a layout with its own test views (NeRF-synthetic)
        return data, data.held_out
    n = len(data.cameras)
    if n < 2:
        raise ValueError(f"CAPTURE: {path} has {n} view; at least 2 are needed (every 8th "
                         "is held out)")
    train = data.split(8)
    return train, train.held_out


def save_png(path: Path, rows: list) -> None:
    """Write rows of (n, H, W, 3) images in [0, 1] as one PNG grid (row by row)."""
    import numpy as np
    from PIL import Image

    grid = np.concatenate([np.concatenate(list(r), axis=1) for r in rows], axis=0)
    from .._atomic import atomic_write

    img = Image.fromarray((np.clip(grid, 0, 1) * 255).round().astype(np.uint8))
    atomic_write(path, img.save)


def save_gif(path: Path, frames, ms: int = 80) -> None:
    """Write (n, H, W, 3) frames in [0, 1] as a looping GIF, ``ms`` milliseconds per frame."""
    import numpy as np
    from PIL import Image

    ims = [Image.fromarray((np.clip(f, 0, 1) * 255).round().astype(np.uint8)) for f in frames]
    from .._atomic import atomic_write

    atomic_write(path, lambda p: ims[0].save(p, save_all=True, append_images=ims[1:],
                                             duration=ms, loop=0))


def add_view_args(p: argparse.ArgumentParser, frames: bool = True) -> None:
    """``--views``, ``--image-size``, ``--heldout`` (the tutorial's renders, when no CAPTURE
    is given) and, with ``frames``, ``--frames`` (the rotating render)."""
    p.add_argument("--views", type=int, default=None,
                   help="training views of the cow (default: the tutorial's)")
    p.add_argument("--image-size", type=int, default=None,
                   help="image size of the cow's views (default: the tutorial's, 128)")
    p.add_argument("--heldout", type=int, default=None,
                   help="held-out views of the cow (default: the tutorial's, 16)")
    if frames:
        p.add_argument("--frames", type=int, default=24,
                       help="frames of the rotating render (0: none; default 24)")


def _plain(text: str) -> str:
    """Docstring markup made plain for a terminal: roles and double backquotes dropped, one
    line, ``%`` escaped for argparse."""
    text = re.sub(r":\w+:`~?([^`]+)`", r"\1", text).replace("``", "").replace("`", "")
    return " ".join(text.split()).replace("%", "%%")


@lru_cache(maxsize=None)
def _docstrings(module: str) -> dict[str, str]:
    """``{function or class name: docstring}`` of ``geofit/<module>``, read with ``ast``
    (nothing is imported)."""
    tree = ast.parse((_PACKAGE / module).read_text(encoding="utf-8"))
    return {n.name: ast.get_docstring(n) or "" for n in ast.walk(tree)
            if isinstance(n, (ast.FunctionDef, ast.ClassDef))}


def module_constant(module: str, name: str):
    """The literal value of the module-level constant ``name`` in ``geofit/<module>``, read
    with ``ast`` (nothing is imported): choices of the parser from their one home."""
    tree = ast.parse((_PACKAGE / module).read_text(encoding="utf-8"))
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else \
            [node.target] if isinstance(node, ast.AnnAssign) and node.value else []
        if any(isinstance(t, ast.Name) and t.id == name for t in targets):
            return ast.literal_eval(node.value)
    raise LookupError(f"{name}: no such constant in geofit/{module}")


def api_doc(api: tuple[str, str], param: str | None = None) -> str:
    """The first sentence of the docstring of ``api = (module file, function)`` (e.g.
    ``("fit/mesh.py", "fit_mesh")``), or of its parameter ``param``'s description.

    The command line's help texts come from here, so they say what the API's docstrings say.

    Raises
    ------
    LookupError
        When the function or the parameter is not documented there.
    """
    module, func = api
    doc = _docstrings(module).get(func)
    if doc is None:
        raise LookupError(f"{func}: not found in geofit/{module}")
    if param is None:
        return _plain(doc.split("\n\n", 1)[0])
    lines = doc.splitlines()
    for i, line in enumerate(lines):
        names = line.split(" : ", 1)[0] if " : " in line else line.rstrip(":")
        if line[:1].strip() and param in [n.strip() for n in names.split(",")]:
            body = []
            for nxt in lines[i + 1:]:
                if nxt.strip() and not nxt[:1].isspace():
                    break
                body.append(nxt)
            text = _plain(" ".join(body))
            return re.split(r"(?<=[.;])\s", text, maxsplit=1)[0].rstrip(".;")
    raise LookupError(f"{func}: no parameter {param!r} in its docstring (geofit/{module})")


def add_command(subparsers, name: str, doc: str | None, func,
                input: tuple[str, str] | None = None, check=None) -> argparse.ArgumentParser:
    """A sub-command's parser with its ``--out`` folder option.

    Its line in the command list is the first paragraph of the module docstring ``doc`` (after
    the ``geofit NAME``: prefix), its description the rest; ``func(args)`` runs it and
    ``check(args)`` (optional) checks its arguments before (nothing heavy imported yet);
    ``input = (name, help)`` adds an optional positional input file (``None`` when not given),
    checked to be a readable file.
    """
    head, _, rest = (doc or "").partition("\n\n")
    help = _plain(head.split(":", 1)[-1] if head.startswith("``geofit") else head)
    p = subparsers.add_parser(name, help=help, description=(help + "\n\n" + rest.replace(
        "``", "")).replace("%", "%%") if doc else None,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.set_defaults(func=func, check=check or check_paths, input_arg=input[0] if input else None)
    if input is not None:
        p.add_argument(input[0], nargs="?", type=Path, default=None, help=input[1])
    p.add_argument("--out", default="out", help="output folder (default: out)")
    return p


def add_fit_options(p: argparse.ArgumentParser, api: tuple[str, str],
                    table: dict[str, str]) -> None:
    """The fit's options a sub-command offers: one flag per entry ``dest: keyword`` of
    ``table`` (``--time-budget``, ``--seed``, ``--recipe``, ...; default None: the fit's own),
    with the help of the keyword's description in the API's docstring, and ``--no-progress``.
    """
    for dest, keyword in table.items():
        kind = {"seed": int, "recipe": str}.get(dest, float if "time" in dest else int)
        p.add_argument("--" + dest.replace("_", "-"), dest=dest, type=kind, default=None,
                       help=f"{api_doc(api, keyword)} (default: {api[1]}'s own)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


#: The command line's flags -> the fit's keywords, the same for every ``geofit fit-*``
#: sub-command and passed on only when given: everything else is the fit's own default. When
#: the fits' keywords change, this table changes (each fit takes one wall-clock ``time_budget``).
FIT_OPTIONS = {"time_budget": "time_budget", "seed": "seed", "recipe": "recipe"}


def add_views_fit_command(subparsers, name: str, doc: str | None, func, api: tuple[str, str],
                          table: dict[str, str], frames: bool = True) -> argparse.ArgumentParser:
    """The parser of a sub-command that fits multi-view images (``fit-views``, ``fit-volume``,
    ``fit-nerf``): :func:`add_command`, the optional ``CAPTURE`` (:func:`add_capture_arg`), the
    view flags (:func:`add_view_args`, ``--frames`` with ``frames``) and the fit's options
    ``table`` documented from ``api`` (:func:`add_fit_options`)."""
    p = add_command(subparsers, name, doc, func)
    add_capture_arg(p)
    add_view_args(p, frames=frames)
    add_fit_options(p, api, table)
    return p


def fit_kwargs(args: argparse.Namespace, table: dict[str, str]) -> dict:
    """The keywords of the fit call: ``{keyword: value}`` for each flag of ``table`` the user
    gave, and ``progress=False`` with ``--no-progress``. Nothing else: the fit's defaults are
    the command's."""
    kw = {keyword: getattr(args, dest) for dest, keyword in table.items()
          if getattr(args, dest, None) is not None}
    if getattr(args, "no_progress", False):
        kw["progress"] = False
    return kw


@dataclass
class ViewsFitRun:
    """What :func:`run_views_fit` gives a multi-view sub-command.

    Attributes
    ----------
    train, test : MultiViewDataset
        The training views and the held-out views (:func:`tutorial_data`).
    result : FitResult
        The fit's result.
    options : dict
        The keywords the fit was called with (:func:`fit_kwargs` of :data:`FIT_OPTIONS`).
    data_seconds : float
        Wall seconds spent reading or rendering the views.
    """

    train: object
    test: object
    result: object
    options: dict
    data_seconds: float

    def summary(self, history: bool = True) -> dict:
        """The head of the sub-command's JSON summary: the dataset's name, view counts and
        image size, the options, ``data_seconds`` and the result's ``summary()`` (its
        ``to_dict()``, with the history, when ``history``)."""
        res = self.result
        return {"dataset": self.train.name, "views": len(self.train), "heldout": len(self.test),
                "image_size": list(self.train.image_size), "options": self.options,
                "data_seconds": self.data_seconds,
                **(res.to_dict() if history else res.summary())}


def run_views_fit(args: argparse.Namespace, tutorial: int, fit) -> ViewsFitRun:
    """The common start of ``fit-views``, ``fit-volume`` and ``fit-nerf``: the views
    (:func:`tutorial_data`, timed), a line saying what is fitted, then ``fit(train,
    **options)`` with only the options given on the command line (:data:`FIT_OPTIONS`)."""
    t0 = time.perf_counter()
    train, test = tutorial_data(args, tutorial)
    data_seconds = time.perf_counter() - t0
    kw = fit_kwargs(args, FIT_OPTIONS)
    print(f"object: {train.name}; {len(train)} views of {train.image_size[0]} px, {len(test)} "
          f"held-out views (made in {data_seconds:.1f} s)"
          + "".join(f", {k}={v}" for k, v in kw.items()))
    return ViewsFitRun(train, test, fit(train, **kw), kw, data_seconds)


def check_input(path, name: str, *, folder: bool = False) -> Path:
    """A readable input file (or folder); see :func:`geofit.batch.check_input`."""
    from ..batch import check_input as check

    return check(path, name, folder=folder)


def check_out(args: argparse.Namespace) -> Path:
    """The ``--out`` folder, created if missing and proved writable, before any work."""
    from ..batch import check_output_folder

    return check_output_folder(args.out, "--out")


def check_paths(args: argparse.Namespace) -> None:
    """The default check of a sub-command: its input file (if any) and capture folder (if
    any) readable, its ``--out`` folder writable. Runs before anything heavy is imported."""
    name = getattr(args, "input_arg", None)
    if name and getattr(args, name, None) is not None:
        check_input(getattr(args, name), name.upper())
    if getattr(args, "capture", None) is not None:
        check_input(args.capture, "CAPTURE", folder=True)
    check_out(args)


def out_dir(args: argparse.Namespace) -> Path:
    """The ``--out`` folder (checked by :func:`check_out` before the work started)."""
    return check_out(args)


def wrote(*paths) -> int:
    """Print ``wrote PATH, PATH...``; the exit code 0."""
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def metric_line(metrics: dict) -> str:
    """``name value, name value, ...`` of the finite numbers of ``metrics`` (4 significant
    digits), the line a sub-command prints last."""
    items = []
    for k, v in metrics.items():
        if isinstance(v, (int, float)) and not isinstance(v, bool) and v == v:
            items.append(f"{k} {v:.4g}")
    return ", ".join(items)


def timing_line(res) -> str:
    """``fit: 30.2 s wall, 41.0 s CPU (solver 25.1 s)`` of a fit's result (the wall and CPU
    seconds of the whole call, what a ``--time-budget`` bounds, and the solver's share)."""
    return (f"fit: {res.wall_seconds:.1f} s wall, {res.total_cpu_seconds:.1f} s CPU (solver "
            f"{res.seconds:.1f} s)")


def finish(command: str, res, metrics: dict, out: Path) -> int:
    """Print ``geofit COMMAND: status (message); wrote OUT`` and then the metrics; the exit
    code: 0 when the fit ``res`` succeeded, else 1."""
    print(f"geofit {command}: {res.status} ({res.message}); wrote {out}")
    print(f"geofit {command}: {timing_line(res)}")
    print(f"geofit {command}: metrics: {metric_line(metrics)}")
    return 0 if res.ok else 1


def write_json(path: Path, obj) -> None:
    """Write ``obj`` as indented JSON (numpy values and non-finite floats made plain),
    atomically (a temporary file beside it, fsync, then ``os.replace``)."""
    from .._atomic import write_text
    from .._json import json_text  # numpy: imported when a fit has run, not at the CLI's checks

    write_text(Path(path), json_text(obj))


def save_rotation(path: Path, render, n_frames: int, elev: float, azim0: float = 180.0) -> None:
    """Write a GIF of ``n_frames`` views around the origin (distance 2.7, elevation ``elev``,
    azimuths from ``azim0``); ``render(cameras)`` returns their ``(n, H, W, >=3)`` images."""
    if n_frames <= 0:
        return
    import numpy as np

    from ..cameras import FoVPerspectiveCameras, look_at_view_transform

    azim = np.linspace(0.0, 360.0, n_frames, endpoint=False) + azim0
    R, T = look_at_view_transform(2.7, elev, azim)
    save_gif(path, render(FoVPerspectiveCameras(R=R, T=T))[..., :3])
