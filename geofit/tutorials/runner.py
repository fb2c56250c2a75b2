"""Running the steps: :func:`run_step`, :func:`run_tutorials` (all steps, then the report)."""
from __future__ import annotations

import json
import time
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path

from .._atomic import write_text
from .._validate import check_choice
from ..data import data_dir, find
from ..report import write_gallery, write_report
from ..viz import plot_model_sizes
from .fit_mesh import step_fit_mesh
from .fit_views import step_fit_views
from .fit_volume import step_fit_volume
from .nerf import step_nerf
from .render_mesh import step_render_mesh
from .render_points import BRIDGE_FILE, step_render_points
from .shared import (
    GEOFIT_COLUMN,
    P3D_COLUMN,
    SIZES,
    STEP_TITLES,
    StepResult,
    TutorialsRun,
    failure_text,
)

__all__ = ["STEPS", "run_step", "run_tutorials"]


# --------------------------------------------------------------------------------------------
# The runner
# --------------------------------------------------------------------------------------------

#: The steps in order: name -> (function, title, PyTorch3D tutorial).
STEPS: dict[str, tuple[Callable[..., StepResult], str, str]] = {
    name: (fn, *STEP_TITLES[name]) for name, fn in (
        ("fit_mesh", step_fit_mesh), ("render_mesh", step_render_mesh),
        ("render_points", step_render_points), ("fit_views", step_fit_views),
        ("fit_volume", step_fit_volume), ("nerf", step_nerf))}


def run_step(name: str, out, size: str = "default", *, progress: bool = True,
             seed: int = 0) -> StepResult:
    """Run one step; an exception becomes a ``"failed: ..."`` result (traceback in error.txt).

    Parameters
    ----------
    name : str
        A key of :data:`STEPS` (the step writes into ``out/<name>``).
    out : path
        The run's output folder.
    size : {"tiny", "default", "full"}
        Problem sizes: a smoke test, the default run (minutes) or the tutorials' own sizes.
    progress : bool
        Show tqdm progress bars.
    seed : int
        Seed of the step's random sampling.

    Returns
    -------
    StepResult
        Never raises for a failure inside the step.

    Raises
    ------
    ValueError
        For an unknown step name or size.
    """
    check_choice(name, "name", tuple(STEPS))
    check_choice(size, "size", SIZES)
    fn, title, tutorial = STEPS[name]
    t0 = time.perf_counter()
    try:
        return fn(out, size, progress=progress, seed=seed)
    except Exception as exc:  # noqa: BLE001 - a failed step is reported, never dropped
        d = Path(out) / name
        d.mkdir(parents=True, exist_ok=True)
        write_text(d / "error.txt", traceback.format_exc())
        res = StepResult(name, title, tutorial, status=failure_text(exc), size=size,
                         seconds=time.perf_counter() - t0)
        res.files["traceback"] = d / "error.txt"
        res.headline = {P3D_COLUMN: "", GEOFIT_COLUMN: ""}
        return res


def _size_chart(steps: Sequence[StepResult], path: Path) -> Path | None:
    sizes = {}
    tutorial_labels = []
    for s in steps:  # workflows
        for m in s.methods:
            n = m["final"].get("n_params")
            if not n:
                continue
            label = f"{s.name}: {m['name']}"
            sizes[label] = n
            if m["name"] == "tutorial":
                tutorial_labels.append(label)
    if not sizes:
        return None
    return plot_model_sizes(sizes, path, highlight=tutorial_labels,
                            title="Free parameters of each fitted model\n"
                                  "(orange: PyTorch3D's recipe, blue: geofit's methods)")


def _data_note() -> str:
    """Which tutorial files were found, and where (the data the run used)."""
    instead = {"dolphin/dolphin.obj": "the procedural target used instead",
               "cow_mesh/cow.obj": "the procedural textured mesh used instead",
               BRIDGE_FILE: "the tutorial's cloud not rendered"}
    found = {n: find(n) for n in instead}
    parts = [f"{n} from {p.parent.parent}" if p is not None else f"{n} not found ({instead[n]})"
             for n, p in found.items()]
    return f"Data folder {data_dir()}: " + "; ".join(parts) + "."


def run_tutorials(out, *, size: str = "default", only: Sequence[str] | None = None,
                  progress: bool = True, seed: int = 0, command: str = "",
                  gallery=None) -> TutorialsRun:
    """Run the workflows and write the report.

    Parameters
    ----------
    out : path
        Output folder (created): one sub-folder per step, ``report.html``, ``report.md``,
        ``report.json`` and ``model_sizes.png``.
    size : {"tiny", "default", "full"}
        See the module docstring.
    only : sequence of str, optional
        Step names to run (default all of :data:`STEPS`, in order).
    progress : bool
        tqdm progress bars (on stderr).
    seed : int
        Seed of every random choice.
    command : str
        The command line, shown in the report.
    gallery : path, optional
        Also copy the figures into this folder under stable names, with a README.md (see
        :func:`geofit.report.write_gallery`), e.g. ``docs/tutorials`` for the README.

    Returns
    -------
    TutorialsRun

    Raises
    ------
    ValueError
        For an unknown size or step name.
    """
    check_choice(size, "size", SIZES)
    names = list(STEPS) if only is None else list(only)
    if not names:
        raise ValueError("only: expected at least one step name, got none")
    for n in names:
        check_choice(n, "only", tuple(STEPS))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    steps = []
    bar = None
    if progress:
        from tqdm import tqdm  # kept local: tqdm, loaded only when used (start-up)

        bar = tqdm(total=len(names), desc="geofit tutorials", unit="step", dynamic_ncols=True)
    for n in names:  # workflows
        if bar is not None:
            bar.set_postfix_str(n)
        steps.append(run_step(n, out, size, progress=progress, seed=seed))
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    charts = {}
    chart = _size_chart(steps, out / "model_sizes.png")
    if chart is not None:
        charts["Model size: free parameters of each method's fitted model (log scale)"] = chart
    seconds = time.perf_counter() - t0
    notes = [f"{sum(s.ok for s in steps)} of {len(steps)} workflows ran.", _data_note()]
    failed = [s.name for s in steps if not s.ok]
    if failed:
        notes.append("Failed: " + ", ".join(failed) + " (see each section).")
    report = dict(write_report(steps, out, command=command, size=size, seconds=seconds,
                               charts=charts, notes=notes))
    if gallery is not None:
        report["gallery"] = write_gallery(steps, gallery, command=command, charts=charts,
                                          size=size, seconds=seconds, notes=notes[1:])
    return TutorialsRun(steps, seconds, out, report, charts)


def _load_json(path) -> dict:  # pragma: no cover - convenience for notebooks
    return json.loads(Path(path).read_text(encoding="utf-8"))
