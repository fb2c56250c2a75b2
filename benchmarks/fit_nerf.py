"""Benchmark: fit a neural radiance field to the cow (PyTorch3D's sixth tutorial) on the CPU.

Data: geofit's ``tutorial_views(6)`` (PyTorch3D's ``generate_cow_renders``: 40 views at
elevation 0, 128 px, black background) and
``held_out_views()`` (16 views between the training azimuths, at elevations 0 and 20).

Methods (all geofit, numpy, float32 networks, gradients by hand):

* ``tutorial`` -- the tutorial's network (60 frequencies, 2 x 256 Softplus, 317,188 parameters)
  and recipe (6 views x 750 Monte Carlo rays x 128 samples per step, Adam 1e-3). A short run:
  its seconds per step are extrapolated to the tutorial's 3000 steps;
* ``scene`` -- geofit's scene-sized recipe (:meth:`geofit.fit.nerf.NerfConfig.scene`) within the
  acceptance budget;
* ``scene_w{width}`` -- the same recipe at other widths, for held-out PSNR against parameter
  count.

Each method records held-out PSNR (all 16 views, full images) at checkpoints against solver time
(checkpoint renders are excluded from the solver time and reported separately as wall time).
``--stability`` runs the stress cases (learning rate x10, few views, noisy images, early stopping)
on the cow and on test shapes no one tuned for (``--shapes``, default a torus, an open cylinder
and ``$GEOFIT_DATA/shapes/suzanne.obj``: :func:`geofit.tutorials.stability.shape_views`) and
writes ``fit_nerf_stability.{json,md}``.

Run from the repository root: ``python benchmarks/fit_nerf.py [--quick] [--stability]``;
the stability table alone with shorter budgets:
``nice -n 15 python benchmarks/fit_nerf.py --only-stability --stability-budget 20
--shape-budget 10``; the test shapes' table alone (12 fits of 100 steps,
``fit_nerf_stability_shapes.{json,md}``): ``--shapes-only``.
"""
from __future__ import annotations

import os
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _harness import (BenchmarkReport, MethodRun, add_shape_options, markdown_table, parser,
                      shape_datasets)

from geofit.structures import MultiViewDataset
from geofit.datasets import held_out_views, tutorial_views
from geofit.fit.nerf import NerfConfig, fit_nerf, render_nerf
from geofit.metrics import psnr
from geofit.render.volume.implicit import OccupancyGrid

#: Acceptance criteria of the issue.
TARGET_PSNR = 25.6          # dB, PyTorch3D's voxel volume of tutorial 5 on the same views
TARGET_SECONDS = 15 * 60    # wall seconds on the 2-core machine
#: PyTorch3D's tutorial NeRF on this machine's CPU (from the issue, measured there).
PYTORCH3D_SECONDS_PER_STEP = 13.6


def load_average() -> list[float]:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return []


def run_method(name: str, label: str, config: NerfConfig, train, test, *, time_budget,
               eval_every, seed=0, verbose=True) -> tuple[MethodRun, object]:
    t0, c0 = time.perf_counter(), time.process_time()
    run = MethodRun(name, label, config=asdict(config))
    wall = []
    cpu = []

    def cb(info):
        m = info.metrics
        run.add(info.seconds, psnr=m["psnr"], held_out_loss=m["held_out_loss"],
                loss=info.value, step=info.iteration)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        if verbose:
            print(f"  [{name}] step {info.iteration:5d}  solver {info.seconds:7.1f} s  "
                  f"wall {wall[-1]:7.1f} s  loss {info.value:.4f}  held-out PSNR "
                  f"{m['psnr']:.2f} dB  (load {load_average()[:1]})", flush=True)

    res = fit_nerf(train, options=config, evaluator=test, time_budget=time_budget,
                   eval_every=eval_every, seed=seed, callback=cb, progress=False)
    run.curve["wall_seconds"] = wall
    run.curve["cpu_seconds"] = cpu
    steps = res.n_iterations
    run.status, run.message = res.status, res.message
    reached = run.first_reaching({"psnr": (">=", TARGET_PSNR)})
    run.final = {
        "psnr": res.psnr, "n_params": res.n_params, "samples_per_ray": res.samples_per_ray,
        "steps": steps, "solver_seconds": res.seconds, "wall_seconds": res.wall_seconds,
        "seconds_per_step": res.seconds / max(steps, 1),
        "solver_seconds_to_target": reached,
        "wall_seconds_to_target": (None if reached is None else
                                   wall[run.seconds.index(reached)]),
        "cpu_seconds": time.process_time() - c0,
        "load_average_end": load_average(),
    }
    return run, res


def main(argv=None) -> int:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--budget", type=float, default=None,
                   help="solver seconds of the scene-sized run (default 720; quick: 30)")
    p.add_argument("--stability", action="store_true", help="also run the stability cases")
    p.add_argument("--only-stability", action="store_true", help="only the stability cases")
    p.add_argument("--stability-budget", type=float, default=90.0,
                   help="solver seconds of each stability case on the cow (default 90; 0: "
                        "no cow cases)")
    p.add_argument("--shape-budget", type=float, default=20.0,
                   help="solver seconds of each stability case on a test shape when "
                        "--shape-steps is 0 (default 20)")
    p.add_argument("--shape-steps", type=int, default=100,
                   help="Adam steps of each stability case on a test shape (default 100: the "
                        "same work at any load; 0: --shape-budget seconds instead)")
    add_shape_options(p, "fit_nerf")
    p.add_argument("--replot", action="store_true",
                   help="only redraw fit_nerf.png from the existing fit_nerf.json")
    p.add_argument("--tutorial-steps", type=int, default=3,
                   help="steps of the tutorial-sized network's short run (default 3)")
    p.add_argument("--widths", default="48,96,160",
                   help="widths of the parameter-count sweep (comma separated; '' for none)")
    args = p.parse_args(argv)
    if args.replot:
        _replot(Path(args.out))
        return 0
    quick = args.quick
    budget = args.budget if args.budget is not None else (30.0 if quick else 720.0)
    size = 32 if quick else 128
    out = Path(args.out)
    print(f"load average at start: {load_average()}", flush=True)
    t = time.perf_counter()
    train = test = None  # --shapes-only: no cow
    if not args.shapes_only:
        train = tutorial_views(6, image_size=size, num_held_out=0)
        test = held_out_views(image_size=size)
        print(f"data: {train!r} and {test!r} rendered in {time.perf_counter() - t:.1f} s",
              flush=True)
    if train is not None and train.name != "cow":
        print("warning: the cow was not found (set GEOFIT_DATA); using the stand-in", flush=True)

    if not (args.only_stability or args.shapes_only):
        report = BenchmarkReport("fit_nerf", config={
            "train_views": len(train), "held_out_views": len(test), "image_size": size,
            "held_out_elevations": sorted(set(test.elev.tolist())), "mesh": train.name,
            "scene_budget_seconds": budget, "quick": quick})
        report.notes += [
            ("seconds are solver seconds: the held-out renders at checkpoints are excluded "
             "(wall_seconds in each curve and in final include them; cpu_seconds is the "
             "process CPU time, both threads, checkpoints included)"),
            ("PSNR is over full 128x128 RGB images of the 16 held-out views (black background "
             "included), renders clipped to [0, 1]"),
            ("tutorial: a short run of the tutorial-sized network; seconds per step are "
             "extrapolated to its 3000 steps"),
            f"load average at start: {load_average()} (the 2 cores are shared with other work)",
        ]
        report.reference = {
            "pytorch3d_tutorial_seconds_per_step_cpu": PYTORCH3D_SECONDS_PER_STEP,
            "pytorch3d_tutorial_hours_3000_steps": PYTORCH3D_SECONDS_PER_STEP * 3000 / 3600,
            "source": "issue 8: PyTorch3D 0.7.9 CPU build running the tutorial's network and "
                      "recipe (750 rays x 128 points per image, 6 images per step), measured "
                      "once on this 2-core machine kind; not re-run here (see "
                      "benchmarks/peers/pytorch3d_tutorials.py)",
            "target_psnr_db": TARGET_PSNR, "target_wall_seconds": TARGET_SECONDS,
            "target_source": "PyTorch3D's voxel volume (tutorial 5) held-out PSNR",
        }
        # the tutorial-sized network: a short run, extrapolated. Its held-out renders skip the
        # samples outside the visual hull (the full 128-sample render of 16 views with this
        # network would take longer than the run); after so few steps its density outside the
        # hull is negligible, so the PSNR is that of the field's full render to within noise.
        tut_steps = 2 if quick else max(int(args.tutorial_steps), 1)
        cfg = NerfConfig.tutorial(n_iter=tut_steps)
        if quick:
            cfg = NerfConfig.tutorial(n_iter=tut_steps, n_rays_per_image=100, n_pts_per_ray=32)
        print(f"tutorial network, {tut_steps} steps ...", flush=True)
        t0, c0 = time.perf_counter(), time.process_time()
        res = fit_nerf(train, recipe="tutorial", options=cfg, evaluator=None, seed=0,
                       progress=False)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        hull = OccupancyGrid.from_silhouettes(train.silhouettes, train.cameras,
                                              resolution=96 if not quick else 32).dilate(1)
        imgs = render_nerf(res.field, test.cameras, size, n_pts_per_ray=cfg.n_pts_per_ray,
                           occupancy=hull)
        p_tut = psnr(np.clip(imgs[..., :3], 0, 1), test.images)
        sps = res.seconds / res.n_iterations
        run = MethodRun("tutorial", f"tutorial network ({res.n_params:,} params), "
                        f"{tut_steps} steps", config=asdict(cfg), status=res.status,
                        message=res.message)
        run.add(res.seconds, psnr=p_tut, step=res.n_iterations)
        run.curve["wall_seconds"] = [wall]
        run.final = {
            "psnr": p_tut, "n_params": res.n_params, "samples_per_ray": res.samples_per_ray,
            "steps": res.n_iterations, "solver_seconds": res.seconds, "wall_seconds": wall,
            "seconds_per_step": sps, "solver_seconds_to_target": None,
            "wall_seconds_to_target": None, "load_average_end": load_average(),
            "extrapolated_seconds_3000_steps": sps * 3000,
            "extrapolated_hours_3000_steps": sps * 3000 / 3600,
            "cpu_seconds_per_step": cpu / res.n_iterations,
            "psnr_note": "held-out render restricted to the visual hull (see notes)",
        }
        report.add(run)
        print(f"  tutorial: {sps:.2f} s/step ({cpu / res.n_iterations:.1f} CPU s/step, both "
              f"threads) -> 3000 steps ~ {sps * 3000 / 3600:.2f} h; "
              f"{res.n_params:,} parameters; PSNR after {tut_steps} steps {p_tut:.2f} dB",
              flush=True)

        widths = [int(w) for w in args.widths.split(",") if w.strip()] if not quick else []
        scene_cfgs = [("scene", "scene-sized (default)", NerfConfig.scene(), budget)]
        for w in widths:
            if w == NerfConfig.scene().n_hidden_neurons:
                continue
            scene_cfgs.append((f"scene_w{w}", f"scene-sized, width {w}",
                               NerfConfig.scene(n_hidden_neurons=w,
                                                n_hidden_color=max(w // 2, 8)),
                               budget / 2))
        for name, label, cfg, b in scene_cfgs:
            if quick:
                cfg = NerfConfig.scene(n_rays_per_image=128, n_pts_per_ray=64,
                                       hull_resolution=32)
            print(f"{name}: {cfg.n_hidden_neurons} wide, budget {b:g} s ...", flush=True)
            run, res = run_method(name, label, cfg, train, test, time_budget=b,
                                  eval_every=None)
            run.label = f"{label} ({res.n_params:,} params)"
            report.add(run)
            f = run.final
            print(f"  {name}: {f['psnr']:.2f} dB held-out after {f['solver_seconds']:.0f} s "
                  f"solver / {f['wall_seconds']:.0f} s wall, {f['steps']} steps, "
                  f"{f['n_params']:,} params, {f['samples_per_ray']:.1f} samples/ray; target "
                  f"{TARGET_PSNR} dB reached at {f['solver_seconds_to_target']} s solver / "
                  f"{f['wall_seconds_to_target']} s wall", flush=True)

        rows = []
        for m in report.methods:
            f = m.final
            rows.append([m.name, f"{f['n_params']:,}", f"{f['samples_per_ray']:.1f}",
                         f["steps"], f"{f['seconds_per_step']:.3f}",
                         f"{f['solver_seconds']:.0f}", f"{f['wall_seconds']:.0f}",
                         f"{f['psnr']:.2f}",
                         "-" if f["wall_seconds_to_target"] is None else
                         f"{f['wall_seconds_to_target']:.0f}", m.status])
        header = ["method", "params", "samples/ray", "steps", "s/step", "solver s", "wall s",
                  "held-out PSNR dB", f"wall s to {TARGET_PSNR} dB", "status"]
        report.tables["summary"] = {"header": header, "rows": rows}
        print(markdown_table(header, rows), flush=True)
        report.write(out / "fit_nerf.json")
        _plot(report, out / "fit_nerf.png")
        print(f"wrote {out / 'fit_nerf.json'} and {out / 'fit_nerf.png'}", flush=True)

    if args.stability or args.only_stability or args.shapes_only:
        budget = 0.0 if args.shapes_only else args.stability_budget
        stability(train, test, out, args, budget=min(budget, 5.0) if quick else budget,
                  shape_budget=min(args.shape_budget, 3.0) if quick else args.shape_budget)
    print(f"load average at end: {load_average()}", flush=True)
    return 0


def _replot(out: Path) -> None:
    """Redraw the chart from the JSON written by a full run."""
    import json

    d = json.loads((out / "fit_nerf.json").read_text(encoding="utf-8"))
    report = BenchmarkReport("fit_nerf")
    for m in d["methods"]:
        curve = dict(m["curve"])
        seconds = curve.pop("seconds")
        report.add(MethodRun(m["name"], m["label"], seconds, curve, m["final"], m["status"],
                             m["message"], m["config"]))
    _plot(report, out / "fit_nerf.png")


def _plot(report: BenchmarkReport, path: Path) -> None:
    """PSNR against solver time (log) and final PSNR against parameter count."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6))
    ax = axes[0]
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    vlines = []
    for i, m in enumerate(report.methods):
        c = colors[i % len(colors)]
        ax.plot(np.maximum(m.seconds, 1e-3), m.curve["psnr"], "o-", ms=3, lw=1.3, color=c,
                label=m.label)
        if m.name == "tutorial":
            t = m.final["extrapolated_seconds_3000_steps"]
            ax.axvline(t, color=c, lw=0.8, ls="--")
            text = f"geofit, tutorial network,\n3000 steps (extrapolated, {t / 3600:.0f} h)"
            vlines.append((t, text, c))
    t_pt3d = PYTORCH3D_SECONDS_PER_STEP * 3000
    ax.axvline(t_pt3d, color="gray", lw=0.8, ls="-.")
    vlines.append((t_pt3d, f"PyTorch3D on this CPU,\n3000 steps ({t_pt3d / 3600:.1f} h)",
                   "gray"))
    ax.axvline(TARGET_SECONDS, color="crimson", lw=0.8, ls="--", label="15 min")
    ax.axhline(TARGET_PSNR, color="black", lw=0.8, ls=":",
               label=f"{TARGET_PSNR} dB (tutorial 5's voxel volume)")
    ax.set_xscale("log")
    lo, hi = ax.get_ylim()
    # the two extrapolations can nearly coincide: label the left line on its left and the
    # right one on its right, with room on the axis for the latter
    vlines.sort(key=lambda v: v[0])
    for j, (t, text, c) in enumerate(vlines):
        right = j == len(vlines) - 1 and len(vlines) > 1
        ax.annotate(text, (t, lo + 0.35 * (hi - lo)), color=c, fontsize=7, rotation=90,
                    ha="left" if right else "right", va="bottom")
    if vlines:
        ax.set_xlim(right=vlines[-1][0] * 4.0)
    ax.set_xlabel("solver wall time (s, log)")
    ax.set_ylabel("held-out PSNR (dB)")
    ax.set_title("held-out PSNR against time")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    ax = axes[1]
    for i, m in enumerate(report.methods):
        ax.plot(m.final["n_params"], m.final["psnr"], "o", ms=7, color=colors[i % len(colors)])
        extra = f" ({m.final['steps']} steps)" if m.name == "tutorial" else ""
        ax.annotate(f"{m.name}{extra}\n{m.final['samples_per_ray']:.0f} samples/ray",
                    (m.final["n_params"], m.final["psnr"]), textcoords="offset points",
                    xytext=(6, -4), fontsize=7)
    ax.axhline(TARGET_PSNR, color="black", lw=0.8, ls=":")
    ax.set_xscale("log")
    ax.set_xlabel("network parameters (log)")
    ax.set_ylabel("final held-out PSNR (dB)")
    ax.set_title("PSNR against parameter count (at the end of each run)")
    ax.grid(alpha=0.3)
    fig.suptitle("NeRF on the cow (tutorial 6): geofit in numpy on a 2-core CPU")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _cases(train, base: NerfConfig, *, shape: bool) -> list:
    """The stress cases on ``train``: (name, setting, config, (images, silhouettes, cameras),
    extra fit_nerf arguments). On a test shape: the baseline, lr x100, 4 views and noise."""
    rng = np.random.default_rng(0)
    noisy = np.clip(train.images + rng.normal(0.0, 0.1, train.images.shape), 0.0, 1.0)
    few = np.linspace(0, len(train), 4, endpoint=False).astype(int)

    def with_lr(factor):
        return NerfConfig(**{**asdict(base), "lr": base.lr * factor})

    full = (train.images, train.silhouettes, train.cameras)
    few_views = (train.images[few], train.silhouettes[few], train.cameras[few])
    noisy_views = (noisy, train.silhouettes, train.cameras)
    cases = [
        ("baseline", "scene preset (lr 5e-3)", base, full, {}),
        ("lr_x10", "learning rate x10 (5e-2)", with_lr(10), full, {}),
        ("lr_x100", "learning rate x100 (0.5)", with_lr(100), full, {}),
        ("few_views", "4 training views", base, few_views, {}),
        ("few_views_early_stop", "4 training views, early stopping (patience 2)", base,
         few_views, {"early_stopping": 2}),
        ("noisy", "images + N(0, 0.1) noise", base, noisy_views, {}),
        ("noisy_early_stop", "images + noise, early stopping (patience 2)", base, noisy_views,
         {"early_stopping": 2}),
    ]
    if shape:
        cases = [c for c in cases if c[0] in ("baseline", "lr_x100", "few_views", "noisy")]
    return cases


def _run_cases(report: BenchmarkReport, rows: list, train, test, base: NerfConfig, *,
               shape: str, budget: float, steps: int = 0) -> None:
    """Fit every case of :func:`_cases` on one dataset; add a MethodRun and a row for each.

    Each case runs ``budget`` solver seconds, or ``steps`` Adam steps when ``steps > 0`` (the
    same work whatever the machine's load)."""
    for name, label, cfg, (im, sil, cams), extra in _cases(train, base,
                                                           shape=shape != "cow"):  # cases
        print(f"stability case {shape}: {name} ...", flush=True)
        n_checks = 15 if "early_stopping" in extra else 5
        if steps > 0:
            cfg = NerfConfig(**{**asdict(cfg), "n_iter": int(steps)})
            limit = {"time_budget": None, "eval_every": max(int(steps) // n_checks, 1)}
        else:  # checkpoints every 1/20 of the time budget (fit_nerf's default)
            limit = {"time_budget": budget, "eval_every": None}
        res = fit_nerf(MultiViewDataset(images=im, silhouettes=sil, cameras=cams),
                       options=replace(cfg, **extra), evaluator=test, seed=0, progress=False,
                       **limit)
        finite = bool(np.all(np.isfinite(res.field.get_flat())) and
                      np.all(np.isfinite(res.images)))
        losses = np.asarray(res.history.loss)
        run = MethodRun(name if shape == "cow" else f"{shape}:{name}", label,
                        status=res.status, message=res.message,
                        final={"shape": shape, "psnr": res.psnr, "steps": res.n_iterations,
                               "finite_parameters_and_renders": finite,
                               "any_nan_in_history": bool(np.isnan(losses).any()),
                               "solver_seconds": res.seconds,
                               "budget": f"{steps} steps" if steps > 0 else f"{budget:g} s",
                               "load_average_end": load_average()})
        for c in res.history.checkpoints:
            run.add(c["seconds"], psnr=c["psnr"], held_out_loss=c["held_out_loss"])
        report.add(run)
        rows.append([shape, name, label, res.status, f"{res.psnr:.2f}", res.n_iterations,
                     "yes" if finite else "NO", res.message])
        print(f"  stability {shape}: {name}: {res.status}, PSNR {res.psnr:.2f} dB, finite "
              f"{finite}: {res.message}  (load {load_average()})", flush=True)


def stability(train, test, out: Path, args, *, budget: float, shape_budget: float) -> None:
    """Stress cases: each must end with a clear status and finite parameters, never NaN.

    They run on the cow (``budget`` solver seconds each) and on each test shape of
    ``args.shapes`` (:func:`geofit.tutorials.stability.shape_views`; ``shape_budget`` each).
    """
    quick = args.quick
    base = NerfConfig.scene()
    if quick:
        base = NerfConfig.scene(n_rays_per_image=128, n_pts_per_ray=64, hull_resolution=32)
    stem = "fit_nerf_stability_shapes" if args.shapes_only else "fit_nerf_stability"
    report = BenchmarkReport(stem, config={
        "budget_seconds": budget, "quick": quick, "shape_budget_seconds": shape_budget,
        "shape_steps": 2 if quick and args.shape_steps else args.shape_steps,
        "cow": None if train is None else {"views": len(train),
                                           "image_size": train.images.shape[1],
                                           "held_out_views": len(test)}, "shapes": {}})
    rows = []
    shape_steps = 2 if quick and args.shape_steps else args.shape_steps
    if budget > 0:
        _run_cases(report, rows, train, test, base, shape="cow", budget=budget)
    for name, data, cfg in shape_datasets(args):  # shapes
        report.config["shapes"][name] = cfg
        if data is not None:
            _run_cases(report, rows, data, data.held_out, base, shape=name,
                       budget=shape_budget, steps=shape_steps)
    shape_limit = (f"{shape_steps} Adam steps" if shape_steps > 0 else
                   f"{shape_budget:g} s solver budget")
    header = ["shape", "case", "setting", "status", "held-out PSNR dB", "steps", "finite",
              "message"]
    report.tables["stability"] = {"header": header, "rows": rows}
    report.notes += [
        f"each case: scene preset, seed 0; cow: {budget:g} s solver budget; test shapes "
        f"({', '.join(report.config['shapes']) or 'none'}): {shape_limit}, "
        "geofit.tutorials.stability.shape_views (normalised, coloured by position, black "
        "background, elevation 0; held-out views at elevations 0 and 20)",
        f"load average at the end: {load_average()} (per case: load_average_end); solver "
        "seconds under load are upper bounds and the budget-limited PSNRs lower bounds"]
    report.write(out / f"{stem}.json")
    cow = (f"the cow {budget:g} s solver budget (40 views, 16 held-out), " if budget > 0
           else "")
    md = ("# fit_nerf stability\n\n" + f"Each case: scene preset; {cow}the test shapes "
          f"{shape_limit} "
          f"({8 if quick else args.shape_views} views of "
          f"{32 if quick else args.shape_image_size} px, "
          f"{4 if quick else 8} held-out). Command: `" + report.command + "`.\n\n"
          + markdown_table(header, rows))
    (out / f"{stem}.md").write_text(md, encoding="utf-8")
    print(md, flush=True)


if __name__ == "__main__":
    sys.exit(main())
