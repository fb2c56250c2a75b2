"""Step 1, deform_source_mesh_to_target_mesh: :func:`geofit.fit.fit_mesh`, PyTorch3D's recipe
next to geofit's methods, and the stability cases."""
from __future__ import annotations

import time

import numpy as np

from ..data import load_target_mesh
from ..fit import CoarseToFine, fit_mesh
from ..metrics import MeshEvaluator
from ..viz import image_panel, plot_accuracy_vs_time, save_png
from .shared import (
    GEOFIT_COLUMN,
    P3D_COLUMN,
    StepResult,
    begin_step,
    fit_row,
    look_at_cameras,
    method_series,
    pick_size,
    progress_bar,
    recipe_cut,
    record_fit,
    settings_text,
    shade_mesh,
)
from .stability import fit_mesh_scenario, mesh_fit_arguments

__all__ = ["step_fit_mesh"]


# --------------------------------------------------------------------------------------------
# 1. fit a mesh to a mesh
# --------------------------------------------------------------------------------------------

_TUTORIAL_STEPS = 2000  # deform_source_mesh_to_target_mesh: Niter = 2000 SGD steps

_FIT_MESH_LABELS = {
    "tutorial": "PyTorch3D recipe: SGD lr 1, momentum 0.9, ico4, sampled chamfer",
    "scipy-lbfgs": "geofit: scipy L-BFGS-B, exact distances (ico4)",
    "large-steps": "geofit: large steps + L-BFGS (ico4)",
    "coarse-to-fine": "geofit: coarse-to-fine + large steps + L-BFGS",
}


#: recipe and MeshFitOptions fields of each run of tutorial 1 beside the default (large_steps 0:
#: the vertices directly); benchmarks/fit_mesh.py runs the same table.
FIT_MESH_RUNS = {
    "tutorial": {"recipe": "tutorial", "method": "sgd"},
    "adam": {"recipe": "sphere", "method": "adam", "lr": 0.01},
    "scipy-lbfgs": {"recipe": "sphere", "method": "lbfgs", "large_steps": 0.0},
    "nlopt-lbfgs": {"recipe": "sphere", "method": "lbfgs-nlopt", "large_steps": 0.0},
    "large-steps": {"recipe": "sphere", "method": "lbfgs", "large_steps": 10.0},
    "coarse-to-fine": {"recipe": "coarse-to-fine", "method": "lbfgs", "large_steps": 10.0},
}


def _fit_mesh_settings(name: str, size: str) -> dict:
    kw = dict(FIT_MESH_RUNS[name])
    stochastic = kw["method"] in ("sgd", "adam")
    if size == "full":
        kw["eval_every"] = 100 if stochastic else 10
        return kw
    if stochastic:
        kw.update(n_iter=pick_size(size, 20, 300, _TUTORIAL_STEPS),
                  eval_every=pick_size(size, 10, 50, 100))
        if size == "tiny":
            kw.update(n_samples=500)
    else:
        kw.update(n_iter=pick_size(size, 8, 30, 100), n_stages=pick_size(size, 1, 2, 3),
                  eval_every=pick_size(size, 4, 10, 10))
        if size == "tiny":
            kw.update(n_samples=500)
    if name == "coarse-to-fine":
        kw["refine"] = CoarseToFine(max_level=pick_size(size, 2, 4, 4),
                                            start_level=pick_size(size, 1, 2, 2))
        kw.pop("n_stages", None)
    elif size == "tiny":
        kw["init"] = 2
    return kw


def _fit_mesh_stability(target, methods, size: str, seed: int, progress: bool) -> list[dict]:
    """Each method on noisy / holed / NaN targets, a degenerate start and a 100x step (the
    scenarios of :mod:`geofit.tutorials.stability`, shared with benchmarks/fit_mesh.py)."""
    budget = pick_size(size, 0.5, 2.0, 20.0)
    n_metric = pick_size(size, 1000, 5000, 20000)
    cases = {
        "noisy target (sigma 1%)": "noise",
        "target with 4 holes": "holes",
        "NaN in the target": "nan_target",
        "degenerate start (every 7th edge collapsed)": "degenerate_start",
        "step 100x too large": "step_x100",
    }
    evaluator = MeshEvaluator(target, n_samples=n_metric, taus=0.01, normalize=True, seed=0)

    def measure(res):
        m = evaluator.evaluate(res.mesh)
        return {"chamfer-L2": m.chamfer_l2, "F@0.01": m.fscore[0.01],
                "NaN vertices": bool(np.isnan(res.mesh.verts).any()),
                "seconds": round(res.seconds, 2)}

    rows = []
    bar = progress_bar(progress, len(cases) * len(methods), "fit_mesh stability")
    for name in methods:  # methods
        for case, mode in cases.items():  # failure cases
            kw = _fit_mesh_settings(name, size)
            kw.pop("eval_every", None)
            source = kw.pop("init", None)
            if kw["method"] in ("sgd", "adam"):
                kw["n_iter"] = min(kw["n_iter"], pick_size(size, 10, 100, 500))
            sc = fit_mesh_scenario(mode, target, kw, source_level=source, seed=seed + 7)
            args = mesh_fit_arguments(sc.kwargs, sc.source if sc.source is not None else source)
            rows.append(fit_row(name, case, lambda: fit_mesh(
                sc.target, evaluator=None, progress=False, time_budget=budget, seed=seed,
                **args), measure))
            bar.update(1)
    bar.close()
    return rows


def step_fit_mesh(out, size: str = "default", *, progress: bool = True, seed: int = 0
                  ) -> StepResult:
    """Deform an ico-sphere into the target mesh: the tutorial's SGD recipe and geofit's solvers.

    Sizes: ``"full"``: :data:`geofit.fit.RECIPES` as they are (SGD 2000 steps, L-BFGS 3 stages
    of 100 iterations); ``"default"``: SGD 300 steps, L-BFGS 2 stages of 30 iterations.
    Progress: tqdm progress bars; seed: sampling seed. Writes into ``out/fit_mesh``; the
    signature and the StepResult are :func:`run_step`'s.
    """
    res, d, t0 = begin_step(out, "fit_mesh", size)
    data = load_target_mesh()
    target = data.mesh
    n_metric = pick_size(size, 2000, 10_000, 100_000)
    evaluator = MeshEvaluator(target, n_samples=n_metric, taus=0.01, normalize=True, seed=0)
    names = ["tutorial", "scipy-lbfgs", "large-steps", "coarse-to-fine"]
    if size == "tiny":
        names = ["tutorial", "large-steps"]
    res.config = {"target": data.name, "target vertices": target.n_verts,
                  "metric samples a side": n_metric}
    res.description = (
        f"An ico-sphere is deformed into the {data.name} (normalised as in the tutorial). "
        "Accuracy: chamfer-L2 (sum of the two mean squared exact point-to-surface distances) and "
        "F-score at 0.01 in the target's normalised frame (geofit.metrics), on seeded samples. "
        "Times are the solvers' own (the clock is paused while the accuracy is measured).")
    results = {}
    for name in names:  # methods
        kw = _fit_mesh_settings(name, size)
        every = kw.pop("eval_every", None)
        fit = fit_mesh(target, evaluator=evaluator, progress=progress, seed=seed,
                       eval_every=every, **mesh_fit_arguments(kw))
        results[name] = fit
        m = fit.metrics
        final = {"seconds": fit.seconds, "n_verts": fit.n_verts, "n_params": fit.n_params,
                 "chamfer_l2": m.chamfer_l2, "fscore@0.01": m.fscore[0.01],
                 "normal_consistency": m.normal_consistency}
        res.files[f"{name} mesh"] = d / f"{name}.obj"
        fit.save_obj(res.files[f"{name} mesh"])
        record_fit(res, d, name, _FIT_MESH_LABELS[name], fit, ("chamfer_l2", "fscore@0.01"),
                    final=final, config={k: repr(v) if not isinstance(v, (int, float, str))
                                         else v for k, v in kw.items()})
        cut = recipe_cut(fit.n_iterations, _TUTORIAL_STEPS) if name == "tutorial" else ""
        res.metrics.append({"method": _FIT_MESH_LABELS[name] + cut, "status": fit.status,
                            "seconds": round(fit.seconds, 2), "iterations": fit.n_iterations,
                            "chamfer-L2": m.chamfer_l2, "F@0.01": m.fscore[0.01],
                            "normal consistency": m.normal_consistency})
        res.param_counts.append({"method": _FIT_MESH_LABELS[name], "vertices": fit.n_verts,
                                 "free parameters": fit.n_params})
    res.config.update({f"{n} settings": settings_text(res.methods[i]["config"])
                       for i, n in enumerate(names)})

    # images: the target and every result from two views, in the normalised frame
    norm = target.normalize()
    cams = look_at_cameras(2.1, [15.0, 15.0], [40.0, 140.0])
    img_size = pick_size(size, 96, 256, 256)
    shots = {"target": shade_mesh(norm.mesh, cams, img_size)}
    for name, fit in results.items():
        verts = (fit.mesh.verts - norm.center) / norm.scale  # the target's normalised frame
        shots[name] = shade_mesh(fit.mesh.update_verts(verts), cams, img_size)
    for k, imgs in shots.items():
        dest = res.targets if k == "target" else res.images
        dest[k] = save_png(np.concatenate(list(imgs), axis=1), d / f"{k}.png")
    cols = ["target"] + [f"{n}\n{results[n].n_verts} verts, {results[n].seconds:.1f} s"
                         for n in results]
    res.comparison = image_panel([[shots[k][v] for k in shots] for v in range(2)],
                                 d / "comparison.png", col_labels=cols,
                                 row_labels=["view 1", "view 2"])
    res.comparison_caption = (f"Target ({data.name}) and the fitted meshes, two views; solver "
                              "seconds and vertex counts above each column.")
    best = min(results, key=lambda n: results[n].metrics.chamfer_l2)
    pt = results["tutorial"]
    res.charts["Speed and accuracy: chamfer-L2 and F-score against solver time"] = \
        plot_accuracy_vs_time(
            method_series(res.methods),
            [{"metric": "chamfer_l2", "label": "chamfer-L2 (normalised frame, log)",
              "logy": True, "target": pt.metrics.chamfer_l2,
              "target_label": "PyTorch3D recipe's final accuracy"},
             {"metric": "fscore@0.01", "label": "F-score @ 0.01", "logy": False,
              "target": pt.metrics.fscore[0.01]}],
            d / "speed_accuracy.png",
            title=f"fit_mesh on the {data.name} ({size} size)")
    res.stability = _fit_mesh_stability(target, ["tutorial", "large-steps"], size, seed,
                                        progress)
    res.headline = {
        P3D_COLUMN: f"chamfer-L2 {pt.metrics.chamfer_l2:.3g}, F {pt.metrics.fscore[0.01]:.3f} in "
              f"{pt.seconds:.1f} s, {pt.n_params:,} params"
              + recipe_cut(pt.n_iterations, _TUTORIAL_STEPS),
        GEOFIT_COLUMN: f"{best}: chamfer-L2 {results[best].metrics.chamfer_l2:.3g}, "
             f"F {results[best].metrics.fscore[0.01]:.3f} in "
             f"{results[best].seconds:.1f} s, {results[best].n_params:,} params",
    }
    if data.path is None:
        res.notes.append("The tutorial's dolphin was not found (set GEOFIT_DATA): the target is "
                         "geofit's procedural stand-in.")
    res.seconds = time.perf_counter() - t0
    return res
