"""``geofit demo`` as a newcomer runs it: wall time of the whole command, and its accuracy.

Each run is a fresh ``python -m geofit demo`` process with no ``GEOFIT_DATA`` and an empty user
cache (so the cow comes from the copy installed with geofit, as on a fresh machine without
network), timed from process start to exit: imports, loading the cow, rendering the views, the
fit, the evaluation and writing ``demo.png`` and ``fit.ply`` all count. The runs differ only in
the silhouette time budget (``--time``); the default (30 s) is the one the README's first
command uses, and the acceptance is <= 60 s on 2 cores.

Run from the repository root::

    python benchmarks/demo.py [--quick] [--budgets 10,20,30,45]

Writes ``benchmarks/results/demo.json`` (with a table: budget, fit seconds, the whole command's
wall seconds, accuracy) and ``demo.png`` (held-out IoU, PSNR and chamfer-L2 against the fit's
seconds). ``--replot`` redraws the chart and the table from the JSON.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _harness import (
    BenchmarkReport,
    MethodRun,
    load_runs,
    markdown_table,
    plot_accuracy_vs_time,
    print_machine,
    record_load,
    result_paths,
)
from _harness import parser as base_parser

ROOT = Path(__file__).resolve().parents[1]

# The child prints the demo's result as JSON on its last line (the demo's own lines come first).
CHILD = """
import json, sys
from geofit.cli.demo import run_demo
r = run_demo(sys.argv[1], views=int(sys.argv[2]), size=int(sys.argv[3]),
             time_budget=float(sys.argv[4]))
print(json.dumps({"name": r.name, "metrics": r.metrics, "seconds": r.seconds,
                  "n_verts": r.mesh.n_verts, "status": r.status}))
"""


def run_once(views: int, size: int, budget: float) -> dict:
    """One fresh process of the demo; returns its result and the process's wall seconds."""
    with tempfile.TemporaryDirectory() as tmp:
        env = {k: v for k, v in os.environ.items() if k != "GEOFIT_DATA"}
        env["XDG_CACHE_HOME"] = str(Path(tmp) / "cache")  # empty: nothing downloaded
        env.setdefault("PYTHONPATH", str(ROOT))
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", CHILD, str(Path(tmp) / "out"), str(views),
                              str(size), str(budget)], env=env, capture_output=True, text=True,
                             check=True, cwd=tmp)
        wall = time.perf_counter() - t0
    res = json.loads(out.stdout.strip().splitlines()[-1])
    res["wall"] = wall
    return res


def draw(run: MethodRun, png_path: Path, load: tuple) -> str:
    """The chart (accuracy against the fit's seconds) and the markdown table of the runs."""
    by_fit = MethodRun(run.name, run.label, seconds=list(run.curve["fit_seconds"]),
                       curve={k: v for k, v in run.curve.items()})
    plot_accuracy_vs_time(
        [by_fit], [{"metric": "iou", "label": "held-out silhouette IoU"},
                   {"metric": "psnr", "label": "held-out PSNR (dB)"},
                   {"metric": "chamfer_l2", "label": "chamfer-L2 to the cow", "logy": True}],
        png_path, title=f"geofit demo: accuracy against the fit's seconds, one point per "
                        f"--time budget (load average {load[0]:.1f} -> {load[1]:.1f})")
    c = run.curve
    return markdown_table(
        ["--time (s)", "fit (s)", "whole command (s)", "held-out IoU", "PSNR (dB)",
         "chamfer-L2", "F@0.01"],
        [[f"{b:g}", f"{f:.1f}", f"{w:.1f}", f"{i:.4f}", f"{p:.2f}", f"{ch:.3g}", f"{fs:.3f}"]
         for b, f, w, i, p, ch, fs in zip(c["budget"], c["fit_seconds"], run.seconds, c["iou"],
                                          c["psnr"], c["chamfer_l2"], c["fscore"])])


def main() -> None:
    p = base_parser(__doc__.split("\n\n")[0])
    p.add_argument("--budgets", default="10,20,30,45",
                   help="silhouette time budgets in seconds (comma-separated)")
    p.add_argument("--replot", action="store_true", help="redraw from the JSON, no runs")
    args = p.parse_args()
    json_path, png_path = result_paths(args.out, "demo", args.quick)
    if args.replot:
        d, (run,) = load_runs(json_path)
        table = draw(run, png_path, (d["config"]["loadavg_before"][0],
                                     d["config"]["loadavg_after"][0]))
        d["tables"]["runs"] = table
        json_path.write_text(json.dumps(d, indent=1) + "\n", encoding="utf-8")
        print(table, end="")
        return
    views, size = (6, 32) if args.quick else (20, 128)
    budgets = [2.0] if args.quick else [float(b) for b in args.budgets.split(",")]
    load_before = os.getloadavg()
    report = BenchmarkReport("demo", config={"views": views, "image_size": size,
                                             "budgets": budgets, "heldout": 8})
    report.notes.append("seconds: wall time of a fresh `geofit demo` process (imports, data, "
                        "rendering, fit, evaluation, files); accuracy on the 8 held-out views "
                        "(hard renders) and against the true cow (normalised frame, 20k "
                        "samples a side)")
    run = report.add(MethodRun("demo", f"geofit demo ({views} views of {size} px)"))
    for b in budgets:  # one process per budget
        r = run_once(views, size, b)
        m = r["metrics"]
        run.add(r["wall"], iou=m["iou"], psnr=m["psnr"], chamfer_l2=m["chamfer_l2"],
                fscore=m["fscore@0.01"], fit_seconds=r["seconds"]["fit"], budget=b)
        print(f"budget {b:g} s: wall {r['wall']:.1f} s (fit {r['seconds']['fit']:.1f} s), "
              f"IoU {m['iou']:.4f}, PSNR {m['psnr']:.2f} dB, chamfer-L2 {m['chamfer_l2']:.3g}, "
              f"F@0.01 {m['fscore@0.01']:.3f} ({r['name']}, {r['n_verts']} vertices)",
              flush=True)
        run.status = r["status"]
    run.final = {k: v[-1] for k, v in run.curve.items()}
    load_after = record_load(report, load_before)
    print_machine(load_before, load_after)
    report.tables["runs"] = draw(run, png_path, (load_before[0], load_after[0]))
    report.write(json_path)
    print(report.tables["runs"], end="")
    print(f"wrote {json_path} and {png_path}")


if __name__ == "__main__":
    main()
