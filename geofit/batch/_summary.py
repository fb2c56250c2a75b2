"""The summary files of a batch: summary.json, summary.csv, summary.png and index.html."""
from __future__ import annotations

import html
from pathlib import Path

from ..viz import chart_style
from ._options import ACCURACY
from ._tasks import atomic_write, write_json

SUMMARY_FILES = ("summary.json", "summary.csv", "summary.png", "index.html")


def write_summary(result) -> list[Path]:
    """Write the four summary files of a :class:`~geofit.batch.BatchResult` into its ``out``.

    ``summary.png`` plots the task's accuracy (:data:`geofit.batch.ACCURACY`) against each
    target's seconds, one labelled point per succeeded target; ``index.html`` is a table with
    each target's status, accuracy, time and picture. All are written atomically.
    """
    out = Path(result.out)
    paths = [write_json(out / "summary.json", result.to_dict()), result.to_csv(out / "summary.csv"),
             _plot(result, out / "summary.png"), _html(result, out / "index.html")]
    return paths


def _plot(result, path: Path) -> Path:
    from matplotlib.figure import Figure  # kept local: matplotlib, loaded only when used (start-up)

    label = ACCURACY[result.task][1]
    ok = [r for r in result.rows if r.ok and r.accuracy >= 0]
    with chart_style():
        fig = Figure(figsize=(6.4, 4.2), dpi=120)
        ax = fig.add_subplot()
        ax.scatter([r.seconds for r in ok], [r.accuracy for r in ok], s=28, zorder=3)
        for r in ok:
            ax.annotate(r.name, (r.seconds, r.accuracy), textcoords="offset points",
                        xytext=(4, 3), fontsize=7)
        ax.set_xlabel("seconds per target (load, fit, evaluation, writing)")
        ax.set_ylabel(label)
        ax.set_xlim(left=0.0)
        reused = f", {result.n_reused} from earlier runs" if result.n_reused else ""
        ax.set_title(f"geofit batch {result.task}: {result.n_ok} ok, {result.n_failed} failed"
                     f"{reused}; this run {result.seconds:.1f} s wall", fontsize=10)
        failed = [r.name for r in result.rows if not r.ok]
        if failed:
            ax.text(0.01, 0.01, "failed: " + ", ".join(failed[:12])
                    + (" ..." if len(failed) > 12 else ""), transform=ax.transAxes,
                    fontsize=7, color="#b00", va="bottom")
        fig.tight_layout()
        atomic_write(path, lambda p: fig.savefig(p))
    return path


def _where(result) -> str:
    """Which workers computed the results: this run's cluster, and for reused results the
    worker processes recorded in them (never "0 workers" for a rerun that reused all)."""
    e = html.escape
    parts = []
    if result.n_workers:
        parts.append(f"this run {result.seconds:.1f} s wall on {result.n_workers} worker(s) x "
                     f"{result.threads_per_worker} thread(s) ({e(result.scheduler)})")
    else:
        parts.append(f"this run {result.seconds:.1f} s wall, no target to compute")
    parts.append(f"the results computed by {result.n_result_workers} worker process(es)")
    return "; ".join(parts)


def _html(result, path: Path) -> Path:
    label = ACCURACY[result.task][1]
    e = html.escape
    rows = []
    for r in result.rows:
        pic = (f'<img src="{e(r.picture)}" alt="{e(r.name)}" loading="lazy">'
               if r.picture else "")
        acc = f"{r.accuracy:.4g}" if r.accuracy >= 0 else "&ndash;"
        cls = "ok" if r.ok else "failed"
        files = "".join(f'<div><a href="{e(v)}">{e(k)}</a></div>' for k, v in r.outputs.items()
                        if not k.startswith("view_"))
        rows.append(
            f'<tr class="{cls}"><td><a href="{e(r.name)}/result.json">{e(r.name)}</a>'
            f'<div class="path">{e(r.target)}</div></td><td>{e(r.status)}'
            f'{" (reused)" if r.reused else ""}</td><td>{acc}</td><td>{r.seconds:.2f}</td>'
            f'<td>{r.n_params}</td><td class="msg">{e(r.message)}{files}</td><td>{pic}</td>'
            f'</tr>')
    doc = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>geofit batch {e(result.task)}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 1.5em; color: #222; }}
table {{ border-collapse: collapse; }}
td, th {{ border-bottom: 1px solid #ddd; padding: 0.4em 0.6em; vertical-align: top;
          text-align: left; }}
tr.failed td {{ background: #fdecea; }}
.path, .msg {{ font-size: 0.8em; color: #666; max-width: 28em; word-break: break-all; }}
img {{ max-width: 480px; }}
</style></head><body>
<h1>geofit batch {e(result.task)}</h1>
<p>{len(result.rows)} targets: {result.n_ok} ok, {result.n_failed} failed,
{result.n_reused} reused from an earlier run; {_where(result)}.</p>
{"".join(f"<p class='msg'>note: {e(n)}</p>" for n in result.notes)}
<p><img src="summary.png" alt="accuracy against seconds"></p>
<p><a href="summary.csv">summary.csv</a> &middot; <a href="summary.json">summary.json</a></p>
<table><thead><tr><th>target</th><th>status</th><th>{e(label)}</th><th>seconds</th>
<th>parameters</th><th>message</th><th>picture</th></tr></thead>
<tbody>
{chr(10).join(rows)}
</tbody></table>
</body></html>
"""
    return atomic_write(path, lambda p: p.write_text(doc, encoding="utf-8"))
