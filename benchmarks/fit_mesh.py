"""Speed-accuracy benchmark of ``geofit.fit.fit_mesh`` on the deform tutorial, and a stability table.

Accuracy against solver wall time, one curve per method (the tutorial's SGD recipe, Adam, scipy
L-BFGS, nlopt L-BFGS, large steps, coarse-to-fine), on the tutorial's dolphin (set
``GEOFIT_DATA=/path/to/data``; without it, geofit's procedural stand-in). Accuracy is
:mod:`geofit.metrics` in the target's normalised frame: chamfer-L2 (sum of the two mean squared
exact point-to-surface distances) and F-score at 0.01, from 100 000 seeded samples a side.
Metric checkpoints are computed with the solver's clock paused, so the times are the solver's own.

Then each method is driven into its failure modes (noisy target, target with holes, a genus-1
target, a degenerate start, a step 100 times too large, a NaN in the target) and the outcome is
tabulated.

Writes ``fit_mesh.json``, ``fit_mesh.png``, ``fit_mesh_stability.json`` and
``fit_mesh_stability.md`` into ``--out`` (default ``benchmarks/results``; ``--quick`` runs
CI-sized versions and writes into a temporary folder unless ``--out`` is given).

    GEOFIT_DATA=/work/shared/data python benchmarks/fit_mesh.py
    python benchmarks/fit_mesh.py --quick
"""
from __future__ import annotations

import tempfile
import time
import traceback
from pathlib import Path

import numpy as np
from _harness import (
    BenchmarkReport,
    MethodRun,
    load_runs,
    markdown_table,
    parser,
    plot_accuracy_vs_time,
)

from geofit import Mesh
from geofit.fit import CoarseToFine, fit_mesh
from geofit.metrics import MeshEvaluator
from geofit.tutorials.stability import MESH_MODES, fit_mesh_scenario

# PyTorch3D's own tutorial run, as stated in the acceptance text (PyTorch3D 0.7.9, CPU,
# 2 cores, this machine; metrics by geofit.metrics as below). Not re-measured by this script.
PYTORCH3D = {"label": "PyTorch3D tutorial (268 s)", "seconds": 268.0, "chamfer_l2": 6.1e-5,
             "fscore@0.01": 0.953, "n_verts": 2562,
             "source": "issue 3 acceptance text: PyTorch3D's deform tutorial, 2000 SGD steps, "
                       "CPU, measured on this 2-core machine; not re-run by this script"}
TIME_LIMIT = PYTORCH3D["seconds"] / 20  # 13.4 s: the acceptance's "1/20 of that time (13 s)"
ACCURACY = {"chamfer_l2": ("<=", PYTORCH3D["chamfer_l2"]),
            "fscore@0.01": (">=", PYTORCH3D["fscore@0.01"])}

#: The runs: fit_mesh keyword arguments of each named run (recipe settings spelled out).
RUNS = {
    "tutorial": {"method": "sgd"},                                   # recipe="tutorial"
    "adam": {"method": "adam", "lr": 0.01},
    "scipy-lbfgs": {"method": "lbfgs", "large_steps": None},
    "nlopt-lbfgs": {"method": "lbfgs-nlopt", "large_steps": None},
    "large-steps": {"method": "lbfgs", "large_steps": 10.0},         # recipe="default"
    "coarse-to-fine": {"method": "lbfgs", "large_steps": 10.0,       # recipe="coarse-to-fine"
                       "coarse_to_fine": True},
}

LABELS = {
    "tutorial": "SGD, tutorial recipe (ico4, lr 1, momentum 0.9)",
    "adam": "Adam lr 0.01 (ico4, tutorial objective)",
    "scipy-lbfgs": "scipy L-BFGS-B (ico4, exact distances)",
    "nlopt-lbfgs": "nlopt LD_LBFGS (ico4, exact distances)",
    "large-steps": "large steps + scipy L-BFGS (ico4)",
    "coarse-to-fine": "coarse-to-fine + large steps + L-BFGS (ico2->)",
}


def load_target():
    from geofit.data import load_target_mesh

    data = load_target_mesh()
    return data.mesh, data.name, None if data.path is None else str(data.path)


# ------------------------------------------------------------------------------ speed/accuracy
def method_settings(name: str, quick: bool) -> tuple[dict, int]:
    """fit_mesh keyword arguments and the checkpoint interval (evaluations) of a method."""
    kw = dict(RUNS[name])
    stochastic = kw["method"] in ("sgd", "adam")
    every = 100 if stochastic else (5 if name == "coarse-to-fine" else 10)
    if quick:
        if stochastic:
            kw["n_iter"] = 60
            every = 20
        else:
            kw.update(n_iter=15, n_stages=1)
            every = 5
        if name == "coarse-to-fine":
            kw["coarse_to_fine"] = CoarseToFine(max_level=3)
    return kw, every


def run_method(name: str, target: Mesh, evaluator: MeshEvaluator, quick: bool) -> MethodRun:
    kw, every = method_settings(name, quick)
    run = MethodRun(name=name, label=LABELS[name],
                    config={k: (repr(v) if not isinstance(v, (int, float, str, bool)) else v)
                            for k, v in kw.items()} | {"checkpoint_every": every})
    t0 = time.perf_counter()
    res = fit_mesh(target, evaluator=evaluator, checkpoint_every=every, progress=False, **kw)
    wall = time.perf_counter() - t0
    a = res.history.as_arrays()
    for i, s in enumerate(a["checkpoint_seconds"]):
        run.add(s, chamfer_l2=a["metrics"]["chamfer_l2"][i],
                **{"fscore@0.01": a["metrics"]["fscore@0.01"][i]},
                normal_consistency=a["metrics"]["normal_consistency"][i])
    # vertex count at each checkpoint (coarse-to-fine grows)
    steps = a["step"]
    run.curve["n_verts"] = [int(a["n_params"][min(np.searchsorted(steps, st), len(steps) - 1)]
                                // 3) for st in a["checkpoint_step"]]
    m = res.metrics
    reach = run.first_reaching(ACCURACY)
    run.final = {"seconds": res.seconds, "cpu_seconds": res.cpu_seconds,
                 "wall_seconds_including_metrics": wall,
                 "n_verts": res.n_verts, "n_iterations": res.n_iterations,
                 "n_evaluations": res.n_evaluations, "chamfer_l2": m.chamfer_l2,
                 "chamfer_l1": m.chamfer_l1, "fscore@0.01": m.fscore[0.01],
                 "normal_consistency": m.normal_consistency,
                 "seconds_to_pytorch3d_accuracy": reach,
                 "stages": [{k: v for k, v in s.items() if k != "message"} for s in res.stages]}
    run.status, run.message = res.status, res.message
    return run


# ------------------------------------------------------------------------------ stability
MODES = ("noise", "holes", "torus", "degenerate_start", "step_x100", "nan_target")
MODE_TEXT = MESH_MODES  # the scenarios live in geofit.tutorials.stability (shared with the report)


def scenario(mode: str, name: str, target: Mesh, quick: bool):
    """(source, target input, fit_mesh kwargs, reference mesh for scoring) of one cell."""
    kw, _ = method_settings(name, quick)
    if kw["method"] in ("sgd", "adam"):
        kw["n_iter"] = 60 if quick else 500
    return fit_mesh_scenario(mode, target, kw, seed=7)


def run_stability(names, target: Mesh, quick: bool, budget: float) -> list[dict]:
    rows = []
    for name in names:  # methods
        for mode in MODES:  # failure modes
            source, tin, kw, reference = scenario(mode, name, target, quick)
            row = {"method": name, "mode": mode}
            t0 = time.perf_counter()
            try:
                res = fit_mesh(tin, init=source, evaluator=None, progress=False,
                               time_budget=budget, **kw)
            except Exception as exc:  # noqa: BLE001 - the table reports it
                msg = str(exc)
                row.update(outcome=f"failed: {type(exc).__name__}: {msg}", status="failed",
                           message=msg, exception=type(exc).__name__,
                           exception_has_message=bool(msg.strip()), nan_vertices=False,
                           chamfer_l2=None, fscore=None, n_verts=None,
                           seconds=time.perf_counter() - t0)
                if not msg.strip():
                    row["traceback"] = traceback.format_exc()
                rows.append(row)
                print(f"  {name:15s} {mode:17s} {row['outcome'][:90]}", flush=True)
                continue
            nan = bool(np.isnan(res.mesh.verts).any())
            m = MeshEvaluator(reference, n_samples=20_000, taus=0.01, normalize=True,
                              seed=0).evaluate(res.mesh)
            outcome = "converged" if res.converged else f"stopped: {res.status}"
            row.update(outcome=outcome, status=res.status, message=res.message,
                       nan_vertices=nan, chamfer_l2=m.chamfer_l2, fscore=m.fscore[0.01],
                       n_verts=res.n_verts, seconds=res.seconds)
            rows.append(row)
            print(f"  {name:15s} {mode:17s} {outcome:22s} cd {m.chamfer_l2:.2e} "
                  f"F {m.fscore[0.01]:.3f} V {res.n_verts} {res.seconds:.1f}s nan={nan}",
                  flush=True)
    return rows


def stability_markdown(rows, names, budget: float) -> str:
    def cell(r):
        if r["status"] == "failed":
            return r["outcome"]
        return (f"{r['outcome']}; cd {r['chamfer_l2']:.1e}, F {r['fscore']:.3f}"
                f"{'; NaN vertices!' if r['nan_vertices'] else ''}")

    by = {(r["method"], r["mode"]): r for r in rows}
    text = ["# fit_mesh stability", "",
            ("Each method (its benchmark recipe; SGD/Adam shortened to 500 steps) on each failure "
            f"mode, with a {budget:g} s time budget. Outcome: `converged`, `stopped: <status>` "
            "(see `geofit.fit.STATUSES`) or `failed: <exception>`; cd = chamfer-L2 and F = "
            "F-score@0.01 in the reference's normalised frame (20 000 samples a side, exact "
            "distances) against the reference surface named below."), ""]
    text += [f"- **{m}**: {MODE_TEXT[m]}" for m in MODES]
    n_nan = sum(bool(r["nan_vertices"]) for r in rows)
    n_silent = sum(r["status"] == "failed" and not r.get("exception_has_message") for r in rows)
    text += ["", (f"NaN vertices in any result: **{'none' if n_nan == 0 else n_nan}**; "
                 f"exceptions without a message: **{'none' if n_silent == 0 else n_silent}**."),
             ""]
    text.append(markdown_table(["method"] + list(MODES),
                               [[n] + [cell(by[(n, m)]) for m in MODES] for n in names]))
    text += ["", "Messages:", ""]
    text.append(markdown_table(["method", "mode", "status", "message"],
                               [[r["method"], r["mode"], r["status"], r["message"][:160]]
                                for r in rows]))
    return "\n".join(text)


def chart(methods, tname: str, path: Path) -> Path:
    """The speed-accuracy chart: chamfer-L2 and F-score@0.01 against solver seconds."""
    import os

    return plot_accuracy_vs_time(
        methods,
        [{"metric": "chamfer_l2", "label": "chamfer-L2 (normalised frame, log)",
          "logy": True, "target": PYTORCH3D["chamfer_l2"],
          "target_label": "PyTorch3D tutorial accuracy"},
         {"metric": "fscore@0.01", "label": "F-score @ 0.01", "logy": False,
          "target": PYTORCH3D["fscore@0.01"]}],
        path,
        title=f"fit_mesh on the {tname}: accuracy vs solver time ({os.cpu_count()} cores)",
        time_limit=TIME_LIMIT,
        reference_points=[{k: PYTORCH3D[k] for k in ("seconds", "chamfer_l2", "fscore@0.01",
                                                     "label")}])


# ------------------------------------------------------------------------------ main
def main(argv=None) -> int:
    p = parser(__doc__.split("\n\n")[0])
    p.add_argument("--methods", default=",".join(LABELS),
                   help=f"comma-separated subset of {','.join(LABELS)}")
    p.add_argument("--no-stability", action="store_true", help="skip the stability table")
    p.add_argument("--stability-only", action="store_true", help="only the stability table")
    p.add_argument("--stability-budget", type=float, default=None,
                   help="seconds per stability run (default 60, quick 5)")
    p.add_argument("--replot", action="store_true",
                   help="only redraw fit_mesh.png from the fit_mesh.json in --out")
    args = p.parse_args(argv)
    if args.replot:
        d, runs = load_runs(Path(args.out) / "fit_mesh.json")
        print(f"wrote {chart(runs, d['config']['target'], Path(args.out) / 'fit_mesh.png')}")
        return 0
    names = [n.strip() for n in args.methods.split(",") if n.strip()]
    for n in names:
        if n not in LABELS:
            p.error(f"--methods: unknown method {n!r}; expected some of {', '.join(LABELS)}")
    out = args.out
    if args.quick and out == p.get_default("out"):
        out = Path(tempfile.mkdtemp(prefix="geofit-bench-"))
    target, tname, tpath = load_target()
    n_metric = 10_000 if args.quick else 100_000
    print(f"target: {tname} ({target.n_verts} vertices) {tpath or ''}")

    if not args.stability_only:
        evaluator = MeshEvaluator(target, n_samples=n_metric, taus=(0.01,), normalize=True,
                                  seed=0)
        report = BenchmarkReport("fit_mesh", config={
            "target": tname, "target_path": tpath, "quick": args.quick,
            "metric": {"n_samples_a_side": n_metric, "tau": 0.01, "frame": "target normalised "
                       "(vertex mean at 0, largest absolute coordinate 1)", "seed": 0,
                       "distances": "exact point-to-surface (geofit.raycast.PointToMeshDistance)"},
            "time_limit_seconds": TIME_LIMIT, "max_verts": PYTORCH3D["n_verts"]})
        report.notes += [
            ("seconds = the solver's wall time on a geofit.fit.Clock that is paused while the "
            "accuracy checkpoints are computed (metric evaluation time excluded); "
            "wall_seconds_including_metrics is the total."),
            ("chamfer_l2 = mean d(pred sample, target)^2 + mean d(target sample, pred)^2; "
            "fscore@0.01 = harmonic mean of the fractions of samples within 0.01 of the other "
            "surface (geofit.metrics)."),
            ("seconds_to_pytorch3d_accuracy = solver time of the first checkpoint with "
            "chamfer_l2 <= 6.1e-5 and fscore@0.01 >= 0.953 (null if never)."),
            ("The machine is shared: machine.load_average_1_5_15min was read when the JSON was "
            "written; other processes running at the same time slow every method."),
        ]
        report.reference = {"pytorch3d_tutorial": PYTORCH3D}
        for name in names:  # methods
            print(f"{name} ...", flush=True)
            run = report.add(run_method(name, target, evaluator, args.quick))
            f = run.final
            reach = f["seconds_to_pytorch3d_accuracy"]
            print(f"  {run.status:10s} solver {f['seconds']:7.2f} s (cpu {f['cpu_seconds']:.2f} s)  "
                  f"V {f['n_verts']:5d}  "
                  f"cd {f['chamfer_l2']:.3e}  F@0.01 {f['fscore@0.01']:.4f}  "
                  f"NC {f['normal_consistency']:.4f}  reaches PyTorch3D accuracy at "
                  f"{'never' if reach is None else f'{reach:.2f} s'}", flush=True)
        ok = [m for m in report.methods
              if m.final["seconds_to_pytorch3d_accuracy"] is not None
              and m.final["n_verts"] <= PYTORCH3D["n_verts"]]
        best = min(ok, key=lambda m: m.final["seconds_to_pytorch3d_accuracy"], default=None)
        acceptance = {
            "criterion": f"chamfer_l2 <= {PYTORCH3D['chamfer_l2']} and fscore@0.01 >= "
                         f"{PYTORCH3D['fscore@0.01']} within {TIME_LIMIT:.1f} s with <= "
                         f"{PYTORCH3D['n_verts']} vertices",
            "best_method": None if best is None else best.name,
            "best_seconds": None if best is None else best.final["seconds_to_pytorch3d_accuracy"],
            "best_n_verts": None if best is None else best.final["n_verts"],
            "passed": bool(best is not None
                           and best.final["seconds_to_pytorch3d_accuracy"] <= TIME_LIMIT),
        }
        report.tables["acceptance"] = acceptance
        path = report.write(Path(out) / "fit_mesh.json")
        png = chart(report.methods, tname, Path(out) / "fit_mesh.png")
        print(f"acceptance: {acceptance}")
        print(f"wrote {path} and {png}")

    if not args.no_stability:
        budget = args.stability_budget or (5.0 if args.quick else 60.0)
        print(f"stability ({budget:g} s per run) ...", flush=True)
        rows = run_stability(names, target, args.quick, budget)
        rep = BenchmarkReport("fit_mesh_stability", config={
            "target": tname, "quick": args.quick, "time_budget_seconds": budget,
            "sgd_adam_steps": 60 if args.quick else 500, "modes": MODE_TEXT,
            "metric": "geofit.metrics, 20000 samples a side, reference's normalised frame"})
        rep.tables["stability"] = rows
        path = rep.write(Path(out) / "fit_mesh_stability.json")
        md = Path(out) / "fit_mesh_stability.md"
        md.write_text(stability_markdown(rows, names, budget), encoding="utf-8")
        bad = [r for r in rows if r["nan_vertices"]
               or (r["status"] == "failed" and not r.get("exception_has_message"))]
        print(f"wrote {path} and {md}; NaN vertices or silent exceptions: {len(bad)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
