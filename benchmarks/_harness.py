"""The harness every geofit benchmark shares: timing, machine facts, one JSON schema, one chart.

A benchmark script builds a :class:`BenchmarkReport`, adds one :class:`MethodRun` per method
(a curve of metrics against solver seconds, the final numbers, the status), then calls
:meth:`BenchmarkReport.write` (JSON) and :func:`plot_accuracy_vs_time` (PNG). Conventions:

* ``seconds`` are the method's own wall time on this machine; work done only to *observe* the
  method (metric checkpoints, plotting) is excluded and the report's ``notes`` say so;
* accuracy is measured with :mod:`geofit.metrics`; the JSON states in which frame;
* the JSON is self-describing: ``schema``, ``benchmark``, ``created`` (UTC), ``command`` (the
  script and its arguments: every file in ``results/`` is written by a script of
  ``benchmarks/``, a rerun is a new file or a flag of the script, never a hand-merged entry),
  ``machine``, ``load`` (1/5/15-minute load averages when the report was made and when it was
  written: the 2 cores are shared, and times under load are upper bounds), ``config``,
  ``notes``, ``reference`` (numbers measured elsewhere, with their source), ``methods`` and
  optional ``tables``.

Run benchmarks from the repository root, e.g. ``python benchmarks/fit_mesh.py [--quick]``.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from geofit._json import json_safe  # layer 0, allowed to benchmarks (docs/architecture.md)
from geofit.report import load_average, machine_summary, package_version
from geofit.viz import STYLE, chart_style
from geofit.viz import plot_accuracy_vs_time as _plot_accuracy_vs_time

SCHEMA = "geofit-benchmark/1"
RESULTS_DIR = Path(__file__).resolve().parent / "results"

__all__ = [
    "RESULTS_DIR",
    "add_shape_options",
    "SCHEMA",
    "STYLE",
    "BenchmarkReport",
    "MethodRun",
    "chart_style",
    "json_safe",
    "load_runs",
    "machine_info",
    "markdown_table",
    "names_option",
    "output_dir",
    "parser",
    "plot_accuracy_vs_time",
    "print_machine",
    "print_parity",
    "record_load",
    "result_paths",
    "shape_datasets",
    "time_call",
]


# ---------------------------------------------------------------------------------------- facts
def machine_info() -> dict[str, Any]:
    """CPU, core count, memory, OS, Python and the versions of the numerical stack.

    :func:`geofit.report.machine_summary` (CPU model and count, affinity, geofit's thread
    count, load, OS, Python, versions) plus the memory and trimesh's version.
    """
    try:
        mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 ** 30
    except (ValueError, OSError, AttributeError):
        mem = None
    info = machine_summary()  # other processes share the cores: read times with its load
    info["memory_gib"] = round(mem, 1) if mem else None
    info["versions"]["trimesh"] = package_version("trimesh")
    return info


def record_load(report: BenchmarkReport, load_before: Sequence[float]) -> tuple[float, ...]:
    """Store the load averages before (given) and after (now) the timings in ``report.config``
    (``loadavg_before``, ``loadavg_after``); returns the one after."""
    load_after = os.getloadavg()
    report.config["loadavg_before"] = list(load_before)
    report.config["loadavg_after"] = list(load_after)
    return load_after


def result_paths(out: str | Path, name: str, quick: bool) -> tuple[Path, Path]:
    """``out/<name>[_quick].json`` and ``.png``."""
    stem = f"{name}_quick" if quick else name
    return Path(out) / f"{stem}.json", Path(out) / f"{stem}.png"


def print_machine(load_before: Sequence[float], load_after: Sequence[float]) -> None:
    """One line: the CPU, the usable cores and the 1-minute load before and after."""
    mi = machine_info()
    print(f"machine: {mi['cpu']} ({mi['cpu_affinity']} cores usable); load average before "
          f"{load_before[0]:.2f}, after {load_after[0]:.2f}")


def print_parity(report: BenchmarkReport, title: str) -> None:
    """Print ``report.tables["parity"]`` and ``["parity_worst"]`` under ``title``, if present."""
    if "parity" in report.tables:
        print(title)
        print(report.tables["parity"], end="")
        print("worst:", report.tables["parity_worst"])


def time_call(fn: Callable[[], Any], *, repeat: int = 1) -> tuple[Any, float]:
    """Run ``fn`` ``repeat`` times; return its last result and the best wall time (s)."""
    best = np.inf
    out = None
    for _ in range(max(int(repeat), 1)):  # repetitions
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return out, float(best)


# ---------------------------------------------------------------------------------------- data
@dataclass
class MethodRun:
    """One method's run: a curve against solver seconds and its final numbers.

    Attributes
    ----------
    name : str
        Short key (``"sgd"``, ``"lbfgs"``).
    label, seconds, curve
        As :class:`geofit.viz.Series` (``seconds``: solver time at each checkpoint).
    final : dict
        Final metrics and sizes (``n_verts``, ...).
    status, message : str
        How the method ended.
    config : dict
        Its settings.
    """

    name: str
    label: str
    seconds: list = field(default_factory=list)
    curve: dict = field(default_factory=dict)
    final: dict = field(default_factory=dict)
    status: str = ""
    message: str = ""
    config: dict = field(default_factory=dict)

    def add(self, seconds: float, **metrics: float) -> None:
        """Append a checkpoint."""
        self.seconds.append(float(seconds))
        for k, v in metrics.items():
            self.curve.setdefault(k, []).append(float(v))

    def first_reaching(self, criteria: Mapping[str, tuple[str, float]]) -> float | None:
        """Seconds of the first checkpoint meeting all ``{metric: ("<=" | ">=", value)}``."""
        for i, s in enumerate(self.seconds):
            ok = True
            for k, (op, v) in criteria.items():
                x = self.curve[k][i]
                ok &= (x <= v) if op == "<=" else (x >= v)
            if ok:
                return s
        return None

    def to_dict(self) -> dict:
        return {"name": self.name, "label": self.label, "status": self.status,
                "message": self.message, "config": self.config, "final": self.final,
                "curve": {"seconds": self.seconds, **self.curve}}


@dataclass
class BenchmarkReport:
    """Everything one benchmark writes to JSON."""

    benchmark: str
    config: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    reference: dict = field(default_factory=dict)
    methods: list = field(default_factory=list)
    tables: dict = field(default_factory=dict)
    command: str = field(default_factory=lambda: " ".join([Path(sys.executable).name]
                                                          + sys.argv))
    load_at_start: list = field(default_factory=lambda: load_average())

    def add(self, run: MethodRun) -> MethodRun:
        self.methods.append(run)
        return run

    def to_dict(self) -> dict:
        return json_safe({
            "schema": SCHEMA,
            "benchmark": self.benchmark,
            "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            "command": self.command,
            "machine": machine_info(),
            "load": {"at_start": self.load_at_start, "at_write": load_average()},
            "config": self.config,
            "notes": self.notes,
            "reference": self.reference,
            "methods": [m.to_dict() for m in self.methods],
            "tables": self.tables,
        })

    def write(self, path: str | Path) -> Path:
        """Write the JSON (indented, sorted keys off: the order above is the reading order)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.to_dict(), indent=1) + "\n", encoding="utf-8")
        return path


# ---------------------------------------------------------------------------------------- chart
# One chart style for every benchmark and for `geofit tutorials`: both draw with geofit.viz
# (STYLE, chart_style() for other figures, the accuracy-vs-time chart below).
def plot_accuracy_vs_time(methods: Sequence[MethodRun], panels: Sequence[Mapping[str, Any]],
                          path: str | Path, *, title: str = "",
                          time_limit: float | None = None,
                          reference_points: Iterable[Mapping[str, Any]] = ()) -> Path:
    """One figure, one panel per metric, one curve per method, accuracy against seconds.

    Parameters
    ----------
    methods : sequence of MethodRun
        The curves.
    panels : sequence of dict
        Per panel: ``metric`` (key in ``MethodRun.curve``), ``label`` (y-axis text),
        ``logy`` (bool), optional ``target`` (a horizontal line: the accuracy to reach) and
        ``target_label``.
    path : str or Path
        PNG to write.
    title : str
        Figure title.
    time_limit : float, optional
        A vertical dashed line (e.g. the time budget of an acceptance criterion).
    reference_points : iterable of dict
        Single measurements to mark: ``seconds``, ``label`` and one value per panel metric.

    Returns
    -------
    Path
    """
    return _plot_accuracy_vs_time(methods, panels, path, title=title, time_limit=time_limit,
                                  reference_points=reference_points)


def chart_with_images(path: str | Path, draw_chart: Callable[[Any], None],
                      images: Mapping[str, np.ndarray], *, chart_width: float = 1.0) -> Path:
    """Write one PNG: a chart on the left, drawn by ``draw_chart(ax)``, and ``images``
    (title -> ``(H, W, 3)`` in [0, 1]) beside it; returns ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n = len(images)
    fig, axes = plt.subplots(1, 1 + n, figsize=(4.2 * (chart_width + n), 4.2),
                             gridspec_kw={"width_ratios": [chart_width] + [1] * n})
    draw_chart(axes[0])
    for ax, (title, img) in zip(axes[1:], images.items()):
        ax.imshow(np.clip(img, 0, 1))
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def load_runs(path: str | Path) -> tuple[dict, list[MethodRun]]:
    """Read a benchmark JSON back: the dict and its methods as :class:`MethodRun` (to re-plot)."""
    d = json.loads(Path(path).read_text(encoding="utf-8"))
    runs = []
    for m in d["methods"]:
        curve = dict(m["curve"])
        seconds = curve.pop("seconds")
        runs.append(MethodRun(name=m["name"], label=m["label"], seconds=seconds, curve=curve,
                              final=m["final"], status=m["status"], message=m["message"],
                              config=m["config"]))
    return d, runs


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """A GitHub-flavoured markdown table (cells converted with ``str``; ``|`` escaped)."""
    def cell(x):
        return str(x).replace("|", "\\|").replace("\n", " ")

    lines = ["| " + " | ".join(cell(h) for h in header) + " |",
             "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(cell(c) for c in r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def parser(description: str, *, reference: Path | None = None) -> argparse.ArgumentParser:
    """The common command line: ``--quick`` (CI-sized) and ``--out DIR``; with a default
    ``reference`` file also the renderers' ``--image-size``, ``--repeat`` and ``--reference``."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--quick", action="store_true",
                   help="reduced sizes for CI (numbers not comparable to the full run)")
    p.add_argument("--out", type=Path, default=RESULTS_DIR,
                   help=f"directory for the JSON and PNG (default {RESULTS_DIR})")
    if reference is not None:
        p.add_argument("--image-size", type=int, default=512)
        p.add_argument("--repeat", type=int, default=5)
        p.add_argument("--reference", type=Path, default=reference)
    return p


def names_option(p: argparse.ArgumentParser, option: str, value: str, allowed: Sequence[str],
                 what: str) -> list[str]:
    """The comma-separated names given to ``--option`` (``value``), each one of ``allowed``;
    ``p.error`` names the first unknown ``what`` otherwise."""
    names = [n.strip() for n in value.split(",") if n.strip()]
    for n in names:
        if n not in allowed:
            p.error(f"--{option}: unknown {what} {n!r}; expected some of {', '.join(allowed)}")
    return names


def output_dir(p: argparse.ArgumentParser, args: argparse.Namespace) -> Path:
    """``--out``; under ``--quick`` without an ``--out`` of its own, a fresh temporary folder
    (a CI-sized run writes nothing into ``results/``)."""
    out = Path(args.out)
    if args.quick and out == p.get_default("out"):
        out = Path(tempfile.mkdtemp(prefix="geofit-bench-"))
    return out


def add_shape_options(p: argparse.ArgumentParser, stem: str) -> argparse.ArgumentParser:
    """The stability tables' test-shape options: ``--shapes-only`` (the table ``stem`` writes
    to ``{stem}_stability_shapes.{json,md}``), ``--shapes``, ``--shape-views`` and
    ``--shape-image-size`` (see :func:`shape_datasets`)."""
    from geofit.tutorials.stability import STABILITY_SHAPES

    p.add_argument("--shapes-only", action="store_true",
                   help=f"only the stability cases on the test shapes, written to "
                        f"{stem}_stability_shapes.{{json,md}} (the cow's table is kept)")
    default = ",".join(STABILITY_SHAPES)
    p.add_argument("--shapes", default=default,
                   help="test shapes the stability cases also run on (geofit.shapes.TEST_SHAPES "
                        "keys or $GEOFIT_DATA/shapes/<name>.obj stems, comma separated; '' for "
                        f"none; default {default})")
    p.add_argument("--shape-views", type=int, default=20,
                   help="training views of each test shape (default 20)")
    p.add_argument("--shape-image-size", type=int, default=64,
                   help="image size of the test shapes' views (default 64)")
    return p


def shape_datasets(args: argparse.Namespace):
    """For each of ``args.shapes``: ``(name, dataset, config)``, the dataset from
    :func:`geofit.tutorials.stability.shape_views` (8 views of 32 px under ``--quick``), or
    None with ``config["skipped"]`` saying why (a data file that is not there)."""
    from geofit.tutorials.stability import shape_views

    for name in [n.strip() for n in args.shapes.split(",") if n.strip()]:  # shapes
        try:
            data = shape_views(name, num_views=8 if args.quick else args.shape_views,
                               image_size=32 if args.quick else args.shape_image_size,
                               num_held_out=4 if args.quick else 8)
        except ValueError as exc:
            print(f"stability {name}: skipped ({exc})", flush=True)
            yield name, None, {"skipped": str(exc)}
            continue
        yield name, data, {"views": len(data), "image_size": data.images.shape[1],
                           "held_out_views": len(data.held_out),
                           "n_verts": data.mesh.n_verts, "n_faces": data.mesh.n_faces}


def parse_args(p: argparse.ArgumentParser, **quick) -> argparse.Namespace:
    """``p.parse_args()``, with the ``quick`` values (option name -> value) replacing the
    given ones under ``--quick``."""
    args = p.parse_args()
    if args.quick:
        for name, value in quick.items():
            setattr(args, name, value)
    return args


def rows_parser(description: str, modes: Sequence[str], rows: Path) -> argparse.ArgumentParser:
    """The parser of a per-shape diagnostic script that appends JSON rows to a file and writes
    its table from them: ``MODE SHAPE... [--options JSON] [--tag T] [--rows PATH]``."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("mode", choices=tuple(modes))
    p.add_argument("shapes", nargs="*")
    p.add_argument("--options", default="{}", help="ViewsFitOptions fields as JSON")
    p.add_argument("--tag", default="")
    p.add_argument("--rows", type=Path, default=rows)
    return p


def append_row(path: str | Path, row: Mapping[str, Any]) -> None:
    """One JSON line appended to ``path`` (the rows a diagnostic script's table is written from)."""
    with open(path, "a") as f:
        f.write(json.dumps(row) + "\n")
