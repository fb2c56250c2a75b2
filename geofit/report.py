"""The report of ``geofit tutorials``: one HTML page and one Markdown page over all workflows.

:func:`write_report` turns the :class:`~geofit.tutorials.StepResult` of every workflow into

* ``report.html`` -- opens in a browser straight from the folder (no server, no network): the
  images and charts are relative links to PNG files next to it; a small script counts, after the
  page has loaded, how many images decoded (``naturalWidth > 0``) and writes the count into the
  element ``#image-check`` (``data-loaded``, ``data-total``, ``data-broken``), so a headless
  browser can check the page;
* ``report.md`` -- the same content in GitHub-flavoured Markdown (images as relative links);
* ``report.json`` -- the numbers, in the layout of geofit's benchmark JSON (``schema``,
  ``benchmark``, ``created``, ``command``, ``machine``, ``config``, ``notes``, ``methods``,
  ``tables``), one entry of ``tables["steps"]`` per workflow.

For each workflow the page shows the targets next to the results, the speed-accuracy chart,
the accuracy and parameter-count tables, the stability table (what happens on bad input) and the
files written (meshes as OBJ, volumes as npz, histories as JSON).
"""
from __future__ import annotations

import datetime as _dt
import html
import math
import os
import platform
import shutil
from collections.abc import Mapping, Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from ._atomic import write_text
from ._json import json_text
from ._threads import cpu_count, get_num_threads

__all__ = ["SCHEMA", "ReportFiles", "format_value", "load_average", "machine_summary",
           "markdown_table", "package_version", "write_gallery", "write_report"]

#: The JSON layout shared with ``benchmarks/_harness.py``.
SCHEMA = "geofit-benchmark/1"

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;
max-width:1200px;padding:0 1em;color:#222;line-height:1.4}
h1{margin-bottom:.2em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .5em;text-align:left;vertical-align:top}
th{background:#f3f3f3}td.num{text-align:right;font-variant-numeric:tabular-nums}
img{max-width:100%;height:auto;border:1px solid #ddd}
figure{margin:.8em 0}figcaption{font-size:.85em;color:#555}
.failed{color:#b00;font-weight:bold}.ok{color:#070;font-weight:bold}
.meta{color:#555;font-size:.9em}code{background:#f5f5f5;padding:0 .2em}
#image-check{font-size:.85em;color:#555}
"""

_SCRIPT = """
window.addEventListener("load", function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (im) { return im.complete && im.naturalWidth > 0; });
  var bad = imgs.filter(function (im) { return !(im.complete && im.naturalWidth > 0); });
  var el = document.getElementById("image-check");
  el.setAttribute("data-loaded", String(ok.length));
  el.setAttribute("data-total", String(imgs.length));
  el.setAttribute("data-broken", bad.map(function (im) {
    return im.getAttribute("src"); }).join(" "));
  el.textContent = ok.length + " of " + imgs.length + " images loaded";
});
"""


class ReportFiles(dict):
    """Paths written by :func:`write_report`: keys ``"html"``, ``"md"`` and ``"json"``."""


# ------------------------------------------------------------------------------------ values
def format_value(v: Any) -> str:
    """Table text of a value: floats to 4 significant digits, ints with separators.

    Examples
    --------
    >>> format_value(0.000123456), format_value(1234567), format_value(None), format_value(0.5)
    ('0.0001235', '1,234,567', '', '0.5')
    """
    if v is None:
        return ""
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,}"
    if isinstance(v, (float, np.floating)):
        x = float(v)
        if math.isnan(x):
            return "nan"
        if math.isinf(x):
            return "inf" if x > 0 else "-inf"
        if x != 0 and (abs(x) >= 1e6 or abs(x) < 1e-4):
            return f"{x:.3e}"
        return f"{x:.4g}"
    return str(v)


def _is_num(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def _columns(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    cols: list[str] = []
    for r in rows:
        for k in r:
            if k not in cols:
                cols.append(k)
    return cols


def markdown_table(rows: Sequence[Mapping[str, Any]], columns: Sequence[str] | None = None) -> str:
    """A GitHub-flavoured Markdown table of dict rows (``|`` escaped, values formatted).

    Examples
    --------
    >>> print(markdown_table([{"a": 1, "b": 0.5}, {"a": 2}]), end="")
    | a | b |
    |---|---|
    | 1 | 0.5 |
    | 2 |  |
    """
    rows = list(rows)
    cols = list(columns) if columns is not None else _columns(rows)
    if not cols:
        return ""

    def cell(x) -> str:
        return format_value(x).replace("|", "\\|").replace("\n", " ")

    lines = ["| " + " | ".join(cell(c) for c in cols) + " |",
             "|" + "|".join("---" for _ in cols) + "|"]
    lines += ["| " + " | ".join(cell(r.get(c)) for c in cols) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _html_table(rows: Sequence[Mapping[str, Any]], columns: Sequence[str] | None = None) -> str:
    rows = list(rows)
    cols = list(columns) if columns is not None else _columns(rows)
    if not cols:
        return ""
    out = ["<table>", "<tr>" + "".join(f"<th>{html.escape(str(c))}</th>" for c in cols) + "</tr>"]
    for r in rows:
        cells = []
        for c in cols:
            v = r.get(c)
            cls = ' class="num"' if _is_num(v) else ""
            text = html.escape(format_value(v))
            if isinstance(v, str) and v.startswith("failed"):
                text = f'<span class="failed">{text}</span>'
            cells.append(f"<td{cls}>{text}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else ``platform.processor()`` or "unknown"."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def package_version(*dists: str) -> str | None:
    """Installed version of the first distribution found among ``dists``, else None."""
    for d in dists:
        try:
            return metadata.version(d)
        except metadata.PackageNotFoundError:
            continue
    return None


def load_average() -> list[float] | None:
    """The 1, 5 and 15 minute load averages (2 decimals), None where the OS has none."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def machine_summary() -> dict[str, Any]:
    """CPU count and model, load average, OS, Python and the numerical stack's versions."""
    return {
        "cpu": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpu_affinity": cpu_count(),
        "geofit_threads": get_num_threads(),
        "load_average_1_5_15min": load_average(),
        "os": platform.platform(),
        "python": platform.python_version(),
        "versions": {k: package_version(*v) for k, v in {
            "geofit": ("geofit",), "numpy": ("numpy",), "scipy": ("scipy",),
            "open3d": ("open3d-cpu", "open3d"), "embreex": ("embreex",), "nlopt": ("nlopt",),
            "matplotlib": ("matplotlib",), "pillow": ("pillow",)}.items()},
    }


# ------------------------------------------------------------------------------------ report
def _rel(path, out: Path) -> str:
    """``path`` relative to ``out`` with forward slashes (for links in the pages)."""
    p = Path(path)
    try:
        rel = p.resolve().relative_to(out.resolve())
    except ValueError:
        rel = Path(os.path.relpath(p.resolve(), out.resolve()))
    return rel.as_posix()


def _step_headline(step) -> dict[str, Any]:
    return {"workflow": step.title, "status": step.status, "seconds": round(step.seconds, 2),
            **{k: v for k, v in (step.headline or {}).items()}}


def write_report(steps: Sequence[Any], out: str | os.PathLike, *, title: str = "geofit tutorials",
                 command: str = "", size: str = "", seconds: float | None = None,
                 charts: Mapping[str, Any] | None = None,
                 machine: Mapping[str, Any] | None = None,
                 notes: Sequence[str] = ()) -> ReportFiles:
    """Write ``report.html``, ``report.md`` and ``report.json`` into ``out``.

    Parameters
    ----------
    steps : sequence of StepResult
        One per workflow (see :class:`geofit.tutorials.StepResult`); failed steps are listed
        with their message.
    out : path
        Output folder; every image a step refers to should lie inside it (links are relative).
    title : str
        Page title.
    command : str
        The command line that made the report (shown at the top).
    size : str
        ``"tiny"``, ``"default"`` or ``"full"``.
    seconds : float, optional
        Total wall time.
    charts : dict str -> path, optional
        Charts over all workflows (e.g. the parameter counts), shown after the summary.
    machine : dict, optional
        Machine facts (default :func:`machine_summary`).
    notes : sequence of str
        Sentences shown under the summary.

    Returns
    -------
    ReportFiles
        ``{"html": Path, "md": Path, "json": Path}``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    machine = dict(machine) if machine is not None else machine_summary()
    charts = dict(charts or {})
    created = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    load = machine.get("load_average_1_5_15min")
    meta = (f"size <code>{html.escape(size)}</code>; {machine.get('cpu_count')} CPU(s) "
            f"({html.escape(str(machine.get('cpu')))}); load average (1/5/15 min) when written: "
            f"{load}; created {created}"
            + (f"; total wall time {seconds:.1f} s" if seconds is not None else ""))
    summary_rows = [_step_headline(s) for s in steps]

    # ---- HTML
    h: list[str] = ["<!doctype html>", '<html lang="en"><head><meta charset="utf-8">',
                    '<meta name="viewport" content="width=device-width, initial-scale=1">',
                    f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>",
                    f"<h1>{html.escape(title)}</h1>"]
    if command:
        h.append(f'<p class="meta">Made by <code>{html.escape(command)}</code></p>')
    h.append(f'<p class="meta">{meta}</p>')
    h.append('<p id="image-check" data-loaded="" data-total="" data-broken="">'
             "images not checked yet (needs JavaScript)</p>")
    h.append("<h2>Summary</h2>")
    h.append(_html_table(summary_rows))
    for n in notes:
        h.append(f"<p>{html.escape(n)}</p>")
    for label, p in charts.items():
        h.append(f'<figure><img src="{html.escape(_rel(p, out))}" alt="{html.escape(label)}">'
                 f"<figcaption>{html.escape(label)}</figcaption></figure>")
    for s in steps:  # workflows
        h.append(f'<h2 id="{html.escape(s.name)}">{html.escape(s.title)}</h2>')
        cls = "ok" if s.ok else "failed"
        h.append(f'<p>PyTorch3D tutorial: <code>{html.escape(s.tutorial)}</code>. Status: '
                 f'<span class="{cls}">{html.escape(s.status)}</span>; '
                 f"{s.seconds:.1f} s wall time.</p>")
        if s.description:
            h.append(f"<p>{html.escape(s.description)}</p>")
        if s.config:
            h.append("<p class=\"meta\">Settings: " + html.escape(
                "; ".join(f"{k} = {format_value(v)}" for k, v in s.config.items())) + "</p>")
        if s.comparison is not None:
            h.append(f'<figure><img src="{html.escape(_rel(s.comparison, out))}" '
                     f'alt="{html.escape(s.title)}: targets and results">'
                     f"<figcaption>{html.escape(s.comparison_caption)}</figcaption></figure>")
        for label, p in s.charts.items():
            h.append(f'<figure><img src="{html.escape(_rel(p, out))}" alt="{html.escape(label)}">'
                     f"<figcaption>{html.escape(label)}</figcaption></figure>")
        if s.metrics:
            h.append("<h3>Accuracy and time</h3>")
            h.append(_html_table(s.metrics))
        if s.param_counts:
            h.append("<h3>Model size</h3>")
            h.append(_html_table(s.param_counts))
        if s.stability:
            h.append("<h3>Stability (where it breaks)</h3>")
            h.append(_html_table(s.stability))
        if s.notes:
            h.append("<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in s.notes) + "</ul>")
        files = {**s.images, **s.targets, **s.files}
        if files:
            h.append("<p class=\"meta\">Files: " + ", ".join(
                f'<a href="{html.escape(_rel(p, out))}">{html.escape(_rel(p, out))}</a>'
                for p in files.values()) + "</p>")
    h.append(f"<script>{_SCRIPT}</script></body></html>")
    html_path = out / "report.html"
    write_text(html_path, "\n".join(h) + "\n")

    # ---- Markdown
    m: list[str] = [f"# {title}", ""]
    if command:
        m += [f"Made by `{command}`", ""]
    m += [meta.replace("<code>", "`").replace("</code>", "`"), "", "## Summary", "",
          markdown_table(summary_rows)]
    m += [n + "\n" for n in notes]
    for label, p in charts.items():
        m += [f"![{label}]({_rel(p, out)})", ""]
    for s in steps:  # workflows
        m += [f"## {s.title}", "",
              (f"PyTorch3D tutorial: `{s.tutorial}`. Status: **{s.status}**; "
              f"{s.seconds:.1f} s wall time."), ""]
        if s.description:
            m += [s.description, ""]
        if s.config:
            m += ["Settings: " + "; ".join(f"{k} = {format_value(v)}"
                                           for k, v in s.config.items()), ""]
        if s.comparison is not None:
            m += [f"![{s.title}: targets and results]({_rel(s.comparison, out)})", "",
                  f"*{s.comparison_caption}*", ""]
        for label, p in s.charts.items():
            m += [f"![{label}]({_rel(p, out)})", "", f"*{label}*", ""]
        for head, rows in (("Accuracy and time", s.metrics), ("Model size", s.param_counts),
                           ("Stability (where it breaks)", s.stability)):
            if rows:
                m += [f"### {head}", "", markdown_table(rows)]
        if s.notes:
            m += [f"- {n}" for n in s.notes] + [""]
        files = {**s.images, **s.targets, **s.files}
        if files:
            m += ["Files: " + ", ".join(f"[{_rel(p, out)}]({_rel(p, out)})"
                                        for p in files.values()), ""]
    md_path = out / "report.md"
    write_text(md_path, "\n".join(m) + "\n")

    # ---- JSON (the benchmark layout)
    data = {
        "schema": SCHEMA, "benchmark": "tutorials", "created": created, "command": command,
        "machine": machine, "config": {"size": size, "total_seconds": seconds},
        "notes": list(notes),
        "methods": [m_ for s in steps for m_ in s.method_records()],
        "tables": {"steps": [s.to_dict(out) for s in steps]},
    }
    json_path = out / "report.json"
    write_text(json_path, json_text(data))
    return ReportFiles(html=html_path, md=md_path, json=json_path)


def write_gallery(steps: Sequence[Any], dest: str | os.PathLike, *, command: str = "",
                  charts: Mapping[str, Any] | None = None, size: str = "",
                  seconds: float | None = None, notes: Sequence[str] = ()) -> list[Path]:
    """Copy the report's figures into ``dest`` under stable names, for the README.

    Per workflow that ran: ``<step>_results.png`` (targets next to results) and
    ``<step>_speed_accuracy.png`` (its first chart); plus each chart of ``charts`` (e.g.
    ``model_sizes.png``, named after its file). ``dest/README.md`` lists them with the command
    that made them, the size, the total time and the machine's load.

    Parameters
    ----------
    steps : sequence of StepResult
    dest : path
        Folder (created); files already there with the same names are replaced.
    command : str
        The command line that made the figures.
    charts : dict str -> path, optional
        Charts over all workflows.
    size : str
        The run size.
    seconds : float, optional
        Total wall time of the run.
    notes : sequence of str
        Sentences listed under the command (e.g. which data was used).

    Returns
    -------
    list of Path
        The images written, in the order listed in ``dest/README.md``.
    """
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    written: list[tuple[str, Path]] = []
    for s in steps:  # workflows
        if not s.ok:
            continue
        if s.comparison is not None:
            p = dest / f"{s.name}_results.png"
            shutil.copyfile(s.comparison, p)
            written.append((f"{s.title}: {s.comparison_caption}", p))
        if s.charts:
            label, src = next(iter(s.charts.items()))
            p = dest / f"{s.name}_speed_accuracy.png"
            shutil.copyfile(src, p)
            written.append((f"{s.title}: {label}", p))
    for label, src in dict(charts or {}).items():
        p = dest / Path(src).name
        shutil.copyfile(src, p)
        written.append((label, p))
    load = machine_summary().get("load_average_1_5_15min")
    lines = ["# geofit tutorials: gallery", "",
             f"Made by `{command}` ({size} size"
             + (f", {seconds:.0f} s in all" if seconds is not None else "")
             + f"; {os.cpu_count()} CPUs, load average {load} when written).", ""]
    lines += [f"{n}\n" for n in notes]
    for label, p in written:
        lines += [f"![{label}]({p.name})", "", f"*{label}*", ""]
    write_text(dest / "README.md", "\n".join(lines))
    return [p for _, p in written]
